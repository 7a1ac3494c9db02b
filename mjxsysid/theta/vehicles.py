"""Vehicles: validation, projection to valid θ, flyability checks and vehicle files (JSON)."""
from __future__ import annotations

import json
from collections.abc import Mapping, Sequence
from pathlib import Path

import jax
import jax.numpy as jnp
import numpy as np

from mjxsysid.runtime import jsonout
from mjxsysid.theta.derived import flyability
from mjxsysid.theta.layout import (ETA, GRAVITY, INERTIA, KT, MASS, N_PARAMS, NONNEGATIVE_MASK, OMEGA_MAX,
                                   PAPER_HARDWARE, PARAM_NAMES, POSITIVE_MASK, TAU_EXT, VEHICLE_KEYS)

_POSITIVE = np.flatnonzero(POSITIVE_MASK)
_NONNEGATIVE = np.flatnonzero(NONNEGATIVE_MASK)


def validate_theta(theta, *, what: str = "theta") -> np.ndarray:
    """Check θ on the host and return it as float32 numpy (..., 19).

    Raises ``ValueError`` naming the first offending parameter (and batch index): wrong shape,
    non-finite entries, non-positive entries where the field table asks > 0 (mass, arm,
    coefficients, inertia, Ω_max, η, τ_m), negative drag, or inertia violating the triangle
    inequality.
    """
    arr = np.asarray(theta, dtype=np.float64)
    if arr.ndim == 0 or arr.shape[-1] != N_PARAMS:
        raise ValueError(f"{what} must have shape (..., {N_PARAMS}) in the order of "
                         f"mjxsysid.theta.PARAM_NAMES; got shape {arr.shape}")
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
        if POSITIVE_MASK[j]:
            fail(flat[:, j] <= 0, name, "must be > 0")
            fail(flat32[:, j] <= 0, name, "is too small (rounds to 0 in float32)")
        if NONNEGATIVE_MASK[j]:
            fail(flat[:, j] < 0, name, "must be >= 0")
    j = flat[:, INERTIA]
    for a in range(3):
        others = j[:, (a + 1) % 3] + j[:, (a + 2) % 3]
        fail(j[:, a] > others * (1 + 1e-6), f"inertia[{a}]",
             "violates the triangle inequality J_a <= J_b + J_c")
    return arr.astype(np.float32)


def _project(t, xp):
    """The projection of [project_valid][mjxsysid.theta.vehicles.project_valid] in numpy or
    jax.numpy (``xp``); t (..., 19)."""
    t = xp.concatenate([t[..., :0], t], -1)  # a copy in either library
    if xp is np:
        t[..., _POSITIVE] = np.maximum(t[..., _POSITIVE], 1e-9)
        t[..., _NONNEGATIVE] = np.maximum(t[..., _NONNEGATIVE], 0.0)
    else:
        t = t.at[..., _POSITIVE].max(1e-9).at[..., _NONNEGATIVE].max(0.0)
    for _ in range(3):
        j = t[..., INERTIA]
        new = [xp.minimum(j[..., a], 0.999 * (j[..., (a + 1) % 3] + j[..., (a + 2) % 3])) for a in range(3)]
        t = xp.concatenate([t[..., :INERTIA.start], xp.stack(new, -1), t[..., INERTIA.stop:]], -1)
    return t


def project_valid(theta) -> tuple[np.ndarray, np.ndarray]:
    """Make decoded/perturbed θ (..., 19) physically valid for simulation: inertia clipped to
    the triangle inequality (J_a ≤ 0.999 (J_b + J_c)), positive entries floored at 1e-9, drag at 0.
    Returns (valid θ, mask (...) of rows that needed changing). Host-side (float64);
    [project_valid_jax][mjxsysid.theta.vehicles.project_valid_jax] is the same projection inside jit."""
    orig = np.array(theta, np.float64)
    t = _project(orig.copy(), np)
    changed = np.any(~np.isclose(t, orig, rtol=1e-7, atol=0), -1)
    return t.astype(np.float32), changed


def project_valid_jax(theta) -> jax.Array:
    """[project_valid][mjxsysid.theta.vehicles.project_valid] for traced arrays (no mask):
    θ (..., 19) -> valid θ (..., 19)."""
    return _project(jnp.asarray(theta), jnp)


def check_flyable(theta, *, what: str = "vehicle") -> np.ndarray:
    """Raise ``ValueError`` (naming ``what`` and the keys involved) for a valid θ (19,) that
    cannot fly: total thrust at Ω_max not above its weight (Σ η_i k_t Ω_max² ≤ m g), or a
    constant external torque larger than the rotors can counter at hover
    ([flyability][mjxsysid.theta.derived.flyability]'s ``torque_margin`` < 1). Returns θ."""
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


def as_batch(theta: Sequence | np.ndarray) -> np.ndarray:
    """Validate and return θ as (n, 19)."""
    arr = validate_theta(theta)
    return arr.reshape(-1, N_PARAMS)


def theta_from_dict(d: Mapping, *, source: str = "vehicle") -> np.ndarray:
    """Vehicle dict (vehicle-file keys, SI units) -> θ (19,). Unknown or missing keys, wrong
    types or lengths, non-finite, non-physical ([validate_theta][mjxsysid.theta.vehicles.validate_theta])
    or unflyable ([check_flyable][mjxsysid.theta.vehicles.check_flyable]) values raise ``ValueError``
    naming ``source`` and the key."""
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
    path.write_text(jsonout.dumps(theta_to_dict(theta), indent=2) + "\n")
    return path


def paper_hardware() -> np.ndarray:
    """The paper's hardware vehicle θ (19,)."""
    return PAPER_HARDWARE.copy()


def vehicle_path(name: str) -> Path:
    """Path of a shipped vehicle file (``mjxsysid/assets/vehicles/<name>.json``)."""
    return Path(__file__).parent.parent / "assets" / "vehicles" / f"{name}.json"
