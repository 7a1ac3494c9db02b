"""Physics of mjxsysid.sim against closed forms, an independent reference and MuJoCo C."""
import jax
import jax.numpy as jnp
import mujoco
import numpy as np
import pytest

from support import reference_dynamics as ref
from mjxsysid import theta as P
from mjxsysid.sim import (Quadrotor, SimConfig, hover_rotor_speed, init_batch, rollout,
                          rollout_batch)
from mjxsysid.sim.rollout import _batched_rollout

B, T = 8, 500  # one compiled shape shared by the tests below


def run(sim, theta, cmds, forces=None, **init):
    theta = np.asarray(theta, np.float32)
    s0 = init_batch(sim, theta, jax.random.PRNGKey(0), **init)
    return rollout_batch(sim, theta, s0, cmds, forces)


def no_torque(theta):
    theta = np.array(theta)
    theta[:, P.TAU_EXT] = 0.0
    return theta


def hover_cmd(theta):
    return np.asarray(hover_rotor_speed(theta) / theta[:, P.OMEGA_MAX, None])


def prior_batch(seed, n=B):
    return np.asarray(P.DEFAULT_PRIOR.sample(jax.random.PRNGKey(seed), n))


def test_hover_equilibrium_random_vehicles(sim):
    th = no_torque(prior_batch(1))
    u = np.broadcast_to(hover_cmd(th)[:, None], (B, T, 4))
    _, fr = run(sim, th, u)
    assert not np.any(fr.diverged)
    drift = np.abs(np.asarray(fr.pos) - [0, 0, 1]).max()
    assert drift < 1e-3, drift  # 1 s of hover
    assert np.abs(np.asarray(fr.omega)).max() < 1e-3
    # Specific force reads +g along body z at hover.
    np.testing.assert_allclose(np.asarray(fr.imu[:, -1, 5]), P.GRAVITY, rtol=1e-4)


def test_motor_step_response(sim):
    th = no_torque(prior_batch(2))
    u = np.full((B, T, 4), 0.8, np.float32)
    _, fr = run(sim, th, u, rotor_speed=np.zeros((B, 4)))
    t = sim.config.dt * np.arange(1, T + 1)
    for b in range(B):
        expect = 0.8 * th[b, P.OMEGA_MAX] * (1 - np.exp(-t / th[b, P.TAU_M]))
        np.testing.assert_allclose(np.asarray(fr.rotor_speed[b, :, 0]), expect,
                                   rtol=1e-4, atol=1e-3 * th[b, P.OMEGA_MAX])


def test_free_fall(sim):
    th = no_torque(prior_batch(3))
    th[:, P.DRAG] = 0.0
    _, fr = run(sim, th, np.zeros((B, T, 4)), rotor_speed=np.zeros((B, 4)), pos=np.array([0, 0, 10.0]))
    t = sim.config.dt * np.arange(1, T + 1)
    z = 10.0 - 0.5 * P.GRAVITY * t**2
    # Semi-implicit Euler: z_k = z0 - g dt² k(k+1)/2, i.e. off by g t dt / 2 at most.
    err = np.abs(np.asarray(fr.pos[:, :, 2]) - z).max()
    assert err <= 0.5 * P.GRAVITY * t[-1] * sim.config.dt * 1.01 + 1e-4, err
    np.testing.assert_allclose(np.asarray(fr.imu[:, -1, 3:]), 0.0, atol=1e-4)  # free fall: 0 g


def test_angular_acceleration_from_differential_thrust(sim):
    th = no_torque(prior_batch(4))
    hov = np.asarray(hover_rotor_speed(th))
    speed = hov * np.array([1.05, 0.95, 0.95, 1.05])  # right side stronger -> roll left (-x)... see below
    u = np.broadcast_to((speed / th[:, P.OMEGA_MAX, None])[:, None], (B, T, 4))
    _, fr = run(sim, th, u, rotor_speed=speed)
    f = th[:, P.ETA] * th[:, P.KT, None] * speed**2
    r = np.asarray(P.rotor_positions(th))
    tau = np.stack([(r[:, :, 1] * f).sum(-1), -(r[:, :, 0] * f).sum(-1),
                    (P.YAW_SIGNS * th[:, P.KTAU, None] / th[:, P.KT, None] * f).sum(-1)], -1)
    alpha = tau / th[:, P.INERTIA]
    # First step from rest: ω = α dt (gyroscopic term vanishes at ω = 0).
    np.testing.assert_allclose(np.asarray(fr.omega[:, 0]), alpha * sim.config.dt, rtol=2e-3,
                               atol=1e-6)
    # Rotors on the right (1, 4) pushing harder roll the vehicle to the left: ω_x < 0.
    assert np.all(np.asarray(fr.omega[:, 0, 0]) < 0)


def test_yaw_sign_convention(sim):
    th = no_torque(prior_batch(5))
    hov = np.asarray(hover_rotor_speed(th))
    speed = hov * np.array([0.97, 1.03, 0.97, 1.03])  # clockwise rotors 2, 4 faster
    u = np.broadcast_to((speed / th[:, P.OMEGA_MAX, None])[:, None], (B, T, 4))
    _, fr = run(sim, th, u, rotor_speed=speed)
    w = np.asarray(fr.omega[:, 10])
    assert np.all(w[:, 2] > 0), w  # reaction torque of clockwise rotors: +z
    np.testing.assert_allclose(w[:, :2], 0.0, atol=1e-4 * np.abs(w[:, 2:]).max())


def test_drag_terminal_velocity(sim):
    th = no_torque(prior_batch(6))
    th[:, P.DRAG] = th[:, P.MASS, None] * 4.0  # time constant m/D = 0.25 s
    fx = 0.3 * th[:, P.MASS]
    forces = np.zeros((B, T, 3), np.float32)
    forces[:, :, 0] = fx[:, None]
    u = np.broadcast_to(hover_cmd(th)[:, None], (B, T, 4))
    _, fr = run(sim, th, u, forces)
    v_term = fx / th[:, 7]
    np.testing.assert_allclose(np.asarray(fr.vel[:, -1, 0]), v_term * (1 - np.exp(-4.0)), rtol=2e-2)


@pytest.fixture(scope="module")
def reference_case():
    th = prior_batch(7, 4)
    rng = np.random.default_rng(0)
    hov = hover_cmd(th)
    cmds = hov[:, None, :] * (1 + 0.1 * np.repeat(rng.uniform(-1, 1, (4, T // 25, 4)), 25, axis=1))
    forces = rng.normal(0, 0.05, (4, T, 3)) * th[:, None, :1]
    ref_states = []
    for b in range(4):
        x0 = np.concatenate([[0, 0, 1, 0, 0, 0, 1, 0, 0, 0, 0, 0, 0], np.asarray(hover_rotor_speed(th[b]))])
        ref_states.append(ref.simulate(th[b], x0, cmds[b], forces[b]))
    return th, cmds.astype(np.float32), forces.astype(np.float32), np.array(ref_states)


def _errors(sim, case):
    th, cmds, forces, xs = case
    n = len(th)  # flown twice over: the (B, T) shape of the other tests (one compile)
    _, fr = run(sim, *(np.concatenate([a, a]) for a in (th, cmds, forces)))
    fr = jax.tree.map(lambda a: a[:n], fr)
    return (np.abs(xs[..., 0:3] - np.asarray(fr.pos)).max(),
            np.abs(xs[..., 10:13] - np.asarray(fr.omega)).max() / np.abs(xs[..., 10:13]).max(),
            np.abs(xs[..., 13:17] - np.asarray(fr.rotor_speed)).max() / th[:, 10].max(),
            np.abs(xs[..., 0:3] - [0, 0, 1]).max())


def test_mjx_matches_numpy_reference(reference_case):
    """1 s of random motor commands (±10 % around hover, 20 Hz) and random forces on 4 random
    vehicles that tumble at up to ~18 rad/s and travel ~3 m. Tolerances: with 4 physics
    substeps (0.5 ms) position within 4 mm and body rates within 2 % of their peak; rotor speeds
    (integrated exactly) within 1e-6 of Ω_max."""
    sim4 = Quadrotor(SimConfig(substeps=4))
    ep, ew, es, travel = _errors(sim4, reference_case)
    assert travel > 0.5  # the case really moves
    assert ep < 4e-3 and ew < 0.02 and es < 1e-6, (ep, ew, es)


def test_substeps_converge_first_order(sim, reference_case):
    """MuJoCo's Euler is first order: 4× smaller steps cut the error about 4×; the default
    single 2 ms step stays within 1.5 cm over the same second."""
    ep1, ew1, _, _ = _errors(sim, reference_case)
    ep4, ew4, _, _ = _errors(Quadrotor(SimConfig(substeps=4)), reference_case)
    assert ep1 < 1.5e-2, ep1
    assert ep1 / ep4 > 3.0, (ep1, ep4)


def test_batched_equals_unbatched(sim):
    th = prior_batch(8)
    rng = np.random.default_rng(1)
    cmds = (hover_cmd(th)[:, None] * (1 + 0.05 * rng.normal(size=(B, T, 4)))).astype(np.float32)
    forces = rng.normal(0, 0.1, (B, T, 3)).astype(np.float32)
    _, frb = run(sim, th, cmds, forces)
    one = jax.jit(lambda t, s, u, f: rollout(sim, t, s, u, f))
    for b in (0, 5):
        s0 = sim.init(th[b], jax.random.split(jax.random.PRNGKey(0), B)[b])
        _, fr = one(th[b], s0, cmds[b], forces[b])
        np.testing.assert_allclose(np.asarray(fr.pos), np.asarray(frb.pos[b]), atol=1e-5)
        np.testing.assert_allclose(np.asarray(fr.omega), np.asarray(frb.omega[b]), atol=1e-4)


def test_new_theta_batch_reuses_compiled_function(sim):
    th = prior_batch(9)
    u = np.broadcast_to(hover_cmd(th)[:, None], (B, T, 4))
    run(sim, th, u)
    n = _batched_rollout(sim)._cache_size()
    th2 = prior_batch(10)
    run(sim, th2, np.broadcast_to(hover_cmd(th2)[:, None], (B, T, 4)))
    assert _batched_rollout(sim)._cache_size() == n


def test_divergence_is_flagged_and_contained(sim):
    th = no_torque(prior_batch(11))
    th[3, P.KT] *= 1e4  # absurd thrust: leaves the speed limit within a few steps
    u = np.broadcast_to(hover_cmd(no_torque(prior_batch(11)))[:, None], (B, T, 4))
    _, fr = run(sim, th, u)
    div = np.asarray(fr.diverged[:, -1])
    assert div[3] and div.sum() == 1
    for leaf in (fr.pos, fr.vel, fr.omega, fr.imu, fr.rotor_speed):
        assert np.all(np.isfinite(np.asarray(leaf)))
    assert np.linalg.norm(np.asarray(fr.vel[3, -1])) < sim.config.vel_limit


def test_matches_mujoco_c_with_same_parameters(sim):
    """θ → model rewrites every field the dynamics use: one MJX step equals MuJoCo C compiled
    with the same vehicle (mass, inertia, rotor sites, gear), including sensors."""
    th = prior_batch(12, 1)[0]
    mj = mujoco.MjModel.from_xml_path(str(P.vehicle_path("x").parent.parent / "quadrotor.xml"))
    mj.body_mass[1] = th[P.MASS]
    mj.body_inertia[1] = th[P.INERTIA]
    for i in range(4):
        mj.site_pos[i + 1] = np.asarray(P.rotor_positions(th))[i]  # site 0 is the IMU
        mj.actuator_gear[i, 5] = P.YAW_SIGNS[i] * th[P.KTAU] / th[P.KT]
    mujoco.mj_setConst(mj, mujoco.MjData(mj))
    d = mujoco.MjData(mj)
    d.qpos[:] = [0.1, -0.2, 1.0, 0.9, 0.1, -0.2, 0.3]
    d.qpos[3:] /= np.linalg.norm(d.qpos[3:])
    d.qvel[:] = [0.5, -0.3, 0.2, 1.0, -2.0, 0.5]
    speed = np.asarray(hover_rotor_speed(th)) * np.array([1.1, 0.9, 1.0, 1.05])
    d.ctrl[:] = th[P.ETA] * th[P.KT] * speed**2  # rotor speeds held (cmd = speed)
    s = sim.init(th, jax.random.PRNGKey(0), pos=d.qpos[:3], quat=d.qpos[3:], vel=d.qvel[:3],
                 omega=d.qvel[3:], rotor_speed=speed)
    xfrc = np.asarray(sim.external_wrench(jnp.asarray(th), s.data, jnp.zeros(3)))
    d.xfrc_applied[1] = xfrc
    # the first step of the (B, T) rollout of the other tests (one compile)
    cmd = np.broadcast_to((speed / th[P.OMEGA_MAX]).astype(np.float32), (B, T, 4))
    _, fr = run(sim, np.repeat(th[None], B, 0), cmd, pos=d.qpos[:3], quat=d.qpos[3:], vel=d.qvel[:3],
                omega=d.qvel[3:], rotor_speed=speed)
    f1 = jax.tree.map(lambda a: np.asarray(a[0, 0]), fr)
    qpos1, qvel1 = np.concatenate([f1.pos, f1.quat]), np.concatenate([f1.vel, f1.omega])
    mujoco.mj_step(mj, d)
    np.testing.assert_allclose(qvel1, d.qvel, rtol=1e-4, atol=1e-5)
    np.testing.assert_allclose(qpos1, d.qpos, rtol=1e-5, atol=1e-6)
    # IMU at the new state equals MuJoCo's gyro and accelerometer sensors there.
    data1 = s.data.replace(qpos=jnp.asarray(qpos1), qvel=jnp.asarray(qvel1))
    d.xfrc_applied[1] = np.asarray(sim.external_wrench(jnp.asarray(th), data1, jnp.zeros(3)))
    mujoco.mj_forward(mj, d)
    np.testing.assert_allclose(f1.imu, d.sensordata[:6], rtol=1e-4, atol=1e-4)


def test_imu_noise_bias_latency():
    """One noisy, delayed simulator (one compile): 63 hovering vehicles give the noise and bias
    statistics, vehicle 0 spins up in roll and its gyro reads the roll rate 3 control steps late."""
    cfg = SimConfig(gyro_noise=0.01, accel_noise=0.1, gyro_bias=0.02, imu_latency=3)
    sim = Quadrotor(cfg)
    th = no_torque(prior_batch(13, 64))
    s0 = init_batch(sim, th, jax.random.PRNGKey(0))
    u = np.array(np.broadcast_to(hover_cmd(th)[:, None], (64, 200, 4)))
    u[0] *= np.array([0.96, 1.04, 1.04, 0.96])  # a roll torque: the roll rate ramps up
    _, fr = rollout_batch(sim, th, s0, u)
    imu = np.asarray(fr.imu)
    bias = np.asarray(s0.imu_bias)
    resid = (imu - bias[:, None] - np.array([0, 0, 0, 0, 0, P.GRAVITY]))[1:]
    np.testing.assert_allclose(resid[..., :3].std(), 0.01, rtol=0.05)
    np.testing.assert_allclose(resid[..., 3:].std(), 0.1, rtol=0.05)
    np.testing.assert_allclose(bias[:, :3].std(), 0.02, rtol=0.3)
    assert np.all(bias[:, 3:] == 0)
    # Latency: against the roll rate 3 steps earlier only the gyro noise is left (mean |n| =
    # 0.008 rad/s); a lag of 2 or 4 steps leaves the ramp's change over one step on top.
    roll, gx = np.asarray(fr.omega[0, :, 0]), imu[0, :, 0] - bias[0, 0]
    assert not np.asarray(fr.diverged[0]).any() and roll[-1] > 1.0, roll[-1]
    err = {lag: float(np.abs(gx[lag:] - roll[:len(roll) - lag]).mean()) for lag in (2, 3, 4)}
    assert err[3] < 0.011 and err[2] > 3 * err[3] and err[4] > 3 * err[3], err


def test_config_validation():
    with pytest.raises(ValueError, match="substeps"):
        SimConfig(substeps=0)
    with pytest.raises(ValueError, match="dt"):
        SimConfig(dt=-1)
    with pytest.raises(ValueError, match="imu_latency"):
        SimConfig(imu_latency=1.5)


def test_rigid_twin_matches_the_mjx_simulator(sim):
    """The tuner's rigid-body twin (mjxsysid.sim.rigid) integrates the same equations with the
    same semi-implicit Euler step: 250 steps of random commands and forces from a tumbling state
    agree with MJX to float32 round-off."""
    import jax
    import jax.numpy as jnp
    from mjxsysid import theta as P
    from mjxsysid.sim.rigid import RigidSim, from_sim_state
    twin = RigidSim(sim.config)
    th = jnp.asarray(P.DEFAULT_PRIOR.sample(jax.random.PRNGKey(4), 1)[0])
    s = sim.init(th, jax.random.PRNGKey(0), vel=(0.5, -0.2, 0.1), omega=(1.0, -2.0, 0.5))
    u = jax.random.uniform(jax.random.PRNGKey(1), (250, 4), minval=0.3, maxval=0.9)
    f = jax.random.normal(jax.random.PRNGKey(2), (250, 3))

    def run(model, st):
        def body(c, x):
            c = model.step(th, c, x[0], x[1])
            return c, (c.pos, c.quat, c.omega, c.imu)
        return jax.lax.scan(body, st, (u, f))[1]

    a = jax.jit(lambda st: run(sim, st))(s)
    b = jax.jit(lambda st: run(twin, st))(from_sim_state(s))
    # The twin's own start (fly_vehicles(..., sim=RigidSim())) is the simulator's, less the IMU bias.
    t0 = twin.init(th, vel=(0.5, -0.2, 0.1), omega=(1.0, -2.0, 0.5), quat=(2.0, 0.0, 0.0, 0.0))
    for name in ("pos", "quat", "vel", "omega", "rotor_speed", "imu_buffer", "step"):
        np.testing.assert_allclose(np.asarray(getattr(t0, name)), np.asarray(getattr(from_sim_state(s), name)),
                                   rtol=1e-6, err_msg=name)
    for name, x, y, tol in zip(("pos", "quat", "omega", "imu"), a, b, (2e-6, 2e-6, 2e-5, 5e-5)):
        assert float(jnp.abs(x - y).max()) < tol * max(1.0, float(jnp.abs(x).max())), name


def test_vibration_filter_spectrum():
    """The pure vibration filter: unit stationary variance and its power at the centre frequency,
    for a low, a mid and a near-Nyquist centre; the aliasing of rotor frequencies."""
    from mjxsysid.sim.quadrotor import aliased_hz, vibration_step
    dt, n = 0.002, 20_000
    f = jnp.array([30.0, 120.0, 230.0])
    e = jax.random.normal(jax.random.PRNGKey(0), (n, 3))
    _, xs = jax.lax.scan(lambda p, ek: (vibration_step(p, ek, f, 20.0, dt),) * 2, jnp.zeros((2, 3)), e)
    x = np.asarray(xs[:, -1])[1000:]
    np.testing.assert_allclose(x.std(0), 1.0, rtol=0.08)
    spec = np.abs(np.fft.rfft(x, axis=0)) ** 2
    freqs = np.fft.rfftfreq(len(x), dt)
    smooth = np.stack([np.convolve(spec[:, j], np.ones(50) / 50, "same") for j in range(3)], 1)
    np.testing.assert_allclose(freqs[smooth.argmax(0)], np.asarray(f), atol=6.0)
    np.testing.assert_allclose(np.asarray(aliased_hz(jnp.array([100.0, 300.0, 400.0, 600.0]), dt)),
                               [100.0, 200.0, 100.0, 100.0], atol=1e-3)
    with pytest.raises(ValueError, match="gyro_vibration"):
        SimConfig(gyro_vibration=-1.0)
    with pytest.raises(ValueError, match="vibration_bandwidth_hz"):
        SimConfig(vibration_bandwidth_hz=300.0)


@pytest.mark.slow
def test_imu_vibration_and_randomized_levels_in_flight():
    """One noisy simulator (one compile): hovering vehicles with white noise, rotor vibration of the
    same std and a bias, levels drawn per episode (``randomize_imu``). Each vehicle's residual std
    follows its drawn level (white and vibration together: √2 σ), its spectrum peaks at the
    (aliased) rotor frequency and its bias stays within its level. Slow (13 s): the default tier
    keeps the filter's spectrum (test_vibration_filter_spectrum) and the unchanged default draws
    (below)."""
    from mjxsysid.sim.quadrotor import aliased_hz
    n = 16
    th = no_torque(prior_batch(3, n))
    u = np.array(np.broadcast_to(hover_cmd(th)[:, None], (n, 1000, 4)))
    sim = Quadrotor(SimConfig(gyro_noise=0.05, accel_noise=0.5, gyro_vibration=0.05, accel_vibration=0.5,
                              gyro_bias=0.025, accel_bias=0.25, randomize_imu=True))
    s0 = init_batch(sim, th, jax.random.PRNGKey(1))
    _, fr = rollout_batch(sim, th, s0, u)
    std = np.asarray(s0.imu_std)                        # the drawn levels times the maxima
    assert std.shape == (n, 3, 6)
    level = np.stack([std[:, 0, 0] / 0.05, std[:, 1, 0] / 0.025], 1)
    np.testing.assert_allclose(std[:, 2, 3], 0.5 * level[:, 0], rtol=1e-6)     # vibration: the white noise's level
    assert level.shape == (n, 2) and np.all((level >= 0) & (level <= 1)) and level.std(0).min() > 0.1
    bias = np.asarray(s0.imu_bias)
    assert np.all(np.abs(bias[:, :3]) <= 0.025 * 4.5 * level[:, 1:]) and np.abs(bias).max() > 0
    resid = (np.asarray(fr.imu) - bias[:, None] - np.array([0, 0, 0, 0, 0, P.GRAVITY]))[:, 100:]
    np.testing.assert_allclose(resid[..., :3].std((1, 2)), np.sqrt(2) * 0.05 * level[:, 0], rtol=0.12, atol=2e-3)
    np.testing.assert_allclose(resid[..., 3:].std((1, 2)), np.sqrt(2) * 0.5 * level[:, 0], rtol=0.12, atol=2e-2)
    rotor = np.asarray(jax.vmap(hover_rotor_speed)(jnp.asarray(th))).mean(1) / (2 * np.pi)
    spec = np.abs(np.fft.rfft(resid[..., 0], axis=1)) ** 2
    peak = np.fft.rfftfreq(resid.shape[1], 0.002)[spec.argmax(1)]
    loud = level[:, 0] > 0.2
    np.testing.assert_allclose(peak[loud], np.asarray(aliased_hz(rotor, 0.002))[loud], atol=15.0)


def test_imu_noise_without_vibration_or_randomisation_is_drawn_as_before():
    """Off (the default): the white noise is drawn exactly as before vibration and randomisation
    existed (its first reading = σ · normal(split(key)[1])), no vibration state, the config's magnitudes. The
    fast check beside the slow in-flight statistics above."""
    th = no_torque(prior_batch(3, 1))
    u = hover_cmd(th)[:, None]
    off = Quadrotor(SimConfig(gyro_noise=0.01, accel_noise=0.1))
    s = off.init(th[0], jax.random.PRNGKey(2))
    s1 = jax.jit(off.step)(th[0], s, u[0, 0])
    _, k = jax.random.split(s.key)
    want = np.array([0.01] * 3 + [0.1] * 3) * np.asarray(jax.random.normal(k, (6,)))
    np.testing.assert_allclose(np.asarray(s1.imu) - np.asarray(s1.imu_buffer[0]), want, atol=1e-6)
    assert not np.asarray(s1.imu_vibration).any() and np.all(np.asarray(s1.imu_std) == off.imu_std())


def test_flights_at_every_noise_level_share_one_program_and_read_their_levels_noise():
    """fly_batch compiles one flight for every IMU level of one structure (the magnitudes are data,
    :meth:`Quadrotor.imu_as_data`), and each flight's gyro reads its own level's white noise and bias
    about the true rate (2 hovering vehicles, 0.4 s). The vibration's structure stays in the program."""
    from mjxsysid.rollout import harness
    from mjxsysid.rollout.flight import fly_vehicles
    from mjxsysid.sim.quadrotor import _imu_free
    from mjxsysid.uses.imu_noise import LEVELS
    th = no_torque(prior_batch(5, 2))
    before = harness._fly_batch.cache_info().misses
    for lv, sigma, bias in (("clean", 0.0, 0.0), ("x1", 0.01, 0.005), ("x5_white", 0.05, 0.0)):
        fl, _, _ = fly_vehicles(th, controller="oracle", reference="hover", duration=0.4, seed=1,
                                sim=Quadrotor(SimConfig(**LEVELS[lv])))
        resid = np.asarray(fl.frame.imu[..., :3]) - np.asarray(fl.frame.omega)      # (2, 200, 3) noise + bias
        np.testing.assert_allclose(resid.std(1).mean(), sigma, rtol=0.15, atol=1e-7)
        assert np.abs(resid.mean(1)).max() <= 4 * bias + 3 * sigma / np.sqrt(200) + 1e-7, lv
    assert harness._fly_batch.cache_info().misses - before <= 1     # 0 where an earlier test flew this shape
    vib = Quadrotor(SimConfig(**LEVELS["x5_vibration"]))
    assert _imu_free(vib).config.vibration and not _imu_free(vib).imu_std()[[0, 1]].any()
    assert _imu_free(Quadrotor(SimConfig(**LEVELS["x20"]))) == Quadrotor(SimConfig())


def test_aero_option_is_rotorpy_form_scaled_to_the_vehicle():
    """SimConfig.aero: the linear drag grows with the mean rotor speed over hover's, plus parasitic drag
    − m c |v| v and translational lift + m g k (v_x² + v_y²); off, the air's force is −D v alone."""
    from mjxsysid.sim.quadrotor import AERO_LIFT, AERO_PARASITIC
    th = jnp.asarray(P.paper_hardware())
    v = jnp.array([2.0, -1.0, 0.5])
    m, D = float(th[P.MASS]), np.asarray(th[P.DRAG], np.float64)
    hover = float(np.sqrt(m * P.GRAVITY / (4 * float(jnp.mean(th[P.ETA])) * float(th[P.KT]))))
    speed = jnp.full(4, 1.2 * hover)
    off = Quadrotor(SimConfig()).aero_force(th, v, speed)
    np.testing.assert_allclose(off, -D * np.asarray(v), rtol=1e-6)
    on = np.asarray(Quadrotor(SimConfig(aero=True)).aero_force(th, v, speed), np.float64)
    vv = np.asarray(v, np.float64)
    want = (-D * vv * 1.2 - m * np.asarray(AERO_PARASITIC) * np.linalg.norm(vv) * vv
            + np.array([0, 0, m * P.GRAVITY * AERO_LIFT * (4.0 + 1.0)]))
    np.testing.assert_allclose(on, want, rtol=1e-4)
    at_rest = Quadrotor(SimConfig(aero=True)).aero_force(th, jnp.zeros(3), speed)
    np.testing.assert_allclose(at_rest, 0.0, atol=1e-6)
