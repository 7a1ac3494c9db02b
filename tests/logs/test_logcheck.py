"""Physical plausibility of flight logs (mjxsysid.logs.checks): logs flown here by the shipped
policy, written as CSV, then spoiled by the common mistakes; every mistake must end in exit 2 or
a warning naming it, and correct logs of prior vehicles must raise nothing."""
import json
import re

import jax
import numpy as np
import pytest

import mjxsysid
from mjxsysid import theta as P
from mjxsysid.cli import main
from mjxsysid.logs import checks as L
from mjxsysid.logs.checks.plausibility import check_gyro
from mjxsysid.logs.checks.rotors import check_motors
from mjxsysid.logs.checks.signals import lagged
from mjxsysid.logs.csvlog import read_log, write_log
from mjxsysid.policy.adaptive.controller import PolicyController
from mjxsysid.policy.interface import PRETRAINED_DIR, resolve_policy
from mjxsysid.rollout.flight import fly_vehicles, one_flight, seen_imu
from support.paths import ROOT

pytestmark = pytest.mark.skipif(not (PRETRAINED_DIR / "cfm.npz").exists(), reason="no shipped decoder")



def _recs(theta, seconds=2.0):
    """Flights of the shipped policy (2 s of a 10 s lemniscate: the shape test_decode's flight
    compiled) -> logs as read_log returns them, and the IMU read after each step."""
    fl, m, _ = fly_vehicles(theta, controller="policy", policy=resolve_policy("mjxsysid"), reference="lemniscate",
                            duration=seconds)
    out = []
    for i in range(len(P.as_batch(theta))):
        f = one_flight(fl, i)
        out.append(({"t": f.time - L.DT, "imu": seen_imu(f.frame.imu).astype(np.float64), "a_cmd": f.a_cmd,
                     "omega_cmd": f.omega_cmd, "motor": f.frame.motor_cmd}, np.asarray(f.frame.imu)))
    return out, np.asarray(m["failed"], bool)


@pytest.fixture(scope="module")
def paper_log():
    (rec, after), = _recs(P.PAPER_HARDWARE)[0]
    return rec, after


@pytest.fixture(scope="module")
def policy():
    return PolicyController.load()


def _all_checks(rec, pol):
    found = L.check_log(rec, policy=pol, zhat=pol.replay(rec["imu"], rec["a_cmd"], rec["omega_cmd"], rec["motor"]))
    return found + (L.prior_check(rec) if not any(f.level == "error" for f in found) else [])


def test_correct_logs_of_prior_vehicles_raise_nothing(paper_log, policy):
    theta = np.asarray(P.WIDE_ACTUATOR_PRIOR.sample(jax.random.PRNGKey(7), 12))
    recs, failed = _recs(theta)
    found = [(i, str(f)) for i, (r, _) in enumerate([paper_log] + recs) for f in _all_checks(r, policy)]
    assert not found, found
    assert failed.sum() <= 1


# mistake -> (level, text the finding must contain)
EXPECTED = {
    "acc_in_g": ("error", "looks like g, not m/s²"),
    "gyro_in_deg_s": ("error", "looks like deg/s"),
    "rotorpy_order": ("error", "RotorPy"),
    "px4_order": ("error", "PX4"),
    "omega_cmd_other": ("warning", "omega_cmd"),
    "frd_frame": ("error", "FRD"),
    "imu_after_step": ("warning", "motor commands"),
}


@pytest.mark.parametrize("kind", sorted(EXPECTED))
def test_each_mistake_is_named(paper_log, policy, kind):
    rec, after = paper_log
    found = _all_checks(L.make_mistake(rec, kind, imu_after=after), policy)
    level, text = EXPECTED[kind]
    assert found and found[0].level == level, found
    assert text in str(found[0]), found[0]


def test_rotor_order_names_the_permutation(paper_log):
    rec, _ = paper_log
    fit = L.rotor_order_fit(L.make_mistake(rec, "rotorpy_order"))
    assert fit["best"] == L.KNOWN_ORDERS[next(n for n in L.KNOWN_ORDERS if n.startswith("RotorPy"))]
    assert L.rotor_order_fit(rec)["best"] == (0, 1, 2, 3)
    # the reorder advice, applied, gives back the correct log
    msg = str(L.check_log(L.make_mistake(rec, "rotorpy_order"))[0])
    cols = [int(c) - 1 for c in re.findall(r"motor_\d = column (\d)", msg)]
    np.testing.assert_array_equal(L.make_mistake(rec, "rotorpy_order")["motor"][:, cols], rec["motor"])


def test_gyro_rate_tracking_gain(paper_log):
    # Below the full-scale limit (a gentle flight in deg/s) the tracking gain still says deg/s.
    rec, _ = paper_log
    slow = dict(rec, imu=rec["imu"].copy(), omega_cmd=rec["omega_cmd"] * 0.1)
    slow["imu"][:, :3] = np.rad2deg(rec["imu"][:, :3] * 0.1)
    found = check_gyro(slow)
    assert found and "deg/s" in str(found[0]) and "gain" in str(found[0])
    assert not check_gyro(rec)


@pytest.mark.parametrize("kind,text", [("time_in_ms", "milliseconds"), ("motor_pwm", "PWM")])
def test_read_log_names_units(paper_log, tmp_path, kind, text):
    rec, _ = paper_log
    bad = L.make_mistake(rec, kind)
    path = write_log(tmp_path / f"{kind}.csv", bad["t"], bad["imu"], bad["a_cmd"], bad["omega_cmd"], bad["motor"])
    with pytest.raises(ValueError, match=text) as e:
        read_log(path)
    assert "resample" not in str(e.value)


def test_cli_exit_2_before_decoding(paper_log, tmp_path, capsys):
    rec, _ = paper_log
    bad = L.make_mistake(rec, "acc_in_g")
    path = write_log(tmp_path / "g.csv", bad["t"], bad["imu"], bad["a_cmd"], bad["omega_cmd"], bad["motor"])
    assert main(["decode", "--log", str(path), "--out", str(tmp_path / "d"), "-q"]) == 2
    err = capsys.readouterr().err
    assert "acc_x, acc_y, acc_z" in err and "multiply acc_x/y/z by 9.81" in err
    assert not (tmp_path / "d").exists()          # no empty output folder left by a decode that stopped


@pytest.fixture(scope="module")
def fast_heavy_log():
    """A vehicle outside the prior (thrust-to-weight 11, RotorPy's hummingbird is 10.2), flown by the policy."""
    th = P.PAPER_HARDWARE.copy()
    th[P.OMEGA_MAX] *= np.sqrt(11.0 / float(P.thrust_to_weight(th)))
    (rec, _), = _recs(th)[0]
    return rec


def test_out_of_prior_and_warnings_reach_every_output_under_quiet(fast_heavy_log, tmp_path, capsys):
    rec = L.make_mistake(fast_heavy_log, "omega_cmd_other")
    est = L.estimate_vehicle(fast_heavy_log)
    assert 8.5 < est["thrust_to_weight"] < 13
    path = write_log(tmp_path / "oop.csv", rec["t"], rec["imu"], rec["a_cmd"], rec["omega_cmd"], rec["motor"])
    out = tmp_path / "d"
    assert main(["decode", "--log", str(path), "--samples", "8", "--window", "instant", "--decoder-only", "--out", str(out), "-q"]) == 0
    cap = capsys.readouterr()
    assert "out of prior: " in cap.err and "thrust-to-weight" in cap.err and "warning: a_cmd, omega_cmd" in cap.err
    assert cap.err.index("out of prior") < len(cap.err) and "thrust_to_weight" in cap.out   # numbers after
    s = json.loads((out / "summary.json").read_text())
    assert s["_checks"]["is_out_of_prior"] and s["_checks"]["warnings"]
    md = (out / "summary.md").read_text()
    assert md.index("Out of the decoders' training prior") < md.index("| thrust_to_weight")
    # the Python API: the same findings
    kinds = {f.level for f in mjxsysid.check_log(path)}
    assert kinds == {"warning", "out_of_prior"}


def test_the_decode_of_a_correct_log_reports_no_finding(paper_log, tmp_path):
    rec, _ = paper_log
    path = write_log(tmp_path / "ok.csv", rec["t"], rec["imu"], rec["a_cmd"], rec["omega_cmd"], rec["motor"])
    assert mjxsysid.check_log(path) == []


def test_docs_conversion_example_runs(paper_log, tmp_path, monkeypatch):
    """The worked example of docs/decoding.md ('Converting autopilot outputs') turns a PX4-style
    log (PWM, FRD, PX4 rotor order, time in µs) of a flown flight back into a correct log."""
    text = (ROOT / "docs" / "decoding.md").read_text()
    code = text.split("<!-- conversion example -->", 1)[1].split("```python", 1)[1].split("```", 1)[0]
    rec, _ = paper_log
    px4 = L.make_mistake(L.make_mistake(L.make_mistake(rec, "px4_order"), "frd_frame"), "motor_pwm")
    # throttle-linear ESC: the autopilot wrote pwm = 1000 + 1000 * throttle with throttle = u²
    px4["motor"] = 1000.0 + 1000.0 * np.asarray(rec["motor"])[:, list(L.KNOWN_ORDERS[next(
        n for n in L.KNOWN_ORDERS if n.startswith("PX4"))])] ** 2
    px4["t"] = np.round(rec["t"] * 1e6)
    monkeypatch.chdir(tmp_path)
    ns = {"px4": px4}
    exec(compile(code, "docs/decoding.md", "exec"), ns)
    out = read_log(tmp_path / "converted.csv")
    np.testing.assert_allclose(out["motor"], rec["motor"], atol=1e-5)
    np.testing.assert_allclose(out["imu"], rec["imu"], atol=1e-4)
    assert L.check_log(out) == []


def _with_white_noise(rec, gyro, accel, seed=0):
    r = {k: np.array(v, copy=True) for k, v in rec.items()}
    r["imu"] = r["imu"] + np.random.default_rng(seed).normal(size=r["imu"].shape) * np.array([gyro] * 3 + [accel] * 3)
    return r


def test_imu_noise_estimate_against_injected_levels(paper_log):
    """White noise added to a clean flown log at known levels, from none to 20× the hardware-like
    one: the estimate is within 10 % of the injected std once the noise dominates the clean
    floor, a per-flight bias leaves it unchanged, and the warning comes past the limit (× 1.5), not
    at × 1 (which decodes as clean flights do: docs/noise.md)."""
    rec, _ = paper_log
    floor = L.estimate_imu_noise(rec)
    lim = L.IMU_NOISE_LIMIT
    assert floor["gyro_noise"] < 0.2 * lim["gyro_noise"] and floor["accel_noise"] < 0.2 * lim["accel_noise"], floor
    assert L.check_imu_noise(rec) == []
    for mult in (0.5, 1.0, 2.0, 5.0, 20.0):
        g, a = 0.01 * mult, 0.1 * mult
        noisy = _with_white_noise(rec, g, a, seed=int(mult * 10))
        est = L.estimate_imu_noise(noisy)
        np.testing.assert_allclose([est["gyro_noise"], est["accel_noise"]], [g, a], rtol=0.1)
        biased = {**noisy, "imu": noisy["imu"] + np.array([0.025, -0.025, 0.025, 0.25, -0.25, 0.25])}
        assert L.estimate_imu_noise(biased) == pytest.approx(est, rel=1e-6)
        found = L.check_imu_noise(noisy)
        if mult <= 1.0:
            assert found == [], (mult, found)
        elif mult >= 2.0:
            assert len(found) == 1 and found[0].level == "warning" and "IMU noise" in found[0].message, (mult, found)


def test_imu_noise_limit_follows_the_decoders_training(paper_log):
    """The warning's limit is what the decoders' training pairs flew (their provenance): the
    shipped decoders (pairs without IMU metadata, or a clean IMU) keep IMU_NOISE_LIMIT; decoders
    trained on a randomised IMU up to gyro 0.05 / accelerometer 0.5 (white or vibration) raise it
    there, so a × 3 log no longer warns; with several decoders the strictest limit holds."""
    from types import SimpleNamespace as NS
    lim = L.IMU_NOISE_LIMIT

    def dec(imu):
        return NS(meta={"data": {"pairs_meta": {} if imu is None else {"imu": imu}}})

    clean = {"gyro_noise": 0.0, "accel_noise": 0.0, "gyro_vibration": 0.0, "accel_vibration": 0.0}
    noisy = {"gyro_noise": 0.05, "accel_noise": 0.2, "gyro_vibration": 0.01, "accel_vibration": 0.5,
             "randomize_imu": True}
    assert L.imu_noise_limit() == lim and L.imu_noise_limit(None, dec(None)) == lim
    assert L.imu_noise_limit(dec(clean)) == lim
    assert L.imu_noise_limit(dec(noisy)) == {"gyro_noise": 0.05, "accel_noise": 0.5}
    assert L.imu_noise_limit(dec(noisy), dec(clean)) == lim
    rec = _with_white_noise(paper_log[0], 0.03, 0.3, seed=3)
    assert [f.level for f in L.check_log(rec)].count("warning") >= 1
    assert not [f for f in L.check_log(rec, imu_limit=L.imu_noise_limit(dec(noisy))) if "IMU noise" in f.message]


def test_imu_noise_warning_reaches_every_output(paper_log, tmp_path, capsys):
    """× 5 the hardware-like white noise added to a correct log: `decode --log -q` says it on
    stderr, in summary.json (_checks.warnings and the estimates) and in summary.md. (Added after
    the flight, the noise is not what the policy read: the replay check says so too.)"""
    rec = _with_white_noise(paper_log[0], 0.05, 0.5)
    path = write_log(tmp_path / "noisy.csv", rec["t"], rec["imu"], rec["a_cmd"], rec["omega_cmd"], rec["motor"])
    kinds = [f for f in mjxsysid.check_log(path)]
    assert [f.column for f in kinds] == ["gyro_x/y/z, acc_x/y/z", "a_cmd, omega_cmd_x/y/z"], kinds
    out = tmp_path / "d"
    assert main(["decode", "--log", str(path), "--samples", "8", "--window", "instant", "--decoder-only", "--out", str(out), "-q"]) == 0
    err = capsys.readouterr().err
    assert "warning: gyro_x/y/z, acc_x/y/z: IMU noise about" in err
    s = json.loads((out / "summary.json").read_text())
    assert any("IMU noise" in w for w in s["_checks"]["warnings"])
    assert s["_checks"]["estimates"]["gyro_noise"] == pytest.approx(0.05, rel=0.1)
    assert "IMU noise about" in (out / "summary.md").read_text()


@pytest.mark.slow
def test_imu_noise_estimate_in_closed_loop():
    """The same estimate on flights whose policy flew through the noise (the simulator's IMU):
    × 5 white noise with a bias (read to 10 %) and × 5 rotor vibration (warned)."""
    from mjxsysid.sim import Quadrotor, SimConfig
    theta = np.asarray(P.WIDE_ACTUATOR_PRIOR.sample(jax.random.PRNGKey(3), 4))
    for cfg, check in ((dict(gyro_noise=0.05, accel_noise=0.5, gyro_bias=0.025, accel_bias=0.25), "value"),
                       (dict(gyro_vibration=0.05, accel_vibration=0.5), "warned")):
        fl, m, _ = fly_vehicles(theta, controller="policy", policy=resolve_policy("mjxsysid"), reference="lemniscate",
                                duration=2.0, sim=Quadrotor(SimConfig(**cfg)))
        for i in np.flatnonzero(~np.asarray(m["failed"], bool)):
            f = one_flight(fl, i)
            rec = {"t": f.time - L.DT, "imu": seen_imu(f.frame.imu).astype(np.float64), "a_cmd": f.a_cmd,
                   "omega_cmd": f.omega_cmd, "motor": f.frame.motor_cmd}
            est = L.estimate_imu_noise(rec)
            if check == "value":
                np.testing.assert_allclose([est["gyro_noise"], est["accel_noise"]], [0.05, 0.5], rtol=0.1)
            assert L.check_imu_noise(rec), (cfg, est)


# ---------------------------------------------------------------- issue 39: the holes a real log found
def test_check_log_cli_exit_0_on_a_correct_log(paper_log, tmp_path, capsys):
    rec, _ = paper_log
    path = write_log(tmp_path / "ok.csv", rec["t"], rec["imu"], rec["a_cmd"], rec["omega_cmd"], rec["motor"])
    assert main(["check-log", str(path)]) == 0
    assert "no findings" in capsys.readouterr().out


def test_motor_columns_that_explain_nothing_are_named(paper_log):
    """`_check_motors`' 'no rotor order explains the rates' could never fire (it needed the best
    score both > 0.2 and < 0.2): motor columns shuffled in time on a flight that moves."""
    rec, _ = paper_log
    shuffled = dict(rec, motor=rec["motor"][np.random.default_rng(0).permutation(len(rec["motor"]))])
    found = check_motors(shuffled)
    assert found and "do not explain the angular acceleration under any rotor order" in found[0].message


def test_throttle_columns_are_named(paper_log):
    """Throttle left as the motor columns (thrust linear in them: u², not u = Ω_cmd/Ω_max)."""
    rec, _ = paper_log
    u = np.asarray(rec["motor"])
    found = [f for f in L.check_log(dict(rec, motor=(u / u.max()) ** 2)) if "throttles" in f.message]
    assert found and found[0].level == "warning" and "√throttle" in found[0].message
    assert not [f for f in L.check_log(rec) if "throttles" in f.message]


def test_a_cmd_is_compared_with_the_specific_force(paper_log):
    rec, _ = paper_log
    normalised = dict(rec, a_cmd=rec["a_cmd"] / P.GRAVITY * 0.5)     # PX4's thrust setpoint, hover 0.5
    found = L.check_log(normalised)
    assert found[0].level == "error" and found[0].column == "a_cmd" and "[0, 1]" in found[0].message
    found = L.check_log(dict(rec, a_cmd=rec["a_cmd"] * 3))
    assert [f.column for f in found] == ["a_cmd"] and found[0].level == "warning"


def test_no_thrust_is_an_error(paper_log):
    rec, _ = paper_log
    idle = dict(rec, motor=np.full_like(rec["motor"], 0.01))
    found = L.check_log(idle)
    assert found[0].level == "error" and "stopped or idling" in found[0].message
    weak = dict(rec, motor=rec["motor"] * 0.15)      # Σu² far too small for the specific force
    found = L.check_log(weak)
    assert found[0].level == "error" and "not supported by the motor commands" in found[0].message


def test_tau_from_the_specific_force_when_the_torque_fit_fails(paper_log):
    """τ_m of 5 ms (below the prior's 20–100 ms) in a log whose torque fit fails (here the
    gyro flat): read from the lag of the specific force behind Σ ū² and flagged; with nothing to
    fit, summary's _checks says τ was not estimable."""
    from mjxsysid.decoding import checks_summary
    rec, _ = paper_log
    u = np.asarray(rec["motor"], np.float64)
    s2 = (lagged(u, 0.005) ** 2).sum(1)
    imu = np.array(rec["imu"], np.float64)
    imu[:, 5] = s2 * (9.75 / s2.mean())
    imu[:, :3] = 0.0
    r = dict(rec, imu=imu)
    est = L.estimate_vehicle(r)
    assert est["torque_fit_r2"] < 0.5 and est["motor_time_constant_thrust"] == pytest.approx(0.005)
    tau = [f for f in L.prior_check(r, est=est) if "motor time constant" in f.message]
    assert tau and "5 ms" in tau[0].message and "specific force" in tau[0].message
    flat = dict(rec, imu=np.column_stack([np.zeros((len(u), 5)), np.full(len(u), 9.75)]))
    # a constant IMU reads as held from a very low rate: its noise is read from the column as logged (0), not NaN
    assert L.estimate_imu_noise(flat)["gyro_noise"] == 0.0
    s = checks_summary({"estimates": L.estimate_vehicle(flat), "findings": []})
    assert not s["motor_time_constant_estimable"] and "not estimable" in s["notes"][0]
