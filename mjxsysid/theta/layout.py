"""θ's layout, written once: the field table and every view of it.

θ is a float array of shape (..., 19) in SI units. [FIELDS][mjxsysid.theta.layout.FIELDS] lists
its fields in order; the names, units, index constants, slices, masks and vehicle-file keys
below are all generated from it.

Body frame: x forward, y left, z up (FLU). Rotors in X configuration, numbered (0-based in
code, 1-based in prose) 1 front-right, 2 front-left, 3 back-left, 4 back-right; rotors 1 and
3 spin counter-clockwise seen from above (reaction yaw torque −k_τΩ²), 2 and 4 clockwise
(+k_τΩ²).
"""
from __future__ import annotations

import dataclasses
import math

import numpy as np

GRAVITY = 9.81  # m/s², must match assets/quadrotor.xml


@dataclasses.dataclass(frozen=True)
class Field:
    """One field of θ.

    - ``name``: the vehicle-file key; entries of a field of ``size`` > 1 are named ``name[i]``.
    - ``unit``: SI unit of each entry ("-" for dimensionless).
    - ``positive``: every entry must be > 0; ``nonnegative``: ≥ 0 (zero allowed).
    - ``log``: normalised in log space for learning, as log(θ + ``log_offset``).
    - ``about``: what the field is, in one line.
    """
    name: str
    size: int
    unit: str
    positive: bool = True
    nonnegative: bool = False
    log: bool = True
    log_offset: float = 0.0
    about: str = ""


FIELDS: tuple[Field, ...] = (
    Field("mass", 1, "kg", about="m"),
    Field("arm_length", 1, "m", about="l, centre of mass to rotor axis"),
    Field("thrust_coeff", 1, "N/(rad/s)^2", about="k_t: T_i = η_i k_t Ω_i²"),
    Field("torque_coeff", 1, "N m/(rad/s)^2", about="k_τ: yaw torque ±η_i k_τ Ω_i²"),
    Field("inertia", 3, "kg m^2", about="J_xx, J_yy, J_zz (principal, body frame)"),
    Field("drag", 3, "kg/s", positive=False, nonnegative=True, log_offset=1e-3,
          about="D_xx, D_yy, D_zz: body-frame linear drag (may be 0)"),
    Field("max_rotor_speed", 1, "rad/s", about="Ω_max"),
    Field("motor_effectiveness", 4, "-", log=False, about="η_1..η_4"),
    Field("motor_time_constant", 1, "s", about="τ_m"),
    Field("external_torque", 3, "N m", positive=False, log=False,
          about="τ_ext: constant body-frame torque"),
)
"""θ's fields in order: the one place its layout is written."""

_STARTS = np.cumsum([0] + [f.size for f in FIELDS]).tolist()
N_PARAMS: int = _STARTS[-1]

SLICES: dict[str, slice] = {f.name: slice(a, a + f.size) for f, a in zip(FIELDS, _STARTS)}
"""Field name -> slice into θ's last axis."""

INDEX: dict[str, int | slice] = {f.name: (a if f.size == 1 else SLICES[f.name]) for f, a in zip(FIELDS, _STARTS)}
"""Field name -> an int (scalar fields) or a slice (vector fields) into θ's last axis."""

# Short names of the index constants, in the order of FIELDS.
MASS, ARM, KT, KTAU, INERTIA, DRAG, OMEGA_MAX, ETA, TAU_M, TAU_EXT = (INDEX[f.name] for f in FIELDS)

PARAM_NAMES: tuple[str, ...] = tuple(f.name if f.size == 1 else f"{f.name}[{i}]" for f in FIELDS for i in range(f.size))
PARAM_UNITS: tuple[str, ...] = tuple(f.unit for f in FIELDS for _ in range(f.size))


def _mask(attr: str) -> np.ndarray:
    return np.concatenate([np.full(f.size, getattr(f, attr), bool) for f in FIELDS])


POSITIVE_MASK = _mask("positive")
"""(19,) bool: entries that must be > 0."""
NONNEGATIVE_MASK = _mask("nonnegative")
"""(19,) bool: entries that must be ≥ 0 (and may be 0)."""
LOG_MASK = _mask("log")
"""(19,) bool: entries normalised in log space (positive scale parameters)."""
LOG_OFFSET = np.concatenate([np.full(f.size, f.log_offset, np.float32) for f in FIELDS])
"""(19,) float32: added before the log on [LOG_MASK][mjxsysid.theta.layout.LOG_MASK] entries."""

VEHICLE_KEYS: dict[str, tuple[slice, int | None]] = {
    f.name: (SLICES[f.name], None if f.size == 1 else f.size) for f in FIELDS}
"""Vehicle-file schema: key -> (slice into θ, length, or None for a scalar)."""

# Rotor layout (body frame FLU), X configuration: unit directions of the arms.
_S = 1.0 / math.sqrt(2.0)
ROTOR_DIRECTIONS = np.array([[_S, -_S], [_S, _S], [-_S, _S], [-_S, -_S]], np.float32)  # (4, 2)
ROTOR_NAMES = ("front-right", "front-left", "back-left", "back-right")
YAW_SIGNS = np.array([-1.0, 1.0, -1.0, 1.0], np.float32)  # reaction yaw torque sign per rotor

PAPER_HARDWARE = np.array(
    [0.925, 0.184, 7.64e-6, 1.07e-7, 8.5e-3, 7.5e-3, 15.5e-3, 0.20, 0.20, 0.85, 1360.0,
     1.0, 1.0, 1.0, 1.0, 0.03, 0.0, 0.0, 0.0], np.float32)
"""The paper's hardware vehicle (Table I), θ (19,): thrust-to-weight 4 k_t Ω_max²/(m g) ≈ 6.2."""
