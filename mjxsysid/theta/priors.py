"""Priors over θ: correlated size-factor distributions, the held-out families and one registry.

[SizeFactorPrior][mjxsysid.theta.priors.SizeFactorPrior] holds what every prior shares (a size
factor c ~ U[0, 1] sets the nominal geometry; inertia, k_t, κ, η, Ω_max, τ_m and τ_ext follow);
its siblings [Prior][mjxsysid.theta.priors.Prior] (the default family: m ∝ l³, anisotropic drag)
and [XAdapPrior][mjxsysid.theta.priors.XAdapPrior] (the released XAdap policy's training
distribution: m linear in c, isotropic drag) add how mass and drag follow the size.
[HeldOutFamily][mjxsysid.theta.priors.HeldOutFamily] lays one kind of damage over a default
prior. [get_prior][mjxsysid.theta.priors.get_prior] finds any of them by name.
"""
from __future__ import annotations

import dataclasses
import functools

import jax
import jax.numpy as jnp
import numpy as np

from mjxsysid.theta.derived import nominal_thrust_to_weight
from mjxsysid.theta.layout import ARM, ETA, GRAVITY, KT, KTAU, MASS, OMEGA_MAX, TAU_EXT
from mjxsysid.theta.vehicles import check_flyable, validate_theta


@dataclasses.dataclass(frozen=True)
class SizeFactorPrior:
    """What every size-factor prior shares (abstract: subclasses say how mass and drag follow
    the size). With c ~ U[0, 1] and multiplicative noise n ~ U[1 − noise, 1 + noise]:

    - inertia     J_xx,yy = inertia_xy m l² n,  J_zz = inertia_z m l² n, J_zz capped at
                  0.98 (J_xx + J_yy) (triangle inequality)
    - thrust      k_t = kt_base exp(kt_rate c) n                     (exponential in c)
    - torque      k_τ = κ k_t, κ ~ U[kappa]
    - Ω_max from a thrust-to-weight ratio r ~ U[twr]: Ω_max = √(r m g / (4 k_t)), with r clipped
      so that every rotor alone has 4 η_i k_t Ω_max² / (m g) in [twr_min_eff, twr_max_eff]
    - η_i ~ U[eta], τ_m ~ U[motor_time_constant]
    - τ_ext ~ U[−1, 1] × (ext_torque_xy m g l, ext_torque_xy m g l, ext_torque_z m g κ):
      a few per cent of the hover torque authority, so it can always be cancelled.
    """
    name: str = "default"
    arm: tuple[float, float] = (0.04, 0.23)
    inertia_xy: float = 0.26
    inertia_z: float = 0.46
    kt_base: float = 2.5e-8
    kt_rate: float = 7.55
    kappa: tuple[float, float] = (0.0069, 0.0161)
    twr: tuple[float, float] = (2.2, 7.0)
    twr_min_eff: float = 1.5
    twr_max_eff: float = 8.5
    eta: tuple[float, float] = (0.7, 1.3)
    motor_time_constant: tuple[float, float] = (0.02, 0.04)
    ext_torque_xy: float = 0.02
    ext_torque_z: float = 0.1
    noise: float = 0.2

    def sample(self, key: jax.Array, n: int) -> jax.Array:
        """Draw n vehicles. key: PRNG key -> θ (n, 19) float32. Pure; jit-able with n static. One
        compiled program per prior for any n up to 4,096 (:func:`sample_bucket`): the first n of the
        bucket's draws, which are the n vehicles drawn on their own to the last bit's rounding (JAX's
        partitionable threefry gives every draw its own counter)."""
        n = int(n)
        draws = _sampled(self, key, sample_bucket(n))
        return draws if len(draws) == n else draws[:n]

    def _draw(self, key, n: int) -> jax.Array:
        """The sampler itself (traced by :meth:`sample`)."""
        raise NotImplementedError


@dataclasses.dataclass(frozen=True)
class Prior(SizeFactorPrior):
    """The default correlated size-factor prior over θ (after Extreme-Adaptation, Zhang et al.
    2025). On top of [SizeFactorPrior][mjxsysid.theta.priors.SizeFactorPrior]:

    - arm length  l = (arm_min + (arm_max − arm_min) c) n
    - mass        m = (mass_base + mass_scale (l / 0.2)³) n                (m ∝ l³ plus avionics)
    - drag        D = (drag_xy, drag_xy, drag_z) (l / 0.184)² × U[drag_noise] per axis (∝ l²)

    The paper vehicle corresponds to c ≈ 0.76 and lies well inside every marginal
    (docs/vehicles.md).
    """
    mass_base: float = 0.04
    mass_scale: float = 1.15
    drag_xy: float = 0.20
    drag_z: float = 0.85
    drag_noise: tuple[float, float] = (0.4, 1.6)

    def _draw(self, key, n: int) -> jax.Array:
        return _sample_prior(self, key, n)


@dataclasses.dataclass(frozen=True)
class XAdapPrior(SizeFactorPrior):
    """The released XAdap policy's training distribution, moment-matched to its published
    mean ± std of the privileged parameters (docs/vehicles.md). On top of
    [SizeFactorPrior][mjxsysid.theta.priors.SizeFactorPrior]:

    - l = (arm_lo + (arm_hi − arm_lo) c) n, clipped to ``arm``
    - m = (m_lo + (m_hi − m_lo) c) n, clipped to ``mass_range`` (linear in c, not ∝ l³)
    - D_xx = D_yy = D_zz = drag_iso (l / 0.2)² n

    The joint structure (one size factor) is a guess: only marginals are published. τ_m and
    τ_ext, not in the statistics, follow the default prior; the training's centre-of-mass
    offsets are not modelled.
    """
    name: str = "xadap"
    arm: tuple[float, float] = (0.03, 0.20)
    mass_range: tuple[float, float] = (0.04, 1.16)
    inertia_xy: float = 0.175
    inertia_z: float = 0.265
    kt_base: float = 1.1e-8
    kt_rate: float = 7.86
    kappa: tuple[float, float] = (0.0062, 0.016)
    drag_iso: float = 0.75
    twr: tuple[float, float] = (2.0, 4.5)
    twr_min_eff: float = 1.5
    twr_max_eff: float = 8.0
    noise: float = 0.1

    def _draw(self, key, n: int) -> jax.Array:
        return _sample_xadap(self, key, n)


@dataclasses.dataclass(frozen=True)
class HeldOutFamily(Prior):
    """A family of vehicles that no policy trains on: a [Prior][mjxsysid.theta.priors.Prior] with
    one kind of damage laid over its draws, and a fixed ``seed`` so every evaluation flies the same
    vehicles ([vehicles][mjxsysid.theta.priors.HeldOutFamily.vehicles]).

    - ``one_motor_eta``: one rotor (drawn uniformly) has this motor effectiveness η, the others
      keep the prior's; Ω_max is then re-clipped as the prior clips it, so every rotor alone still
      lifts ``twr_min_eff``× its share of the weight (a worn motor on a vehicle that can carry it).
    - ``payload_torque_xy``: a constant roll/pitch torque of magnitude ``payload_torque_xy`` m g l
      in a uniformly drawn horizontal direction (an off-centre payload), in place of the prior's.
    - ``yaw_torque_z``: a constant yaw torque ± ``yaw_torque_z`` m g κ (sign drawn), in place of
      the prior's.

    ``description`` says what the family stands for in one line (tables and the docs).
    """
    description: str = ""
    seed: int = 0
    one_motor_eta: float | None = None
    payload_torque_xy: float | None = None
    yaw_torque_z: float | None = None

    def _draw(self, key, n: int) -> jax.Array:
        return _sample_heldout(self, key, n)

    def vehicles(self, n: int) -> np.ndarray:
        """The family's n evaluation vehicles, the same on every call (seeded by ``seed``):
        θ (n, 19), validated and flyable ([check_flyable][mjxsysid.theta.vehicles.check_flyable])."""
        if not isinstance(n, (int, np.integer)) or isinstance(n, bool) or n < 1:
            raise ValueError(f"n (vehicles of held-out family {self.name!r}) must be a positive integer, got {n!r}")
        theta = validate_theta(np.asarray(self.sample(jax.random.PRNGKey(self.seed), int(n))), what=self.name)
        for i, t in enumerate(theta):
            check_flyable(t, what=f"{self.name} vehicle {i}")
        return theta


# ----------------------------------------------------------------------------------------
# Sampling
# ----------------------------------------------------------------------------------------

@functools.partial(jax.jit, static_argnums=(0, 2))
def _sampled(p: SizeFactorPrior, key, n: int):
    return p._draw(key, n)


SAMPLE_BUCKET = 4096
"""Draws of 2 to this many vehicles share one compiled sampler per prior (:func:`sample_bucket`)."""


def sample_bucket(n: int) -> int:
    """The number of vehicles compiled for a draw of n: 4,096 for any n from 2 to 4,096, so one program per
    prior (drawing 4,096 costs about what drawing 2 does; compiling is the cost). n itself for one vehicle,
    above 4,096, and where JAX's threefry is not partitionable (the first n draws of more would then be
    other vehicles)."""
    if n <= 1 or n > SAMPLE_BUCKET or not getattr(jax.config, "jax_threefry_partitionable", True):
        return n
    return SAMPLE_BUCKET


def _uniforms(p: SizeFactorPrior, n: int):
    """Samplers u(key, lo, hi, shape) ~ U[lo, hi] and noise(key, shape) ~ U[1 ± p.noise]."""
    def u(k, lo, hi, shape=(n,)):
        return jax.random.uniform(k, shape, jnp.float32, lo, hi)

    def noise(k, shape=(n,)):
        return u(k, 1.0 - p.noise, 1.0 + p.noise, shape)

    return u, noise


def _sample_prior(p: Prior, key, n: int):
    ks = jax.random.split(key, 16)
    u, noise = _uniforms(p, n)
    c = u(ks[0], 0.0, 1.0)
    arm = (p.arm[0] + (p.arm[1] - p.arm[0]) * c) * noise(ks[1])
    mass = (p.mass_base + p.mass_scale * (arm / 0.2) ** 3) * noise(ks[2])
    dscale = (arm / 0.184) ** 2
    dn = u(ks[6], *p.drag_noise, (n, 3))
    drag = jnp.stack([p.drag_xy * dscale, p.drag_xy * dscale, p.drag_z * dscale], -1) * dn
    return _sample_rest(p, ks, n, c, arm, mass, drag)


def _sample_xadap(p: XAdapPrior, key, n: int):
    ks = jax.random.split(key, 16)
    u, noise = _uniforms(p, n)
    c = u(ks[0], 0.0, 1.0)
    arm = jnp.clip((p.arm[0] + (p.arm[1] - p.arm[0]) * c) * noise(ks[1]), *p.arm)
    m_lo, m_hi = p.mass_range
    mass = jnp.clip((m_lo + (m_hi - m_lo) * c) * noise(ks[2]), m_lo, m_hi)
    drag = p.drag_iso * (arm / 0.2) ** 2 * noise(ks[6])
    return _sample_rest(p, ks, n, c, arm, mass, jnp.stack([drag, drag, drag], -1))


def _sample_rest(p: SizeFactorPrior, ks, n: int, c, arm, mass, drag):
    """What every size-factor prior shares, given size factor c, arm, mass (n,) and drag (n, 3):
    inertia ∝ m l², k_t exponential in c, κ, η, Ω_max from the thrust-to-weight ratio, τ_m,
    τ_ext. Keys ks[3], ks[4], ks[5], ks[7..10]. Returns θ (n, 19)."""
    u, noise = _uniforms(p, n)
    ml2 = mass * arm**2
    jn = noise(ks[3], (n, 3))
    jxx = p.inertia_xy * ml2 * jn[:, 0]
    jyy = p.inertia_xy * ml2 * jn[:, 1]
    jzz = jnp.minimum(p.inertia_z * ml2 * jn[:, 2], 0.98 * (jxx + jyy))
    kt = p.kt_base * jnp.exp(p.kt_rate * c) * noise(ks[4])
    kappa = u(ks[5], *p.kappa)
    eta = u(ks[7], *p.eta, (n, 4))
    twr = jnp.clip(u(ks[8], *p.twr), p.twr_min_eff / eta.min(-1), p.twr_max_eff / eta.max(-1))
    omega_max = jnp.sqrt(twr * mass * GRAVITY / (4.0 * kt))
    tau_m = u(ks[9], *p.motor_time_constant)
    ext_scale = jnp.stack([p.ext_torque_xy * mass * GRAVITY * arm] * 2
                          + [p.ext_torque_z * mass * GRAVITY * kappa], -1)
    tau_ext = u(ks[10], -1.0, 1.0, (n, 3)) * ext_scale
    cols = [mass, arm, kt, kappa * kt, jxx, jyy, jzz, drag[:, 0], drag[:, 1], drag[:, 2], omega_max,
            eta[:, 0], eta[:, 1], eta[:, 2], eta[:, 3], tau_m, tau_ext[:, 0], tau_ext[:, 1],
            tau_ext[:, 2]]
    return jnp.stack(cols, -1)


def _sample_heldout(p: HeldOutFamily, key, n: int):
    k_base, k_motor, k_dir, k_sign = jax.random.split(key, 4)
    t = _sample_prior(p, k_base, n)
    if p.one_motor_eta is not None:
        which = jax.random.randint(k_motor, (n,), 0, 4)
        eta = jnp.where(jax.nn.one_hot(which, 4, dtype=bool), p.one_motor_eta, t[:, ETA])
        twr = jnp.clip(nominal_thrust_to_weight(t), p.twr_min_eff / eta.min(-1), p.twr_max_eff / eta.max(-1))
        omega_max = jnp.sqrt(twr * t[:, MASS] * GRAVITY / (4.0 * t[:, KT]))
        t = t.at[:, ETA].set(eta).at[:, OMEGA_MAX].set(omega_max)
    if p.payload_torque_xy is not None:
        phi = jax.random.uniform(k_dir, (n,), jnp.float32, 0.0, 2.0 * jnp.pi)
        mag = p.payload_torque_xy * t[:, MASS] * GRAVITY * t[:, ARM]
        t = t.at[:, TAU_EXT.start].set(mag * jnp.cos(phi)).at[:, TAU_EXT.start + 1].set(mag * jnp.sin(phi))
    if p.yaw_torque_z is not None:
        sign = jnp.where(jax.random.bernoulli(k_sign, 0.5, (n,)), 1.0, -1.0)
        t = t.at[:, TAU_EXT.start + 2].set(sign * p.yaw_torque_z * t[:, MASS] * GRAVITY * t[:, KTAU] / t[:, KT])
    return t


# ----------------------------------------------------------------------------------------
# The named priors
# ----------------------------------------------------------------------------------------

DEFAULT_PRIOR = Prior()
SLOW_ACTUATOR_PRIOR = Prior(name="slow_actuators", motor_time_constant=(0.05, 0.10))
# The default vehicles with τ_m over the default and the slow-actuator range together: the
# decoders' training prior, so that slow motors can be decoded while the policy is not retrained.
WIDE_ACTUATOR_PRIOR = Prior(name="wide_actuators", motor_time_constant=(0.02, 0.10))
# At and past the edges of the default prior, where the oracle (K_θ with the true θ and the
# paper's fixed rate gains) still flies: thrust-to-weight 1.5–2.5, every rotor alone still
# lifting ≥ 1.5× its share of the weight, τ_m 0.04–0.06 s, η down to 0.5 (a worn motor), 2× the
# roll/pitch external torque and 1.2× the yaw torque (docs/probing.md, "The stress prior").
STRESS_PRIOR = Prior(name="stress", twr=(1.5, 2.5), twr_min_eff=1.5, motor_time_constant=(0.04, 0.06),
                     eta=(0.5, 1.3), ext_torque_xy=0.04, ext_torque_z=0.12)
# A wider stress prior (τ_m to 0.12 s, rotors down to 1.2× their share, 3× the roll/pitch
# torque), past where the fixed-gain K_θ oracle's 40 rad/s rate loop outruns the motors
# (docs/probing.md).
STRESS_WIDE_PRIOR = Prior(name="stress_wide", twr=(1.5, 2.5), twr_min_eff=1.2, motor_time_constant=(0.04, 0.12),
                          eta=(0.5, 1.3), ext_torque_xy=0.06, ext_torque_z=0.12)
XADAP_PRIOR = XAdapPrior()


def xadap_training_prior(**overrides) -> XAdapPrior:
    """The released XAdap policy's training distribution ([XAdapPrior][mjxsysid.theta.priors.XAdapPrior]),
    optionally with fields replaced (e.g. ``ext_torque_xy=0``)."""
    return XAdapPrior(**overrides)


PRIORS: dict[str, SizeFactorPrior] = {
    "default": DEFAULT_PRIOR, "slow_actuators": SLOW_ACTUATOR_PRIOR, "wide_actuators": WIDE_ACTUATOR_PRIOR,
    "xadap": XADAP_PRIOR, "stress": STRESS_PRIOR, "stress_wide": STRESS_WIDE_PRIOR}
"""The training and stress priors by name."""

# Each family is the default prior with one kind of damage, past what any policy of mjxsysid
# trains on (the default prior, its probed systems, the stress prior), in ranges the oracle (the
# lag-aware K_θ with the true θ) flies (docs/probing.md, "Held-out families").
HELDOUT_FAMILIES: dict[str, HeldOutFamily] = {f.name: f for f in (
    HeldOutFamily(name="weak_motor", seed=101, one_motor_eta=0.5,
                  description="one motor at η 0.5, the others 0.7–1.3 (every rotor still lifts ≥ 1.5× its share)"),
    HeldOutFamily(name="slow_motors", seed=102, motor_time_constant=(0.08, 0.10),
                  description="motor time constant τ_m 0.08–0.10 s (the default prior: 0.02–0.04 s)"),
    HeldOutFamily(name="low_thrust", seed=103, twr=(1.6, 1.8), eta=(0.85, 1.15), twr_min_eff=1.36,
                  description="thrust-to-weight 1.6–1.8 (the default prior: 2.2–7), η 0.85–1.15"),
    HeldOutFamily(name="payload_offset", seed=104, payload_torque_xy=0.15,
                  description="a constant roll/pitch torque 0.15 m g l in a random direction (an off-centre "
                              "payload: 30 % of the mass half an arm off; the default prior: ≤ 0.02 per axis)"),
    HeldOutFamily(name="yaw_torque", seed=105, yaw_torque_z=0.4,
                  description="a constant yaw torque ± 0.4 m g κ (4× the default prior's largest; at hover the "
                              "rotors can counter at least 1.25× it)"),
)}
"""Vehicles no training method sees, by name."""


def get_prior(name: str | SizeFactorPrior) -> SizeFactorPrior:
    """A prior by name ([PRIORS][mjxsysid.theta.priors.PRIORS] or
    [HELDOUT_FAMILIES][mjxsysid.theta.priors.HELDOUT_FAMILIES]); a prior object is returned as is."""
    if isinstance(name, SizeFactorPrior):
        return name
    if name in HELDOUT_FAMILIES:
        return HELDOUT_FAMILIES[name]
    if name not in PRIORS:
        raise ValueError(f"unknown prior {name!r}; choose from {sorted(PRIORS)} or a held-out family "
                         f"{sorted(HELDOUT_FAMILIES)}")
    return PRIORS[name]


def widened_prior(prior: Prior, amount: float, name: str | None = None) -> Prior:
    """``prior`` widened by ``amount`` (natural-log units) in every direction, knowing nothing of
    where a policy is weak: every sampled range (arm length, κ, drag noise, thrust-to-weight, η,
    τ_m) moves out by a factor e^amount at both ends (lo e^−a, hi e^a; η's upper end and the drag
    noise's stay below 2 so the draws remain physical) and the external-torque scales grow by
    e^a. The flyability limits (``twr_min_eff``, ``twr_max_eff``) stay: every draw can still fly.
    The fair control of the probe loop (``experiments.probe_loop``, variant ``widened``)."""
    if not (np.isfinite(amount) and amount >= 0):
        raise ValueError(f"widened_prior: amount must be a finite number >= 0 (log units), got {amount}")
    f = float(np.exp(amount))

    def wide(r, cap=None):
        lo, hi = r[0] / f, r[1] * f
        return (lo, min(hi, cap) if cap is not None else hi)

    return dataclasses.replace(
        prior, name=name or f"{prior.name}_widened_{amount:.2f}", arm=wide(prior.arm), kappa=wide(prior.kappa),
        drag_noise=wide(prior.drag_noise, 1.99), twr=wide(prior.twr), eta=wide(prior.eta, 1.99),
        motor_time_constant=wide(prior.motor_time_constant), ext_torque_xy=prior.ext_torque_xy * f,
        ext_torque_z=prior.ext_torque_z * f)
