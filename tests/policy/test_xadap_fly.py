"""The released Xadap policy as a low-level controller (mjxsysid.policy.xadap.controller).

Needs the released policy files (env var MJXSYSID_XADAP_DIR, default
``<repo>/../shared/external/xadap``) and the optional ``onnx`` package; the tests that need
them skip with a message otherwise.
"""
from __future__ import annotations


import jax
import jax.numpy as jnp
import numpy as np
import pytest

from mjxsysid import theta as P
from mjxsysid.control.low_level import Command
from mjxsysid.policy.xadap.network import build_history_input, normalize_state, xadap_encoder, xadap_policy
from mjxsysid.theta import XAdapPrior, xadap_training_prior
from mjxsysid.policy.xadap.controller import NN_TO_MJX, XAdapController, butterworth2, make_xadap_low_level

from support.paths import XADAP_DIR

G = np.float32(P.GRAVITY)
HOVER_IMU = jnp.array([0.0, 0.0, 0.0, 0.0, 0.0, G], jnp.float32)
HOVER_CMD = Command(jnp.float32(G), jnp.zeros(3, jnp.float32))


@pytest.fixture(scope="module")
def weights(xadap_weights):
    return xadap_weights


def test_butterworth_matches_scipy():
    from scipy.signal import butter

    for fc, fs in ((30.0, 100.0), (30.0, 500.0), (5.0, 500.0)):
        b, a = butterworth2(fc, fs)
        b_ref, a_ref = butter(2, fc / (fs / 2), btype="low")
        np.testing.assert_allclose(b, b_ref, rtol=1e-12)
        np.testing.assert_allclose(a, a_ref, rtol=1e-12)
    with pytest.raises(ValueError, match="cut-off"):
        butterworth2(60.0, 100.0)


def test_training_prior_matches_released_statistics():
    pr = xadap_training_prior()
    assert isinstance(pr, P.SizeFactorPrior) and isinstance(pr, XAdapPrior)
    th = np.asarray(pr.sample(jax.random.PRNGKey(0), 20_000))
    P.validate_theta(th)
    assert th[:, P.MASS].min() >= 0.04 - 1e-6 and th[:, P.MASS].max() <= 1.16 + 1e-6
    assert th[:, P.ARM].min() >= 0.03 - 1e-6 and th[:, P.ARM].max() <= 0.20 + 1e-6
    # README: mass 0.60 ± 0.33, arm 0.113 ± 0.049, k_t 3.7e-6 ± 6.3e-6, Ω_max 3379 ± 2435
    assert abs(th[:, P.MASS].mean() - 0.60) < 0.03 and abs(th[:, P.MASS].std() - 0.33) < 0.03
    assert abs(th[:, P.ARM].mean() - 0.113) < 0.005
    assert 3.0e-6 < th[:, P.KT].mean() < 4.5e-6
    assert 2900 < th[:, P.OMEGA_MAX].mean() < 3900
    f = P.flyability(th)
    assert f["twr_min"].min() >= 1.5 - 1e-3 and np.all(f["torque_margin"] > 1.0)


def test_load_options(weights):
    c = XAdapController.load(weights)
    assert (c.decimation, c.accel_filter, c.rate_hz) == (1, "butter", pytest.approx(500.0))
    c = XAdapController.load(weights, rate_hz=100, accel_filter=False)
    assert (c.decimation, c.accel_filter) == (5, "none")
    assert XAdapController.load(weights, accel_filter="wrapper").accel_filter == "wrapper"
    with pytest.raises(ValueError, match="divide"):
        XAdapController.load(weights, rate_hz=300)
    with pytest.raises(ValueError, match="accel_filter"):
        XAdapController.load(weights, accel_filter="kalman")


def test_motor_order_and_signs(weights):
    """After a hover warm-up, rate / thrust commands move the rotors as the FLU geometry and
    yaw signs of mjxsysid require (rotors FR, FL, BL, BR; yaw signs −, +, −, +)."""
    ctrl = XAdapController.load(weights)
    warm = jax.jit(lambda c: jax.lax.scan(lambda c, _: ctrl.step(c, HOVER_IMU, HOVER_CMD), c,
                                          None, length=120)[0])
    carry = warm(ctrl.init(jax.random.PRNGKey(0)))
    step = jax.jit(ctrl.step)
    _, u0 = step(carry, HOVER_IMU, HOVER_CMD)

    def du(omega_cmd=(0.0, 0.0, 0.0), a_cmd=G, imu=HOVER_IMU):
        _, u = step(carry, imu, Command(jnp.float32(a_cmd), jnp.asarray(omega_cmd, jnp.float32)))
        return np.asarray(u - u0)

    d = du((1.0, 0, 0))  # roll right-side-up about +x: left rotors (FL, BL) speed up
    assert d[1] > 0 and d[2] > 0 and d[0] < 0 and d[3] < 0, d
    d = du((0, 1.0, 0))  # pitch about +y (nose down): back rotors (BL, BR) speed up
    assert d[2] > 0 and d[3] > 0 and d[0] < 0 and d[1] < 0, d
    d = du((0, 0, 1.0))  # yaw about +z: the + yaw-sign rotors (FL, BR) speed up
    assert np.all(np.sign(d) == P.YAW_SIGNS), d
    assert np.all(du(a_cmd=G + 2.0) > 0)  # more collective thrust: all rotors
    d = du(imu=HOVER_IMU.at[0].set(1.0))  # measured roll rate: opposed
    assert d[1] < 0 and d[2] < 0 and d[0] > 0 and d[3] > 0, d
    np.testing.assert_array_equal(NN_TO_MJX, [0, 3, 1, 2])


def test_history_layout_and_latent(weights):
    """φ sees the 100 previous steps (oldest first, current step appended after φ and π ran),
    π sees [normalize([s, r_prev]), ẑ], and motor = (0.5 r + 0.5)[[0, 3, 1, 2]]."""
    ctrl = XAdapController.load(weights, accel_filter=False)
    step = jax.jit(ctrl.step)
    rng = np.random.default_rng(0)
    carry = ctrl.init(jax.random.PRNGKey(0))
    for k in range(6):
        imu = jnp.asarray(rng.normal([0, 0, 0, 0, 0, G], [1, 1, 1, 0.5, 0.5, 1]), jnp.float32)
        cmd = Command(jnp.float32(G + rng.normal()), jnp.asarray(rng.normal(size=3), jnp.float32))
        new, u = step(carry, imu, cmd)
        s = np.concatenate([np.asarray(imu[:3]), [imu[5]], np.asarray(cmd.omega_cmd), [cmd.a_cmd]])
        z = xadap_encoder(weights, build_history_input(weights, carry.s_hist, carry.r_hist))
        np.testing.assert_allclose(new.z, z, rtol=1e-5, atol=1e-6)
        np.testing.assert_allclose(ctrl.latent(new), z, rtol=1e-5, atol=1e-6)
        obs = normalize_state(weights, np.concatenate([s, np.asarray(carry.r_last)]))
        r = xadap_policy(weights, jnp.concatenate([obs, z]))
        np.testing.assert_allclose(new.r_last, r, rtol=1e-5, atol=1e-6)
        np.testing.assert_allclose(u, np.clip(0.5 * np.asarray(r) + 0.5, 0, 1)[[0, 3, 1, 2]],
                                   atol=1e-6)
        np.testing.assert_allclose(new.s_hist[-1], s, rtol=1e-6)  # newest row last
        np.testing.assert_array_equal(new.s_hist[:-1], carry.s_hist[1:])
        np.testing.assert_array_equal(new.r_hist[-1], new.r_last)
        np.testing.assert_array_equal(new.r_hist[:-1], carry.r_hist[1:])
        assert int(new.count) == k + 1
        carry = new
    assert np.all(np.asarray(carry.s_hist[:-6]) == 0)  # reset: zeros, physical units


def test_decimation_and_filter(weights):
    """rate 100 Hz under the 500 Hz simulator: π runs every 5th step, the command is held and
    the history advances once per policy step; the Butterworth starts at steady state."""
    ctrl = XAdapController.load(weights, rate_hz=100.0)

    def body(c, _):
        c, u = ctrl.step(c, HOVER_IMU, HOVER_CMD)
        return c, (u, c.fz)

    carry, (u, fz) = jax.jit(lambda c: jax.lax.scan(body, c, None, length=12))(ctrl.init())
    u = np.asarray(u)
    for k in range(12):
        np.testing.assert_array_equal(u[k], u[5 * (k // 5)])
    assert not np.array_equal(u[0], u[5])
    assert int(carry.count) == 12
    s_hist = np.asarray(carry.s_hist)
    assert np.all(s_hist[:-3] == 0) and np.all(s_hist[-3:, 3] != 0)
    np.testing.assert_allclose(fz, G, rtol=1e-5)  # constant input: filter output = input
    wrap = XAdapController.load(weights, rate_hz=100.0, accel_filter="wrapper")
    c1, _ = wrap.step(wrap.init(), HOVER_IMU, HOVER_CMD)
    b, _ = butterworth2(30.0, 100.0)
    np.testing.assert_allclose(c1.fz, b[0] * G, rtol=1e-5)  # wrapper's zero-started buffer


def test_hovers_in_distribution_vehicles(weights, sim):
    """jit/vmap inside the unchanged harness; 2 s hover of 4 in-distribution vehicles.

    Measured (64 vehicles of xadap_training_prior, seed 0, 500 Hz, Butterworth, baseline
    gains): 2-s hover RMSE median 2.3 cm, 95th percentile 5.2 cm, max 10.5 cm (the worst
    corner vehicle: m 1.09 kg, TWR 2.1, weakest η 0.79); these 4 fly 3.4 / 8.3 / 2.7 / 5.4 cm.
    A wrong motor order crashes every vehicle within 2 s (RMSE ≈ 0.4 m), so a 12 cm bound
    per vehicle and 6 cm on the mean separate working from broken conventions with margin.
    """
    from mjxsysid.rollout.flight import broadcast, make_reference
    from mjxsysid.rollout.harness import Disturbance, batch_metrics, fly_batch
    from mjxsysid.control.high_level import Cascade

    n = 4
    theta = np.asarray(xadap_training_prior().sample(jax.random.PRNGKey(0), n))
    low = make_xadap_low_level(XADAP_DIR, n)
    assert low.weights.pi_out_w.shape == (4, 256) and low.decimation == 1  # shared, not copied per vehicle
    ref, _ = make_reference("hover")
    flight = fly_batch(sim, theta, low, broadcast(Cascade.make("baseline"), n), broadcast(ref, n),
                       broadcast(Disturbance.make(), n), jax.random.PRNGKey(1), 1000)
    m = batch_metrics(flight)
    rmse = np.asarray(m["pos_rmse_m"])
    assert not np.any(np.asarray(m["failed"])), rmse
    assert rmse.max() < 0.12 and rmse.mean() < 0.06, rmse
    mc = np.asarray(flight.frame.motor_cmd)
    assert np.all(np.isfinite(mc)) and mc.min() >= 0 and mc.max() <= 1
