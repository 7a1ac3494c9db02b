"""SimConfig's other static motor map (motor_idle, motor_kappa) against its closed form."""
import jax
import jax.numpy as jnp
import numpy as np
import pytest

from mjxsysid import theta as P
from mjxsysid.sim import Quadrotor, SimConfig, hover_rotor_speed, init_batch, rollout_batch
from mjxsysid.sim.motors import commanded_speed, mean_square_speed, rotor_speed_after

B, T = 8, 500  # tests/sim/test_sim.py's compiled shape
IDLE, KAPPA = 0.1, 0.5


def speed_map(u, idle, kappa):
    """Ω / Ω_max of a held command u in float64: Indiflight's idle + (1 − idle) √(κ u² + (1 − κ) u)."""
    u = np.asarray(u, np.float64)
    return idle + (1 - idle) * np.sqrt(kappa * u * u + (1 - kappa) * u)


def map_inverse(s, idle, kappa):
    """The command whose steady speed is s Ω_max (s ≥ idle): the positive root of κ u² + (1 − κ) u = q²."""
    q = (np.asarray(s, np.float64) - idle) / (1 - idle)
    return (-(1 - kappa) + np.sqrt((1 - kappa) ** 2 + 4 * kappa * q * q)) / (2 * kappa)


def vehicles():
    th = np.array(P.DEFAULT_PRIOR.sample(jax.random.PRNGKey(1), B))
    th[:, P.TAU_EXT] = 0.0
    return th


def test_default_map_is_the_linear_one_to_the_bit():
    """Off (idle 0, κ 1): Ω_max u on [0, 1], so the simulator's rotor speeds are the exact lag towards
    Ω_max u, bit for bit; the map's ends are idle Ω_max and Ω_max."""
    u = jnp.array([-0.2, 0.0, 0.37, 1.3], jnp.float32)
    np.testing.assert_array_equal(commanded_speed(u, 2000.0, SimConfig()), jnp.clip(u, 0.0, 1.0) * 2000.0)
    assert not SimConfig().motor_map and SimConfig(motor_idle=0.1).motor_map and SimConfig(motor_kappa=0.0).motor_map
    ends = commanded_speed(jnp.array([0.0, 1.0]), 2000.0, SimConfig(motor_idle=IDLE, motor_kappa=KAPPA))
    np.testing.assert_allclose(ends, [IDLE * 2000.0, 2000.0], rtol=1e-6)
    th = jnp.asarray(vehicles()[0])
    sim = Quadrotor()
    s = sim.init(th, jax.random.PRNGKey(0), rotor_speed=jnp.zeros(4))
    cmd = jnp.array([0.2, 0.5, 0.7, 0.9], jnp.float32)
    s1 = jax.jit(sim.step)(th, s, cmd)
    _, want = mean_square_speed(jnp.zeros(4), jnp.clip(cmd, 0.0, 1.0) * th[P.OMEGA_MAX], th[P.TAU_M], sim.config.physics_dt)
    np.testing.assert_array_equal(np.asarray(s1.rotor_speed), np.asarray(want))


def test_held_command_reaches_the_maps_speed_and_thrust():
    """With the map on, a held command settles at the map's speed: from rest the speeds reach
    Ω_max map(u) (rotor_speed_after reproduces them), and the command the map says gives the hover
    speed makes thrust = weight and holds a vehicle started at hover speeds at rest (specific force g); the linear map's command for the same speed
    would not (the option changes the flight)."""
    th = vehicles()
    cfg = SimConfig(motor_idle=IDLE, motor_kappa=KAPPA)
    sim = Quadrotor(cfg)
    s_hover = np.asarray(hover_rotor_speed(th), np.float64) / th[:, P.OMEGA_MAX, None]   # (B, 4)
    assert np.all(s_hover > IDLE)
    u = map_inverse(s_hover, IDLE, KAPPA).astype(np.float32)
    np.testing.assert_allclose(speed_map(u, IDLE, KAPPA), s_hover, rtol=1e-5)
    cmds = np.broadcast_to(u[:, None], (B, T, 4))
    s0 = init_batch(sim, th, jax.random.PRNGKey(0), rotor_speed=np.zeros((B, 4)))
    _, fr = rollout_batch(sim, th, s0, cmds, None)
    speed = np.asarray(fr.rotor_speed[:, -1], np.float64)
    want = th[:, P.OMEGA_MAX, None] * speed_map(u, IDLE, KAPPA)
    np.testing.assert_allclose(speed, want, rtol=1e-5)
    thrust = np.sum(th[:, P.ETA] * th[:, P.KT, None] * speed**2, 1)
    np.testing.assert_allclose(thrust, th[:, P.MASS] * P.GRAVITY, rtol=1e-4)
    _, rest = rollout_batch(sim, th, init_batch(sim, th, jax.random.PRNGKey(0)), cmds, None)   # from hover speeds
    assert np.abs(np.asarray(rest.pos) - [0, 0, 1]).max() < 1e-3
    np.testing.assert_allclose(np.asarray(rest.imu[:, -1, 5]), P.GRAVITY, rtol=1e-4)
    after = jax.vmap(lambda t, c: rotor_speed_after(t, jnp.zeros(4), c, cfg))(jnp.asarray(th), jnp.asarray(cmds))
    np.testing.assert_allclose(np.asarray(after), speed, rtol=1e-5)
    linear = np.asarray(commanded_speed(jnp.asarray(u), 1.0, SimConfig()), np.float64)
    assert np.all(np.sum(th[:, P.ETA] * th[:, P.KT, None] * (linear * th[:, P.OMEGA_MAX, None]) ** 2, 1)
                  < 0.8 * th[:, P.MASS] * P.GRAVITY)


def test_map_settings_are_checked():
    with pytest.raises(ValueError, match="motor_idle"):
        SimConfig(motor_idle=1.0)
    with pytest.raises(ValueError, match="motor_kappa"):
        SimConfig(motor_kappa=2.5)
    with pytest.raises(ValueError, match="motor_kappa"):
        SimConfig(motor_kappa=float("nan"))


def test_a_convex_map_is_the_square_at_kappa_2_and_between_below():
    """κ > 1: s = u √(2 − κ + (κ − 1) u²): u² at κ 2 (an ESC linear in its command read as thrust-linear), u at 1,
    monotone and Ω_max at full command in between."""
    u = jnp.linspace(0.0, 1.0, 21)
    s2 = commanded_speed(u, 1.0, SimConfig(motor_idle=0.1, motor_kappa=2.0))
    np.testing.assert_allclose(s2, 0.1 + 0.9 * u ** 2, atol=1e-6)
    s15 = np.asarray(commanded_speed(u, 1.0, SimConfig(motor_kappa=1.5)))
    assert np.all(np.diff(s15) > 0) and s15[-1] == pytest.approx(1.0) and np.all(s15 <= np.asarray(u) + 1e-7)
    assert np.all(s15 >= np.asarray(u) ** 2 - 1e-7)
