"""Betaflight blackbox logs (mjxsysid.logs.blackbox): a log written here (headers, I frames, known
gyro/acc/motors/setpoints) read back with every conversion checked, and the real samples of
shared/data/logs/formats/blackbox (Indiflight 504 Hz, Betaflight 3.1.5 1980 Hz), skipped without them.
numpy and orangebox only: no JAX compile."""
import shutil
import sys

import numpy as np
import pytest

pytest.importorskip("orangebox")

from mjxsysid.logs import blackbox as B
from mjxsysid.logs.csvlog import read_any_log
from mjxsysid.logs.formats import detect
from mjxsysid.logs.blackbox_frames import END_OF_LOG
from mjxsysid.logs.formats_write import BLACKBOX_IDLE, blackbox_log
from support.paths import ROOT

SAMPLES = ROOT.parent / "shared" / "data" / "logs" / "formats" / "blackbox"
INDIFLIGHT = SAMPLES / "indiflight_iros2024_LOG00281.BFL"
BETAFLIGHT = SAMPLES / "betaflight315_cs110_example_smooth_tune.BBL"

RATE = 1000                                   # Hz of the written log
MOTOR_FLIGHT = (1000, 700, 800, 900)          # M1 rear-right, M2 front-right, M3 rear-left, M4 front-left
IDLE = BLACKBOX_IDLE


def flight_fields(indiflight: bool = True, seconds=(1.0, 3.0, 1.0)) -> dict:
    """Idle on the ground, flight, idle; two garbage frames first (time far ahead)."""
    n0, n1, n2 = (int(s * RATE) for s in seconds)
    n = n0 + n1 + n2
    t = 1_000_000 + np.arange(n) * (1_000_000 // RATE)
    t = np.concatenate([[50_000_000, 50_000_500], t])
    n += 2
    fly = np.zeros(n, bool)
    fly[2 + n0:2 + n0 + n1] = True
    col = lambda v: np.full(n, v)                                   # noqa: E731
    f = {"time": t}
    f.update({f"gyroADC[{i}]": col(v) for i, v in enumerate((100, -200, 300))})     # deg/s × 10
    f.update({f"accSmooth[{i}]": col(v) for i, v in enumerate((205, -410, 2048))})
    f.update({f"motor[{i}]": np.where(fly, v, IDLE) for i, v in enumerate(MOTOR_FLIGHT)})
    if indiflight:
        f.update({f"gyroSp[{i}]": col(v) for i, v in enumerate((50, 60, 70))})          # FRD, deg/s × 10
        f.update({f"spfSp[{i}]": col(v) for i, v in enumerate((0, 0, -981))})          # cm/s², FRD
        f.update({f"omega[{i}]": col(v) for i, v in enumerate((1000, 2000, 3000, 4000))})
        f.update({f"vel[{i}]": col(v) for i, v in enumerate((0, 100, 50))})            # cm/s NED: east, down
        c = int(round(np.cos(np.pi / 4) * B.QUAT_SCALE))
        f.update({f"quat[{i}]": col(v) for i, v in enumerate((c, 0, 0, c))})           # yaw 90°: nose east
    return f


HEADERS = {"Firmware revision": "Indiflight 5.0.0 (test)", "gyro_scale": "0x3f800000", "motorOutput": f"{IDLE},2047",
           "acc_1G": "2048", "blackbox_high_resolution": "1"}


@pytest.fixture(scope="module")
def written(tmp_path_factory):
    path = tmp_path_factory.mktemp("bb") / "LOG00001.BFL"
    path.write_bytes(blackbox_log(flight_fields(), HEADERS))
    return path, B.read(path)


def test_written_log_units_frame_order_rate_and_segment(written):
    path, r = written
    n = len(r["t"])
    assert np.allclose(np.diff(r["t"]), 0.002) and r["imu"].shape == (n, 6) and r["motor"].shape == (n, 4)
    # gyro deg/s × 10 -> rad/s, already FLU; acc / acc_1G × g, already FLU
    np.testing.assert_allclose(r["imu"][:, :3], np.deg2rad([10.0, -20.0, 30.0]) * np.ones((n, 1)), rtol=1e-9)
    np.testing.assert_allclose(r["imu"][:, 3:], np.array([205, -410, 2048]) / 2048 * 9.81 * np.ones((n, 1)), rtol=1e-9)
    # motors: √((m − idle) / (2047 − idle)), mjxsysid order FR (M2), FL (M4), BL (M3), BR (M1)
    m1, m2, m3, m4 = MOTOR_FLIGHT
    want = np.sqrt((np.array([m2, m4, m3, m1]) - IDLE) / (2047 - IDLE))
    np.testing.assert_allclose(r["motor"][n // 2], want, rtol=1e-9)
    # Indiflight setpoints FRD -> FLU, spfSp cm/s² z down -> a_cmd m/s² up
    np.testing.assert_allclose(r["omega_cmd"][0], np.deg2rad([5.0, -6.0, -7.0]), rtol=1e-9)
    np.testing.assert_allclose(r["a_cmd"], 9.81, rtol=1e-9)
    np.testing.assert_allclose(r["rotor_speed"][0], [2000, 4000, 3000, 1000])
    # 1 m/s east, 0.5 m/s down, nose east: 1 m/s forward, 0.5 m/s along −z (FLU)
    np.testing.assert_allclose(r["velocity_body"][0], [1.0, 0.0, -0.5], atol=1e-3)
    src = r["source"]
    assert src["rates_hz"]["imu"] == pytest.approx(RATE) and src["missing"] == []
    assert r["resampled"]["imu"] == "interpolated (linear) from 1000 Hz"
    assert r["resampled"]["motor"] == "held (zero-order) from 1000 Hz"
    # the garbage frames dropped, t from the first valid frame; airborne 1–4 s, 0.5 s trimmed at each end
    assert "2 of 5002 dropped" in " ".join(src["conversions"])
    seg = src["segment"]
    assert seg["t0"] == pytest.approx(1.5, abs=0.01) and seg["t1"] == pytest.approx(3.5, abs=0.01)
    assert "airborne" in seg["why"]
    tn, xn = r["native"]["imu"]
    assert len(tn) == pytest.approx(2 * RATE, abs=3) and np.median(np.diff(tn)) == pytest.approx(1e-3)


def test_segment_argument_and_read_any_log_by_content(written, tmp_path):
    path, _ = written
    r = B.read(path, "0.5:2")
    assert r["t"][0] == pytest.approx(0.5) and r["t"][-1] == pytest.approx(2.0)
    assert "--segment" in r["source"]["segment"]["why"]
    assert r["motor"][0].max() == 0 and r["motor"][-1].min() > 0.3        # idle on the ground, then flying
    other = tmp_path / "flight.csv"
    shutil.copy(path, other)
    assert detect(other) == "Betaflight blackbox"
    assert read_any_log(other)["source"]["format"] == "Betaflight blackbox"
    with pytest.raises(ValueError, match="end must come after"):
        B.read(path, "2:1")


def test_log_without_setpoints_fills_them_and_says_so(tmp_path):
    path = tmp_path / "bf.bbl"
    path.write_bytes(blackbox_log(flight_fields(indiflight=False),
                                    {**HEADERS, "blackbox_high_resolution": "0", "Firmware revision": "Betaflight"}))
    r = B.read(path)
    assert r["source"]["missing"] == ["omega_cmd", "a_cmd"] and "rotor_speed" not in r
    np.testing.assert_allclose(r["omega_cmd"], r["imu"][:, :3])
    np.testing.assert_allclose(r["a_cmd"], r["imu"][:, 5])
    np.testing.assert_allclose(r["imu"][0, :3], np.deg2rad([100.0, -200.0, 300.0]), rtol=1e-9)   # no / 10
    conv = " ".join(r["source"]["conversions"])
    assert "filled with the measured gyro" in conv and "filled with the measured specific force" in conv


def test_several_logs_largest_by_default_or_log_index(tmp_path):
    short = blackbox_log(flight_fields(seconds=(0.5, 2.5, 0.5)), HEADERS)
    long = blackbox_log(flight_fields(seconds=(0.5, 3.5, 0.5)), HEADERS)
    path = tmp_path / "two.bbl"
    path.write_bytes(short + long)
    r = B.read(path)
    assert r["source"]["log_index"] == 2 and "log 2 of 2 (the largest" in r["source"]["conversions"][0]
    one = B.read(path, log_index=1)
    assert one["source"]["segment"]["t1"] < r["source"]["segment"]["t1"]
    with pytest.raises(ValueError, match="numbered 1..2"):
        B.read(path, log_index=3)


def test_bad_input_and_missing_dependency(tmp_path, monkeypatch, written):
    assert not B.sniff(b"ULog\x01\x12\x35") and B.sniff(written[0].read_bytes()[:4096])
    junk = tmp_path / "junk.bbl"
    junk.write_bytes(b"not a blackbox log at all\n")
    with pytest.raises(ValueError, match="not a blackbox log"):
        B.read(junk)
    hexa = tmp_path / "hexa.bbl"
    f = flight_fields(indiflight=False)
    f["motor[4]"] = f["motor[0]"]
    hexa.write_bytes(blackbox_log(f, HEADERS))
    with pytest.raises(ValueError, match="more than four motors"):
        B.read(hexa)
    noacc = tmp_path / "noacc.bbl"
    f = {k: v for k, v in flight_fields(indiflight=False).items() if not k.startswith("accSmooth")}
    noacc.write_bytes(blackbox_log(f, HEADERS))
    with pytest.raises(ValueError, match=r"no accSmooth\[0\]"):
        B.read(noacc)
    props_out = tmp_path / "props_out.bbl"
    props_out.write_bytes(blackbox_log(flight_fields(indiflight=False), {**HEADERS, "yaw_motors_reversed": "1"}))
    with pytest.raises(ValueError, match="props out"):
        B.read(props_out)
    monkeypatch.setitem(sys.modules, "orangebox", None)
    assert B.read(written[0])["source"]["format"] == "Betaflight blackbox"      # decoded without orangebox
    odd = tmp_path / "odd.bbl"                                   # an encoding the decoder does not plan: orangebox's
    odd.write_bytes(written[0].read_bytes().replace(b"H Field P encoding:1,1,", b"H Field P encoding:10,1,"))
    with pytest.raises(ImportError, match=r'pip install -e "\.\[blackbox\]"'):
        B.read(odd)


def _p_frames_log() -> bytes:
    """A log of one I frame and three P frames by hand: every group encoding (tag8_4s16 in 4-, 8- and
    16-bit fields across nibbles, tag2_3s32 in each of its four layouts, tag8_8svb with a field left
    out, null; not last: orangebox loops forever on a group that ends the frame) and the predictors
    previous, straight line, average of two and increment."""
    from mjxsysid.logs.formats_write import _vb_bytes

    def vb(*vals, signed=True):
        out = b""
        for v in vals:
            b, m = _vb_bytes([(v << 1) ^ (v >> 63) if signed else v])
            out += b[m].tobytes()
        return out
    names = ["loopIteration", "time", "a", "b", "c", "d", "e", "f", "g", "h", "x", "y", "z"]
    head = [B.MAGIC.decode(), "H Data version:2", "H I interval:32", "H P interval:1/1",
            "H Firmware type:Cleanflight", f"H Field I name:{','.join(names)}",
            "H Field I signed:0,0,1,1,1,1,1,1,1,1,1,1,1", "H Field I predictor:0,0,0,0,0,0,0,0,0,0,0,0,0",
            "H Field I encoding:1,1,0,0,0,0,0,0,0,0,0,0,0", "H Field P predictor:6,2,1,3,3,3,3,1,1,1,1,1,1",
            "H Field P encoding:9,0,0,8,8,8,8,7,7,7,6,6,0"]
    body = b"I" + vb(0, 1000, signed=False) + vb(5, -3, 40, 700, -9, 1, 2, 3, 100, -100, 7)
    tag4 = bytes([1 | 2 << 2 | 3 << 4 | 1 << 6, 0x3A, 0xBC, 0xDE, 0xF7])
    tag3 = bytes([0xC0 | 0 | 1 << 2 | 3 << 4, 0x85, 0x34, 0x92, 1, 2, 3, 0x84])   # 8-, 16- and 32-bit fields
    body += b"P" + vb(2, -1) + tag4 + tag3 + b"\x01" + vb(-7, 1)
    body += b"P" + vb(0, 4) + bytes([0]) + bytes([0x1B]) + b"\x03" + vb(5, -6, -2)
    body += b"P" + vb(1, 0) + bytes([2 | 2 << 2 | 2 << 4 | 2 << 6, 0x80, 0x7F, 0x01, 0xFE]) + bytes([0x45, 0xE2]) \
        + b"\x02" + vb(9, 300)
    body += b"P" + vb(0, 0) + bytes([0]) + bytes([0x8F, 0x21, 0x3F]) + b"\x00" + vb(0)
    return "\n".join(head).encode() + b"\n" + body + b"E\xff" + END_OF_LOG


def test_p_frames_decode_as_orangebox(tmp_path):
    """The decoder and orangebox (the reference) agree frame by frame on every encoding and predictor."""
    from orangebox import Parser
    from orangebox.types import FrameType
    from mjxsysid.logs.blackbox_frames import decode_frames
    data = _p_frames_log()
    path = tmp_path / "p.bbl"
    path.write_bytes(data)
    headers, names, frames = decode_frames(data, 0, len(data))
    parser = Parser.load(str(path))
    ref = [list(f.data[:len(names)]) for f in parser.frames()]
    assert names == [f.name for f in parser.reader.field_defs[FrameType.INTRA]] and len(frames) == 5
    assert frames == ref and headers == dict(parser.headers)
    assert [f[0] for f in frames] == [0, 1, 2, 3, 4] and frames[1][3:7] == [-3 + 3, 40 - 85, 700 - 12817, -9 + 7]


def test_tag8_4s16_needs_data_version_2():
    """tag8_4s16 (encoding 8) changed its layout in data version 2: under version 1, or no version
    header, the decoder refuses it."""
    from mjxsysid.logs.blackbox_frames import Unsupported, decode_frames
    data = _p_frames_log()
    for old in (data.replace(b"H Data version:2", b"H Data version:1"), data.replace(b"H Data version:2\n", b"")):
        with pytest.raises(Unsupported, match="data version 1"):
            decode_frames(old, 0, len(old))


def test_dshot_command_and_frames():
    np.testing.assert_allclose(B.rotor_command(np.array([[158, 2047, 1102.5, 0]]), 158, 2047),
                               [[1.0, 0.0, np.sqrt(0.5), 0.0]])                         # FR=M2, FL=M4, BL=M3, BR=M1
    assert B.hex_float(1065353216) == 1.0 and B.hex_float("0x40000000") == 2.0
    assert B.clean_run(np.array([900, 10, 20, 30, 5, 6])) == (1, 4)
    q = np.array([[np.cos(np.pi / 4), 0, 0, np.sin(np.pi / 4)]])
    np.testing.assert_allclose(B.world_to_body(q, np.array([[0.0, 1.0, 0.0]])), [[1.0, 0.0, 0.0]], atol=1e-12)


@pytest.fixture(scope="module")
def indiflight():
    if not INDIFLIGHT.is_file():
        pytest.skip(f"blackbox samples not found at {SAMPLES}")
    return B.read(INDIFLIGHT)


@pytest.fixture(scope="module")
def betaflight():
    if not BETAFLIGHT.is_file():
        pytest.skip(f"blackbox samples not found at {SAMPLES}")
    return B.read(BETAFLIGHT)


@pytest.mark.parametrize("sample", [INDIFLIGHT, BETAFLIGHT], ids=["indiflight", "betaflight"])
def test_samples_decode_as_orangebox(sample):
    """Frame by frame as orangebox, but where orangebox misreads: Betaflight's log opens with a
    logging-resume event (two values) that orangebox reads as nothing, so its first frames are garbage
    (loop iteration 1, 4, 8, … at 517, 502, 489 µs), where the decoder reads the resumed iteration 80,608."""
    if not sample.is_file():
        pytest.skip(f"{sample} not found (../shared is absent)")
    from orangebox import Parser
    from orangebox.types import FrameType
    from mjxsysid.logs.blackbox_frames import decode_frames
    data = sample.read_bytes()
    _, names, frames = decode_frames(data, 0, len(data))
    parser = Parser.load(str(sample))
    ref = [list(f.data[:len(names)]) for f in parser.frames()]
    assert names == [f.name for f in parser.reader.field_defs[FrameType.INTRA]]
    if sample == INDIFLIGHT:
        assert frames == ref
    else:
        assert frames[-76329:] == ref[-76329:] and len(frames) == len(ref) + 1
        assert [f[0] for f in frames[:2]] == [80608, 80612] and [f[0] for f in ref[:2]] == [1, 4]


def test_indiflight_sample(indiflight):
    r, src = indiflight, indiflight["source"]
    assert src["rates_hz"]["imu"] == pytest.approx(504.3, abs=0.5) and src["missing"] == []
    seg = src["segment"]
    assert 0.5 < seg["t0"] and seg["t1"] < 43 and seg["t1"] - seg["t0"] > 15      # airborne 0.9–42.8 s
    assert np.median(r["imu"][:, 5]) == pytest.approx(9.9, abs=0.4)
    assert 1000 < np.median(r["rotor_speed"]) < 3000 and r["rotor_speed"].max() < 4200
    for i in range(3):                                                              # setpoints in the gyro's frame
        assert np.corrcoef(r["omega_cmd"][:, i], r["imu"][:, i])[0, 1] > 0.5
    assert np.corrcoef(r["a_cmd"], r["imu"][:, 5])[0, 1] > 0.5
    for i in range(2):                                                              # rotor drag opposes body velocity
        assert np.corrcoef(r["velocity_body"][:, i], r["imu"][:, 3 + i])[0, 1] < -0.1


def test_betaflight_sample(betaflight):
    r, src = betaflight, betaflight["source"]
    assert src["rates_hz"]["imu"] == pytest.approx(1980, rel=0.01)
    assert "dropped" not in " ".join(src["conversions"])      # the logging-resume event read: no garbage frames
    assert src["missing"] == ["omega_cmd", "a_cmd"]
    seg = src["segment"]
    assert seg["t0"] == pytest.approx(0, abs=0.5) and 36 < seg["t1"] < 39
    assert np.median(r["imu"][:, 5]) == pytest.approx(9.9, abs=0.4)
    assert 0.3 < r["motor"].mean() < 0.7 and r["motor"].max() <= 1
