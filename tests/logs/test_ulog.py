"""PX4 ULog logs (mjxsysid.logs.ulog, `mjxsysid check-log`, issues 39 and 55): ULogs the project
writes itself (mjxsysid.logs.ulog_write, a numpy flight of known thrust-to-weight, rotor order and
rates) read back through every conversion; where ../shared is present, PX4's sample
(../shared/data/ulog/sample_px4_events.ulg: jMAVSim's Iris, thrust-to-weight 2.04, IMU 250 Hz,
motors 10 Hz) and an old never-armed log; the conversions' pieces, and the checks that must not
read resampled columns as if they were 500 Hz. numpy only: no JAX compile."""
import sys

import numpy as np
import pytest

pytest.importorskip("pyulog")

from mjxsysid.cli import main
from mjxsysid.logs import checks as L
from mjxsysid.logs import ulog as U
from mjxsysid.logs.csvlog import read_any_log, read_log, write_log
from mjxsysid.logs.ulog_write import write_ulog
from support.paths import PX4_SAMPLE, SHARED_DATA
from support.synthetic_log import synthetic_flight

SAMPLE = PX4_SAMPLE
BENCH = SHARED_DATA / "logs" / "px4" / "real_bench_disarmed.ulg"
needs_sample = pytest.mark.skipif(not SAMPLE.is_file(), reason=f"PX4's sample log not found at {SAMPLE}")
PX4_DEFAULT_RATES = {"imu": 250, "motor": 10, "setpoint": 50}
TWR = 2.04


@pytest.fixture(scope="module")
def flight():
    """A numpy flight: 3 s on the ground, 10 s airborne, 2 s on the ground."""
    return synthetic_flight(seconds=10.0, ground_s=(3.0, 2.0), twr=TWR, tau=0.03)


def _write(path, r, **kw):
    on = r["motor"].max(1) > 0
    return write_ulog(path, r["t"], r["imu"], r["a_cmd"], r["omega_cmd"], r["motor"], armed=on, landed=~on, **kw)


@pytest.fixture(scope="module")
def written(flight, tmp_path_factory):
    """The flight as a PX4 ULog at PX4's default logging rates (IMU 250 Hz, motors 10 Hz, setpoints 50 Hz)."""
    return _write(tmp_path_factory.mktemp("ulog") / "flight.ulg", flight, rates=PX4_DEFAULT_RATES)


@pytest.fixture(scope="module")
def sample(written):
    return U.read_ulog(written)


def test_written_ulog_reads_back_every_conversion(flight, tmp_path):
    """Every topic at 500 Hz: read_ulog undoes the writer's FRD frame, PX4 motor order, Ω² thrust
    and a_cmd · hover / g exactly (to float32), and cuts the armed, airborne segment; detected by
    content under a wrong suffix."""
    path = _write(tmp_path / "flight.txt", flight)
    r = read_any_log(path)
    assert r["source"]["format"] == "PX4 ULog"
    seg = r["source"]["segment"]
    assert seg["t0"] == pytest.approx(3.0, abs=0.003) and seg["t1"] == pytest.approx(12.998, abs=0.003)
    keep = (flight["t"] >= r["t"][0] - 1e-9) & (flight["t"] <= r["t"][-1] + 1e-9)
    assert keep.sum() == len(r["t"])
    for k, tol in (("imu", 1e-5), ("motor", 1e-6), ("a_cmd", 1e-5), ("omega_cmd", 1e-6)):
        np.testing.assert_allclose(r[k], flight[k][keep], atol=tol, rtol=1e-6, err_msg=k)
    assert r["source"]["rates_hz"]["imu"] == pytest.approx(500) and r["resampled"]["motor"] == "native (500 Hz)"
    assert L.estimate_vehicle(r)["thrust_to_weight"] == pytest.approx(TWR, rel=0.02)
    assert L.rotor_order_fit(r)["best"] == (0, 1, 2, 3) and L.check_log(r) == []


def test_written_at_px4_rates_reads_as_the_log_contract(sample):
    r = sample
    n = len(r["t"])
    assert r["imu"].shape == (n, 6) and r["motor"].shape == (n, 4) and r["omega_cmd"].shape == (n, 3)
    assert r["a_cmd"].shape == (n,) and np.allclose(np.diff(r["t"]), 0.002)
    seg = r["source"]["segment"]
    assert 2.99 < seg["t0"] < 3.01 and 12.9 < seg["t1"] < 13.0 and "airborne" in seg["why"]
    assert r["source"]["rates_hz"]["imu"] == pytest.approx(250, rel=0.02)
    assert r["source"]["rates_hz"]["motor"] == pytest.approx(10, rel=0.02)
    assert r["resampled"] == {"imu": "interpolated (linear) from 250 Hz", "motor": "held (zero-order) from 10 Hz",
                              "omega_cmd": "held (zero-order) from 50 Hz", "a_cmd": "held (zero-order) from 50 Hz"}
    conv = " ".join(r["source"]["conversions"])
    assert "FRD" in conv and "√control" in conv and "front-right, back-left, front-left, back-right" in conv
    assert set(r["native"]) == {"imu", "motor", "omega_cmd", "a_cmd"}
    tn, xn = r["native"]["motor"]
    assert xn.shape[1] == 4 and tn[0] <= r["t"][0] and tn[-1] >= r["t"][-1]
    # FLU: +g on z at hover, motors in [0, 1], a_cmd about g in flight
    assert 9.0 < r["imu"][:, 5].mean() < 10.5 and 0.3 < r["motor"].min() and r["motor"].max() <= 1
    assert r["a_cmd"].mean() == pytest.approx(r["imu"][:, 5].mean(), rel=0.05)


@needs_sample
def test_px4_sample_reads_as_the_log_contract():
    r = U.read_ulog(SAMPLE)
    seg = r["source"]["segment"]
    assert 18.9 < seg["t0"] < 19.0 and 27.3 < seg["t1"] < 27.5 and "airborne" in seg["why"]   # ~8.5 s in flight
    assert r["resampled"] == {"imu": "interpolated (linear) from 250 Hz", "motor": "held (zero-order) from 10 Hz",
                              "omega_cmd": "held (zero-order) from 50 Hz", "a_cmd": "held (zero-order) from 50 Hz",
                              "velocity_body": "interpolated (linear) from 10 Hz"}
    assert 9.0 < r["imu"][:, 5].mean() < 10.5


@needs_sample
def test_sample_thrust_to_weight_is_jmavsims():
    """jMAVSim's Iris: 4 × 4 N, 0.8 kg: thrust-to-weight 2.04, with √control; about twice that
    with the throttle read as the rotor-speed command (what the issue found by hand: 4.23)."""
    sample = U.read_ulog(SAMPLE)
    assert L.estimate_vehicle(sample)["thrust_to_weight"] == pytest.approx(2.04, rel=0.06)
    wrong = {k: sample[k] for k in ("t", "imu", "a_cmd", "omega_cmd")}
    wrong["motor"] = sample["motor"] ** 2
    assert L.estimate_vehicle(wrong)["thrust_to_weight"] > 4.0


def test_sample_checks_say_what_the_rates_allow(sample):
    found = L.check_log(sample)
    assert [f.level for f in found] == ["warning"], found
    assert "cannot tell the rotor order at this motor rate (10 Hz)" in found[0].message
    est = L.estimate_vehicle(sample)
    assert est["imu_rate_hz"] == pytest.approx(250, rel=0.02) and est["gyro_noise"] > 1e-4   # native samples, not ~1e-14
    tau, why = L.motor_time_constant(est)
    assert tau is None and "10 Hz" in why


def test_segment_and_read_any_log(sample, written, tmp_path):
    r = U.read_ulog(written, "5:9")
    assert r["t"][0] == pytest.approx(5.0, abs=0.005) and r["t"][-1] == pytest.approx(9.0, abs=0.005)
    assert "--segment" in r["source"]["segment"]["why"]
    assert read_any_log(written, (5.0, 9.0))["t"].shape == r["t"].shape
    with pytest.raises(ValueError, match="end must come after"):
        U.read_ulog(written, "9:5")
    path = write_log(tmp_path / "x.csv", sample["t"], sample["imu"], sample["a_cmd"], sample["omega_cmd"], sample["motor"])
    part = read_any_log(path, "5:7")
    assert part["t"][0] >= 5 and part["t"][-1] <= 7 and len(part["t"]) == pytest.approx(1000, abs=2)
    assert part["source"]["segment"]["why"].startswith("--segment")


def test_resampled_csv_is_detected_and_checks_read_its_knots(sample, tmp_path):
    """The sample written as a CSV (what a user's hand conversion gives): read back with no
    declared rates, the interpolated IMU and the held motors are named, the noise is read at the
    knots (as from the native samples), the rotor order not fitted at 10 Hz."""
    path = write_log(tmp_path / "px4.csv", sample["t"], sample["imu"], sample["a_cmd"], sample["omega_cmd"],
                     sample["motor"])
    rec = read_log(path)
    found = L.check_log(rec)
    text = " | ".join(str(f) for f in found)
    assert "look interpolated (linear) from about 250 Hz" in text or "look interpolated (linear) from about 249" in text
    assert "held (zero-order) from about 10" in text and "cannot tell the rotor order" in text
    assert all(f.level == "warning" for f in found)
    est, native = L.estimate_imu_noise(rec), L.estimate_imu_noise(sample)
    assert est["gyro_noise"] == pytest.approx(native["gyro_noise"], rel=0.3)
    assert est["accel_noise"] == pytest.approx(native["accel_noise"], rel=0.3)


def test_write_log_keeps_boot_time_digits(sample, tmp_path):
    t = 12345.678 + 0.002 * np.arange(len(sample["t"]))
    path = write_log(tmp_path / "boot.csv", t, sample["imu"], sample["a_cmd"], sample["omega_cmd"], sample["motor"])
    np.testing.assert_allclose(read_log(path)["t"], t, rtol=0, atol=1e-9)


def test_airframe_and_rotor_order_from_parameters():
    for bad, text in (({"MAV_TYPE": 13}, "hexarotor"), ({"CA_ROTOR_COUNT": 6}, "four rotors"),
                      ({"CA_AIRFRAME": 1}, "not a multirotor")):
        with pytest.raises(ValueError, match=text):
            U.check_airframe(bad)
    assert U.check_airframe({"MAV_TYPE": 2, "CA_ROTOR_COUNT": 4, "CA_AIRFRAME": 0})
    assert U.rotor_order_from_params({})[0] == L.KNOWN_ORDERS[next(n for n in L.KNOWN_ORDERS if n.startswith("PX4"))]
    geo = {"CA_ROTOR0_PX": 0.15, "CA_ROTOR0_PY": 0.2, "CA_ROTOR0_KM": 0.05,      # front-right
           "CA_ROTOR1_PX": 0.15, "CA_ROTOR1_PY": -0.2, "CA_ROTOR1_KM": -0.05,    # front-left
           "CA_ROTOR2_PX": -0.15, "CA_ROTOR2_PY": -0.2, "CA_ROTOR2_KM": 0.05,    # back-left
           "CA_ROTOR3_PX": -0.15, "CA_ROTOR3_PY": 0.2, "CA_ROTOR3_KM": -0.05}    # back-right
    assert U.rotor_order_from_params(geo)[0] == (0, 1, 2, 3)
    with pytest.raises(ValueError, match="spin opposite"):
        U.rotor_order_from_params({k: (-v if k.endswith("KM") else v) for k, v in geo.items()})
    with pytest.raises(ValueError, match="same quadrant"):
        U.rotor_order_from_params({**geo, "CA_ROTOR3_PY": -0.2})


def test_thrust_model_pwm_limits_and_a_second_publisher():
    u = np.linspace(0, 1, 11)
    np.testing.assert_allclose(U.throttle_to_rotor_speed(u, 0.0), np.sqrt(u))
    np.testing.assert_allclose(U.throttle_to_rotor_speed(u, 1.0), u)
    assert U.throttle_to_rotor_speed(1.0, 0.4) == pytest.approx(1.0)
    rng = np.random.default_rng(0)
    pwm = np.concatenate([np.full((20, 4), 1000.0), 1400 + 100 * rng.random((200, 4))])
    mixed = pwm.copy()
    mixed[25::2] = 1500.0                     # a second publisher's constant rows, interleaved
    keep, c = U.drop_interleaved_rows(mixed)
    assert c == 1500.0 and keep[:20].all() and not keep[25::2].any() and keep[26::2].all()
    assert U.drop_interleaved_rows(pwm)[1] is None
    lo, hi, said = U.pwm_limits({"PWM_MAIN_MIN": 1230.0, "PWM_MAIN_MAX": 1950.0}, pwm)
    assert (lo, hi) == (1000.0, 1950.0) and "idle at 1000" in said


def test_pyulog_missing_names_the_extra(monkeypatch):
    monkeypatch.setitem(sys.modules, "pyulog", None)
    with pytest.raises(ImportError, match=r"pip install mjxsysid\[px4\]"):
        U.read_ulog(SAMPLE)


def test_check_log_cli_on_the_written_log(written, capsys):
    assert main(["check-log", str(written)]) == 1           # a warning: motors at 10 Hz
    out = capsys.readouterr().out
    assert "thrust-to-weight 2.0" in out and "motor: held (zero-order) from 10 Hz" in out
    assert "warning  motor_1, motor_2, motor_3, motor_4  cannot tell the rotor order" in out
    assert "motor time constant not estimable" in out


def test_check_log_cli_errors_on_a_disarmed_log(sample, written, tmp_path, capsys):
    """A bench log: every motor at zero, the vehicle at rest (the issue's 'thrust-to-weight 3.9e12')."""
    rest = np.zeros_like(sample["imu"])
    rest[:, 5] = 9.81
    path = write_log(tmp_path / "bench.csv", 0.002 * np.arange(len(rest)), rest, np.zeros(len(rest)),
                     np.zeros((len(rest), 3)), np.zeros((len(rest), 4)))
    assert main(["check-log", str(path)]) == 2
    out = capsys.readouterr().out
    assert "error" in out and "stopped or idling" in out
    assert main(["check-log", str(written), "--segment", "0:2.9"]) == 2   # the log before arming
    out = capsys.readouterr().out
    assert "stopped or idling" in out and "multiply by g" not in out


def test_never_armed_ulog_is_refused_as_such(flight, tmp_path):
    """A ULog that never arms: refused for that, with the next step (not 'no thrust setpoint')."""
    r = flight
    path = write_ulog(tmp_path / "bench.ulg", r["t"], r["imu"], r["a_cmd"], r["omega_cmd"], 0 * r["motor"],
                      armed=np.zeros(len(r["t"]), bool), hover_thrust=0.5)
    with pytest.raises(ValueError, match=r"never armed .*Next step: log a flight"):
        read_any_log(path)


@pytest.mark.skipif(not BENCH.is_file(), reason=f"old-format PX4 log not found at {BENCH}")
def test_old_never_armed_px4_log(capsys):
    """PX4 ≤ 1.9 (vehicle_rates_setpoint.thrust, vehicle_status.arming_state): never armed, said so;
    a part of it given by hand is refused for its idle motors, with no CSV author's a_cmd advice."""
    with pytest.raises(ValueError, match="never armed") as e:
        read_any_log(BENCH)
    assert "thrust setpoint" not in str(e.value) and "--segment" in str(e.value)
    assert main(["check-log", str(BENCH), "--segment", "10:20"]) == 2
    out = capsys.readouterr().out
    assert "stopped or idling" in out and "multiply by g" not in out
    assert "vehicle_rates_setpoint (thrust, PX4" in read_any_log(BENCH, "10:20")["source"]["topics"]["a_cmd"]


def test_decode_help_points_to_the_contract_docs():
    from mjxsysid.cli import build_parser
    p = build_parser()
    sub = next(a for a in p._actions if a.__class__.__name__ == "_SubParsersAction")
    text = " ".join(sub.choices["decode"].format_help().split())
    assert "docs/decoding.md" in text and "docs/px4.md" in text and "README" not in text


def test_pwm_limits_per_channel_minus_one_means_unset():
    """PX4's PWM_MAIN_MINn = −1 leaves the global PWM_MAIN_MIN in force (the F450 log's parameters)."""
    params = {"PWM_MAIN_MIN": 1230, "PWM_MAIN_MAX": 1950, **{f"PWM_MAIN_MIN{i}": -1 for i in range(1, 9)},
              **{f"PWM_MAIN_MAX{i}": -1 for i in range(1, 9)}}
    lo, hi, said = U.pwm_limits(params, np.full((10, 4), 1500.0))
    assert (lo, hi) == (1230.0, 1950.0) and "PWM_MAIN_MIN" in said


def test_fast_data_section_reads_what_pyulogs_loop_reads(written, monkeypatch):
    """The numpy data section (logs.ulog_fast) gives the record pyulog's own message loop gives."""
    from mjxsysid.logs import ulog_fast
    took = []
    real = ulog_fast.read_data_section
    with monkeypatch.context() as m:      # the numpy path must be the one that read it
        m.setattr(ulog_fast, "read_data_section", lambda *a: took.append(real(*a)) or took[-1])
        fast = U.read_ulog(written)
    assert took == [True]
    monkeypatch.setattr(ulog_fast, "read_data_section", lambda *a: False)
    slow = U.read_ulog(written)
    assert fast["source"] == slow["source"]
    for k in ("t", "imu", "motor", "a_cmd", "omega_cmd"):
        np.testing.assert_array_equal(fast[k], slow[k], err_msg=k)


def test_fast_ulog_object_is_pyulogs_on_a_real_log(monkeypatch):
    """On PX4's sample (logged messages, changed parameters, info messages in its data section) the ULog
    the numpy data section fills is pyulog's own: every topic's data, and the rest of the object."""
    pyulog = pytest.importorskip("pyulog")
    from support.paths import require_shared
    from mjxsysid.logs import ulog_fast
    path = str(require_shared(PX4_SAMPLE))
    took, real = [], ulog_fast.read_data_section
    monkeypatch.setattr(ulog_fast, "read_data_section", lambda *a: took.append(real(*a)) or took[-1])
    fast, ref = ulog_fast.load(pyulog.ULog, path), pyulog.ULog(path)
    assert took == [True]                     # the numpy path filled it
    assert [(d.name, d.multi_id) for d in fast.data_list] == [(d.name, d.multi_id) for d in ref.data_list]
    for a, b in zip(fast.data_list, ref.data_list):
        for k in b.data:
            np.testing.assert_array_equal(a.data[k], b.data[k], err_msg=f"{b.name}.{k}")
    assert len(ref.logged_messages) and [(m.timestamp, m.message) for m in fast.logged_messages] == \
        [(m.timestamp, m.message) for m in ref.logged_messages]
    assert fast.changed_parameters == ref.changed_parameters and fast.msg_info_dict == ref.msg_info_dict
    assert [(d.timestamp, d.duration) for d in fast.dropouts] == [(d.timestamp, d.duration) for d in ref.dropouts]
    assert fast.last_timestamp == ref.last_timestamp
