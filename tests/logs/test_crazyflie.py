"""Crazyflie uSD-card logs (mjxsysid.logs.crazyflie): logs the test writes itself in the deck's
binary format (versions 1 and 2, with known gyro, accelerometer, motor commands, rotor speeds and
velocity) read back through every conversion, the bad files refused with a sentence, and the real
samples of ../shared (skipped where absent). numpy only: no JAX compile."""
import shutil
import time
from pathlib import Path

import numpy as np
import pytest

from mjxsysid import theta as P
from mjxsysid.logs import crazyflie as C
from mjxsysid.logs.csvlog import read_any_log
from mjxsysid.logs.formats import detect
from mjxsysid.logs.formats_write import usd_log
from support.paths import ROOT

SHARED = ROOT.parent / "shared" / "data" / "logs"
G = P.GRAVITY
D2R = np.pi / 180


def write_usd(path, version, events, records):
    """A uSD log (:func:`~mjxsysid.logs.formats_write.usd_log`): ``events`` [(id, name, [(variable, struct
    code)])], ``records`` [(id, timestamp ticks, values)] in time order."""
    by_event = {}
    for eid, stamp, values in records:
        by_event.setdefault(eid, []).append((stamp, values))
    names = {eid: [v for v, _ in variables] for eid, _, variables in events}
    blocks = [(eid, np.array([s for s, _ in r], np.uint64),
               {n: np.array([v[k] for _, v in r]) for k, n in enumerate(names[eid])}) for eid, r in by_event.items()]
    Path(path).write_bytes(usd_log(version, events, blocks))
    return path


IMU_MOTOR = [(f"acc.{a}", "f") for a in "xyz"] + [(f"gyro.{a}", "f") for a in "xyz"] + \
            [(f"motor.m{k}", "I") for k in range(1, 5)]
DUTY = np.array([0.25, 0.36, 0.49, 0.64])       # Crazyflie M1..M4: √ -> 0.5, 0.6, 0.7, 0.8
GYRO_DEG = np.array([10.0, -20.0, 30.0])
ACC_G = np.array([0.1, -0.2, 1.05])


def flight_v2(path, seconds_ground=1.0, seconds_flight=4.0, cut=None):
    """1 kHz event 'imuMotors' (µs since a boot 5 s before) on the ground, in flight (a motor cut
    in the air at ``cut`` (t0, t1) s: motors off, free fall), on the ground again; a 100 Hz event
    'pose' interleaved."""
    events = [(7, "imuMotors", IMU_MOTOR), (3, "pose", [("locSrv.x", "f"), ("locSrv.yaw", "h")])]
    recs = []
    total = 2 * seconds_ground + seconds_flight
    for i in range(int(total * 1000)):
        t = 5.0 + i * 1e-3
        flying = seconds_ground <= i * 1e-3 < seconds_ground + seconds_flight
        falling = flying and cut is not None and cut[0] <= t < cut[1]
        if flying and not falling:
            vals = [*ACC_G, *GYRO_DEG, *(DUTY * 65535).round().astype(int)]
        else:
            vals = [0.0, 0.0, 0.05 if falling else 1.0, 0.0, 0.0, 0.0, 0, 0, 0, 0]
        recs.append((7, round(t * 1e6), vals))
        if i % 10 == 5:
            recs.append((3, round(t * 1e6) + 300, [0.5, -3]))
    return write_usd(path, 2, events, recs)


@pytest.fixture(scope="module")
def v2(tmp_path_factory):
    return flight_v2(tmp_path_factory.mktemp("cf") / "log", cut=(7.5, 7.8))


def test_synthetic_log_units_frame_order_rate_segment(v2):
    r = C.read(v2)
    s = r["source"]
    n = len(r["t"])
    assert r["imu"].shape == (n, 6) and r["motor"].shape == (n, 4) and r["a_cmd"].shape == (n,)
    assert np.allclose(np.diff(r["t"]), 0.002)
    # flight 6–10 s on the Crazyflie's clock, 0.5 s trimmed at each end; the 0.3 s cut in the air bridged
    assert s["segment"]["t0"] == pytest.approx(6.5, abs=0.003) and s["segment"]["t1"] == pytest.approx(9.5, abs=0.003)
    assert "1 motor cuts in the air" in s["segment"]["why"] and "Crazyflie's clock" in s["segment"]["clock"]
    assert s["rates_hz"]["imu"] == pytest.approx(1000, rel=1e-3) and s["rates_hz"]["motor"] == pytest.approx(1000, rel=1e-3)
    assert r["resampled"]["imu"] == "interpolated (linear) from 1000 Hz"
    assert r["resampled"]["motor"] == "held (zero-order) from 1000 Hz"
    steady = (r["t"] < 7.4) | (r["t"] > 7.9)
    # deg/s -> rad/s, g -> m/s², FLU kept (no sign change)
    np.testing.assert_allclose(r["imu"][steady, :3], np.tile(GYRO_DEG * D2R, (steady.sum(), 1)), rtol=1e-6)
    np.testing.assert_allclose(r["imu"][steady, 3:], np.tile(ACC_G * G, (steady.sum(), 1)), rtol=1e-6)
    # √(pwm/65535), Crazyflie M1, M2, M3, M4 = FR, BR, BL, FL -> mjxsysid FR, FL, BL, BR = M1, M4, M3, M2
    np.testing.assert_allclose(r["motor"][steady], np.tile([0.5, 0.8, 0.7, 0.6], (steady.sum(), 1)), atol=1e-5)
    assert np.all(r["motor"][(r["t"] > 7.55) & (r["t"] < 7.75)] == 0)
    # no setpoints: the measurements stand in, and it is said
    np.testing.assert_array_equal(r["a_cmd"], r["imu"][:, 5])
    np.testing.assert_array_equal(r["omega_cmd"], r["imu"][:, :3])
    assert s["missing"] == ["a_cmd", "omega_cmd", "rotor_speed", "velocity_body"]
    conv = " ".join(s["conversions"])
    for said in ("CRC32 checked: matches", "√(pwm/65535)", "M1, M4, M3, M2", "FLU", "π/180", "no setpoints"):
        assert said in conv
    assert s["events"]["imu"].startswith("imuMotors") and "rotor_speed" not in r
    tn, xn = r["native"]["motor"]
    assert tn[0] <= r["t"][0] and tn[-1] >= r["t"][-1] and xn.shape[1] == 4


def test_segment_override_and_read_any_log_by_content(v2, tmp_path):
    r = C.read(v2, "6.2:7")
    assert r["t"][0] == pytest.approx(6.2) and r["t"][-1] == pytest.approx(7.0, abs=0.002)
    assert "--segment" in r["source"]["segment"]["why"]
    with pytest.raises(ValueError, match="need at least"):
        C.read(v2, "6.2:6.3")
    wrong = shutil.copy(v2, tmp_path / "flight.csv")
    assert detect(wrong) == "Crazyflie uSD"
    assert read_any_log(wrong)["source"]["format"] == "Crazyflie uSD"
    assert C.sniff(Path(v2).read_bytes()[:4096])
    assert not C.sniff(b"ULog\x01\x12\x35" + bytes(100)) and not C.sniff(b"t,gyro_x,gyro_y\n0,1,2\n")
    assert not C.sniff(b"\xbc\x07\x00\x01\x00")                       # an unknown version


def test_version_1_rpm_pwm_names_and_body_velocity(tmp_path):
    """Version 1 (u32 ms), the RPM deck's rotor speeds, the 'pwm' motor names, a state estimate:
    yawed +90°, flying +x in the world, is flying −y (to its right) in its body frame."""
    variables = [(f"gyro.{a}", "f") for a in "xyz"] + [(f"acc.{a}", "f") for a in "xyz"] + \
                [(f"pwm.m{k}_pwm", "H") for k in range(1, 4)] + [("pwm.m4_pwm", "I")] + \
                [(f"rpm.m{k}", "H") for k in range(1, 5)] + \
                [(f"stateEstimate.v{a}", "f") for a in "xyz"] + [(f"stateEstimate.q{a}", "f") for a in "xyzw"]
    rng = np.random.default_rng(0)
    recs = []
    for i in range(3000):                                              # 6 s at 500 Hz, airborne throughout
        duty = np.clip(DUTY + 0.05 * rng.standard_normal(4), 0.05, 1.0)
        pwm = (duty * 65535).round()
        rpm = (20000 * np.sqrt(pwm / 65535)).round()
        h = np.sqrt(0.5)
        recs.append((65535, 1000 + 2 * i, [0, 0, 0, 0, 0, 1.0, *pwm.astype(int), *rpm.astype(int),
                                           1.0, 0, 0, 0, 0, h, h]))
    path = write_usd(tmp_path / "jana", 1, [(65535, "fixedFrequency", variables)], recs)
    r = C.read(path)
    s = r["source"]
    assert s["version"] == 1 and s["rates_hz"]["imu"] == pytest.approx(500) and r["resampled"]["imu"] == "native (500 Hz)"
    assert "kept whole" in s["segment"]["why"] and s["missing"] == ["a_cmd", "omega_cmd"]
    np.testing.assert_allclose(r["velocity_body"], np.tile([0.0, -1.0, 0.0], (len(r["t"]), 1)), atol=1e-6)
    w = 20000 * 2 * np.pi / 60                                         # rad/s at full command
    fit = s["rotor_speed_fit"]
    assert fit["slope"] == pytest.approx(w, rel=1e-3) and fit["r2"] > 0.999 and abs(fit["intercept"]) < 5
    tn, u = r["native"]["motor"]
    np.testing.assert_allclose(r["native"]["rotor_speed"][1], w * u, rtol=2e-3)   # same order as the motors
    assert "pwm.m1_pwm" in s["events"]["motor"] and "R² 1.000" in " ".join(s["conversions"])


def test_refusals_name_the_file_the_problem_and_the_next_step(v2, tmp_path):
    no_motor = write_usd(tmp_path / "nomotor", 2, [(1, "fixedFrequency", IMU_MOTOR[:6])],
                         [(1, 1000 * i, [0, 0, 1, 0, 0, 0]) for i in range(500)])
    with pytest.raises(ValueError, match=r"nomotor: no event logs the motor commands .*fixedFrequency: acc.x.*config.txt"):
        C.read(no_motor)
    data = Path(v2).read_bytes()
    cut = tmp_path / "cut"
    cut.write_bytes(data[:len(data) // 2 + 7])                         # power lost while logging
    with pytest.raises(ValueError, match="cut: the uSD log ends mid-record .*close_truncated"):
        C.read(cut)
    assert C.close_truncated(cut, tmp_path / "closed") > 0
    assert C.read(tmp_path / "closed", "6:7")["source"]["conversions"][0].startswith("CRC32 checked: matches")
    flipped = bytearray(data)
    flipped[len(data) // 2] ^= 0x01                                    # one bit changed on the card
    (tmp_path / "flip").write_bytes(bytes(flipped))
    assert "warning: the CRC32" in C.read(tmp_path / "flip")["source"]["conversions"][0]
    (tmp_path / "text").write_bytes(b"\xbc hello")
    with pytest.raises(ValueError, match="text: not a readable Crazyflie uSD log"):
        C.read(tmp_path / "text")


def test_fifty_seconds_at_1khz_with_two_events_read_fast(tmp_path):
    path = flight_v2(tmp_path / "long", seconds_ground=5.0, seconds_flight=40.0)
    t = time.perf_counter()
    r = C.read(path)
    assert time.perf_counter() - t < 1.5 and len(r["native"]["imu"][0]) >= 39000


REAL = {  # file: (segment must lie within, README's rate)
    "crazyflie/log10.bin": ((31.0, 69.5), 1011),
    "crazyflie/log15.bin": ((50.5, 94.0), 1011),
    "crazyflie/log16.bin": ((31.0, 39.5), 1012),
    "formats/crazyflie_usd/jana00": ((None, None), 507),
    "formats/crazyflie_usd/jana01": ((None, None), 507),
}


@pytest.mark.parametrize("name", sorted(REAL))
def test_real_samples(name):
    path = SHARED / name
    if not path.is_file():
        pytest.skip(f"{path} not found (../shared is absent)")
    (lo, hi), rate = REAL[name]
    assert detect(path) == "Crazyflie uSD"
    r = C.read(path)
    s = r["source"]
    seg = s["segment"]
    assert s["rates_hz"]["imu"] == pytest.approx(rate, rel=0.01)
    assert 9.3 < r["imu"][:, 5].mean() < 10.6                      # hover specific force z ≈ +g (FLU)
    if lo is None:                                                  # airborne throughout
        assert "kept whole" in seg["why"] and len(r["t"]) * 0.002 > 9.0
        assert 1700 < r["rotor_speed"].min() and r["rotor_speed"].max() < 2600      # rad/s, 18–23 k rpm
        assert s["rotor_speed_fit"]["r2"] > 0.6 and np.abs(r["velocity_body"]).max() < 1.5
    else:
        assert lo <= seg["t0"] and seg["t1"] <= hi and seg["t1"] - seg["t0"] > 0.8 * (hi - lo - 1.5)
        assert "rotor_speed" not in r and "velocity_body" not in r
