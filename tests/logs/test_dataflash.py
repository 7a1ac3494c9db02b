"""ArduPilot DataFlash logs (mjxsysid.logs.dataflash): a log written here (FMT records then records,
known gyro, accelerometer, motor outputs, setpoints and velocity) read back through every conversion,
and the real ArduCopter 3.4 sample of /work/shared (skipped where absent). numpy only: no JAX."""
import shutil
import sys
from pathlib import Path

import numpy as np
import pytest

pytest.importorskip("pymavlink")

from mjxsysid import theta as P
from mjxsysid.logs import dataflash as D
from mjxsysid.logs.csvlog import read_any_log
from mjxsysid.logs.formats import detect
from mjxsysid.logs.formats_write import ARDUCOPTER_MESSAGES, DataFlashLog

SHARED = Path(__file__).resolve().parents[2] / ".." / "shared" / "data" / "logs" / "formats"
SAMPLE = SHARED / "ardupilot_dataflash" / "erle_Erle-Brain3.BIN"

GYRO_FRD, ACC_FRD = (0.1, 0.2, 0.3), (0.5, 0.6, -9.81)
MOTOR_PWM = {1: 1500, 2: 1600, 3: 1700, 4: 1800}          # ArduCopter motor n -> PWM µs in flight
SERVO_FUNCTION = {1: 34, 2: 33, 3: 36, 4: 35}             # output n drives motor function - 32
PARAMS = {"FRAME_CLASS": 1, "FRAME_TYPE": 1, "MOT_PWM_MIN": 1000, "MOT_PWM_MAX": 2000, "MOT_THST_EXPO": 0.5,
          "MOT_THST_HOVER": 0.3, "AHRS_EKF_TYPE": 3, **{f"SERVO{n}_FUNCTION": f for n, f in SERVO_FUNCTION.items()}}


def write_synthetic(path):
    """10 s at 100 Hz (IMU, RATE, XKF1, ATT) and 50 Hz (RCOU, CTUN); armed 1–9 s, motors up 3–7 s;
    a second IMU instance and a second EKF core with other values (not to be read)."""
    w = DataFlashLog(ARDUCOPTER_MESSAGES)
    w.add("PARM", TimeUS=np.zeros(len(PARAMS), np.uint64), Name=[k.encode() for k in PARAMS],
          Value=[float(v) for v in PARAMS.values()])
    w.add("MSG", TimeUS=1000, Message=b"ArduCopter V4.0.3 (abcdef12)")
    w.add("EV", TimeUS=[1_000_000, 9_000_000], Id=[10, 11])
    us = 10_000 * np.arange(1000) + 500
    imu = dict(zip(("GyrX", "GyrY", "GyrZ", "AccX", "AccY", "AccZ"), GYRO_FRD + ACC_FRD))
    w.add("IMU", TimeUS=us, **imu, I=0)
    w.add("IMU", TimeUS=us, **{k: 9.0 for k in imu}, I=1)
    w.add("RATE", TimeUS=us, RDes=10.0, PDes=20.0, YDes=30.0)
    w.add("XKF1", TimeUS=us, C=0, VN=1.0, VE=0.0, VD=-0.5)                     # north 1 m/s, up 0.5 m/s
    w.add("XKF1", TimeUS=us, C=1, VN=7.0, VE=7.0, VD=7.0)
    w.add("ATT", TimeUS=us, Roll=0.0, Pitch=0.0, Yaw=90.0)                      # heading east
    out = us[::2] + 100
    flying = (3.0 <= us[::2] * 1e-6) & (us[::2] * 1e-6 <= 7.0)
    pwm = {f"C{n}": np.where(flying, MOTOR_PWM[SERVO_FUNCTION[n] - 32], 1100) for n in range(1, 5)}
    w.add("RCOU", TimeUS=out, **pwm, C5=1500, C6=0)
    w.add("CTUN", TimeUS=out, ThO=np.where(flying, 0.3, 0.0), ThH=0.3)
    Path(path).write_bytes(w.bytes())
    return path


@pytest.fixture(scope="module")
def synthetic(tmp_path_factory):
    return write_synthetic(tmp_path_factory.mktemp("df") / "synthetic.bin")


def omega(pwm, e=0.5):
    u = (pwm - 1000) / 1000
    return np.sqrt((1 - e) * u + e * u * u)


def test_synthetic_log_conversions(synthetic):
    r = D.read_dataflash(synthetic)
    n = len(r["t"])
    assert r["imu"].shape == (n, 6) and r["motor"].shape == (n, 4) and r["a_cmd"].shape == (n,)
    assert np.allclose(np.diff(r["t"]), 0.002)
    # FRD -> FLU, instance 0 only
    np.testing.assert_allclose(r["imu"], np.tile([0.1, -0.2, -0.3, 0.5, -0.6, 9.81], (n, 1)), atol=1e-5)
    # SERVOn_FUNCTION, then ArduCopter M1 FR, M2 BL, M3 FL, M4 BR -> mjxsysid FR, FL, BL, BR
    want = [omega(MOTOR_PWM[1]), omega(MOTOR_PWM[3]), omega(MOTOR_PWM[2]), omega(MOTOR_PWM[4])]
    np.testing.assert_allclose(r["motor"], np.tile(want, (n, 1)), atol=1e-6)
    np.testing.assert_allclose(r["omega_cmd"], np.tile(np.deg2rad([10.0, -20.0, -30.0]), (n, 1)), atol=1e-6)
    np.testing.assert_allclose(r["a_cmd"], P.GRAVITY, atol=1e-6)
    # heading east, moving north and up: the vehicle moves to its left and up; core 0 only
    np.testing.assert_allclose(r["velocity_body"], np.tile([0.0, 1.0, 0.5], (n, 1)), atol=1e-5)
    s = r["source"]
    assert s["rates_hz"]["imu"] == pytest.approx(100) and s["rates_hz"]["motor"] == pytest.approx(50)
    assert r["resampled"]["imu"] == "interpolated (linear) from 100 Hz"
    assert r["resampled"]["motor"] == "held (zero-order) from 50 Hz"
    assert 3.4 < s["segment"]["t0"] < 3.6 and 6.4 < s["segment"]["t1"] < 6.6
    assert "armed 1.00–9.00 s" in s["segment"]["why"] and s["missing"] == []
    conv = " ".join(s["conversions"])
    assert "SERVOn_FUNCTION" in conv and "MOT_PWM_MIN/MAX" in conv and "MOT_THST_EXPO e = 0.5" in conv
    assert "XKF1" in conv and "FRD" in conv
    tn, xn = r["native"]["motor"]
    assert tn[0] <= r["t"][0] and tn[-1] >= r["t"][-1] and xn.shape[1] == 4


def test_segment_detection_and_read_any_log(synthetic, tmp_path):
    r = D.read_dataflash(synthetic, "2:8")
    assert r["t"][0] == pytest.approx(2.0) and r["t"][-1] == pytest.approx(8.0)
    assert r["source"]["segment"]["why"].startswith("--segment")
    with pytest.raises(ValueError, match="end must come after"):
        D.read_dataflash(synthetic, "8:2")
    renamed = tmp_path / "flight.csv"
    shutil.copy(synthetic, renamed)
    assert detect(renamed) == "ArduPilot DataFlash"
    assert read_any_log(renamed)["source"]["format"] == "ArduPilot DataFlash"


def test_mappings_frames_and_armed_stretches():
    assert D.motor_channels({}, (3, 4))[0] == [1, 2, 3, 4]
    assert "before 3.5" in D.motor_channels({}, (3, 4))[1]
    with pytest.raises(ValueError, match="beyond 4"):
        D.motor_channels({f"SERVO{n}_FUNCTION": 32 + n for n in range(1, 7)}, (4, 0))
    with pytest.raises(ValueError, match="FRAME_TYPE = 0"):
        D.check_frame({"FRAME_CLASS": 1, "FRAME_TYPE": 0})
    with pytest.raises(ValueError, match="not a quad"):
        D.check_frame({"FRAME_CLASS": 2})
    assert D.pwm_range({"MOT_PWM_MIN": 0, "MOT_PWM_MAX": 0, "RC3_MIN": 1100, "RC3_MAX": 1900})[:2] == (1100, 1900)
    t = np.concatenate([np.arange(0, 5, 0.01), np.arange(20, 30, 0.01)])   # logging paused 5-20 s
    msgs = {"EV": {"TimeUS": np.array([0.5e6, 4e6, 21e6]), "Id": np.array([10, 11, 10])}}
    got = D.armed_stretches(msgs, t)
    assert got[0] == (0.5, 4.0) and got[1][0] == 21.0 and got[1][1] == pytest.approx(29.99)
    with pytest.raises(ValueError, match="ArduPlane"):
        D.firmware({"MSG": {"Message": np.array(["ArduPlane V4.1.0 (123)"])}})


def test_numpy_records_read_as_pymavlinks(synthetic, monkeypatch):
    """The numpy parser and pymavlink (the fallback for a damaged log) give the same log."""
    assert D.parse_records(synthetic.read_bytes(), D.TYPES) is not None      # the numpy path reads it
    fast = D.read_dataflash(synthetic)
    monkeypatch.setattr(D, "parse_records", lambda *a, **k: None)
    slow = D.read_dataflash(synthetic)
    assert fast["source"] == slow["source"]
    for k in ("t", "imu", "a_cmd", "omega_cmd", "motor", "velocity_body"):
        np.testing.assert_allclose(fast[k], slow[k], atol=1e-6)


def test_bad_input_and_missing_pymavlink(synthetic, tmp_path, monkeypatch):
    bad = tmp_path / "x.bin"
    bad.write_bytes(b"not a log" * 100)
    with pytest.raises(ValueError, match="not an ArduPilot DataFlash"):
        D.read_dataflash(bad)
    empty = tmp_path / "y.bin"
    empty.write_bytes(D.MAGIC + bytes(200))
    with pytest.raises(ValueError, match=str(empty.name)):
        D.read_dataflash(empty)
    data = synthetic.read_bytes()
    damaged = tmp_path / "damaged.bin"                       # garbage between records: they no longer chain
    damaged.write_bytes(data[:len(data) // 2] + b"\x00\x01\x02" + data[len(data) // 2:])
    assert D.parse_records(damaged.read_bytes()) is None and D.parse_records(data) is not None
    monkeypatch.setitem(sys.modules, "pymavlink", None)
    assert D.read_dataflash(synthetic)["source"]["format"] == "ArduPilot DataFlash"     # numpy alone
    with pytest.raises(ImportError, match=r'pip install -e "\.\[ardupilot\]"'):
        D.read_dataflash(damaged)


@pytest.mark.skipif(not SAMPLE.is_file(), reason=f"real DataFlash sample not found at {SAMPLE}")
def test_real_arducopter_sample():
    """ArduCopter 3.4 (Erle-Brain 3): IMU 23.6 Hz and RCOU 9.4 Hz (default LOG_BITMASK), armed 10.2 s,
    airborne 14.7–275.4 s by its EV messages."""
    r = D.read_dataflash(SAMPLE)
    s = r["source"]
    assert s["rates_hz"]["imu"] == pytest.approx(23.6, abs=0.1)
    assert s["rates_hz"]["motor"] == pytest.approx(9.4, abs=0.1)
    assert r["resampled"]["motor"] == "held (zero-order) from 9 Hz"
    assert 14.5 < s["segment"]["t0"] < 20 and 265 < s["segment"]["t1"] < 275.5
    assert r["imu"][:, 5].mean() == pytest.approx(9.8, abs=0.3)
    assert r["a_cmd"].mean() == pytest.approx(r["imu"][:, 5].mean(), rel=0.05)
    assert 0.3 < r["motor"].min() and r["motor"].max() < 0.8
    assert "before 3.5" in " ".join(s["conversions"]) and "RC3_MIN/MAX" in " ".join(s["conversions"])
    assert np.abs(r["velocity_body"]).max() < 6
