"""Quantities derived from θ: rotor positions, thrust-to-weight, the identifiable combinations, the
derived quantities a posterior's summary reports, and flyability."""
from __future__ import annotations

import math

import jax
import jax.numpy as jnp
import numpy as np

from mjxsysid.theta.layout import (ARM, ETA, GRAVITY, INERTIA, KT, KTAU, MASS, OMEGA_MAX, ROTOR_DIRECTIONS,
                                   TAU_EXT)


def rotor_positions(theta: jax.Array) -> jax.Array:
    """Rotor centres in the body frame. θ (..., 19) -> (..., 4, 3), z = 0."""
    theta = jnp.asarray(theta)
    xy = theta[..., ARM, None, None] * jnp.asarray(ROTOR_DIRECTIONS)
    return jnp.concatenate([xy, jnp.zeros(xy.shape[:-1] + (1,), xy.dtype)], -1)


def xp_of(*arrays):
    """jax.numpy for traced or device arrays, NumPy otherwise: the same function then runs inside
    jit and on the host, where eager jax.numpy would compile each operation on first use."""
    return jnp if any(isinstance(a, jax.Array) for a in arrays) else np


def _float32(theta):
    """θ as float32 in its own array library ([xp_of][mjxsysid.theta.derived.xp_of]), as
    jax.numpy would hold it."""
    xp = xp_of(theta)
    return xp, xp.asarray(theta, xp.float32)


def thrust_to_weight(theta):
    """4 η̄ k_t Ω_max² / (m g): the four rotors' thrust at full speed over the weight, η̄ the motors'
    mean effectiveness. The one thrust-to-weight every report gives (a log sees it:
    [coords][mjxsysid.identify.coords]). θ (..., 19) -> (...)."""
    xp, theta = _float32(theta)
    return nominal_thrust_to_weight(theta) * xp.mean(theta[..., ETA], -1)


def nominal_thrust_to_weight(theta):
    """4 k_t Ω_max² / (m g): the thrust-to-weight at η = 1, what the priors draw and the latent's
    identifiable combinations use (not reported: [thrust_to_weight][mjxsysid.theta.derived.thrust_to_weight]
    is). θ (..., 19) -> (...)."""
    _, theta = _float32(theta)
    return 4.0 * theta[..., KT] * theta[..., OMEGA_MAX] ** 2 / (theta[..., MASS] * GRAVITY)


def torque_ratio(theta):
    """κ = k_τ / k_t in metres. θ (..., 19) -> (...)."""
    _, theta = _float32(theta)
    return theta[..., KTAU] / theta[..., KT]


def angular_authority(theta):
    """l k_t Ω_max² / J per axis (rad/s²): how hard the vehicle can be rotated.
    θ (..., 19) -> (..., 3)."""
    _, theta = _float32(theta)
    num = theta[..., ARM] * theta[..., KT] * theta[..., OMEGA_MAX] ** 2
    return num[..., None] / theta[..., INERTIA]


IDENTIFIABLE_NAMES = ("nominal_thrust_to_weight", "torque_ratio",
                      "angular_authority[0]", "angular_authority[1]", "angular_authority[2]")
"""The identifiable combinations' names: the latent's training targets, at η = 1. Records written
before the thrust-to-weight was made one name call the first "thrust_to_weight"."""


def identifiable(theta):
    """The combinations a hover latent can reveal (docs/concepts.md), at η = 1: what the policy's
    latent is trained and scored on (not reported: [derived][mjxsysid.theta.derived.derived] is).
    θ (..., 19) -> (..., 5); NumPy in, NumPy out ([xp_of][mjxsysid.theta.derived.xp_of])."""
    xp, theta = _float32(theta)
    return xp.concatenate([nominal_thrust_to_weight(theta)[..., None], torque_ratio(theta)[..., None],
                           angular_authority(theta)], -1)


DERIVED_NAMES = ("thrust_to_weight", "torque_ratio",
                 "angular_authority[0]", "angular_authority[1]", "angular_authority[2]")
"""The derived quantities a posterior's summary reports beside θ's 19 parameters."""


def derived(theta):
    """The [DERIVED_NAMES][mjxsysid.theta.derived.DERIVED_NAMES] quantities: θ (..., 19) -> (..., 5)
    (the identifiable combinations with the thrust-to-weight of the rotors as they are, η̄ in)."""
    xp, theta = _float32(theta)
    return xp.concatenate([thrust_to_weight(theta)[..., None], torque_ratio(theta)[..., None],
                           angular_authority(theta)], -1)


def flyability(theta) -> dict[str, np.ndarray]:
    """Per-vehicle flyability figures (host side). θ (..., 19) -> dict of (...) arrays:
    ``twr_min``/``twr_max`` (4 min/max η k_t Ω_max² / m g), ``torque_margin`` (smallest ratio of
    available roll/pitch/yaw torque at hover to |τ_ext|; inf if τ_ext = 0)."""
    t = np.asarray(theta, np.float64)
    eta = t[..., ETA]
    tmax = t[..., KT] * t[..., OMEGA_MAX] ** 2
    w = t[..., MASS] * GRAVITY
    twr_min = 4 * eta.min(-1) * tmax / w
    twr_max = 4 * eta.max(-1) * tmax / w
    # Torque available around hover: each rotor can add (η_i T_max − w/4) of thrust.
    spare = np.clip(eta.min(-1) * tmax - w / 4, 0, None)
    arm_xy = t[..., ARM] / math.sqrt(2)
    avail = np.stack([4 * arm_xy * spare, 4 * arm_xy * spare,
                      4 * (t[..., KTAU] / t[..., KT]) * spare], -1)
    ext = np.abs(t[..., TAU_EXT])
    with np.errstate(divide="ignore"):
        margin = np.where(ext > 0, avail / np.maximum(ext, 1e-30), np.inf).min(-1)
    return {"twr_min": twr_min, "twr_max": twr_max, "torque_margin": margin}
