"""The holes real logs found in reading and reporting a log (issue 55): ground time cut, rotor
orders of the autopilots, interpolation detected whatever the number format, native rates counted
in samples, valid JSON, decode's printed quantities. Logs the project writes itself (numpy
flights, tests/support/synthetic_log.py): no JAX compile."""
import json

import numpy as np
import pytest

from mjxsysid.cli import main
from mjxsysid.runtime.jsonout import dumps
from mjxsysid.logs import checks as L
from mjxsysid.logs.checks.rotors import check_motors
from mjxsysid.logs.csvlog import LOG_COLUMNS, read_any_log, read_log, write_log
from mjxsysid.logs.grid import hold, interp_linear
from support.synthetic_log import synthetic_flight

TWR = 2.42


def _refuse(const):
    raise ValueError(f"not JSON: {const}")


def _csv(path, r, fmt=None):
    if fmt is None:
        return write_log(path, r["t"], r["imu"], r["a_cmd"], r["omega_cmd"], r["motor"])
    arr = np.column_stack([r["t"], r["imu"], r["a_cmd"], r["omega_cmd"], r["motor"]])
    np.savetxt(path, arr, delimiter=",", header=",".join(LOG_COLUMNS), comments="", fmt=fmt)
    return path


def test_ground_time_is_cut_and_said(tmp_path):
    """3 s before take-off and 2 s after landing with the rotors stopped: cut at the airborne
    segment (take-off and touch-down trimmed), said in source; the log-only thrust-to-weight is the
    vehicle's (read whole: about 3.4)."""
    r = synthetic_flight(seconds=10.0, ground_s=(3.0, 2.0), twr=TWR)
    rec = read_any_log(_csv(tmp_path / "ground.csv", r))
    seg = rec["source"]["segment"]
    assert seg["t0"] == pytest.approx(3.5, abs=0.01) and seg["t1"] == pytest.approx(12.5, abs=0.01)
    assert "airborne from the motor commands" in seg["why"] and rec["source"]["format"] == "CSV"
    assert rec["t"][0] >= 3.5 - 1e-9 and rec["t"][-1] <= 12.5 + 1e-9
    assert rec["source"]["rates_hz"] == {"imu": 500.0, "motor": 500.0, "a_cmd": 500.0, "omega_cmd": 500.0}
    assert set(rec["native"]) == {"imu", "motor", "a_cmd", "omega_cmd"} and rec["source"]["conversions"]
    assert L.estimate_vehicle(rec)["thrust_to_weight"] == pytest.approx(TWR, rel=0.02)
    assert L.estimate_vehicle(read_log(tmp_path / "ground.csv"))["thrust_to_weight"] > 1.2 * TWR
    whole = read_any_log(_csv(tmp_path / "air.csv", synthetic_flight(seconds=4.0)))
    assert len(whole["t"]) == 2000 and "kept whole" in whole["source"]["segment"]["why"]


@pytest.mark.parametrize("name,order", [("Crazyflie", (0, 3, 2, 1)), ("Betaflight", (3, 0, 2, 1)),
                                        ("PX4/ArduPilot", (0, 2, 1, 3))])
def test_autopilot_rotor_orders_are_named(name, order):
    """Motor columns in an autopilot's order: that order named, fitted under its own lag (the
    rotors' 60 ms), the reordering given."""
    r = synthetic_flight(seconds=8.0, tau=0.06, gyro_noise=0.01)
    rec = {k: r[k] for k in ("t", "imu", "a_cmd", "omega_cmd")}
    rec["motor"] = r["motor"][:, list(order)]
    fit = L.rotor_order_fit(rec)
    assert fit["best"] == order and fit["scores"][order] > 0.9 and fit["taus"][order] == pytest.approx(0.06)
    (f,) = check_motors(rec)
    assert f.level in ("error", "warning") and f"look like {name}" in f.message and "reorder" in f.message


def test_interpolated_imu_with_6_decimals_is_detected(tmp_path):
    """IMU interpolated from 100 Hz and motors held from exactly 100 Hz, written with 6 decimals:
    both detected, the rates 100 Hz (samples, not value changes), the noise read at the knots, and
    τ_m estimable in check-log as in decode's likelihood."""
    from mjxsysid.identify.logdata import MIN_MOTOR_RATE_HZ, motor_rate_hz
    r = synthetic_flight(seconds=10.0, gyro_noise=0.01, acc_noise=0.1)
    k = np.arange(0, len(r["t"]), 5)
    r = dict(r, imu=interp_linear(r["t"][k], r["imu"][k], r["t"]), motor=hold(r["t"][k], r["motor"][k], r["t"]))
    rec = read_any_log(_csv(tmp_path / "six.csv", r, fmt="%.6f"))
    assert rec["resampled"]["imu"].startswith("interpolated (linear) from about 100 Hz")
    assert rec["resampled"]["motor"].startswith("held (zero-order) from about 100 Hz")
    assert rec["source"]["rates_hz"]["imu"] == 100.0 and rec["source"]["rates_hz"]["motor"] == 100.0
    est = L.estimate_vehicle(rec)
    assert est["gyro_noise"] == pytest.approx(0.01, rel=0.3) and est["imu_rate_hz"] == pytest.approx(100)
    assert L.motor_time_constant(est)[0] is not None
    assert motor_rate_hz(rec) == pytest.approx(100) and motor_rate_hz(rec) >= MIN_MOTOR_RATE_HZ * (1 - 1e-9)
    found = " | ".join(str(f) for f in L.check_log(rec))
    assert "imu columns look interpolated" in found and "motor columns look held" in found


def test_value_quantum_reads_the_number_format():
    x = np.array([[9.812345, 0.012345], [10.05123, 0.5]])
    from mjxsysid.logs.checks.rates import value_quantum
    q = value_quantum(x)
    assert q[0, 0] == pytest.approx(1e-6) and q[1, 0] == pytest.approx(1e-5) and q[0, 1] == pytest.approx(1e-6)


def test_json_outputs_are_valid_json(tmp_path, capsys):
    """check-log --json of a log whose motors are logged at 10 Hz (the thrust lag not estimable:
    NaN inside) parses with a parser that refuses NaN; null where the number is missing."""
    r = synthetic_flight(seconds=6.0)
    k = np.arange(0, len(r["t"]), 50)
    r = dict(r, motor=hold(r["t"][k], r["motor"][k], r["t"]))
    main(["check-log", str(_csv(tmp_path / "slow.csv", r)), "--json"])
    got = json.loads(capsys.readouterr().out, parse_constant=_refuse)
    assert got["estimates"]["motor_time_constant_thrust"] is None
    assert json.loads(dumps({"a": float("nan"), "b": np.float32(np.inf), "c": np.arange(2)}),
                      parse_constant=_refuse) == {"a": None, "b": None, "c": [0, 1]}


def test_decode_prints_what_the_log_pins_first():
    from mjxsysid.decoding.command import printed_summary
    band = {"mean": 1.0, "q05": 0.9, "q95": 1.1}
    summary = {"thrust_to_weight": band, "torque_ratio": band,
               "motor_time_constant": band, "authority_total[0]": band,
               "_log_grounded": {"gap": {"thrust_to_weight": {"seen_by_log": True},
                                         "motor_time_constant": {"seen_by_log": True},
                                         "authority_total[0]": {"seen_by_log": False}}}}
    out = printed_summary(summary)
    assert list(out)[:3] == ["thrust_to_weight", "motor_time_constant", "torque_ratio"]     # each once
    assert "authority_total[0]" not in out and out["not_seen_by_log"] == ["authority_total[0]"]
    assert list(printed_summary({"thrust_to_weight": band, "x": 1})) == ["thrust_to_weight"]


def test_information_gap_tick_labels_do_not_overlap_and_unseen_bands_are_grey(tmp_path):
    """information_gap.png's log-scale panels (authorities spanning 50–4000 rad/s²): no two tick
    labels of a panel overlap."""
    from support.figures import kept_figure, overlapping_tick_labels

    from mjxsysid.render.posterior import UNSEEN_COLOR, plot_information_gap
    band = {"unit": "rad/s^2", "width_ratio": 2.0}
    gap = {f"q{i}": dict(band, decoder_q05=lo, decoder_q95=hi, log_q05=2 * lo, log_q95=hi / 2, log_median=3 * lo)
           for i, (lo, hi) in enumerate([(50, 4000), (5, 400), (0.005, 0.12), (2, 200), (10, 45), (0.3, 1.6)])}
    gap["q5"]["seen_by_log"] = False
    with kept_figure() as shown:
        plot_information_gap(gap, tmp_path / "gap.png")
        for ax in shown["fig"].axes[:len(gap)]:
            assert overlapping_tick_labels(ax) == []
        # a quantity the log does not see: its log band grey and its title says so, the others green with their ratio
        axes = shown["fig"].axes
        assert axes[5].get_title().endswith("not seen by the log") and axes[5].lines[1].get_color() == UNSEEN_COLOR
        assert axes[0].get_title().endswith("width ratio 2") and axes[0].lines[1].get_color() == "tab:green"


def test_the_logs_minimum_rows_are_the_policys_history():
    from mjxsysid.logs.csvlog import MIN_ROWS
    from mjxsysid.logs.grid import MIN_ROWS as ULOG_MIN_ROWS
    from mjxsysid.policy.adaptive.networks import HISTORY
    assert MIN_ROWS == ULOG_MIN_ROWS == HISTORY


def test_tau_m_is_read_from_command_to_measured_rotor_speed():
    """A log that measures rotor speed (RPM deck, bidirectional DShot): the lag from command to speed
    is the rotors' 35 ms, whatever the idle offset; a log without speeds gives None."""
    from mjxsysid.logs.checks.rotors import check_rotor_speed
    from mjxsysid.logs.speedmap import first_row, row_speed, speed_fit
    rng = np.random.default_rng(0)
    T = 5000
    steps = np.repeat(rng.uniform(0.3, 0.9, (T // 100, 4)), 100, axis=0)
    omega = 3000.0 * row_speed(steps, 0.035) - 200.0 + rng.normal(0, 5, (T, 4))
    fit = speed_fit({"motor": steps, "rotor_speed": omega}, first_row(T))
    assert fit["used"] and fit["tau_m_s"] == pytest.approx(0.035, rel=0.05) and fit["r2"] > 0.99 > fit["r2_no_lag"]
    assert fit["omega_ref_rad_s"] == pytest.approx(2800.0, rel=0.02) and fit["delay_s"] == 0.0
    assert check_rotor_speed({"motor": steps, "rotor_speed": omega}) == []
    assert not speed_fit({"motor": steps})["used"]
    bad = check_rotor_speed({"motor": steps, "rotor_speed": rng.normal(2000, 300, (T, 4))})
    assert bad and bad[0].level == "warning" and "do not follow" in bad[0].message


def test_check_log_fits_the_rotor_speeds_once(tmp_path, monkeypatch, capsys):
    """``check-log`` on a log with rotor speeds: the check and the printed report read one command→speed fit."""
    import mjxsysid.logs.csvlog as csvlog
    from mjxsysid.logs import speedmap
    r = synthetic_flight(seconds=4.0, twr=TWR)
    path = _csv(tmp_path / "speeds.csv", r)
    read = csvlog.read_any_log
    monkeypatch.setattr(csvlog, "read_any_log", lambda p, seg=None: {**read(p, seg), "rotor_speed": 3000.0 * r["rotor_speed"]})
    calls = []
    fit = speedmap.speed_fit
    monkeypatch.setattr(speedmap, "speed_fit", lambda *a, **k: calls.append(1) or fit(*a, **k))
    main(["check-log", str(path), "--prior", "none"])
    assert "rotor speeds: used by the likelihood" in capsys.readouterr().out
    assert len(calls) == 1


def test_the_checks_and_the_posterior_read_one_rotor_speed_fit(monkeypatch):
    """``decode --log``: the plausibility checks and the posterior's preparation share one command→speed fit."""
    from mjxsysid.identify.logdata import prepare
    from mjxsysid.logs import speedmap
    from mjxsysid.logs.checks.plausibility import check_log
    r = synthetic_flight(seconds=4.0, twr=TWR)
    rec = {**r, "rotor_speed": 3000.0 * r["rotor_speed"]}
    calls = []
    fit = speedmap._speed_fit
    monkeypatch.setattr(speedmap, "_speed_fit", lambda *a, **k: calls.append(1) or fit(*a, **k))
    monkeypatch.setattr(speedmap, "_LAST", [])
    check_log(rec)
    prepare(rec)
    assert len(calls) == 1
    prepare({**rec, "rotor_speed": rec["rotor_speed"].copy()})      # other arrays: fitted anew
    assert len(calls) == 2
