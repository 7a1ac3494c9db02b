"""The log space's layout, written once: its tables and every view of them.

What a flight log sees of θ, and what the inference works on, in three tables of
[Coord][mjxsysid.identify.logspace.Coord], in order:

- [V_FIELDS][mjxsysid.identify.logspace.V_FIELDS]: the visible coordinates v (12,). An IMU log
  with the motor commands changes with them ([coords][mjxsysid.identify.coords]).
- [H_FIELDS][mjxsysid.identify.logspace.H_FIELDS]: the hidden coordinates h (7,). Such a log
  does not change with them.
- [NUISANCE_FIELDS][mjxsysid.identify.logspace.NUISANCE_FIELDS]: the nuisances (9,). Per channel
  of [CHANNELS][mjxsysid.identify.logspace.CHANNELS], the IMU's white-noise level log σ and the
  model discrepancy log δ; then the accelerometer's z bias.

The vectors built from them:

- x (21,) = [v, nuisances]: the likelihood's parameters.
- y (17,) = [v, log σ, bias]: what the posterior samples (δ is set at the mode).
- z (13,) = [v, bias]: what the mode's least squares fits (σ and δ held).

And [QUANTITIES][mjxsysid.identify.logspace.QUANTITIES], a table of
[Quantity][mjxsysid.identify.logspace.Quantity]: the 13 physical quantities the posterior reports,
each made of entries of v, each with one name.

The index constants, generated from the tables:

- v: ``LOG_TW``, ``RHO``, ``LOG_TAU_M``, ``LOG_AUTH`` (``LOG_AUTH_X``, ``_Y``, ``_Z``), ``LOG_YAW``,
  ``EXT_ACC``. v comes first in x, y and z, so these index all three.
- h: ``LOG_MASS``, ``LOG_ARM``, ``LOG_OMEGA_MAX``, ``ETA_MEAN``, ``LOG_DRAG``.
- the nuisances (9,): ``LOG_NOISE``, ``LOG_DISCREPANCY``, ``BIAS``; a per-channel array (4,):
  ``GYRO``, ``ACC_Z``.
- x: ``X_V``, ``X_NUIS``, ``X_LOG_NOISE`` (``_GYRO``), ``X_LOG_DISCREPANCY`` (``_GYRO``), ``X_BIAS``.
- y: ``Y_V``, ``Y_LOG_NOISE``, ``Y_BIAS``, ``Y_NUIS``; ``Y_IN_X`` and ``NUIS_IN_Y`` (what y keeps).
- z: ``Z_V``, ``Z_BIAS``; ``Z_IN_Y``.

Between them: [x_from_y][mjxsysid.identify.logspace.x_from_y], ``y_from_x``, ``y_from_z``,
``z_from_y``; [pack][mjxsysid.identify.logspace.pack] builds a vector from its fields by name.

Outside this module, no code indexes these vectors with an integer (tests/identify/test_logspace.py).
"""
from __future__ import annotations

import dataclasses

import numpy as np

from mjxsysid.theta import xp_of


@dataclasses.dataclass(frozen=True)
class Coord:
    """One field of a log-space vector.

    - ``name``: entries of a field of ``size`` > 1 are named ``name[label]``.
    - ``unit``: of each entry; ``log(u)`` for the natural log of a quantity in u.
    - ``labels``: the entries' labels (default 0, 1, …).
    - ``about``: what the field is, in one line.
    """
    name: str
    size: int
    unit: str
    about: str = ""
    labels: tuple[str, ...] | None = None

    def entry_names(self) -> tuple[str, ...]:
        if self.size == 1:
            return (self.name,)
        labels = self.labels or tuple(str(i) for i in range(self.size))
        return tuple(f"{self.name}[{a}]" for a in labels)


CHANNELS = ("gyro_x", "gyro_y", "gyro_z", "acc_z")
"""The likelihood's channels: the gyro's three axes and the accelerometer's body z."""
N_CHANNELS = len(CHANNELS)
GYRO = slice(CHANNELS.index("gyro_x"), CHANNELS.index("gyro_z") + 1)
"""The gyro's channels in a per-channel array (4,)."""
ACC_Z = CHANNELS.index("acc_z")
"""The accelerometer's channel in a per-channel array (4,)."""

V_FIELDS: tuple[Coord, ...] = (
    Coord("log_thrust_to_weight", 1, "log(-)", "log of thrust_to_weight, 4 η̄ k_t Ω_max² / (m g)"),
    Coord("rel_effectiveness", 3, "-", "ρ_1..3 = η_i / η̄ (ρ_4 = 4 − ρ_1 − ρ_2 − ρ_3)"),
    Coord("log_motor_time_constant", 1, "log(s)", "log τ_m"),
    Coord("log_authority", 3, "log(rad/s^2)", "log of η̄ l k_t Ω_max² / J per body axis"),
    Coord("log_yaw_authority", 1, "log(rad/s^2)", "log of η̄ κ k_t Ω_max² / J_z"),
    Coord("ext_acc", 3, "rad/s^2", "τ_ext / J: the external torque's angular acceleration"),
)
"""The visible coordinates v, in order."""

H_FIELDS: tuple[Coord, ...] = (
    Coord("log_mass", 1, "log(kg)", "log m"),
    Coord("log_arm_length", 1, "log(m)", "log l"),
    Coord("log_max_rotor_speed", 1, "log(rad/s)", "log Ω_max"),
    Coord("mean_effectiveness", 1, "-", "η̄, the motors' mean effectiveness"),
    Coord("log_drag", 3, "log(kg/s)", "log of the body drag per axis"),
)
"""The hidden coordinates h, in order."""

NUISANCE_FIELDS: tuple[Coord, ...] = (
    Coord("log_noise", N_CHANNELS, "log(rad/s), log(m/s^2)", "log σ: the IMU's white noise per sample",
          CHANNELS),
    Coord("log_discrepancy", N_CHANNELS, "log(rad/s), log(m/s^2)", "log δ: what the model lacks", CHANNELS),
    Coord("acc_z_bias", 1, "m/s^2", "the accelerometer's z bias"),
)
"""The nuisances after v in x, in order."""


def _starts(fields) -> list[int]:
    return np.cumsum([0] + [f.size for f in fields]).tolist()


def _index(fields, offset: int = 0) -> dict[str, int | slice]:
    """Field name -> an int (size 1) or a slice, from ``offset``."""
    return {f.name: (offset + a if f.size == 1 else slice(offset + a, offset + a + f.size))
            for f, a in zip(fields, _starts(fields))}


def _names(fields) -> tuple[str, ...]:
    return tuple(n for f in fields for n in f.entry_names())


def _units(fields) -> tuple[str, ...]:
    return tuple(f.unit for f in fields for _ in range(f.size))


def _shift(i: int | slice, by: int) -> int | slice:
    return i + by if isinstance(i, int) else slice(i.start + by, i.stop + by)


def _sub(block: slice, inner: int | slice) -> int | slice:
    """An index into a block (a slice of a vector) -> the same index into the vector."""
    return _shift(inner, block.start)


V_NAMES = _names(V_FIELDS)
"""The visible coordinates' entry names (12)."""
V_UNITS = _units(V_FIELDS)
N_V = len(V_NAMES)
V_INDEX = _index(V_FIELDS)
"""Field name -> an int or a slice into v (and into x, y, z: v comes first)."""
H_NAMES = _names(H_FIELDS)
"""The hidden coordinates' entry names (7)."""
H_UNITS = _units(H_FIELDS)
N_H = len(H_NAMES)
H_INDEX = _index(H_FIELDS)
NUIS_NAMES = _names(NUISANCE_FIELDS)
"""The nuisances' entry names (9)."""
N_NUIS = len(NUIS_NAMES)
NUIS_INDEX = _index(NUISANCE_FIELDS)
"""Field name -> an int or a slice into the nuisances (9,)."""

# v's index constants, in the order of V_FIELDS
LOG_TW, RHO, LOG_TAU_M, LOG_AUTH, LOG_YAW, EXT_ACC = (V_INDEX[f.name] for f in V_FIELDS)
LOG_AUTH_X, LOG_AUTH_Y, LOG_AUTH_Z = range(LOG_AUTH.start, LOG_AUTH.stop)
# h's, in the order of H_FIELDS
LOG_MASS, LOG_ARM, LOG_OMEGA_MAX, ETA_MEAN, LOG_DRAG = (H_INDEX[f.name] for f in H_FIELDS)
# the nuisances', in the order of NUISANCE_FIELDS (into the nuisances (9,))
LOG_NOISE, LOG_DISCREPANCY, BIAS = (NUIS_INDEX[f.name] for f in NUISANCE_FIELDS)

# x (21,) = [v, nuisances]
X_FIELDS = V_FIELDS + NUISANCE_FIELDS
"""x's fields, in order."""
X_NAMES = _names(X_FIELDS)
N_X = len(X_NAMES)
X_INDEX = _index(X_FIELDS)
X_V = slice(0, N_V)
X_NUIS = slice(N_V, N_X)
X_LOG_NOISE, X_LOG_DISCREPANCY, X_BIAS = (X_INDEX[f.name] for f in NUISANCE_FIELDS)
X_LOG_NOISE_GYRO = _sub(X_LOG_NOISE, GYRO)
X_LOG_DISCREPANCY_GYRO = _sub(X_LOG_DISCREPANCY, GYRO)


def _positions(fields, index: dict, n: int) -> np.ndarray:
    """The entries of ``fields`` in a vector of ``n`` laid out by ``index``, in the fields' order."""
    return np.concatenate([np.atleast_1d(np.arange(n)[index[f.name]]) for f in fields])


# y (17,) = [v, log σ, bias]: x without log δ
Y_NUIS_FIELDS = tuple(f for f in NUISANCE_FIELDS if f.name != "log_discrepancy")
"""The nuisances y samples, in order (δ is set at the mode)."""
Y_FIELDS = V_FIELDS + Y_NUIS_FIELDS
Y_NAMES = _names(Y_FIELDS)
N_Y = len(Y_NAMES)
Y_INDEX = _index(Y_FIELDS)
Y_V = slice(0, N_V)
Y_NUIS = slice(N_V, N_Y)
"""log σ and the bias in y: the nuisances y samples."""
Y_LOG_NOISE, Y_BIAS = (Y_INDEX[f.name] for f in Y_NUIS_FIELDS)
Y_IN_X = _positions(Y_FIELDS, X_INDEX, N_X)
"""x's entries that y holds, in y's order: y = x[..., Y_IN_X]."""
NUIS_IN_Y = _positions(Y_NUIS_FIELDS, NUIS_INDEX, N_NUIS)
"""The nuisances' entries (of 9) that y holds: y[..., Y_NUIS] = nuisances[..., NUIS_IN_Y]."""

# z (13,) = [v, bias]: y without log σ
Z_FIELDS = V_FIELDS + tuple(f for f in Y_NUIS_FIELDS if f.name == "acc_z_bias")
"""The fields the mode's least squares fits, in order (σ and δ held)."""
N_Z = sum(f.size for f in Z_FIELDS)
Z_V = slice(0, N_V)
Z_BIAS = _index(Z_FIELDS)["acc_z_bias"]
Z_IN_Y = _positions(Z_FIELDS, Y_INDEX, N_Y)
"""y's entries that z holds, in z's order: z = y[..., Z_IN_Y]."""


def y_from_x(x):
    """x (..., 21) -> y (..., 17)."""
    return x[..., Y_IN_X]


def x_from_y(y, log_delta):
    """y (..., 17) and log δ (4,) -> x (..., 21), in y's array library (NumPy or jax.numpy)."""
    xp = xp_of(y)
    y = xp.asarray(y)
    ld = xp.broadcast_to(xp.asarray(log_delta, y.dtype), y.shape[:-1] + (N_CHANNELS,))
    return xp.concatenate([y[..., Y_V], y[..., Y_LOG_NOISE], ld, y[..., Y_BIAS, None]], -1)


def z_from_y(y):
    """y (..., 17) -> z (..., 13)."""
    return y[..., Z_IN_Y]


def y_from_z(z, log_sigma):
    """z (..., 13) and log σ (4,) or (..., 4) -> y (..., 17), in z's array library."""
    xp = xp_of(z)
    z = xp.asarray(z)
    ls = xp.broadcast_to(xp.asarray(log_sigma, z.dtype), z.shape[:-1] + (N_CHANNELS,))
    return xp.concatenate([z[..., Z_V], ls, z[..., Z_BIAS, None]], -1)


def pack(fields, **parts):
    """A vector (..., Σ size) from its fields' values, concatenated in the order of ``fields``: a
    field of size 1 given as (...), a larger one as (..., size); NumPy or jax.numpy, as given.
    ValueError names a missing or unknown field."""
    want = [f.name for f in fields]
    if set(parts) != set(want):
        raise ValueError(f"pack: fields {sorted(set(want) - set(parts))} missing, "
                         f"{sorted(set(parts) - set(want))} unknown (want {want})")
    xp = xp_of(*parts.values())
    cols = [xp.asarray(parts[f.name])[..., None] if f.size == 1 else xp.asarray(parts[f.name]) for f in fields]
    return xp.concatenate(cols, -1)


@dataclasses.dataclass(frozen=True)
class Quantity:
    """A physical quantity the log-grounded posterior reports, made of entries of v.

    - ``of``: the v entries it is made of ([V_NAMES][mjxsysid.identify.logspace.V_NAMES]).
    - ``form``: "exp" (exp of a log coordinate), "plain" (the coordinate itself) or "rest"
      (4 minus the sum of its entries: ρ_4); "exp" and "plain" take one entry.
    - ``in_theta``: the same quantity, with the same name and definition, is in θ's summary too
      (θ's field or derived quantity). A summary of both enters it once; any other name in both
      tables is an error ([joint_summary][mjxsysid.identify.gap.joint_summary]).
    """
    name: str
    unit: str
    of: tuple[str, ...]
    form: str = "exp"
    about: str = ""
    in_theta: bool = False


QUANTITIES: tuple[Quantity, ...] = (
    Quantity("thrust_to_weight", "-", ("log_thrust_to_weight",),
             about="4 η̄ k_t Ω_max² / (m g): the four rotors' thrust at full speed over the weight", in_theta=True),
    Quantity("motor_time_constant", "s", ("log_motor_time_constant",), about="τ_m", in_theta=True),
    *(Quantity(f"authority_total[{i}]", "rad/s^2", (f"log_authority[{i}]",),
               about=f"η̄ l k_t Ω_max² / J_{'xyz'[i]}") for i in range(3)),
    Quantity("yaw_authority_total", "rad/s^2", ("log_yaw_authority",), about="η̄ κ k_t Ω_max² / J_z"),
    *(Quantity(f"relative_effectiveness[{i}]", "-", (f"rel_effectiveness[{i}]",), "plain",
               about=f"ρ_{i + 1} = η_{i + 1} / η̄") for i in range(3)),
    Quantity("relative_effectiveness[3]", "-", tuple(f"rel_effectiveness[{i}]" for i in range(3)), "rest",
             about="ρ_4 = 4 − ρ_1 − ρ_2 − ρ_3"),
    *(Quantity(f"external_acc[{i}]", "rad/s^2", (f"ext_acc[{i}]",), "plain",
               about=f"τ_ext / J along body {'xyz'[i]}") for i in range(3)),
)
"""The quantities an IMU log identifies, in their units: what the log-grounded posterior reports."""

LOG_NAMES = tuple(q.name for q in QUANTITIES)
"""The reported quantities' names (13), in the order of [QUANTITIES][mjxsysid.identify.logspace.QUANTITIES]."""
LOG_UNITS = tuple(q.unit for q in QUANTITIES)
QUANTITY = {q.name: q for q in QUANTITIES}
"""Name -> its [Quantity][mjxsysid.identify.logspace.Quantity]."""
V_OF_QUANTITY: tuple[tuple[int, ...], ...] = tuple(tuple(V_NAMES.index(n) for n in q.of) for q in QUANTITIES)
"""Per quantity of [QUANTITIES][mjxsysid.identify.logspace.QUANTITIES], the indices of the v entries it is made of."""

RENAMED = {"thrust_to_weight_total": "thrust_to_weight"}
"""Old quantity name -> its name now (read with a FutureWarning: [Summary][mjxsysid.identify.gap.Summary])."""


def quantities_of_v(v):
    """v (..., 12) -> the [QUANTITIES][mjxsysid.identify.logspace.QUANTITIES] (..., 13) in their units
    (NumPy, float64)."""
    v = np.asarray(v, np.float64)
    cols = []
    for q, idx in zip(QUANTITIES, V_OF_QUANTITY):
        a = v[..., idx]
        if q.form == "exp":
            with np.errstate(over="ignore"):
                cols.append(np.exp(a.sum(-1)))
        else:
            cols.append(a.sum(-1) if q.form == "plain" else 4.0 - a.sum(-1))
    return np.stack(cols, -1)
