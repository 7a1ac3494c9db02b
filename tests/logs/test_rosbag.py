"""ROS bags (mjxsysid.logs.rosbag): a ROS 1 bag and a ROS 2 bag written here (mavros topics with known
gyro, accelerometer, PWM, rate setpoints and velocity; header stamps apart from the receive times)
read back through every conversion, and the real mavros sample of /work/shared (skipped where
absent). numpy only: no JAX."""
import shutil
import sys
from pathlib import Path

import numpy as np
import pytest

pytest.importorskip("rosbags")

from rosbags.rosbag2 import StoragePlugin

from mjxsysid.logs import rosbag as R
from mjxsysid.logs.csvlog import read_any_log
from mjxsysid.logs.formats import detect
from mjxsysid.logs.formats_write import write_bag
from mjxsysid.logs.rosbag import typestore_with_mavros

SHARED = Path(__file__).resolve().parents[2] / ".." / "shared" / "data" / "logs" / "formats"
SAMPLE = SHARED / "rosbag" / "bintel_2018-07-18-17-07-35.bag"

BASE = 1_600_000_000.0            # header stamps, s
IMU_LAG, RC_LAG = 0.05, 0.3       # s the bag received each message after its stamp
PWM = (1500, 1600, 1700, 1800)    # PX4 outputs 1..4 in flight (M1 FR, M2 BL, M3 FL, M4 BR)


def _messages(ts):
    """(topic, msgtype, receive time ns, message) of a 10 s flight, motors up 2–8.5 s (stamp time)."""
    T = ts.types
    Time, Header, Vec, Quat = (T["builtin_interfaces/msg/Time"], T["std_msgs/msg/Header"],
                               T["geometry_msgs/msg/Vector3"], T["geometry_msgs/msg/Quaternion"])

    def header(t, frame=""):
        sec = int(t)
        return Header(seq=0, stamp=Time(sec=sec, nanosec=int(round((t - sec) * 1e9))), frame_id=frame) \
            if "seq" in Header.__dataclass_fields__ else \
            Header(stamp=Time(sec=sec, nanosec=int(round((t - sec) * 1e9))), frame_id=frame)

    yaw90 = Quat(x=0.0, y=0.0, z=np.sin(np.pi / 4), w=np.cos(np.pi / 4))     # body x points north (ENU)
    out = []
    cov = np.zeros(9)
    for i in range(2000):                                                   # 200 Hz IMU
        t = BASE + 0.005 * i
        imu = T["sensor_msgs/msg/Imu"](header=header(t, "base_link"), orientation=yaw90, orientation_covariance=cov,
                                       angular_velocity=Vec(x=0.1, y=-0.2, z=0.3), angular_velocity_covariance=cov,
                                       linear_acceleration=Vec(x=0.5, y=0.6, z=9.81),
                                       linear_acceleration_covariance=cov)
        out.append(("/uav/imu/data", "sensor_msgs/msg/Imu", t + IMU_LAG, imu))
        if i % 2 == 0:                                                      # 100 Hz motors
            flying = 2.0 <= t - BASE <= 8.5
            ch = np.array(list(PWM) + [0] * 4 if flying else [1100] * 4 + [0] * 4, np.uint16)
            out.append(("/uav/rc/out", "mavros_msgs/msg/RCOut", t + RC_LAG,
                        T["mavros_msgs/msg/RCOut"](header=header(t), channels=ch)))
        if i % 4 == 0:                                                      # 50 Hz setpoints, velocity, a 2nd IMU
            out.append(("/uav/setpoint/target_attitude", "mavros_msgs/msg/AttitudeTarget", t + IMU_LAG,
                        T["mavros_msgs/msg/AttitudeTarget"](header=header(t), type_mask=0, orientation=yaw90,
                                                            body_rate=Vec(x=0.4, y=0.5, z=0.6), thrust=0.5)))
            tw = T["geometry_msgs/msg/Twist"](linear=Vec(x=0.0, y=1.0, z=0.5), angular=Vec(x=0.0, y=0.0, z=0.0))
            out.append(("/uav/local_position/velocity_local", "geometry_msgs/msg/TwistStamped", t + IMU_LAG,
                        T["geometry_msgs/msg/TwistStamped"](header=header(t, "map"), twist=tw)))
            out.append(("/uav/imu/data_raw", "sensor_msgs/msg/Imu", t + IMU_LAG,
                        T["sensor_msgs/msg/Imu"](header=header(t), orientation=yaw90, orientation_covariance=cov,
                                                 angular_velocity=Vec(x=9.0, y=9.0, z=9.0),
                                                 angular_velocity_covariance=cov,
                                                 linear_acceleration=Vec(x=9.0, y=9.0, z=9.0),
                                                 linear_acceleration_covariance=cov)))
    return [(topic, typ, int(round(t * 1e9)), msg) for topic, typ, t, msg in sorted(out, key=lambda m: m[2])]


def write_ros1(path):
    ts = typestore_with_mavros(True)
    return write_bag(path, ts, _messages(ts))


def write_ros2(path, storage):
    ts = typestore_with_mavros(False)
    return write_bag(path, ts, _messages(ts), storage)


@pytest.fixture(scope="module")
def ros1(tmp_path_factory):
    return write_ros1(tmp_path_factory.mktemp("bag") / "flight.bag")


def check_conversions(r):
    n = len(r["t"])
    assert r["imu"].shape == (n, 6) and np.allclose(np.diff(r["t"]), 0.002)
    np.testing.assert_allclose(r["imu"], np.tile([0.1, -0.2, 0.3, 0.5, 0.6, 9.81], (n, 1)), atol=1e-6)
    # PX4 M1 FR, M2 BL, M3 FL, M4 BR -> mjxsysid FR, FL, BL, BR; √u on 1000–2000 µs
    want = np.sqrt((np.array([PWM[0], PWM[2], PWM[1], PWM[3]]) - 1000) / 1000)
    np.testing.assert_allclose(r["motor"], np.tile(want, (n, 1)), atol=1e-9)
    np.testing.assert_allclose(r["omega_cmd"], np.tile([0.4, 0.5, 0.6], (n, 1)), atol=1e-6)
    np.testing.assert_allclose(r["a_cmd"], 9.81, atol=1e-5)               # filled with the measured specific force
    # world ENU north 1, up 0.5; body x points north: forward 1, up 0.5
    np.testing.assert_allclose(r["velocity_body"], np.tile([1.0, 0.0, 0.5], (n, 1)), atol=1e-6)
    s = r["source"]
    assert s["missing"] == ["a_cmd"] and "/uav/imu/data (2000 messages; not used: /uav/imu/data_raw (500))" \
        == s["topics"]["imu"]
    assert s["rates_hz"]["imu"] == pytest.approx(200, rel=1e-3)
    assert s["rates_hz"]["motor"] == pytest.approx(100, rel=1e-3)
    assert r["resampled"]["imu"] == "interpolated (linear) from 200 Hz"
    # header stamps, not receive times: the motors rise 2 s after the first stamp, the bag starts IMU_LAG after it
    assert s["segment"]["t0"] == pytest.approx(2.0 + 0.5 - IMU_LAG, abs=0.011)
    assert s["segment"]["t1"] == pytest.approx(8.5 - 0.5 - IMU_LAG, abs=0.011)


def test_ros1_bag_conversions(ros1):
    check_conversions(R.read_rosbag(ros1))


@pytest.mark.parametrize("storage", [StoragePlugin.SQLITE3, StoragePlugin.MCAP])
def test_ros2_bag_folder_and_mcap_file(tmp_path, storage):
    folder = write_ros2(tmp_path / "flight", storage)
    check_conversions(R.read_rosbag(folder))
    if storage == StoragePlugin.MCAP:
        (mcap,) = folder.glob("*.mcap")
        assert R.sniff(mcap.read_bytes()[:4096])
        renamed = tmp_path / "flight.log"                  # a bare MCAP file, its suffix wrong
        shutil.copy(mcap, renamed)
        check_conversions(R.read_rosbag(renamed))
    else:
        (db3,) = folder.glob("*.db3")
        assert R.sniff(db3.read_bytes()[:4096])


def test_segment_detection_and_read_any_log(ros1, tmp_path):
    r = R.read_rosbag(ros1, "1:9")
    assert r["t"][0] == pytest.approx(1.0) and r["t"][-1] == pytest.approx(9.0)
    renamed = tmp_path / "flight.csv"
    shutil.copy(ros1, renamed)
    assert detect(renamed) == "ROS bag"
    assert read_any_log(renamed)["source"]["segment"] == R.read_rosbag(ros1)["source"]["segment"]


def test_bad_input_and_missing_rosbags(tmp_path, monkeypatch):
    bad = tmp_path / "x.bag"
    bad.write_bytes(b"not a bag" * 100)
    with pytest.raises(ValueError, match="not a ROS bag"):
        R.read_rosbag(bad)
    with pytest.raises(ValueError, match="without metadata.yaml"):
        R.read_rosbag(tmp_path)
    cut = tmp_path / "cut.bag"
    cut.write_bytes(R.ROS1_MAGIC + b"\n" + bytes(100))
    with pytest.raises(ValueError, match="cut.bag: not a readable ROS bag"):
        R.read_rosbag(cut)
    assert not R.sniff(b"SQLite format 3\x00" + bytes(200))
    monkeypatch.setitem(sys.modules, "rosbags.highlevel", None)
    with pytest.raises(ImportError, match=r'pip install -e "\.\[rosbag\]"'):
        R.read_rosbag(bad)


@pytest.mark.skipif(not SAMPLE.is_file(), reason=f"real ROS bag sample not found at {SAMPLE}")
def test_real_mavros_sample():
    """Intel Aero with PX4 and mavros: /mavros/imu/data 126 Hz median, /mavros/rc/out 127 Hz median,
    motors armed throughout; motion capture shows it on the ground until about 12 s after the bag starts
    and back down at about 33 s."""
    r = R.read_rosbag(SAMPLE)
    s = r["source"]
    assert s["rates_hz"]["imu"] == pytest.approx(126, abs=2) and s["rates_hz"]["motor"] == pytest.approx(127, abs=2)
    assert 0.05 < s["max_gap_s"]["imu"] < 0.1                          # bursty: 89 Hz mean, gaps to 71 ms
    assert s["topics"]["imu"].startswith("/mavros/imu/data") and s["topics"]["motor"].startswith("/mavros/rc/out")
    assert 7 < s["segment"]["t0"] < 13 and 31 < s["segment"]["t1"] < 35
    assert r["imu"][:, 5].mean() == pytest.approx(9.8, abs=0.3)
    assert 0.4 < r["motor"].min() and r["motor"].max() < 0.95
    assert set(s["missing"]) == {"omega_cmd", "a_cmd", "velocity_body"}


def test_ros1_definition_of_another_md5_is_left_to_rosbags_before_any_message_is_gathered(ros1, tmp_path,
                                                                                          monkeypatch):
    """A ROS 1 bag whose IMU definition's MD5 is not the typestore's is left to rosbags, and no message
    matrix is built for it first."""
    from mjxsysid.logs import rosbag_fast
    md5 = typestore_with_mavros(True).generate_msgdef("sensor_msgs/msg/Imu", ros_version=1)[1].encode()
    data = Path(ros1).read_bytes()
    assert md5 in data
    bag = tmp_path / "other_imu.bag"
    bag.write_bytes(data.replace(md5, b"0" * len(md5)))
    with monkeypatch.context() as m:
        m.setattr(rosbag_fast, "_bag", lambda *a: pytest.fail("a message matrix was built"))
        assert R._fast_bag(bag) is None


@pytest.mark.parametrize("kind", ["ros1", "mcap"])
def test_numpy_paths_read_as_rosbags(ros1, tmp_path, monkeypatch, kind):
    """A ROS 1 bag and an MCAP bag read with numpy (chunks, message indexes, fixed-layout messages) give
    rosbags' log to the bit."""
    from mjxsysid.logs import rosbag_fast
    bag = ros1 if kind == "ros1" else write_ros2(tmp_path / "flight", StoragePlugin.MCAP)
    assert R._fast_bag(Path(bag)) is not None
    real, got = rosbag_fast.fields, []
    with monkeypatch.context() as m:      # every topic's fields from the fixed layout, none message by message
        m.setattr(rosbag_fast, "fields", lambda *a, **k: got.append(real(*a, **k)) or got[-1])
        fast = R.read_rosbag(bag)
    assert got and all(g is not None for g in got)
    for name in ("read_ros1", "read_mcap", "fields"):
        monkeypatch.setattr(rosbag_fast, name, lambda *a, **k: None)
    slow = R.read_rosbag(bag)
    assert fast["source"] == slow["source"]
    for k in ("t", "imu", "a_cmd", "omega_cmd", "motor", "velocity_body"):
        np.testing.assert_array_equal(fast[k], slow[k])


def test_connections_of_one_topic_merge_in_time_order():
    """A topic's connections merged by receive time: matrices of one message length stay one matrix,
    messages of other lengths become bytes."""
    from types import SimpleNamespace as NS
    a, b = np.arange(12, dtype=np.uint8).reshape(3, 4), 100 + np.arange(8, dtype=np.uint8).reshape(2, 4)
    bag = NS(messages={1: (np.array([0, 20, 40]), a), 2: (np.array([10, 30]), b)})
    cons = [NS(id=1, msgtype="m"), NS(id=2, msgtype="m")]
    msgtype, t, raw = R._merged(bag, cons)
    assert msgtype == "m" and t.tolist() == [0, 10, 20, 30, 40] and isinstance(raw, np.ndarray)
    np.testing.assert_array_equal(raw, np.stack([a[0], b[0], a[1], b[1], a[2]]))
    bag.messages[2] = (np.array([10, 30]), [b"xy", b"z"])
    assert R._merged(bag, cons)[2] == [a[0].tobytes(), b"xy", a[1].tobytes(), b"z", a[2].tobytes()]
