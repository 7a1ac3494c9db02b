"""The body-frame velocity a log may carry (``velocity_body`` (T, 3) m/s FLU): PX4 ULog's
vehicle_local_position rotated by vehicle_attitude (read and written), the CSV contract's optional
vel_body_x/y/z columns, the simulator's flight written as both logs; a log without it reads as
before. numpy only (the flight-logs test calls the simulator's quaternion helper eagerly)."""
from types import SimpleNamespace

import numpy as np
import pytest

from mjxsysid.logs.csvlog import LOG_COLUMNS, VELOCITY_COLUMNS, read_any_log, read_log, write_log
from mjxsysid.logs.grid import world_to_body
from support.paths import SHARED_DATA, require_shared
from support.synthetic_log import synthetic_flight

PX4_LOGS = SHARED_DATA / "logs" / "px4"
F450 = PX4_LOGS / "real_f450_hop.ulg"
PX4_SAMPLE = SHARED_DATA / "ulog" / "sample_px4_events.ulg"


def _quat(axis_angle):
    """Rotation vectors (N, 3) -> unit quaternions w x y z (N, 4)."""
    a = np.asarray(axis_angle, np.float64)
    ang = np.linalg.norm(a, axis=1, keepdims=True)
    axis = np.where(ang > 0, a / np.where(ang > 0, ang, 1), 0)
    return np.concatenate([np.cos(ang / 2), axis * np.sin(ang / 2)], 1)


@pytest.fixture(scope="module")
def flight():
    """A numpy flight (airborne throughout) with a tumbling, yawing attitude and a world velocity (z up)."""
    r = synthetic_flight(seconds=4.0)
    t = r["t"]
    quat = _quat(np.stack([0.4 * np.sin(1.3 * t), 0.3 * np.cos(0.9 * t), 1.5 + 0.8 * t], -1))
    vel = np.stack([3 * np.sin(0.5 * t), 2 * np.cos(0.3 * t), 0.8 * np.sin(2 * t)], -1)
    return {**r, "quat": quat, "vel": vel, "velocity_body": world_to_body(quat, vel)}


def _ulog(path, r, **kw):
    from mjxsysid.logs.ulog_write import write_ulog
    return write_ulog(path, r["t"], r["imu"], r["a_cmd"], r["omega_cmd"], r["motor"], **kw)


# ---- PX4 ULog

def test_ulog_round_trip_carries_the_body_velocity(flight, tmp_path):
    """write_ulog's vehicle_attitude and vehicle_local_position (NED) read back as the flight's body
    velocity (FLU), to float32."""
    pytest.importorskip("pyulog")
    from mjxsysid.logs.ulog import read_ulog
    r = read_ulog(_ulog(tmp_path / "f.ulg", flight, quat=flight["quat"], vel=flight["vel"]))
    assert len(r["t"]) == len(flight["t"]) and r["source"]["missing"] == []
    np.testing.assert_allclose(r["velocity_body"], flight["velocity_body"], atol=2e-6)
    assert r["resampled"]["velocity_body"] == "native (500 Hz)"
    assert r["source"]["topics"]["velocity_body"] == "vehicle_local_position (vx, vy, vz) + vehicle_attitude (q)"
    assert any(c.startswith("velocity_body: vehicle_local_position") for c in r["source"]["conversions"])


def test_ulog_velocity_at_px4_rates_is_interpolated(flight, tmp_path):
    """The estimate at 50 Hz (PX4 logs it at 10–50 Hz): interpolated (linear) to 2 ms and said; past
    its last sample (under one step before the IMU ends) held."""
    pytest.importorskip("pyulog")
    from mjxsysid.logs.ulog import read_ulog
    r = read_ulog(_ulog(tmp_path / "f.ulg", flight, quat=flight["quat"], vel=flight["vel"], rates={"estimate": 50}))
    assert r["resampled"]["velocity_body"] == "interpolated (linear) from 50 Hz"
    tn, vn = r["native"]["velocity_body"]
    assert tn.shape == (len(flight["t"]) // 10,) and tn[-1] == pytest.approx(flight["t"][-10])
    inside = r["t"] <= tn[-1] + 1e-9
    assert np.abs(r["velocity_body"] - flight["velocity_body"])[inside].max() < 0.01     # smooth: 20 ms knots
    np.testing.assert_array_equal(r["velocity_body"][~inside], np.broadcast_to(vn[-1], (int((~inside).sum()), 3)))


def test_ulog_without_the_estimate_reads_as_before(flight, tmp_path):
    pytest.importorskip("pyulog")
    from mjxsysid.logs.ulog import read_ulog
    r = read_ulog(_ulog(tmp_path / "f.ulg", flight))
    assert "velocity_body" not in r and "velocity_body" not in r["native"] and "velocity_body" not in r["resampled"]
    assert r["source"]["missing"] == ["velocity_body"]
    assert "no vehicle_local_position" in r["source"]["conversions"][-1]
    with pytest.raises(ValueError, match="both quat and vel"):
        _ulog(tmp_path / "g.ulg", flight, quat=flight["quat"])


def _px4_topics(q_wxyz, v_ned, t, **flags):
    """pyulog-like data dicts of vehicle_local_position and vehicle_attitude at times t (s, start 0)."""
    ts = np.round(np.asarray(t) * 1e6)
    lp = {"timestamp": ts, "vx": v_ned[:, 0], "vy": v_ned[:, 1], "vz": v_ned[:, 2], **flags}
    att = {"timestamp": ts, **{f"q[{i}]": q_wxyz[:, i] for i in range(4)}}
    return lp, att


def test_ulog_velocity_frames_by_hand():
    """PX4's conventions, independent of the writer: heading east (q: 90° about NED's z, down), a
    velocity east is forward (+x FLU), one north is to the left (+y FLU), one down is −z FLU."""
    from mjxsysid.logs.ulog_velocity import ulog_velocity_body
    t = 0.1 * np.arange(11)
    q = np.tile([np.cos(np.pi / 4), 0, 0, np.sin(np.pi / 4)], (11, 1))
    for v_ned, want in (((0, 2, 0), (2, 0, 0)), ((1, 0, 0), (0, 1, 0)), ((0, 0, 1.5), (0, 0, -1.5))):
        (tn, v), said = ulog_velocity_body(*_px4_topics(q, np.tile(v_ned, (11, 1)).astype(float), t), 0, 0.3, 0.7)
        np.testing.assert_allclose(v, np.tile(want, (len(tn), 1)), atol=1e-12)
        assert tn[0] <= 0.3 and tn[-1] >= 0.7 and "FRD to FLU" in said


def test_ulog_velocity_invalid_or_absent_is_said_not_raised():
    from mjxsysid.logs.ulog_velocity import ulog_velocity_body
    t = 0.1 * np.arange(11)
    q = np.tile([1.0, 0, 0, 0], (11, 1))
    v = np.ones((11, 3))
    xy = np.ones(11)
    xy[5] = 0
    got, said = ulog_velocity_body(*_px4_topics(q, v, t, v_xy_valid=xy, v_z_valid=np.ones(11)), 0, 0.2, 0.8)
    assert got is None and "v_xy_valid false on 1 of its" in said
    got, _ = ulog_velocity_body(*_px4_topics(q, v, t, v_xy_valid=xy), 0, 0.65, 0.9)   # invalid outside the segment
    assert got is not None
    v[3, 2] = np.nan
    got, said = ulog_velocity_body(*_px4_topics(q, v, t), 0, 0.2, 0.8)
    assert got is None and "not finite on 1" in said
    lp, _ = _px4_topics(q, np.ones((11, 3)), t)
    assert "no vehicle_local_position" in ulog_velocity_body(None, None, 0, 0.2, 0.8)[1]
    assert "vehicle_attitude (q) is not" in ulog_velocity_body(lp, None, 0, 0.2, 0.8)[1]
    assert "does not cover" in ulog_velocity_body(lp, _px4_topics(q, v, t)[1], 0, 0.2, 1.5)[1]


# ---- CSV contract

def test_csv_velocity_columns_read_back(flight, tmp_path):
    path = write_log(tmp_path / "v.csv", flight["t"], flight["imu"], flight["a_cmd"], flight["omega_cmd"],
                     flight["motor"], velocity_body=flight["velocity_body"])
    assert path.read_text().splitlines()[0].split(",") == list(LOG_COLUMNS + VELOCITY_COLUMNS)
    r = read_log(path)
    np.testing.assert_allclose(r["velocity_body"], flight["velocity_body"], rtol=1e-6, atol=1e-6)
    a = read_any_log(path)
    assert a["source"]["missing"] == [] and "velocity_body" in a["resampled"]
    # the careful parser (a blank line sends the file past the fast path) reads the same
    text = path.read_text().splitlines()
    (tmp_path / "b.csv").write_text("\n".join(text[:50] + [""] + text[50:]) + "\n")
    np.testing.assert_array_equal(read_log(tmp_path / "b.csv")["velocity_body"], r["velocity_body"])


def test_csv_with_some_velocity_columns_is_refused(flight, tmp_path):
    path = write_log(tmp_path / "v.csv", flight["t"], flight["imu"], flight["a_cmd"], flight["omega_cmd"],
                     flight["motor"], velocity_body=flight["velocity_body"])
    rows = [ln.split(",") for ln in path.read_text().splitlines()]
    (tmp_path / "two.csv").write_text("\n".join(",".join(r[:-1]) for r in rows) + "\n")
    with pytest.raises(ValueError, match=r"velocity column\(s\) \['vel_body_z'\] missing") as e:
        read_log(tmp_path / "two.csv")
    assert "line 1" in str(e.value)
    rows[40][-2] = "fast"
    (tmp_path / "bad.csv").write_text("\n".join(",".join(r) for r in rows) + "\n")
    with pytest.raises(ValueError, match="line 41, column vel_body_y: 'fast' is not a number"):
        read_log(tmp_path / "bad.csv")
    rows[40][-2] = "nan"
    (tmp_path / "nan.csv").write_text("\n".join(",".join(r) for r in rows) + "\n")
    with pytest.raises(ValueError, match="line 41, column vel_body_y: 'nan' is not finite"):
        read_log(tmp_path / "nan.csv")


def test_csv_without_velocity_reads_as_before(flight, tmp_path):
    path = write_log(tmp_path / "plain.csv", flight["t"], flight["imu"], flight["a_cmd"], flight["omega_cmd"],
                     flight["motor"])
    assert path.read_text().splitlines()[0] == ",".join(LOG_COLUMNS)
    r = read_log(path)
    assert set(r) == {"t", "imu", "a_cmd", "omega_cmd", "motor"}
    a = read_any_log(path)
    assert "velocity_body" not in a and "velocity_body" not in a["resampled"]
    assert a["source"]["missing"] == ["velocity_body"]


# ---- the simulator's flight as logs

def test_flight_logs_carry_the_flights_body_velocity(flight, tmp_path):
    """write_flight_logs (``mjxsysid fly``): flight.ulg and flight.csv read back with flight_log's
    velocity_body (the true velocity in the body frame), to float32."""
    pytest.importorskip("pyulog")
    from mjxsysid.logs.ulog import read_ulog
    from mjxsysid.logs.ulog_write import write_flight_logs
    from mjxsysid.rollout.flight import flight_log
    f32 = lambda x: np.asarray(x, np.float32)  # noqa: E731
    frame = SimpleNamespace(imu=f32(flight["imu"]), motor_cmd=f32(flight["motor"]), quat=f32(flight["quat"]),
                            vel=f32(flight["vel"]))
    one = SimpleNamespace(time=f32(flight["t"] + 0.002), a_cmd=f32(flight["a_cmd"]),
                          omega_cmd=f32(flight["omega_cmd"]), frame=frame)
    want = flight_log(frame)["velocity_body"]
    np.testing.assert_allclose(want, flight["velocity_body"], atol=1e-5)
    ulg, csv = write_flight_logs(one, tmp_path)
    r = read_ulog(ulg)
    assert len(r["t"]) == len(want)
    np.testing.assert_allclose(r["velocity_body"], want, atol=1e-5)
    np.testing.assert_allclose(read_log(csv)["velocity_body"], want, rtol=1e-6, atol=1e-6)


# ---- real PX4 logs (../shared, absent in a clone)

def test_px4_sample_velocity_is_the_climb():
    """jMAVSim's Iris (PX4's sample, valid estimate in flight): a body velocity, finite, under 30 m/s,
    its z (FLU, up) the estimate's −vz (NED, down): the flight is near level."""
    pytest.importorskip("pyulog")
    from pyulog import ULog
    from mjxsysid.logs.ulog import _topic, read_ulog
    r = read_ulog(require_shared(PX4_SAMPLE))
    v = r["velocity_body"]
    assert v.shape == (len(r["t"]), 3) and np.isfinite(v).all() and np.abs(v).max() < 30
    assert np.abs(v[:, 2]).max() > 0.5                  # it climbs and descends at about 1 m/s
    lp = _topic(ULog(str(PX4_SAMPLE)), "vehicle_local_position")
    t_lp = (np.asarray(lp["timestamp_sample"], np.float64) - r["source"]["log_start_us"]) * 1e-6
    assert np.corrcoef(v[:, 2], -np.interp(r["t"], t_lp, lp["vz"]))[0, 1] > 0.99


def test_real_px4_hop_without_horizontal_velocity_says_so():
    """The F450 hop (a real PX4 log, no GPS): v_xy_valid false throughout, velocity_body not given
    and said; every other column read as before."""
    pytest.importorskip("pyulog")
    from mjxsysid.logs.ulog import read_ulog
    r = read_ulog(require_shared(F450))
    assert "velocity_body" not in r and r["source"]["missing"] == ["velocity_body"]
    assert any("v_xy_valid false" in c for c in r["source"]["conversions"])
    assert np.isfinite(r["imu"]).all()
