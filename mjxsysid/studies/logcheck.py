"""Physical plausibility of a flight log, before anything is decoded.

A log can pass every check of its format (columns, numbers, 500 Hz, motor commands in [0, 1])
and still be wrong in a way only physics sees: the accelerometer in g, the gyro in deg/s, the
motor columns in another autopilot's rotor order, a command column that is not what the policy
was given. Each check here rests on what every multirotor obeys, not on numbers fitted to
mjxsysid's own logs:

- **specific force against gravity.** Over a flight that does not end in a fall, the
  accelerometer (specific force, body frame) averages to gravity's magnitude in the world frame,
  so its mean norm is at least about g; at hover it reads +g on the body z axis (FLU: thrust up).
- **gyro scale.** A MEMS gyro's full-scale range is at most 2000 °/s (34.9 rad/s); a rate
  controller follows its body-rate command, so gyro ≈ omega_cmd (gain 1, not 180/π).
- **rotor order.** Euler's equation J ω̇ = τ: the angular acceleration the gyro shows must follow
  the torque the motor commands imply through the rotor layout (roll from the left–right
  difference of Ω², pitch from back–front, yaw from the spin directions), with a positive gain
  on every axis. Every one of the 24 orders is fitted; a clearly better one is named.
- **motor columns.** Normalised rotor-speed commands lie in [0, 1] (checked on reading); values
  that do not drive the angular acceleration under any rotor order are not rotor commands.
- **the policy on its own inputs.** For a log flown by the policy being decoded, the policy
  replayed on the logged IMU and commands must output the logged motor commands.
- **IMU noise.** A rigid body's rates and specific force change smoothly from one 2 ms sample to
  the next (rotors lag their commands), so the second difference of a clean IMU is tiny and that
  of a noisy one is the noise's: its robust spread estimates the white-noise level per sample
  (:func:`estimate_imu_noise`). Past what the decoders were calibrated under
  (:data:`IMU_NOISE_LIMIT`), high-frequency noise reads as a smaller, quicker vehicle.

:func:`check_log` returns :class:`Finding` s: ``error`` where the log cannot be right (the CLI
exits 2), ``warning`` where it is suspicious. :func:`prior_check` estimates, from the log alone,
what the decoders cannot be trusted beyond: thrust-to-weight (specific force per unit Σ u²),
the motor time constant (the lag of specific force behind the commands) and the weakest
motor's effectiveness (the hover balance), each against the decoders' training prior.
"""
from __future__ import annotations

import dataclasses
import itertools

import numpy as np

from mjxsysid import theta as P

DT = 0.002
"""s: one control step (500 Hz)."""

GYRO_FULL_SCALE = np.deg2rad(2000.0)
"""rad/s: the largest full-scale range of common MEMS gyros (±2000 °/s). A body rate beyond it
cannot have been measured: the column is not in rad/s."""

SMOOTH_STEPS = 10
"""Moving-average length (20 ms) applied alike to both sides of the torque and rate fits: it
removes sensor noise above 25 Hz while keeping the rotor dynamics (τ_m ≥ a few ms)."""

LAGS = (0.003, 0.005, 0.0075, 0.01, 0.0125, 0.015, 0.02, 0.03, 0.04, 0.06, 0.08, 0.1, 0.13)
"""s: the rotor time constants tried when fitting the commands to what the IMU shows."""

KNOWN_ORDERS = {
    "mjxsysid (front-right, front-left, back-left, back-right)": (0, 1, 2, 3),
    "RotorPy (front-left, front-right, back-right, back-left)": (1, 0, 3, 2),
    "PX4 quad-X (front-right, back-left, front-left, back-right)": (0, 2, 1, 3),
    "Betaflight quad-X (back-right, front-right, back-left, front-left)": (3, 0, 2, 1),
}
"""Rotor orders of common tools: the mjxsysid rotor (0 front-right, 1 front-left, 2 back-left,
3 back-right) in each of the log's columns motor_1..motor_4."""


@dataclasses.dataclass(frozen=True)
class Finding:
    """One result of a check: ``level`` 'error' (the log cannot be right), 'warning' (suspicious)
    or 'out_of_prior' (the decoders were not trained on such a vehicle); ``column`` the log
    column(s) concerned; ``message`` what was found, the likely cause and the fix."""
    level: str
    column: str
    message: str

    def __str__(self) -> str:
        return f"{self.column}: {self.message}"

    def as_dict(self) -> dict:
        return dataclasses.asdict(self)


def warn(finding) -> None:
    """Print a finding on stderr: always, whatever ``--quiet`` says (as errors are)."""
    import sys
    label = "out of prior" if getattr(finding, "level", "") == "out_of_prior" else "warning"
    print(f"{label}: {finding}", file=sys.stderr, flush=True)


class LogError(ValueError):
    """A log that cannot be right: ``findings`` holds every finding (errors and warnings)."""

    def __init__(self, path, findings):
        self.findings = list(findings)
        errs = [f for f in self.findings if f.level == "error"]
        super().__init__(f"{path}: " + "; ".join(str(f) for f in errs))


# ------------------------------------------------------------------------------- helpers
def _smooth(x, n: int = SMOOTH_STEPS):
    """Moving average over ``n`` rows along axis 0 (valid part only)."""
    c = np.cumsum(np.concatenate([np.zeros((1,) + x.shape[1:]), x], 0), 0)
    return (c[n:] - c[:-n]) / n


def _lag(x, tau: float):
    """First-order lag with time constant ``tau`` (s) at 500 Hz along axis 0, starting at x[0]
    (the rotor speed following its command, exactly discretised)."""
    from scipy.signal import lfilter
    a = np.exp(-DT / tau)
    zi = (a * x[0])[None] if x.ndim > 1 else np.array([a * x[0]])
    return lfilter([1 - a], [1, -a], x, axis=0, zi=zi)[0]


def _fit(x, y):
    """Least squares y ≈ k x + b -> (k, R²)."""
    xc, yc = x - x.mean(0), y - y.mean(0)
    sxx, syy = float((xc * xc).sum()), float((yc * yc).sum())
    if sxx <= 0 or syy <= 0:
        return 0.0, 0.0
    k = float((xc * yc).sum()) / sxx
    return k, 1.0 - float(((yc - k * xc) ** 2).sum()) / syy


def _torque_basis():
    """(3, 4): roll, pitch and yaw torque per unit thrust-like Ω² of each mjxsysid rotor
    (positions ±1/√2, reaction yaw signs), without the vehicle's scale."""
    d = P.ROTOR_DIRECTIONS
    return np.stack([d[:, 1], -d[:, 0], P.YAW_SIGNS]).astype(np.float64)


def order_name(order) -> str:
    order = tuple(int(i) for i in order)
    for name, o in KNOWN_ORDERS.items():
        if o == order:
            return name
    return "columns motor_1..4 = " + ", ".join(P.ROTOR_NAMES[i] for i in order)


FIT_ROWS = 30_000
"""Rows (60 s) the dynamics fits use at most: a longer log contributes evenly spaced contiguous
pieces of that many rows in all (physics does not change along a flight; the cost stays bounded)."""


def fit_rows(rec: dict, max_rows: int = FIT_ROWS) -> dict:
    """``rec`` itself, or for a log longer than ``max_rows`` six evenly spaced contiguous pieces of
    it, ``max_rows`` rows in all, joined (imu and motor only: what the fits read)."""
    t = len(rec["imu"])
    if t <= max_rows:
        return rec
    k, n = 6, max_rows // 6
    idx = np.concatenate([np.arange(s, s + n) for s in np.linspace(0, t - n, k).astype(int)])
    out = {k: np.asarray(rec[k])[idx] for k in ("imu", "motor") if k in rec}
    for key in ("native", "resampled"):    # what the checks know of the columns' own rates
        if key in rec:
            out[key] = rec[key]
    return out


# ------------------------------------------------------------------- columns' own rates
MIN_ORDER_RATE_HZ = 100.0
"""Hz: the motor-command rate below which the rotor order and τ_m cannot be told from the log:
the rotors follow their commands within τ_m (5–100 ms), so commands held for longer than 10 ms
no longer show which rotor moved the vehicle when (PX4 logs its motors at 10 Hz by default)."""

RESAMPLED_FRACTION = 0.3
"""Share of rows at which a column group is exactly held (no change) or exactly linear (zero
second difference on every channel) past which it is taken as resampled from a lower rate
(a 500 Hz log of a real vehicle: none; from 250 Hz: about half the rows)."""


def detect_resampled(t, x):
    """Whether the columns ``x`` (T, k) sampled at ``t`` (T,) were brought to their grid from a
    lower rate -> None (not resampled), or (how, native rate Hz, knot rows): 'held (zero-order)' if
    every channel repeats its previous row on most rows, 'interpolated (linear)' if every
    channel's second difference is zero (to the CSV's 7 digits) on most rows; the knot rows are
    the native samples."""
    x = np.asarray(x, np.float64).reshape(len(x), -1)
    if len(x) < 10:
        return None
    span = max(float(t[-1] - t[0]), DT)
    same = np.all(np.diff(x, axis=0) == 0, axis=1)
    if same.mean() > RESAMPLED_FRACTION:
        knots = np.concatenate([[0], np.flatnonzero(~same) + 1])
        return "held (zero-order)", len(knots) / span, knots
    d2 = np.diff(x, 2, axis=0)
    scale = np.maximum(np.maximum(np.abs(x[:-2]), np.abs(x[1:-1])), np.abs(x[2:]))
    lin = np.all(np.abs(d2) <= 2.5e-6 * scale + 1e-12, axis=1)   # zero to the CSV's 7 digits (each ±5e-7)
    if lin.mean() > RESAMPLED_FRACTION:
        knots = np.concatenate([[0], np.flatnonzero(~lin) + 1, [len(x) - 1]])
        return "interpolated (linear)", len(knots) / span, knots
    return None


def column_rates(rec: dict) -> dict:
    """For the imu and motor column groups: {group: (rate Hz, how, native (t, values) or None)} —
    the rate at which the group was sampled before it reached the 2 ms grid: what the reader
    declared (``rec["native"]``, ``rec["resampled"]``: :func:`~mjxsysid.logs.ulog.read_ulog`),
    else what :func:`detect_resampled` finds (a CSV resampled from a lower rate: its native
    samples are its knots), else 500 Hz 'native'."""
    out = {}
    native, said = rec.get("native") or {}, rec.get("resampled") or {}
    t = np.asarray(rec["t"], np.float64) if "t" in rec else DT * np.arange(len(rec["imu"]))
    for key in ("imu", "motor"):
        if key not in rec and key not in native:
            continue
        if key in native:
            tn, xn = native[key]
            d = np.diff(np.asarray(tn, np.float64))
            rate = float(1.0 / np.median(d[d > 0])) if np.any(d > 0) else 1.0 / DT
            out[key] = (rate, said.get(key, "native"), (np.asarray(tn, np.float64), np.asarray(xn, np.float64)))
            continue
        found = detect_resampled(t, rec[key])
        if found is None:
            out[key] = (1.0 / DT, "native", None)
        else:
            how, rate, knots = found
            x = np.asarray(rec[key], np.float64)
            out[key] = (rate, f"{how} from about {rate:.3g} Hz (detected: the column values)", (t[knots], x[knots]))
    return out


def _resampled(rate: float) -> bool:
    return abs(rate * DT - 1.0) > 0.05


def check_resampled(rec: dict) -> list[Finding]:
    """A warning naming each column group a CSV carries resampled from a lower rate (held or
    linearly interpolated: detected from its values), what it was, and what the checks do about
    it. A reader that declares its resampling (``rec["resampled"]``, a ULog) is not warned for it
    here (the source says it); the checks that cannot work at its rate say so themselves."""
    out = []
    declared = rec.get("resampled") or {}
    for key, (rate, how, _) in column_rates(rec).items():
        if key in declared or not _resampled(rate):
            continue
        cols = "gyro_x … acc_z" if key == "imu" else "motor_1, motor_2, motor_3, motor_4"
        out.append(Finding("warning", cols, f"the {key} columns look {how}: not sampled every 2 ms step. The "
                           f"decoders read the policy's 500 Hz inputs; a log resampled from another rate does not "
                           f"give the inputs the policy saw (docs/decoding.md). The checks read the native "
                           f"samples (the knots) where they can"))
    return out


EXCITED_ALPHA = 1.0
"""rad/s²: the spread of the (smoothed) angular acceleration below which a flight is too still
to tell the rotor order (a hover in still air)."""


def rotor_order_fit(rec: dict) -> dict:
    """Fit the angular acceleration (gyro, differentiated and smoothed) to the torque the motor
    commands imply for each of the 24 rotor orders. -> dict: ``scores`` {order: mean R² over
    roll, pitch, yaw (an axis with a negative gain counts −1)}, ``gains`` {order: (3,)},
    ``best`` order, ``given`` score of the log's own order (0, 1, 2, 3), ``tau`` the lag used,
    ``excited`` whether the flight moved the vehicle enough to tell (rate changes above noise).
    A long log is fitted on :func:`fit_rows` of it."""
    rec = fit_rows(rec)
    u2 = np.asarray(rec["motor"], np.float64) ** 2
    gyro = np.asarray(rec["imu"], np.float64)[:, :3]
    alpha = _smooth(np.diff(gyro, axis=0) / DT)                           # (T−n, 3)
    basis = _torque_basis()
    best_tau, best_s, cache = None, -np.inf, {}
    for tau in LAGS:  # the lag from the log's own order (the rotor time constant); every order then uses it
        uf = _smooth(_lag(u2, tau)[:-1])  # row t: the rotors over step t, which alpha[t] spans
        s = np.mean([_fit(uf @ basis[k], alpha[:, k])[1] for k in range(3)])
        cache[tau] = uf
        if s > best_s:
            best_tau, best_s = tau, s
    uf = cache[best_tau]
    scores, gains = {}, {}
    for order in itertools.permutations(range(4)):
        b = basis[:, list(order)]          # column j is rotor order[j]
        ks, r2 = zip(*(_fit(uf @ b[k], alpha[:, k]) for k in range(3)))
        scores[order] = float(np.mean([r if k > 0 else -1.0 for k, r in zip(ks, r2)]))
        gains[order] = np.asarray(ks)
    best = max(scores, key=scores.get)
    # Excited: the angular acceleration varies well above what the gyro's noise makes of it
    # (a moving average of n differences of white noise σ has std σ √2 / (n dt)).
    sigma = estimate_imu_noise({"imu": np.asarray(rec["imu"])})["gyro_noise"]
    floor = sigma * np.sqrt(2.0) / (SMOOTH_STEPS * DT)
    excited = bool(np.std(alpha) > max(3.0 * floor, EXCITED_ALPHA))
    return {"scores": scores, "gains": gains, "best": best, "given": scores[(0, 1, 2, 3)], "tau": best_tau,
            "excited": excited, "given_r2": float(best_s)}


# -------------------------------------------------------------------------------- checks
def check_log(rec: dict, *, policy=None, zhat=None, imu_limit: dict | None = None) -> list[Finding]:
    """Physical plausibility of a flight log read by
    [read_log][mjxsysid.studies.decode.read_log] (``rec``: t, imu (T, 6), a_cmd, omega_cmd (T, 3),
    motor (T, 4)). ``policy``: the loaded latent policy being decoded, and ``zhat`` (T, 8) its
    replay of the log (both optional): then the policy's own actions on the logged inputs are
    compared with the logged motor commands (without them there is no replay check here: the
    policy's replay is :func:`check_replay`, run by ``decode`` and ``mjxsysid.check_log``).
    ``imu_limit``: the IMU noise the decoders are calibrated under (:func:`imu_noise_limit`;
    default :data:`IMU_NOISE_LIMIT`). Columns resampled from a lower rate (declared by the reader
    in ``rec["native"]`` / ``rec["resampled"]``, or detected in a CSV) are named, and each check
    reads the native samples or says that it cannot tell at that rate. -> findings, errors first."""
    out = []
    out += _check_specific_force(rec)
    out += _check_gyro(rec)
    if not any(f.level == "error" for f in out):   # the thrust checks need a sane accelerometer
        out += _check_thrust(rec)
        out += _check_a_cmd(rec)
    if not any(f.level == "error" for f in out):   # the dynamics checks need sane units and thrust
        out += check_resampled(rec)
        out += _check_motors(rec)
        out += _check_thrust_model(rec)
        out += check_imu_noise(rec, imu_limit)
        if policy is not None and zhat is not None and hasattr(policy, "replay_actions"):
            out += check_replay(rec, policy, zhat)
    return sorted(out, key=lambda f: f.level != "error")


def _check_specific_force(rec) -> list[Finding]:
    acc = np.asarray(rec["imu"], np.float64)[:, 3:6]
    g = P.GRAVITY
    norm = np.linalg.norm(acc, axis=1)
    med = float(np.median(norm))
    mean = np.mean(acc, 0)
    seconds = len(acc) * DT
    cols = "acc_x, acc_y, acc_z"
    if 0.5 < med < 2.0:
        return [Finding("error", cols, f"the specific force has median norm {med:.3g} in flight: looks like g, "
                        f"not m/s² (an accelerometer reads about 9.81 m/s² at hover): multiply acc_x/y/z by {g}")]
    if 0.5 * g * 1000 < med < 2.0 * g * 1000:
        return [Finding("error", cols, f"the specific force has median norm {med:.4g}: looks like milli-g "
                        f"(mg), not m/s²: multiply acc_x/y/z by {g / 1000:g}")]
    if med < 0.5 * g or med > 5 * g:
        lvl = "error" if seconds >= 1.0 else "warning"
        return [Finding(lvl, cols, f"the specific force has median norm {med:.3g} m/s²; a flying (or resting) "
                        f"vehicle's accelerometer averages about g = {g} m/s² over a flight: check the unit "
                        f"(m/s² expected) and that the columns are the accelerometer (specific force)")]
    axis = int(np.argmax(np.abs(mean)))
    if axis != 2 or mean[2] < 0:
        name = "xyz"[axis]
        sign = "+" if mean[axis] > 0 else "−"
        fix = ("the body z axis points down (FRD, as PX4 logs): convert to FLU by negating the y and z columns "
               "of gyro and acc" if axis == 2 else
               f"the thrust axis is {sign}{name}: map the columns to FLU (x forward, y left, z up, thrust on +z)")
        return [Finding("error", cols, f"the mean specific force is {mean.round(2).tolist()} m/s², largest on "
                        f"{sign}{name}; a multirotor's thrust is along +z in mjxsysid's body frame (FLU): {fix}")]
    return []


def _check_gyro(rec) -> list[Finding]:
    gyro = np.asarray(rec["imu"], np.float64)[:, :3]
    w_cmd = np.asarray(rec["omega_cmd"], np.float64)
    out = []
    peak = float(np.percentile(np.abs(gyro), 99.9))
    if peak > GYRO_FULL_SCALE:
        out.append(Finding("error", "gyro_x, gyro_y, gyro_z",
                           f"body rates reach {peak:.4g} (99.9th percentile of |gyro|), beyond any gyro's full "
                           f"scale ({GYRO_FULL_SCALE:.1f} rad/s = 2000 °/s): looks like deg/s, not rad/s: "
                           f"multiply gyro_x/y/z by π/180"))
    cpeak = float(np.percentile(np.abs(w_cmd), 99.9))
    if cpeak > GYRO_FULL_SCALE:
        out.append(Finding("error", "omega_cmd_x, omega_cmd_y, omega_cmd_z",
                           f"commanded body rates reach {cpeak:.4g}, beyond what any gyro measures "
                           f"({GYRO_FULL_SCALE:.1f} rad/s): looks like deg/s: multiply omega_cmd_x/y/z by π/180"))
    if out:
        return out
    # A rate-tracking controller follows its command: the gain from omega_cmd to gyro is about 1.
    gs, ws = _smooth(gyro).ravel(), _smooth(w_cmd).ravel()
    if np.std(ws) > 0.05:   # rad/s of commanded rate: enough to measure a gain
        k, r2 = _fit(ws, gs)
        ratio = 180.0 / np.pi
        if r2 > 0.3 and ratio / 3 < k < ratio * 3:
            out.append(Finding("warning", "gyro_x, gyro_y, gyro_z",
                               f"the body rates follow omega_cmd with gain {k:.3g} (R² {r2:.2f}); a rate "
                               f"controller tracks its command with gain about 1: the gyro looks like deg/s "
                               f"(multiply gyro_x/y/z by π/180)"))
        elif r2 > 0.3 and 1 / (ratio * 3) < k < 3 / ratio:
            out.append(Finding("warning", "omega_cmd_x, omega_cmd_y, omega_cmd_z",
                               f"the body rates follow omega_cmd with gain {k:.3g} (R² {r2:.2f}), not about 1: "
                               f"omega_cmd looks like deg/s (multiply omega_cmd_x/y/z by π/180)"))
    return out


IDLE_COMMAND = 0.05
"""Normalised rotor-speed command below which a rotor is taken as stopped or idling (a
multirotor hovers at 0.4–0.9; PX4's idle spin is about 0.2 of Ω_max)."""

TWR_IMPOSSIBLE = 25.0
"""Thrust-to-weight past which the motor commands cannot be what holds the vehicle up (the most
powerful racing quadrotors reach about 15): the specific force is not supported by them."""


def _check_thrust(rec) -> list[Finding]:
    """An error for a log whose rotors do not carry the vehicle: motor commands at idle or zero
    on most rows (disarmed, on the ground, a bench log), or a specific force far beyond what the
    commands could produce."""
    u = np.asarray(rec["motor"], np.float64)
    acc_z = np.asarray(rec["imu"], np.float64)[:, 5]
    cols = "motor_1, motor_2, motor_3, motor_4"
    idle = float(np.mean(u.max(1) < IDLE_COMMAND))
    if idle > 0.5:
        return [Finding("error", cols, f"every motor command is below {IDLE_COMMAND:g} of full rotor speed on "
                        f"{idle:.0%} of the rows: the rotors were stopped or idling (disarmed, on the ground, a "
                        f"bench log), nothing carried the vehicle, there is no flight to decode. Cut the airborne "
                        f"part (--segment T0:T1; a ULog is cut at its armed, airborne segment)")]
    s2 = float((u ** 2).sum(1).mean())
    twr = 4.0 * float(acc_z.mean()) / (P.GRAVITY * max(s2, 1e-12))
    if acc_z.mean() > 0.5 * P.GRAVITY and twr > TWR_IMPOSSIBLE:
        return [Finding("error", cols, f"the specific force (mean {acc_z.mean():.3g} m/s² on z) is not supported by "
                        f"the motor commands (mean Σu² {s2:.3g}): it would need a thrust-to-weight of {twr:.3g}. "
                        f"The rotors did not carry the vehicle (on the ground, a bench log), or the motor columns "
                        f"are not Ω_cmd/Ω_max (throttles: Ω_cmd/Ω_max = √throttle; docs/decoding.md, 'Converting autopilot "
                        f"outputs')")]
    return []


A_CMD_RATIO = (0.67, 1.5)
"""How far the mean a_cmd may lie from the mean specific force along z (a ratio) before it is
flagged: a_cmd is the mass-normalised collective thrust the vehicle was commanded, which the
accelerometer measures along body z (drag and the rotors' lag average out over a flight)."""


def _check_a_cmd(rec) -> list[Finding]:
    a = np.asarray(rec["a_cmd"], np.float64)
    acc_z = float(np.asarray(rec["imu"], np.float64)[:, 5].mean())
    if acc_z < 0.5 * P.GRAVITY:
        return []
    lo, hi = float(a.min()), float(a.max())
    if lo >= -1e-6 and hi <= 1.0 + 1e-6:
        return [Finding("error", "a_cmd", f"a_cmd lies in [0, 1] (mean {a.mean():.3g}) while the specific force along "
                        f"z averages {acc_z:.3g} m/s²: it looks like a normalised thrust setpoint (PX4's "
                        f"vehicle_thrust_setpoint), not m/s². a_cmd is the commanded mass-normalised collective "
                        f"thrust in m/s²: multiply by g / hover thrust (PX4: hover_thrust_estimate or "
                        f"MPC_THR_HOVER; docs/px4.md)")]
    ratio = float(a.mean()) / acc_z
    if not A_CMD_RATIO[0] < ratio < A_CMD_RATIO[1]:
        return [Finding("warning", "a_cmd", f"a_cmd averages {a.mean():.3g} m/s², the specific force along z it "
                        f"commands {acc_z:.3g} m/s² (ratio {ratio:.2g}): a_cmd is the mass-normalised collective "
                        f"thrust commanded (m/s², about g at hover); check its unit and scale (docs/decoding.md)")]
    return []


THRUST_MODEL_RATIO = 0.3
"""The hover-balance ratio (:func:`thrust_model_fit`) below which the motor columns are taken as
throttles: thrust ∝ Ω² gives 1 without drag and about 0.5 with the vertical drag of the prior's
vehicles (the paper vehicle 0.54); columns that are throttles (thrust ∝ the column, read as Ω)
give half of that (0.12–0.14 on the same flights)."""


def thrust_model_fit(rec, tau: float = 0.02) -> dict:
    """The thrust model against the hover balance: acc_z ≈ k Σ ū² fitted on the changes along the
    flight (ū the motor columns lagged by ``tau``) and the balance of the means,
    mean acc_z / mean Σ ū². For columns Ω_cmd/Ω_max (thrust ∝ ū²) the two agree (``ratio``
    k / balance about 1, less with vertical drag); for throttles (thrust ∝ ū: the columns' square is
    the thrust's) the changes are twice as steep in Σ ū² as the balance: the ratio halves.
    -> ``ratio``, ``r2`` of the fit."""
    rec = fit_rows(rec)
    x = _smooth((_lag(np.asarray(rec["motor"], np.float64), tau) ** 2).sum(1))
    y = _smooth(np.asarray(rec["imu"], np.float64)[:, 5])
    k, r2 = _fit(x, y)
    return {"ratio": float(k * x.mean() / max(float(y.mean()), 1e-12)), "r2": float(r2)}


def _check_thrust_model(rec) -> list[Finding]:
    fit = thrust_model_fit(rec)
    if fit["r2"] > 0.5 and fit["ratio"] < THRUST_MODEL_RATIO:
        return [Finding("warning", "motor_1, motor_2, motor_3, motor_4",
                        f"the specific force changes along the flight with Σ motor² at {fit['ratio']:.2f} of the "
                        f"gain the hover balance gives (mean acc_z / mean Σ motor²; R² {fit['r2']:.2f}); rotor-speed "
                        f"commands give 0.5–1, throttles half that: the motor columns look like throttles (thrust linear in the column), "
                        f"not rotor-speed commands. Thrust ∝ Ω²: for an ESC whose thrust is linear in throttle, "
                        f"Ω_cmd/Ω_max = √throttle (PX4: √((1 − f) u + f u²) with THR_MDL_FAC f; docs/px4.md)")]
    return []


def estimate_thrust_lag(rec) -> dict:
    """The motor time constant from the specific force: the lag (of :data:`LAGS`) with which
    Σ ū² (the commands lagged, squared) best fits acc_z -> ``tau`` (s) and ``r2``."""
    rec = fit_rows(rec)
    u = np.asarray(rec["motor"], np.float64)
    y = _smooth(np.asarray(rec["imu"], np.float64)[:, 5])
    best = (LAGS[0], -np.inf)
    for tau in LAGS:
        r2 = _fit(_smooth((_lag(u, tau) ** 2).sum(1)), y)[1]
        if r2 > best[1]:
            best = (tau, r2)
    return {"tau": float(best[0]), "r2": float(best[1])}


def _check_motors(rec) -> list[Finding]:
    cols = "motor_1, motor_2, motor_3, motor_4"
    rate = column_rates(rec)["motor"][0]
    if rate < MIN_ORDER_RATE_HZ:
        return [Finding("warning", cols, f"cannot tell the rotor order at this motor rate ({rate:.3g} Hz): the rotors "
                        f"follow their commands within a few tens of ms, commands {1e3 / rate:.3g} ms apart do not "
                        f"show which rotor turned the vehicle; the order is taken as given (for a ULog: from its "
                        f"parameters). Log the motor commands at ≥ {MIN_ORDER_RATE_HZ:g} Hz to have it checked "
                        f"(PX4: docs/px4.md, 'Logging rates')")]
    fit = rotor_order_fit(rec)
    if not fit["excited"]:
        return []
    given, best, sbest = fit["given"], fit["best"], fit["scores"][fit["best"]]
    gains = fit["gains"][(0, 1, 2, 3)]
    if best != (0, 1, 2, 3) and sbest > 0.5 and sbest - given > 0.25:
        wrong_sign = [a for a, k in zip(("roll", "pitch", "yaw"), gains) if k <= 0]
        lvl = "error" if any(a in ("roll", "pitch") for a in wrong_sign) else "warning"
        what = (f"in this order the motors' torque turns the vehicle against its measured "
                f"{'/'.join(wrong_sign)} acceleration" if wrong_sign else "")
        reorder = ", ".join(f"motor_{j + 1} = column {best.index(j) + 1}" for j in range(4))
        return [Finding(lvl, cols, f"the angular acceleration fits the torque of another rotor order clearly better "
                        f"(mean R² {sbest:.2f} vs {given:.2f} for mjxsysid's order{'; ' + what if what else ''}): "
                        f"the columns look like {order_name(best)}; mjxsysid's order is front-right, front-left, "
                        f"back-left, back-right: reorder ({reorder})")]
    if sbest < 0.2:
        return [Finding("warning", cols, f"the motor commands do not explain the angular acceleration under any rotor "
                        f"order (best mean R² {sbest:.2f}): are motor_1..4 normalised rotor-speed commands Ω_cmd/Ω_max "
                        f"(not body rates, torques or PWM)? See docs/decoding.md, 'Converting autopilot outputs'")]
    return []


NOISE_DIFF_ORDER = 2
"""The finite difference whose spread estimates the IMU noise: for white noise of std σ the k-th
difference has std σ √C(2k, k) (√6 for k = 2), while a smooth signal's shrinks by dt² per order."""

IMU_NOISE_LIMIT = {"gyro_noise": 0.015, "accel_noise": 0.15}
"""rad/s and m/s² per 2 ms sample: the white-noise level past which :func:`check_imu_noise` warns.
The shipped decoders were trained on flights without IMU noise and the policy with gyro 0.005 rad/s
and accelerometer 0.05 m/s²; at twice that (0.01 / 0.1, the tuning experiment's hardware-like
simulator) their 90 % intervals cover the truth as often as on clean flights, at four times that the
angular authorities' coverage falls 6–10 points, at ten times 25 (docs/noise.md): the limit lies
between, at three times. Correct logs of the prior read at most 0.008 rad/s (docs/decoding.md)."""


def imu_noise_limit(*decoders) -> dict:
    """The IMU noise past which a log is flagged, for these decoders (objects with a ``meta``
    dict, as :func:`~mjxsysid.cfm.load.load_decoders` returns; None entries skipped): the IMU their
    training pairs flew (``meta['data']['pairs_meta']['imu']``, recorded by ``collect``) where it
    reaches past :data:`IMU_NOISE_LIMIT` — white noise or rotor vibration, the larger, per sensor;
    with ``randomize_imu`` those are the maxima of the per-flight levels — else
    :data:`IMU_NOISE_LIMIT`. Several decoders: the strictest (the smallest limit)."""
    limits = []
    for d in decoders:
        imu = ((getattr(d, "meta", None) or {}).get("data") or {}).get("pairs_meta", {}).get("imu")
        if not imu:
            limits.append(dict(IMU_NOISE_LIMIT))
            continue
        trained = {"gyro_noise": max(float(imu.get("gyro_noise", 0.0)), float(imu.get("gyro_vibration", 0.0))),
                   "accel_noise": max(float(imu.get("accel_noise", 0.0)), float(imu.get("accel_vibration", 0.0)))}
        limits.append({k: max(IMU_NOISE_LIMIT[k], trained[k]) for k in IMU_NOISE_LIMIT})
    if not limits:
        return dict(IMU_NOISE_LIMIT)
    return {k: min(lim[k] for lim in limits) for k in IMU_NOISE_LIMIT}


def estimate_imu_noise(rec: dict) -> dict:
    """The IMU's white-noise level per sample from the log alone: 1.4826 · MAD of the
    :data:`NOISE_DIFF_ORDER`-th difference of each channel over √C(2k, k), the median over the
    three axes -> ``gyro_noise`` (rad/s), ``accel_noise`` (m/s²). A per-flight bias does not enter
    (differences remove it); narrow-band vibration counts as far as it reaches the upper band (a
    tone at a quarter of the sampling rate or above reads as about its std, far below it less).
    The first 0.2 s are skipped (take-off); a long log reads :func:`fit_rows` of it. An IMU
    resampled from a lower rate (:func:`column_rates`) is read at its native samples: the level
    is then per native sample (``imu_rate_hz`` says at which rate)."""
    from math import comb
    imu = None
    rate, _, nat = column_rates(rec)["imu"]
    if nat is not None and len(nat[1]) >= 4 * (NOISE_DIFF_ORDER + 2):
        imu = nat[1][-FIT_ROWS:]        # interpolated values have no noise: read the native samples
    if imu is None:                     # (a few "native" samples: a held constant column, read as logged)
        imu = np.asarray(fit_rows(rec)["imu"], np.float64)
    skip = int(round(0.2 * rate))           # the first 0.2 s (take-off)
    imu = imu[min(skip, len(imu) // 4):]
    k = NOISE_DIFF_ORDER
    d = np.diff(imu, n=k, axis=0)
    sd = 1.4826 * np.median(np.abs(d - np.median(d, 0)), 0) / np.sqrt(comb(2 * k, k))
    return {"gyro_noise": float(np.median(sd[:3])), "accel_noise": float(np.median(sd[3:])), "imu_rate_hz": float(rate)}


def check_imu_noise(rec: dict, limit: dict | None = None, est: dict | None = None) -> list[Finding]:
    """A warning if the IMU noise :func:`estimate_imu_noise` finds (or ``est``) is past ``limit``
    (default :data:`IMU_NOISE_LIMIT`) on the gyro or the accelerometer."""
    limit = IMU_NOISE_LIMIT if limit is None else limit
    est = estimate_imu_noise(rec) if est is None else est
    over = [k for k in ("gyro_noise", "accel_noise") if est[k] > limit[k]]
    if not over:
        return []
    cols = ", ".join(c for k, c in (("gyro_noise", "gyro_x/y/z"), ("accel_noise", "acc_x/y/z")) if k in over)
    rate = est.get("imu_rate_hz", 1.0 / DT)
    per = "per sample" if not _resampled(rate) else f"per native sample at {rate:.3g} Hz"
    return [Finding("warning", cols, f"IMU noise about {est['gyro_noise']:.2g} rad/s (gyro) and "
                    f"{est['accel_noise']:.2g} m/s² (accelerometer) {per}, from the log's sample-to-sample "
                    f"changes: past what the decoders were calibrated under ({limit['gyro_noise']:g} rad/s, "
                    f"{limit['accel_noise']:g} m/s²). High-frequency IMU noise (rotor vibration, an unfiltered "
                    f"sensor) reads as a smaller, quicker vehicle: the decoded bands are likely too low in mass "
                    f"and inertia and too high in angular authority, and not calibrated. Fly with the IMU "
                    f"filtered or the vibration damped (the policy must read the same IMU the log records); "
                    f"docs/noise.md")]


REPLAY_ROWS = 4000
"""Rows (evenly spaced) at which the policy's own action is compared with the logged one."""

REPLAY_TOLERANCE = 0.005
"""RMS difference of normalised motor commands above which the logged motor commands are not
the policy's on the logged inputs: a float32 replay of a CSV with 7 significant digits agrees
to about 1e-6, so 0.5 % of full rotor speed is far above round-off."""


def check_replay(rec, policy, zhat) -> list[Finding]:
    """The policy (a loaded latent policy with ``replay_actions``) replayed on the logged inputs
    against the logged motor commands (``zhat`` (T, 8): its replay of the log) -> a warning if
    they differ by more than :data:`REPLAY_TOLERANCE`, naming the IMU if the previous row's
    reading explains them."""
    t = len(rec["t"])
    rows = np.unique(np.linspace(1, t - 1, min(REPLAY_ROWS, t - 1)).astype(int))
    act = np.asarray(policy.replay_actions(rec["imu"], rec["a_cmd"], rec["omega_cmd"], rec["motor"], zhat, rows))
    err = float(np.sqrt(np.mean((act - np.asarray(rec["motor"])[rows]) ** 2)))
    if err <= REPLAY_TOLERANCE:
        return []
    # Rows whose IMU was read after the step: the policy acted on the previous row's reading.
    prev = np.concatenate([rec["imu"][:1], rec["imu"][:-1]])
    act1 = np.asarray(policy.replay_actions(prev, rec["a_cmd"], rec["omega_cmd"], rec["motor"], zhat, rows))
    err1 = float(np.sqrt(np.mean((act1 - np.asarray(rec["motor"])[rows]) ** 2)))
    if err1 < 0.5 * err:
        return [Finding("warning", "gyro_x … acc_z", f"each row's IMU is the reading after the motor command took "
                        f"effect: the policy outputs the logged motors from the previous row's IMU (RMS Δu {err1:.2g}, "
                        f"vs {err:.2g} from the same row): log the IMU the policy acted on (shift the IMU columns one "
                        f"row down; docs/decoding.md, 'Row timing')")]
    return [Finding("warning", "a_cmd, omega_cmd_x/y/z", f"the policy replayed on the logged IMU and commands does not "
                    f"output the logged motor commands (RMS Δu {err:.2g} of full rotor speed, tolerance "
                    f"{REPLAY_TOLERANCE}): if this log was flown by this policy, a command column (a_cmd or "
                    f"omega_cmd: e.g. another controller's rate command) or the IMU is not what the policy was "
                    f"given; log exactly the policy's inputs. A log not flown by this policy is decoded off its "
                    f"training distribution")]


# ---------------------------------------------------------------------------- out of prior
def estimate_vehicle(rec: dict, fit: dict | None = None) -> dict:
    """What the log alone says about the vehicle. From the thrust equation, specific force
    acc_z = (T/W · g / 4) Σ η_i ū_i² with ū the commands lagged by τ_m (drag along body z
    averages out over a flight): ``thrust_to_weight`` = 4 mean(acc_z) / (g mean Σ ū²) (the
    vehicle's T/W times the harmonic mean of its η); from
    the hover balance (each rotor of an X layout delivers the same thrust, so η_i ∝ 1 / mean u_i²)
    ``min_motor_effectiveness``, the weakest rotor's relative to the mean; from Euler's equation
    (the rotor order fit, ``fit`` of :func:`rotor_order_fit` if already computed)
    ``motor_time_constant``, the lag of the angular acceleration behind the commands, and
    ``torque_fit_r2``, how well that fit explains it; ``gyro_noise`` and ``accel_noise`` from
    :func:`estimate_imu_noise`."""
    full = rec
    motor_rate = column_rates(rec)["motor"][0]
    fit = rotor_order_fit(rec) if fit is None else fit
    rec = fit_rows(rec)
    acc_z = np.asarray(rec["imu"], np.float64)[:, 5]
    # Thrust follows the rotor speed, the command lagged by τ_m: its mean square is below the
    # command's when the commands chatter (the lag removes variance), so lag them first.
    u2 = _lag(np.asarray(rec["motor"], np.float64), fit["tau"]) ** 2
    skip = min(100, len(acc_z) // 4)   # the first 0.2 s: the log may start before take-off settles
    ms = u2[skip:].mean(0)
    twr = 4.0 * float(acc_z[skip:].mean()) / (P.GRAVITY * max(float(ms.sum()), 1e-12))
    eta = (1.0 / np.maximum(ms, 1e-12)) / np.mean(1.0 / np.maximum(ms, 1e-12))
    lag = estimate_thrust_lag(rec) if motor_rate >= MIN_ORDER_RATE_HZ else {"tau": float("nan"), "r2": 0.0}
    torque_r2 = fit["given_r2"] if motor_rate >= MIN_ORDER_RATE_HZ else 0.0
    return {"thrust_to_weight": twr, "motor_time_constant": float(fit["tau"]), "torque_fit_r2": torque_r2,
            "motor_time_constant_thrust": lag["tau"], "thrust_fit_r2": lag["r2"], "motor_rate_hz": float(motor_rate),
            "min_motor_effectiveness": float(eta.min()), **estimate_imu_noise(full)}


TAU_FIT_R2 = 0.5
"""R² a fit (torque or thrust) must reach for its lag to count as the motor time constant."""


def motor_time_constant(est: dict):
    """τ_m from :func:`estimate_vehicle`'s estimates: the torque fit's lag where it explains the
    angular acceleration (R² > :data:`TAU_FIT_R2`), else the thrust fit's (the lag of the specific
    force behind Σ ū²) where that explains acc_z -> (τ s, 'torque' | 'thrust'), or (None, why not)."""
    if est.get("torque_fit_r2", 0.0) > TAU_FIT_R2:
        return float(est["motor_time_constant"]), "torque"
    if est.get("thrust_fit_r2", 0.0) > TAU_FIT_R2 and np.isfinite(est.get("motor_time_constant_thrust", np.nan)):
        return float(est["motor_time_constant_thrust"]), "thrust"
    rate = est.get("motor_rate_hz", 1.0 / DT)
    if rate < MIN_ORDER_RATE_HZ:
        return None, (f"the motor time constant is not estimable from this log: motor commands at {rate:.3g} Hz "
                      f"(≥ {MIN_ORDER_RATE_HZ:g} Hz needed)")
    return None, (f"the motor time constant is not estimable from this log: neither the angular acceleration "
                  f"(R² {est.get('torque_fit_r2', 0.0):.2f}) nor the specific force (R² "
                  f"{est.get('thrust_fit_r2', 0.0):.2f}) follows the lagged motor commands; the "
                  f"motor_time_constant estimate is not a measurement")


PRIOR_MARGIN = {"thrust_to_weight": 1.0, "motor_time_constant": 1.4, "motor_effectiveness": 1.0}
"""How far past the training prior's physical range (a factor) a log-only estimate must lie to
be flagged. Thrust-to-weight and the weakest rotor: none (the prior's extremes — every rotor's
η·T/W ≤ 8.5, one rotor at η's floor with three at its top — are already beyond what its
vehicles reach on average); τ_m: one step of the estimator's grid of lags. Their false-alarm
and hit rates are measured in docs/decoding.md, 'Out of prior'."""


def prior_bounds(prior="wide_actuators") -> dict:
    """The ranges of the decoders' training prior that :func:`prior_check` compares with: the
    largest thrust-to-weight any rotor reaches (T/W × η), τ_m and η."""
    p = P.get_prior(prior)
    lo, hi = p.eta
    return {"thrust_to_weight": (p.twr_min_eff, p.twr_max_eff), "motor_time_constant": p.motor_time_constant,
            # the weakest rotor relative to the mean of four: one at the floor, three at the top
            "motor_effectiveness": (lo / ((lo + 3 * hi) / 4), hi / ((hi + 3 * lo) / 4))}


def prior_check(rec: dict, prior="wide_actuators", est: dict | None = None) -> list[Finding]:
    """Whether the logged vehicle lies outside the decoders' training ``prior`` by the log-only
    estimates of :func:`estimate_vehicle` (each beyond the prior's range by :data:`PRIOR_MARGIN`)
    -> 'out_of_prior' findings (empty: inside)."""
    est = estimate_vehicle(rec) if est is None else est
    b = prior_bounds(prior)
    out = []
    twr = est["thrust_to_weight"]
    lo, hi = b["thrust_to_weight"]
    m = PRIOR_MARGIN
    if twr > hi * m["thrust_to_weight"] or twr < lo / m["thrust_to_weight"]:
        out.append(Finding("out_of_prior", "acc_z, motor_1..4",
                           f"thrust-to-weight about {twr:.3g} from the log (specific force per Σ motor²), outside "
                           f"the decoders' training prior ({lo:g}–{hi:g}): the decoded bands are not calibrated here"))
    tau, src = motor_time_constant(est)
    tlo, thi = b["motor_time_constant"]
    if tau is not None and (tau < tlo / m["motor_time_constant"] or tau > thi * m["motor_time_constant"]):
        what = ("lag of the angular acceleration behind the commands" if src == "torque"
                else "lag of the specific force behind the commands")
        out.append(Finding("out_of_prior", "acc_z, motor_1..4",
                           f"motor time constant about {tau * 1e3:.3g} ms from the log ({what}), outside the decoders' training prior ({tlo * 1e3:g}–{thi * 1e3:g} "
                           f"ms): the decoded bands are not calibrated here"))
    eta = est["min_motor_effectiveness"]
    if eta < b["motor_effectiveness"][0] / m["motor_effectiveness"]:
        out.append(Finding("out_of_prior", "motor_1..4",
                           f"one motor needs {1 / eta:.2g}× the mean squared command to hold its share (effectiveness "
                           f"about {eta:.2g} of the others'), beyond the decoders' training prior (at least "
                           f"{b['motor_effectiveness'][0]:.2g}): the decoded bands are not calibrated here"))
    return out


# ----------------------------------------------------------------------- common mistakes
MISTAKES = ("acc_in_g", "gyro_in_deg_s", "time_in_ms", "motor_pwm", "rotorpy_order", "px4_order",
            "omega_cmd_other", "frd_frame", "imu_after_step")
"""The mistakes :func:`make_mistake` makes to a correct log (what the checks must catch)."""


def make_mistake(rec: dict, kind: str, *, imu_after=None) -> dict:
    """A correct log ``rec`` (the arrays of ``read_log``) with one common mistake made -> a new
    dict: ``acc_in_g`` (accelerometer in g), ``gyro_in_deg_s``, ``time_in_ms``, ``motor_pwm``
    (1000–2000 µs pulses), ``rotorpy_order`` / ``px4_order`` (motor columns in that tool's rotor
    order), ``omega_cmd_other`` (the rate command of another controller than the policy's: here
    the measured body rates), ``frd_frame`` (body frame FRD: y right, z down), ``imu_after_step`` (each row's IMU read
    after the step: ``imu_after`` (T, 6), the reading after each step, else the next row's)."""
    r = {k: np.array(v, copy=True) for k, v in rec.items()}
    if kind == "acc_in_g":
        r["imu"][:, 3:6] /= P.GRAVITY
    elif kind == "gyro_in_deg_s":
        r["imu"][:, :3] = np.rad2deg(r["imu"][:, :3])
    elif kind == "time_in_ms":
        r["t"] = r["t"] * 1000.0
    elif kind == "motor_pwm":
        r["motor"] = 1000.0 + 1000.0 * r["motor"]
    elif kind in ("rotorpy_order", "px4_order"):
        order = KNOWN_ORDERS[next(n for n in KNOWN_ORDERS if n.lower().startswith(kind.split("_")[0]))]
        r["motor"] = r["motor"][:, list(order)]
    elif kind == "omega_cmd_other":
        r["omega_cmd"] = r["imu"][:, :3].copy()
    elif kind == "frd_frame":
        r["imu"][:, [1, 2, 4, 5]] *= -1
        r["omega_cmd"][:, [1, 2]] *= -1
    elif kind == "imu_after_step":
        r["imu"] = (np.concatenate([r["imu"][1:], r["imu"][-1:]]) if imu_after is None
                    else np.array(imu_after, copy=True))
    else:
        raise ValueError(f"unknown mistake {kind!r}; choose from {MISTAKES}")
    return r
