"""mujoco.sysid as the independent estimate beside the log-grounded posterior
(mjxsysid.identify.mujoco_sysid): on a log MuJoCo itself flew with the same model (so the
model is exact), Gauss–Newton from a start 25 % off recovers every visible coordinate and the
s²(JᵀJ)⁻¹ intervals hold the truth (10 or more of 13); bad inputs are named."""
import numpy as np
import pytest

pytest.importorskip("tabulate")          # mujoco's sysid extra (in the dev extra)
import mujoco
import mujoco.rollout

from mjxsysid import theta as P
from mjxsysid.identify import mujoco_sysid as MS
from mjxsysid.identify.coords import (
    LOG_NAMES,
    hidden_from_theta,
    log_quantities,
    theta_from,
    visible_from_theta,
)

DT = 0.002


def mujoco_log(theta, seconds=2.0, gyro_noise=0.0, acc_noise=0.0, seed=0):
    """Fly θ (19,) with MuJoCo's model of :mod:`.mujoco_sysid` from hover under chirped motor
    commands -> imu (T, 6), motor (T, 4), qpos (T, 7), qvel (T, 6): row k is the state the step k
    starts from, the reading MuJoCo's step k records and the command it applies."""
    rng = np.random.default_rng(seed)
    spec = MS.quadrotor_spec(DT)
    MS.apply_theta(spec, theta)
    model = spec.compile()
    data = mujoco.MjData(model)
    t = np.asarray(theta, np.float64)
    n = int(seconds / DT)
    hover = np.sqrt(t[P.MASS] * P.GRAVITY / (4 * t[P.KT] * t[P.ETA])) / t[P.OMEGA_MAX]
    tt = DT * np.arange(n)[:, None]
    d = P.ROTOR_DIRECTIONS.astype(np.float64)
    roll, pitch, yaw = (0.04 * np.sin(2 * np.pi * f * tt + p) for f, p in ((3.1, 0.0), (2.3, 1.0), (1.7, 2.0)))
    motor = np.clip(hover * (1 + 0.03 * np.sin(2 * np.pi * 1.1 * tt) + d[:, 1] * roll - d[:, 0] * pitch
                             + P.YAW_SIGNS * yaw), 0, 1)
    ctrl = np.concatenate([motor ** 2, np.ones((n, 3))], 1)
    data.qpos[:] = [0, 0, 1, 1, 0, 0, 0]
    data.act[:4] = hover ** 2
    state0 = np.empty(mujoco.mj_stateSize(model, mujoco.mjtState.mjSTATE_FULLPHYSICS))
    mujoco.mj_getState(model, data, state0, mujoco.mjtState.mjSTATE_FULLPHYSICS)
    state, sens = mujoco.rollout.rollout(model, data, state0, ctrl)
    states = np.concatenate([state0[None], state[0, :-1]], 0)
    imu = sens[0] + np.concatenate([np.full(3, gyro_noise), np.full(3, acc_noise)]) * rng.standard_normal((n, 6))
    return imu, motor, states[:, 1:8], states[:, 8:14]


@pytest.fixture(scope="module")
def vehicle():
    th = np.asarray(P.paper_hardware(), np.float64).copy()
    th[P.ETA] = [0.85, 1.0, 1.05, 0.95]
    th[P.TAU_EXT] = [2e-4, -1e-4, 5e-5]
    th[P.DRAG] = 1e-6                      # MuJoCo's model has no drag (the fit's body-z drag stays ~0)
    return th


def test_exact_model_recovers_every_visible_coordinate_and_covers_it(vehicle):
    imu, motor, qpos, qvel = mujoco_log(vehicle, gyro_noise=0.005, acc_noise=0.05)
    v = np.asarray(visible_from_theta(vehicle), np.float64)
    off = v.copy()
    off[[0, 4, 5, 6, 7, 8]] += np.log(1.25)                  # the log coordinates 25 % high
    off[9:12] *= 0.5
    start = np.asarray(theta_from(off, np.asarray(hidden_from_theta(vehicle), np.float64), np.float64))
    r = MS.identify(imu, motor, qpos, qvel, start_theta=start, max_chunks=8, max_iters=12)
    q, truth = r.quantities(), log_quantities(vehicle)
    rel = np.abs(q["estimate"][:10] / truth[:10] - 1)
    assert rel.max() < 0.05 and np.median(rel) < 0.01, dict(zip(LOG_NAMES, rel.round(4)))
    inside = (q["q05"] <= truth) & (truth <= q["q95"])
    assert inside.sum() >= 10, dict(zip(LOG_NAMES, inside))   # 90 % bands: about 1.3 of 13 outside
    assert np.all(q["q95"] - q["q05"] > 0) and np.all(np.isfinite(q["q95"]))
    assert 0.5 < r.s2 < 2.0                                   # residuals normalised by the log's own noise


def test_bad_inputs_are_named(vehicle):
    imu, motor, qpos, qvel = mujoco_log(vehicle, seconds=0.5)
    with pytest.raises(ValueError, match=r"qvel must be \(250, 6\)"):
        MS.identify(imu, motor, qpos, qvel[:, :3])
    with pytest.raises(ValueError, match="log too short for mujoco.sysid"):
        MS.identify(imu, motor, qpos, qvel)
