"""data-driven-dynamics' PX4 tables (mjxsysid.logs.px4csv) where ../shared holds the sample: a PX4 SITL flight
of Gazebo-classic's Iris (../shared/data/logs/px4-sitl-gazebo/quadrotor_model.csv, 55.6 s at 100 Hz). Its
truth, from PX4/PX4-SITL_gazebo-classic models/iris/iris.sdf.jinja: 1.545 kg (base 1.5, IMU 0.015, GPS 0.01,
rotors 4 × 0.005), motorConstant 5.84e-6 N s², Ω = 100 + 1000 u rad/s up to maxRotVelocity 1100: thrust-to-weight
4 · 5.84e-6 · 1100² / (1.545 g) = 1.87; the motors' time constants 12.5 ms up and 25 ms down. The round trip of
a flight the project writes itself is in test_formats_write.py."""
import numpy as np
import pytest

from mjxsysid import theta as P
from mjxsysid.logs.csvlog import read_any_log
from support.paths import SHARED_DATA, require_shared

SAMPLE = SHARED_DATA / "logs" / "px4-sitl-gazebo" / "quadrotor_model.csv"
TWR = 4 * 5.84e-6 * 1100 ** 2 / (1.545 * P.GRAVITY)
PWM_HOVER = 1710.0


def test_the_gazebo_iris_table_reads_as_a_hovering_quadrotor():
    """Detected by content; 100 Hz in every column, off the ground throughout (55.6 s); the specific force
    +9.7 m/s² along body z (FLU) at hover, every rotor at √u of its median PWM, a body velocity within the
    flight's few m/s; the gyro from ang_vel (ang_acc_b is its derivative, not a rate)."""
    r = read_any_log(require_shared(SAMPLE))
    s = r["source"]
    assert s["format"] == "PX4 CSV (data-driven-dynamics)" and s["missing"] == ["a_cmd", "omega_cmd"]
    assert all(abs(hz - 100.0) < 0.5 for hz in s["rates_hz"].values()), s["rates_hz"]
    assert 55.0 < r["t"][-1] - r["t"][0] < 56.0 and "landed column" in s["segment"]["why"]
    assert 9.5 < np.median(r["imu"][:, 5]) < 9.9
    np.testing.assert_allclose(np.median(r["motor"], 0), np.sqrt((PWM_HOVER - 1000) / 1000), atol=0.01)
    v = r["velocity_body"]
    assert np.all(np.isfinite(v)) and np.abs(v).max() < 10 and np.abs(v).max(0)[0] > 2
    assert np.abs(np.median(r["imu"][:, :3], 0)).max() < 0.01          # a rate, not an angular acceleration


@pytest.mark.slow
def test_the_gazebo_iris_thrust_to_weight_is_inside_through_the_motor_map_check():
    """The table read through PX4's THR_MDL_FAC 0 (thrust ∝ u) while Gazebo's rotor speed is linear in u from
    0.09 Ω_max: under the linear map thrust-to-weight comes out 1.54, 17 % low and sharp. The motor-map check
    flags it, a convex map fits best (κ 2, idle +0.1: Gazebo's own), and the calibrated band holds 1.87. The fast
    check of the same: tests/identify/test_idlecheck.py's convex map on an exact-model log."""
    from mjxsysid.identify import coords as C
    from mjxsysid.identify.inference import log_grounded_posterior
    rec = read_any_log(require_shared(SAMPLE))
    post = log_grounded_posterior(rec, None, samples=600, particles=512, seed=0, refine=True)
    f = post["features"]
    assert f["idle_gain"] > 20 and "κ 2" in f["idle_at"], f["idle_at"]
    lo, hi = np.percentile(C.log_quantities(post["theta"])[:, 0], [5, 95])
    assert lo <= TWR <= hi and hi / lo < 1.4, (lo, hi)


def test_a_file_of_no_known_format_is_refused_by_what_it_is(tmp_path):
    """An empty file, and a binary file no reader claims, are named as such (not as a broken CSV)."""
    (tmp_path / "empty.ulg").write_bytes(b"")
    with pytest.raises(ValueError, match=r"empty.ulg: empty file \(0 bytes\)"):
        read_any_log(tmp_path / "empty.ulg")
    (tmp_path / "noise.bin").write_bytes(np.random.default_rng(0).integers(0, 256, 5000, dtype=np.uint8).tobytes())
    with pytest.raises(ValueError, match=r"noise.bin: not a flight log mjxsysid reads: .*PX4 ULog.*not a text CSV"):
        read_any_log(tmp_path / "noise.bin")
