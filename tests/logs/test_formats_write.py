"""A flight written in every format (mjxsysid.logs.formats_write) and read back by the format's reader,
detected by content: the same rows within the format's resolution (the Crazyflie's PWM duty, blackbox's
integer units, DataFlash's float32 and µs PWM, mavros' µs PWM), the same times, and the channels a format
does not carry said missing. numpy, orangebox, pymavlink and rosbags only: no JAX compile."""
import numpy as np
import pytest

from mjxsysid.logs import formats_write as W
from mjxsysid.logs.csvlog import read_any_log
from mjxsysid.logs.grid import world_to_body
from mjxsysid.logs.ulog import throttle_to_rotor_speed
from support.synthetic_log import synthetic_flight

D2R = np.pi / 180


@pytest.fixture(scope="module")
def flight():
    """4 s airborne at 500 Hz, a tumbling and yawing attitude, a world velocity (z up)."""
    r = synthetic_flight(seconds=4.0)
    t = r["t"]
    rv = np.stack([0.4 * np.sin(1.3 * t), 0.3 * np.cos(0.9 * t), 1.5 + 0.8 * t], -1)
    ang = np.linalg.norm(rv, axis=1, keepdims=True)
    quat = np.concatenate([np.cos(ang / 2), rv / ang * np.sin(ang / 2)], 1)
    vel = np.stack([3 * np.sin(0.5 * t), 2 * np.cos(0.3 * t), 0.8 * np.sin(2 * t)], -1)
    return {**r, "quat": quat, "vel": vel, "velocity_body": world_to_body(quat, vel)}


def _read_back(write, path, flight, **kw):
    """Write ``flight`` with ``write`` at ``path``, read it back -> (the reader's record, the flight's rows
    at its times)."""
    write(path, flight["t"], flight["imu"], flight["a_cmd"], flight["omega_cmd"], flight["motor"],
          quat=flight["quat"], vel=flight["vel"], **kw)
    r = read_any_log(path)
    i = np.round(r["t"] / 0.002).astype(int)
    np.testing.assert_allclose(r["t"], flight["t"][i], atol=2e-6)    # on the flight's 2 ms grid (the rows' values, checked by
    # the callers, show they are those rows)
    assert len(i) > 0.7 * len(flight["t"])
    return r, {k: flight[k][i] for k in ("imu", "a_cmd", "omega_cmd", "motor", "velocity_body")}


def _close(r, want, tol: dict):
    for k, atol in tol.items():
        np.testing.assert_allclose(r[k], want[k], atol=atol, err_msg=k)


def test_crazyflie_round_trip(flight, tmp_path):
    """float32 IMU in deg/s and g, the PWM duty Ω_cmd² · 65535 in M1..M4 order; no setpoints logged."""
    r, want = _read_back(W.write_crazyflie, tmp_path / "log", flight)
    s = r["source"]
    assert s["format"] == "Crazyflie uSD" and s["missing"] == ["a_cmd", "omega_cmd", "rotor_speed"]
    assert s["conversions"][0].startswith("CRC32 checked: matches")
    _close(r, want, {"imu": 1e-4, "motor": 2e-4, "velocity_body": 1e-5})


def test_blackbox_round_trip(flight, tmp_path):
    """Indiflight's integer units: gyro 0.1 deg/s, acc_1G 2048, DShot 158–2047, setpoints, cm/s and quat × 8127."""
    r, want = _read_back(W.write_blackbox, tmp_path / "LOG00001.BFL", flight)
    s = r["source"]
    assert s["format"] == "Betaflight blackbox" and s["missing"] == []
    _close(r, want, {"imu": 5e-3, "motor": 2e-3, "omega_cmd": 1e-3, "a_cmd": 6e-3, "velocity_body": 0.01})


def test_dataflash_round_trip(flight, tmp_path):
    """float32 IMU, RATE and CTUN, PWM µs through MOT_THST_EXPO, XKF1 velocity rotated by ATT's angles."""
    r, want = _read_back(W.write_dataflash, tmp_path / "log.bin", flight)
    s = r["source"]
    assert s["format"] == "ArduPilot DataFlash" and s["missing"] == [] and "MOT_THST_EXPO e = 0.65" in " ".join(
        s["conversions"])
    _close(r, want, {"imu": 1e-5, "motor": 3e-3, "omega_cmd": 1e-5, "a_cmd": 1e-4, "velocity_body": 1e-4})


def test_px4csv_round_trip(flight, tmp_path):
    """data-driven-dynamics' table: µs stamps, PWM through PX4's THR_MDL_FAC 0 (√u) in quad-X order, FRD, the NED
    velocity rotated by the FRD attitude; no setpoints (filled from the IMU and said); the landed rows left out."""
    r, want = _read_back(W.write_px4csv, tmp_path / "flight.csv", flight)
    s = r["source"]
    assert s["format"] == "PX4 CSV (data-driven-dynamics)" and s["missing"] == ["a_cmd", "omega_cmd"]
    _close(r, want, {"imu": 1e-8, "motor": 1e-8, "velocity_body": 1e-8})
    np.testing.assert_allclose(r["omega_cmd"], r["imu"][:, :3])
    W.write_px4csv(tmp_path / "landed.csv", flight["t"], flight["imu"], flight["a_cmd"], flight["omega_cmd"],
                   flight["motor"], landed_s=1.0)
    r = read_any_log(tmp_path / "landed.csv")
    assert r["t"][0] >= flight["t"][0] + 1.0 and "the landed column" in r["source"]["segment"]["why"]


def test_px4csv_says_what_is_wrong(flight, tmp_path):
    """A table without a required column, or with a cell that is not a number, is refused by name."""
    from mjxsysid.logs import px4csv
    path = W.write_px4csv(tmp_path / "f.csv", flight["t"], flight["imu"], flight["a_cmd"], flight["omega_cmd"],
                          flight["motor"])
    lines = path.read_text().splitlines()
    (tmp_path / "bad.csv").write_text("\n".join([lines[0], lines[1], lines[2].replace(",", ",x", 3)] + lines[3:]))
    with pytest.raises(ValueError, match="bad.csv: .*(not a number|does not read as numbers)"):
        px4csv.read(tmp_path / "bad.csv")
    (tmp_path / "nogyro.csv").write_text("\n".join([lines[0].replace("ang_vel_x", "w_x")] + lines[1:]))
    with pytest.raises(ValueError, match=r"nogyro.csv: .*\['ang_vel_x'\]"):
        px4csv.read(tmp_path / "nogyro.csv")


@pytest.mark.parametrize("ros2", [False, True])
def test_rosbag_round_trip(flight, tmp_path, ros2):
    """float64 mavros topics (stamped at 1.6e9 s: 0.2 µs apart), PWM µs; no thrust setpoint in m/s² (filled
    from the IMU and said)."""
    pytest.importorskip("rosbags")
    from rosbags.rosbag2 import StoragePlugin
    kw = {"storage": StoragePlugin.MCAP} if ros2 else {}
    r, want = _read_back(W.write_rosbag, tmp_path / ("bag" if ros2 else "f.bag"), flight, **kw)
    s = r["source"]
    assert s["format"] == "ROS bag" and s["missing"] == ["a_cmd"]
    _close(r, want, {"imu": 1e-4, "motor": 3e-3, "velocity_body": 1e-4})
    # held: stamps 0.2 µs off the grid may hold the sample before, one 2 ms step late
    i = np.round(r["t"] / 0.002).astype(int)
    late = np.abs(r["omega_cmd"] - flight["omega_cmd"][np.maximum(i - 1, 0)]).max(1) < 1e-9
    assert np.all(late | (np.abs(r["omega_cmd"] - want["omega_cmd"]).max(1) < 1e-9))


def test_interleave_orders_by_time_then_block():
    a = (np.array([0, 2]), np.array([[1, 1], [2, 2]], np.uint8))
    b = (np.array([1, 2]), np.array([[7], [8]], np.uint8))
    assert W.interleave([a, b], chunk=1) == bytes([1, 1, 7, 2, 2, 8])


@pytest.mark.parametrize("expo", [0.0, 0.5, 0.65])
def test_throttle_inverts_the_thrust_curve(expo):
    s = np.linspace(0, 1, 11)
    np.testing.assert_allclose(throttle_to_rotor_speed(W.throttle_for_rotor_speed(s, expo), expo), s, atol=1e-12)


def test_quat_and_vel_go_together(flight, tmp_path):
    with pytest.raises(ValueError, match="both quat and vel"):
        W.write_crazyflie(tmp_path / "x", flight["t"], flight["imu"], flight["a_cmd"], flight["omega_cmd"],
                          flight["motor"], quat=flight["quat"])
