"""The 19 physical parameters θ of a quadrotor: names, units, nominal values, priors,
normalisation and validation.

θ is a float array of shape (..., 19) in SI units, in the order of :data:`PARAM_NAMES`
(DESIGN §2)::

    0  mass                     kg
    1  arm_length               m        centre of mass to rotor axis
    2  thrust_coeff             N/(rad/s)^2        T_i = η_i k_t Ω_i²
    3  torque_coeff             N·m/(rad/s)^2      yaw torque ±η_i k_τ Ω_i²
    4-6  inertia[0..2]          kg·m²    J_xx, J_yy, J_zz (principal, body frame)
    7-9  drag[0..2]             kg/s     body-frame linear drag D_xx, D_yy, D_zz
    10 max_rotor_speed          rad/s    Ω_max
    11-14 motor_effectiveness[0..3]  –   η_1..η_4
    15 motor_time_constant      s        τ_m
    16-18 external_torque[0..2] N·m      constant body-frame torque τ_ext

Body frame: x forward, y left, z up (FLU). Rotors in X configuration, numbered (0-based in
code, 1-based in prose) 1 front-right, 2 front-left, 3 back-left, 4 back-right; rotors 1 and
3 spin counter-clockwise seen from above (reaction yaw torque −k_τΩ²), 2 and 4 clockwise
(+k_τΩ²). See the README figure.

Everything learned works in a normalised space (:class:`Normalizer`): log of positive scale
parameters, then standardised. Public interfaces keep physical units.
"""
from __future__ import annotations

import dataclasses
import json
import math
from pathlib import Path
from typing import Mapping, Sequence

import jax
import jax.numpy as jnp
import numpy as np

GRAVITY = 9.81  # m/s², must match assets/quadrotor.xml

PARAM_NAMES: tuple[str, ...] = (
    "mass", "arm_length", "thrust_coeff", "torque_coeff",
    "inertia[0]", "inertia[1]", "inertia[2]",
    "drag[0]", "drag[1]", "drag[2]",
    "max_rotor_speed",
    "motor_effectiveness[0]", "motor_effectiveness[1]",
    "motor_effectiveness[2]", "motor_effectiveness[3]",
    "motor_time_constant",
    "external_torque[0]", "external_torque[1]", "external_torque[2]",
)
PARAM_UNITS: tuple[str, ...] = (
    "kg", "m", "N/(rad/s)^2", "N m/(rad/s)^2",
    "kg m^2", "kg m^2", "kg m^2",
    "kg/s", "kg/s", "kg/s",
    "rad/s", "-", "-", "-", "-", "s", "N m", "N m", "N m",
)
N_PARAMS = len(PARAM_NAMES)

# Index helpers (slices into θ).
MASS, ARM, KT, KTAU = 0, 1, 2, 3
INERTIA = slice(4, 7)
DRAG = slice(7, 10)
OMEGA_MAX = 10
ETA = slice(11, 15)
TAU_M = 15
TAU_EXT = slice(16, 19)

# Vehicle-file schema: key -> (slice into θ, length or None for scalar).
VEHICLE_KEYS: dict[str, tuple[slice, int | None]] = {
    "mass": (slice(0, 1), None),
    "arm_length": (slice(1, 2), None),
    "thrust_coeff": (slice(2, 3), None),
    "torque_coeff": (slice(3, 4), None),
    "inertia": (INERTIA, 3),
    "drag": (DRAG, 3),
    "max_rotor_speed": (slice(10, 11), None),
    "motor_effectiveness": (ETA, 4),
    "motor_time_constant": (slice(15, 16), None),
    "external_torque": (TAU_EXT, 3),
}

# Rotor layout (body frame FLU), X configuration: unit directions of the arms.
_S = 1.0 / math.sqrt(2.0)
ROTOR_DIRECTIONS = np.array([[_S, -_S], [_S, _S], [-_S, _S], [-_S, -_S]], np.float32)  # (4, 2)
ROTOR_NAMES = ("front-right", "front-left", "back-left", "back-right")
YAW_SIGNS = np.array([-1.0, 1.0, -1.0, 1.0], np.float32)  # reaction yaw torque sign per rotor

PAPER_HARDWARE = np.array(
    [0.925, 0.184, 7.64e-6, 1.07e-7, 8.5e-3, 7.5e-3, 15.5e-3, 0.20, 0.20, 0.85, 1360.0,
     1.0, 1.0, 1.0, 1.0, 0.03, 0.0, 0.0, 0.0], np.float32)
"""The paper's hardware vehicle (Table I): thrust-to-weight 4 k_t Ω_max²/(m g) ≈ 6.2."""


# ----------------------------------------------------------------------------------------
# Derived quantities
# ----------------------------------------------------------------------------------------

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
    """θ as float32 in its own array library (:func:`xp_of`), as jax.numpy would hold it."""
    xp = xp_of(theta)
    return xp, xp.asarray(theta, xp.float32)


def thrust_to_weight(theta):
    """4 k_t Ω_max² / (m g) with η = 1. θ (..., 19) -> (...)."""
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


IDENTIFIABLE_NAMES = ("thrust_to_weight", "torque_ratio",
                      "angular_authority[0]", "angular_authority[1]", "angular_authority[2]")


def identifiable(theta):
    """The combinations a hover latent can reveal (DESIGN §6). θ (..., 19) -> (..., 5); NumPy in,
    NumPy out (:func:`xp_of`)."""
    xp, theta = _float32(theta)
    return xp.concatenate([thrust_to_weight(theta)[..., None], torque_ratio(theta)[..., None],
                           angular_authority(theta)], -1)


# ----------------------------------------------------------------------------------------
# Validation and vehicle files
# ----------------------------------------------------------------------------------------

def validate_theta(theta, *, what: str = "theta") -> np.ndarray:
    """Check θ on the host and return it as float32 numpy (..., 19).

    Raises ``ValueError`` naming the first offending parameter (and batch index): wrong shape,
    non-finite entries, non-positive mass / arm / coefficients / inertia / Ω_max / η / τ_m,
    negative drag, or inertia violating the triangle inequality.
    """
    arr = np.asarray(theta, dtype=np.float64)
    if arr.ndim == 0 or arr.shape[-1] != N_PARAMS:
        raise ValueError(f"{what} must have shape (..., {N_PARAMS}) in the order of "
                         f"mjxsysid.params.PARAM_NAMES; got shape {arr.shape}")
    flat = arr.reshape(-1, N_PARAMS)

    def fail(mask, name, msg):
        bad = np.argwhere(mask)
        if bad.size:
            i = int(bad[0][0])
            loc = f" (batch element {i})" if flat.shape[0] > 1 else ""
            raise ValueError(f"{what}: {name} {msg}{loc}; got {flat[i].tolist()}")

    with np.errstate(over="ignore", under="ignore"):
        flat32 = flat.astype(np.float32)
    for j, name in enumerate(PARAM_NAMES):
        fail(~np.isfinite(flat[:, j]), name, "is not finite")
        fail(~np.isfinite(flat32[:, j]), name, "is too large (beyond float32)")
        positive = j in (MASS, ARM, KT, KTAU, OMEGA_MAX, TAU_M) or 4 <= j <= 6 or 11 <= j <= 14
        if positive:
            fail(flat[:, j] <= 0, name, "must be > 0")
            fail(flat32[:, j] <= 0, name, "is too small (rounds to 0 in float32)")
        if 7 <= j <= 9:
            fail(flat[:, j] < 0, name, "must be >= 0")
    j = flat[:, INERTIA]
    for a in range(3):
        others = j[:, (a + 1) % 3] + j[:, (a + 2) % 3]
        fail(j[:, a] > others * (1 + 1e-6), f"inertia[{a}]",
             "violates the triangle inequality J_a <= J_b + J_c")
    return arr.astype(np.float32)


_POSITIVE = [MASS, ARM, KT, KTAU, OMEGA_MAX, TAU_M, 4, 5, 6, 11, 12, 13, 14]


def _project(t, xp):
    """The projection of :func:`project_valid` in numpy or jax.numpy (``xp``); t (..., 19)."""
    pos = np.array(_POSITIVE)
    t = xp.concatenate([t[..., :0], t], -1)  # a copy in either library
    if xp is np:
        t[..., pos] = np.maximum(t[..., pos], 1e-9)
        t[..., DRAG] = np.maximum(t[..., DRAG], 0.0)
    else:
        t = t.at[..., pos].max(1e-9).at[..., DRAG].max(0.0)
    for _ in range(3):
        j = t[..., INERTIA]
        new = [xp.minimum(j[..., a], 0.999 * (j[..., (a + 1) % 3] + j[..., (a + 2) % 3])) for a in range(3)]
        t = xp.concatenate([t[..., :4], xp.stack(new, -1), t[..., 7:]], -1)
    return t


def project_valid(theta) -> tuple[np.ndarray, np.ndarray]:
    """Make decoded/perturbed θ (..., 19) physically valid for simulation: inertia clipped to
    the triangle inequality (J_a ≤ 0.999 (J_b + J_c)), positive entries floored at 1e-9, drag at 0.
    Returns (valid θ, mask (...) of rows that needed changing). Host-side (float64);
    :func:`project_valid_jax` is the same projection inside jit."""
    orig = np.array(theta, np.float64)
    t = _project(orig.copy(), np)
    changed = np.any(~np.isclose(t, orig, rtol=1e-7, atol=0), -1)
    return t.astype(np.float32), changed


def project_valid_jax(theta) -> jax.Array:
    """:func:`project_valid` for traced arrays (no mask): θ (..., 19) -> valid θ (..., 19)."""
    return _project(jnp.asarray(theta), jnp)


def check_flyable(theta, *, what: str = "vehicle") -> np.ndarray:
    """Raise ``ValueError`` (naming ``what`` and the keys involved) for a valid θ (19,) that
    cannot fly: total thrust at Ω_max not above its weight (Σ η_i k_t Ω_max² ≤ m g), or a
    constant external torque larger than the rotors can counter at hover
    (:func:`flyability`'s ``torque_margin`` < 1). Returns θ."""
    t = np.asarray(theta, np.float64)
    twr = float(t[ETA].sum() * t[KT] * t[OMEGA_MAX] ** 2 / (t[MASS] * GRAVITY))
    if not twr > 1.0:
        raise ValueError(f"{what}: cannot hover: thrust-to-weight Σ η_i k_t Ω_max² / (m g) = {twr:.3g} <= 1 "
                         f"(keys thrust_coeff, max_rotor_speed, motor_effectiveness, mass)")
    margin = float(flyability(t)["torque_margin"])
    if not margin >= 1.0:
        raise ValueError(f"{what}: external_torque {t[TAU_EXT].tolist()} is more than the rotors can "
                         f"counter at hover (torque margin {margin:.3g} < 1)")
    return theta


def theta_from_dict(d: Mapping, *, source: str = "vehicle") -> np.ndarray:
    """Vehicle dict (vehicle-file keys, SI units) -> θ (19,). Unknown or missing keys, wrong
    types or lengths, non-finite, non-physical (:func:`validate_theta`) or unflyable
    (:func:`check_flyable`) values raise ``ValueError`` naming ``source`` and the key."""
    if not isinstance(d, Mapping):
        raise ValueError(f"{source}: expected a JSON object with keys {list(VEHICLE_KEYS)}")
    unknown = sorted(map(str, set(d) - set(VEHICLE_KEYS)))
    missing = [k for k in VEHICLE_KEYS if k not in d]
    if unknown:
        raise ValueError(f"{source}: unknown key(s) {unknown}; allowed: {list(VEHICLE_KEYS)}")
    if missing:
        raise ValueError(f"{source}: missing key(s) {missing}")
    theta = np.zeros(N_PARAMS, np.float64)

    def number(x) -> bool:
        return isinstance(x, (int, float, np.integer, np.floating)) and not isinstance(x, (bool, np.bool_))

    for key, (sl, n) in VEHICLE_KEYS.items():
        v = d[key]
        if n is None:
            if not number(v):
                raise ValueError(f"{source}: {key} must be a number, got {_short(v)}")
            vals = [v]
        else:
            if not isinstance(v, (list, tuple)) or len(v) != n or not all(number(x) for x in v):
                raise ValueError(f"{source}: {key} must be a list of {n} numbers, got {_short(v)}")
            vals = list(v)
        try:
            theta[sl] = vals if n is not None else vals[0]
        except OverflowError:
            raise ValueError(f"{source}: {key} is too large (beyond float32), got {_short(v)}") from None
    return check_flyable(validate_theta(theta, what=source), what=source)


def _short(v, n: int = 80) -> str:
    r = repr(v)
    return r if len(r) <= n else r[: n - 1] + "…"


def theta_to_dict(theta) -> dict:
    """θ (19,) -> vehicle dict (plain Python floats)."""
    theta = validate_theta(theta)
    if theta.shape != (N_PARAMS,):
        raise ValueError(f"theta_to_dict takes one vehicle, shape ({N_PARAMS},); got {theta.shape}")
    t = [float(f"{x:.7g}") for x in theta.astype(np.float64)]  # float32 precision, clean JSON
    return {k: (t[sl][0] if n is None else t[sl])
            for k, (sl, n) in VEHICLE_KEYS.items()}


def load_vehicle(path) -> np.ndarray:
    """Read a vehicle JSON file -> θ (19,). Errors name the file and the key."""
    path = Path(path)
    if not path.is_file():
        raise FileNotFoundError(f"vehicle file not found: {path}")

    def no_duplicates(pairs):
        seen = set()
        for k, _ in pairs:
            if k in seen:
                raise ValueError(f"{path}: key {k} appears twice")
            seen.add(k)
        return dict(pairs)

    try:
        d = json.loads(path.read_bytes().decode("utf-8"), object_pairs_hook=no_duplicates)
    except UnicodeDecodeError:
        raise ValueError(f"{path}: not a text (UTF-8) file") from None
    except json.JSONDecodeError as e:
        raise ValueError(f"{path}: not valid JSON ({e})") from None
    except RecursionError:
        raise ValueError(f"{path}: not valid JSON (nested too deeply)") from None
    return theta_from_dict(d, source=str(path))


def save_vehicle(theta, path) -> Path:
    """Write θ (19,) as a vehicle JSON file."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text(json.dumps(theta_to_dict(theta), indent=2) + "\n")
    return path


def paper_hardware() -> np.ndarray:
    """The paper's hardware vehicle θ (19,)."""
    return PAPER_HARDWARE.copy()


def vehicle_path(name: str) -> Path:
    """Path of a shipped vehicle file (``mjxsysid/assets/vehicles/<name>.json``)."""
    return Path(__file__).parent / "assets" / "vehicles" / f"{name}.json"


# ----------------------------------------------------------------------------------------
# Priors
# ----------------------------------------------------------------------------------------

@dataclasses.dataclass(frozen=True)
class Prior:
    """Correlated size-factor prior over θ (after Extreme-Adaptation, Zhang et al. 2025).

    A size factor c ~ U[0, 1] sets the nominal geometry; each quantity then gets independent
    multiplicative noise U[1 − noise, 1 + noise]:

    - arm length  l = arm_min + (arm_max − arm_min) c
    - mass        m = mass_base + mass_scale (l / 0.2)³               (m ∝ l³ plus avionics)
    - inertia     J_xx,yy = inertia_xy m l²,  J_zz = inertia_z m l²  (J ∝ l⁵); J_zz is capped
                  at 0.98 (J_xx + J_yy) (triangle inequality)
    - thrust      k_t = kt_base exp(kt_rate c)                        (exponential in c)
    - torque      k_τ = κ k_t, κ ~ U[kappa]
    - drag        D = drag_xy/z (l / 0.184)² × U[drag_noise]          (∝ l²)
    - Ω_max from a thrust-to-weight ratio r ~ U[twr]: Ω_max = √(r m g / (4 k_t)), with r clipped
      so that every rotor alone has 4 η_i k_t Ω_max² / (m g) in [twr_min_eff, twr_max_eff]
    - η_i ~ U[eta], τ_m ~ U[motor_time_constant]
    - τ_ext ~ U[−1, 1] × (ext_torque_xy m g l, ext_torque_xy m g l, ext_torque_z m g κ):
      a few per cent of the hover torque authority, so it can always be cancelled.

    The paper vehicle corresponds to c ≈ 0.76 and lies well inside every marginal
    (between the 15th and 85th percentiles of each; see docs/prior.md).
    """
    name: str = "default"
    arm: tuple[float, float] = (0.04, 0.23)
    mass_base: float = 0.04
    mass_scale: float = 1.15
    inertia_xy: float = 0.26
    inertia_z: float = 0.46
    kt_base: float = 2.5e-8
    kt_rate: float = 7.55
    kappa: tuple[float, float] = (0.0069, 0.0161)
    drag_xy: float = 0.20
    drag_z: float = 0.85
    drag_noise: tuple[float, float] = (0.4, 1.6)
    twr: tuple[float, float] = (2.2, 7.0)
    twr_min_eff: float = 1.5
    twr_max_eff: float = 8.5
    eta: tuple[float, float] = (0.7, 1.3)
    motor_time_constant: tuple[float, float] = (0.02, 0.04)
    ext_torque_xy: float = 0.02
    ext_torque_z: float = 0.1
    noise: float = 0.2

    def sample(self, key: jax.Array, n: int) -> jax.Array:
        """Draw n vehicles. key: PRNG key -> θ (n, 19) float32. Pure; jit-able with n static."""
        return _sample_prior(self, key, n)

    def replace(self, **kw) -> "Prior":
        return dataclasses.replace(self, **kw)


DEFAULT_PRIOR = Prior()
SLOW_ACTUATOR_PRIOR = Prior(name="slow_actuators", motor_time_constant=(0.05, 0.10))
# The default vehicles with motor time constants over the default and the slow-actuator range
# together: the prior mjxsysid's decoders are trained on, so that slow motors can be decoded
# (the predictive tuner's slow-actuator experiment, paper §V-A) while the policy is not retrained.
WIDE_ACTUATOR_PRIOR = Prior(name="wide_actuators", motor_time_constant=(0.02, 0.10))
# At and past the edges of the default prior (issue 18's stress test), where the oracle (K_θ with
# the true θ and the paper's fixed rate gains) still flies: thrust-to-weight 1.5–2.5 (the
# default's floor is 2.2), every rotor alone still lifting ≥ 1.5× its share of the weight (as in
# the default prior), motors up to 1.5× slower than the default's slowest (τ_m 0.04–0.06 s), motor
# effectiveness down to 0.5 (a worn motor), 2× the roll/pitch external torque and 1.2× the yaw
# torque. On the probe-loop run's 1,000 draws (10 s lemniscate): the oracle flies 97.5 %, the
# shipped policy 99.5 % at 1.59× the oracle's RMSE (docs/probing.md).
STRESS_PRIOR = Prior(name="stress", twr=(1.5, 2.5), twr_min_eff=1.5, motor_time_constant=(0.04, 0.06),
                     eta=(0.5, 1.3), ext_torque_xy=0.04, ext_torque_z=0.12)
# The first stress prior (τ_m to 0.12 s, rotors down to 1.2× their share, 3× the roll/pitch
# torque): kept to report both ways. Past τ_m ≈ 0.06 s the fixed-gain K_θ oracle itself fails
# (its 40 rad/s rate loop outruns the motors): of the probe-loop run's 1,000 draws it flew 41.9 %,
# the shipped policy 52.4 %, so a ratio to the oracle says little there
# (tools/stress_prior_oracle.py: which edge costs the oracle what).
STRESS_WIDE_PRIOR = Prior(name="stress_wide", twr=(1.5, 2.5), twr_min_eff=1.2, motor_time_constant=(0.04, 0.12),
                          eta=(0.5, 1.3), ext_torque_xy=0.06, ext_torque_z=0.12)


# ----------------------------------------------------------------------------------------
# Held-out families: vehicles no training method sees
# ----------------------------------------------------------------------------------------

@dataclasses.dataclass(frozen=True)
class HeldOutFamily(Prior):
    """A family of vehicles that no policy trains on: a :class:`~mjxsysid.params.Prior` with one
    kind of damage laid over its draws, and a fixed ``seed`` so every evaluation flies the same
    vehicles (:meth:`vehicles`).

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

    def sample(self, key: jax.Array, n: int) -> jax.Array:
        """Draw n vehicles. key: PRNG key -> θ (n, 19) float32."""
        return _sample_heldout(self, key, n)

    def vehicles(self, n: int) -> np.ndarray:
        """The family's n evaluation vehicles, the same on every call (seeded by ``seed``):
        θ (n, 19), validated and flyable (:func:`check_flyable`)."""
        if not isinstance(n, (int, np.integer)) or isinstance(n, bool) or n < 1:
            raise ValueError(f"n (vehicles of held-out family {self.name!r}) must be a positive integer, got {n!r}")
        theta = validate_theta(np.asarray(self.sample(jax.random.PRNGKey(self.seed), int(n))), what=self.name)
        for i, t in enumerate(theta):
            check_flyable(t, what=f"{self.name} vehicle {i}")
        return theta


def _sample_heldout(p: HeldOutFamily, key, n: int):
    k_base, k_motor, k_dir, k_sign = jax.random.split(key, 4)
    t = _sample_prior(p, k_base, n)
    if p.one_motor_eta is not None:
        which = jax.random.randint(k_motor, (n,), 0, 4)
        eta = jnp.where(jax.nn.one_hot(which, 4, dtype=bool), p.one_motor_eta, t[:, ETA])
        twr = jnp.clip(thrust_to_weight(t), p.twr_min_eff / eta.min(-1), p.twr_max_eff / eta.max(-1))
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


# Each family is the default prior with one kind of damage, past what any policy of mjxsysid
# trains on (the default prior, its probed systems, the stress prior). Ranges chosen so that the
# oracle (the lag-aware K_θ with the true θ) flies them: docs/probing.md, "Held-out families".
HELDOUT_FAMILIES = {f.name: f for f in (
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

# ----------------------------------------------------------------------------------------
# The released policy's training distribution
# ----------------------------------------------------------------------------------------

@dataclasses.dataclass(frozen=True)
class XAdapPrior(Prior):
    """A :class:`~mjxsysid.params.Prior` fitted to the released policy's training statistics.

    The released mean.csv / var.csv give mean ± std of the privileged parameters (README):
    mass 0.60 ± 0.33 kg and arm 0.113 ± 0.049 m are uniform-like (so mass is *linear* in the
    size factor here, not ∝ l³ as in the default prior), J ≈ 0.19 m l² (std/mean ≈ 1.2),
    k_t exponential in c (mean 3.7e-6, std 6.3e-6), κ ≈ U[0.0062, 0.016], drag ≈ isotropic,
    Ω_max 3379 ± 2435 rad/s, η U[0.7, 1.3]. Sampling, with c ~ U[0, 1] and noise
    n ~ U[1 ± noise]:

    - l = (arm_lo + (arm_hi − arm_lo) c) n, clipped to ``arm``; m likewise from ``mass_range``
    - J_xx,yy = inertia_xy m l² n, J_zz = inertia_z m l² n (≤ 0.98 (J_xx + J_yy))
    - k_t = kt_base exp(kt_rate c) n, κ ~ U[kappa], k_τ = κ k_t
    - D_xx = D_yy = D_zz = drag_iso (l / 0.2)² n
    - Ω_max from thrust-to-weight r ~ U[twr] clipped to [twr_min_eff, twr_max_eff] / η
    - η ~ U[eta], τ_m ~ U[motor_time_constant], τ_ext as :class:`~mjxsysid.params.Prior`.

    Moment match (200k samples; README in brackets): mass 0.60 ± 0.32 (0.60 ± 0.33), arm
    0.115 ± 0.049 (0.113 ± 0.049), J_xx 2.3e-3 ± 2.3e-3 (2.2e-3 ± 2.5e-3), J_zz 3.4e-3 ±
    3.5e-3 (3.3e-3 ± 4.1e-3), κ 0.0111 ± 0.0028 (same), k_t 3.6e-6 ± 6.2e-6 (3.7e-6 ± 6.3e-6),
    drag 0.29 ± 0.22 (0.30 ± 0.27), Ω_max 3420 ± 2280 (3379 ± 2435) rad/s. Thrust-to-weight
    ratio spans 1.5 – 5.8 (with η), angular authority 85 – 2300 rad/s². The joint structure
    (one size factor) is a guess: only marginals are published. Not in the statistics, taken
    from the default prior: τ_m ~ U[0.02, 0.04] s (the policy prefers faster motors: see the
    module notes) and τ_ext; the training's centre-of-mass offsets are not modelled.
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

    def sample(self, key: jax.Array, n: int) -> jax.Array:
        """Draw n vehicles. key: PRNG key -> θ (n, 19) float32."""
        return _sample_xadap(self, key, n)


def _sample_xadap(p: XAdapPrior, key, n: int):
    ks = jax.random.split(key, 16)
    u, noise = _uniforms(p, n)
    c = u(ks[0], 0.0, 1.0)
    arm = jnp.clip((p.arm[0] + (p.arm[1] - p.arm[0]) * c) * noise(ks[1]), *p.arm)
    m_lo, m_hi = p.mass_range
    mass = jnp.clip((m_lo + (m_hi - m_lo) * c) * noise(ks[2]), m_lo, m_hi)
    drag = p.drag_iso * (arm / 0.2) ** 2 * noise(ks[6])
    return _sample_rest(p, ks, n, c, arm, mass, jnp.stack([drag, drag, drag], -1))


def xadap_training_prior(**overrides) -> XAdapPrior:
    """The released Xadap policy's training distribution (moment-matched; see
    :class:`XAdapPrior`), optionally with fields replaced (e.g. ``ext_torque_xy=0``)."""
    return XAdapPrior(**overrides)


XADAP_PRIOR = XAdapPrior()


def widened_prior(prior: Prior, amount: float, name: str | None = None) -> Prior:
    """``prior`` widened by ``amount`` (natural-log units) in every direction, knowing nothing of
    where a policy is weak: every sampled range (arm length, κ, drag noise, thrust-to-weight, η,
    τ_m) moves out by a factor e^amount at both ends (lo e^−a, hi e^a; η's upper end and the drag
    noise's stay below 2 so the draws remain physical) and the external-torque scales grow by
    e^a. The flyability limits (``twr_min_eff``, ``twr_max_eff``) stay: every draw can still fly.
    The fair control of issue 28 (``experiments.probe_loop``, variant ``widened``)."""
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


PRIORS = {"default": DEFAULT_PRIOR, "slow_actuators": SLOW_ACTUATOR_PRIOR, "wide_actuators": WIDE_ACTUATOR_PRIOR,
          "xadap": XADAP_PRIOR, "stress": STRESS_PRIOR,
          "stress_wide": STRESS_WIDE_PRIOR}


def get_prior(name: str | Prior) -> Prior:
    if isinstance(name, Prior):
        return name
    if name in HELDOUT_FAMILIES:
        return HELDOUT_FAMILIES[name]
    if name not in PRIORS:
        raise ValueError(f"unknown prior {name!r}; choose from {sorted(PRIORS)} or a held-out family "
                         f"{sorted(HELDOUT_FAMILIES)}")
    return PRIORS[name]


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


def _uniforms(p: Prior, n: int):
    """Samplers u(key, lo, hi, shape) ~ U[lo, hi] and noise(key, shape) ~ U[1 ± p.noise]."""
    def u(k, lo, hi, shape=(n,)):
        return jax.random.uniform(k, shape, jnp.float32, lo, hi)

    def noise(k, shape=(n,)):
        return u(k, 1.0 - p.noise, 1.0 + p.noise, shape)

    return u, noise


def _sample_rest(p: Prior, ks, n: int, c, arm, mass, drag):
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


# ----------------------------------------------------------------------------------------
# Normalisation
# ----------------------------------------------------------------------------------------

LOG_MASK = np.array([1, 1, 1, 1, 1, 1, 1, 1, 1, 1, 1, 0, 0, 0, 0, 1, 0, 0, 0], bool)
"""Entries normalised in log space (positive scale parameters)."""
_LOG_EPS = np.zeros(N_PARAMS, np.float32)
_LOG_EPS[DRAG] = 1e-3  # drag may be 0: log(D + 1e-3 kg/s)


@jax.tree_util.register_pytree_node_class
@dataclasses.dataclass(frozen=True)
class Normalizer:
    """θ ↔ learning space: y = (f(θ) − shift) / scale, f = log(θ + eps) on :data:`LOG_MASK`
    entries and identity elsewhere. shift, scale: (19,).

    ``flow_map`` (19, 19) and ``flow_offset`` (19,), optional: the coordinates a decoder learns
    in, v = y @ flow_map + flow_offset (:meth:`to_flow`, :meth:`from_flow`); None: v = y. See
    :func:`identifiable_flow_map`. ``normalize`` / ``denormalize`` never apply it: decoders
    return samples in the standard y space whatever their flow coordinates. The four maps are
    jitted (one program each per shape, not a dozen eager operations compiled one by one)."""
    shift: jax.Array
    scale: jax.Array
    flow_map: jax.Array | None = None
    flow_offset: jax.Array | None = None

    def tree_flatten(self):
        return (self.shift, self.scale, self.flow_map, self.flow_offset), None

    @classmethod
    def tree_unflatten(cls, aux, children):
        return cls(*children)

    @staticmethod
    def _f(theta):
        return jnp.where(LOG_MASK, jnp.log(jnp.where(LOG_MASK, theta + _LOG_EPS, 1.0)), theta)

    @jax.jit
    def normalize(self, theta):
        """θ (..., 19) physical -> (..., 19) normalised."""
        return (self._f(jnp.asarray(theta)) - self.shift) / self.scale

    @jax.jit
    def denormalize(self, y):
        """(..., 19) normalised -> θ (..., 19) physical."""
        f = jnp.asarray(y) * self.scale + self.shift
        return jnp.where(LOG_MASK, jnp.exp(f) - _LOG_EPS, f)

    @jax.jit
    def to_flow(self, y):
        """Normalised y (..., 19) -> the decoder's flow coordinates v (..., 19)."""
        if self.flow_map is None:
            return jnp.asarray(y)
        return jnp.asarray(y) @ self.flow_map + self.flow_offset

    @jax.jit
    def from_flow(self, v):
        """Flow coordinates v (..., 19) -> normalised y (..., 19) (exact inverse of :meth:`to_flow`)."""
        if self.flow_map is None:
            return jnp.asarray(v)
        return jnp.linalg.solve(self.flow_map.T, (jnp.asarray(v) - self.flow_offset)[..., None])[..., 0]

    def with_flow(self, flow_map, flow_offset) -> "Normalizer":
        return Normalizer(self.shift, self.scale, jnp.asarray(flow_map, jnp.float32),
                          jnp.asarray(flow_offset, jnp.float32))

    @classmethod
    def fit(cls, theta) -> "Normalizer":
        """Mean / std of f(θ) over samples θ (n, 19)."""
        f = np.asarray(cls._f(jnp.asarray(theta, jnp.float32)), np.float64)
        return cls(jnp.asarray(f.mean(0), jnp.float32),
                   jnp.asarray(np.maximum(f.std(0), 1e-6), jnp.float32))

    def to_dict(self) -> dict:
        d = {"shift": np.asarray(self.shift).tolist(), "scale": np.asarray(self.scale).tolist()}
        if self.flow_map is not None:
            d["flow_map"] = np.asarray(self.flow_map).tolist()
            d["flow_offset"] = np.asarray(self.flow_offset).tolist()
        return d

    @classmethod
    def from_dict(cls, d) -> "Normalizer":
        norm = cls(jnp.asarray(d["shift"], jnp.float32), jnp.asarray(d["scale"], jnp.float32))
        if d.get("flow_map") is not None:
            fm, fo = np.asarray(d["flow_map"], np.float64), np.asarray(d.get("flow_offset"), np.float64)
            n = norm.shift.shape[-1]
            if fm.shape != (n, n) or fo.shape != (n,) or not (np.all(np.isfinite(fm)) and np.all(np.isfinite(fo))):
                raise ValueError(f"normalizer flow_map must be ({n}, {n}) and flow_offset ({n},) finite values, "
                                 f"got {fm.shape} and {fo.shape}")
            if not np.linalg.cond(fm) < 1e8:
                raise ValueError("normalizer flow_map is singular (condition number ≥ 1e8)")
            norm = norm.with_flow(fm, fo)
        return norm


DECODER_COORDS = ("theta", "identifiable")
"""Coordinates a decoder can learn in: the normalised θ entries, or a log-linear
reparametrisation whose axes are the identifiable combinations (:func:`identifiable_flow_map`)."""


def identifiable_log_matrix() -> np.ndarray:
    """M (19, 19): u = f(θ) @ M with f the normaliser's log/identity map, where u equals f except
    u[Ω_max] = log k_t + 2 log Ω_max − log m + mean(η) (log thrust-to-weight up to a constant; the
    mean η as the linearisation of log mean η) and u[J_a] = log l + log k_t + 2 log Ω_max − log J_a
    (log angular authority a). Invertible (each replaced coordinate keeps its own entry with a
    non-zero weight)."""
    m = np.eye(N_PARAMS)
    tw = np.zeros(N_PARAMS)
    tw[KT], tw[OMEGA_MAX], tw[MASS] = 1.0, 2.0, -1.0
    tw[ETA] = 0.25
    m[:, OMEGA_MAX] = tw
    for a in range(3):
        col = np.zeros(N_PARAMS)
        col[ARM], col[KT], col[OMEGA_MAX], col[INERTIA.start + a] = 1.0, 1.0, 2.0, -1.0
        m[:, INERTIA.start + a] = col
    return m


def identifiable_flow_map(norm: "Normalizer", theta) -> "Normalizer":
    """``norm`` with the flow coordinates of :func:`identifiable_log_matrix`, standardised over
    the samples θ (n, 19) (e.g. those ``norm`` was fitted to): v = y @ A + c has zero mean and
    unit std per axis; the axes of Ω_max and J are log thrust-to-weight and log angular
    authorities, the others the normalised θ entries."""
    y = np.asarray(norm.normalize(theta), np.float64)
    a0 = np.diag(np.asarray(norm.scale, np.float64)) @ identifiable_log_matrix()   # y -> u up to a constant
    v0 = y @ a0
    std = np.maximum(v0.std(0), 1e-6)
    a = a0 / std
    c = -(v0 / std).mean(0)
    return norm.with_flow(a, c)


def prior_normalizer(prior: str | Prior = "default", n: int = 100_000, seed: int = 0,
                     coords: str = "theta") -> Normalizer:
    """Normaliser fitted to ``n`` samples of a prior (seeded, deterministic); ``coords``
    ("theta" | "identifiable", :data:`DECODER_COORDS`) sets its flow coordinates."""
    if coords not in DECODER_COORDS:
        raise ValueError(f"unknown decoder coordinates {coords!r}; choose from {DECODER_COORDS}")
    theta = get_prior(prior).sample(jax.random.PRNGKey(seed), n)
    norm = Normalizer.fit(theta)
    return identifiable_flow_map(norm, theta) if coords == "identifiable" else norm


def as_batch(theta: Sequence | np.ndarray) -> np.ndarray:
    """Validate and return θ as (n, 19)."""
    arr = validate_theta(theta)
    return arr.reshape(-1, N_PARAMS)
