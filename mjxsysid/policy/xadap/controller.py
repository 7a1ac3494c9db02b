"""The released Extreme-Adaptation ("Xadap") policy as an mjxsysid low-level controller.

:class:`XAdapController` wraps the pure-JAX networks of :mod:`mjxsysid.policy.xadap` in the
low-level interface of :mod:`mjxsysid.control.low_level`, so that the released policy flies
under any high-level controller (e.g. :class:`~mjxsysid.control.high_level.Cascade`) in the
unchanged harness (:func:`~mjxsysid.rollout.harness.fly_batch`)::

    low = make_xadap_low_level(XADAP_DIR, batch_size=B)          # rate 500 Hz, filter on
    flight = fly_batch(sim, theta, low, high, refs, dist, key, steps)

Conventions (released files' README, the published wrapper ``Xadap_NN_control.py``, and
closed-loop checks in mjxsysid):

* **state** s (8) = [ω (3) gyro, rad/s body FLU; specific force along body z (1), m/s²,
  low-passed (below); ω_cmd (3) rad/s; a_cmd (1) m/s² mass-normalised collective thrust].
  mjxsysid's body frame (x forward, y left, z up) is the network's frame: no sign change
  (positive roll / pitch / yaw-rate commands produce positive body rates in closed loop).
* **policy input** (20) = [normalize_state([s_k, r_{k−1}]) (12), ẑ_k (8)].
* **adaptation input** (1200) = :func:`~mjxsysid.policy.xadap.network.build_history_input` of the
  last 100 *previous* policy steps (oldest first): at step k the history holds
  s_{k−100..k−1} and r_{k−100..k−1}; s_k and r_k are appended *after* φ and π ran (as the
  wrapper does; appending s_k first flies identically). ẑ_k = φ(history) is recomputed at
  every policy step.
* **history at reset**: zeros in physical units, as the wrapper (filling it with hover
  values instead made no measurable difference: the 100-step window is flushed in 0.2 s).
* **action**: raw r ∈ [−1, 1] (network order 0 front-right, 1 back-left, 2 back-right,
  3 front-left); normalised rotor speed Ω_cmd/Ω_max = 0.5 r + 0.5, reordered to mjxsysid
  order (front-right, front-left, back-left, back-right) = nn[[0, 3, 1, 2]]. The yaw signs
  agree (FR −, FL +, BL −, BR + in both). Of the 24 possible orders only this one flies (the
  other 23 crash every vehicle within 2 s). Ω_max is not needed: the harness takes
  normalised commands.
* **rate**: a static ``decimation`` (simulator steps per policy step); default 500 Hz
  (decimation 1 under the default 500 Hz simulator). The motor command is held between
  policy steps (zero-order hold); the high-level controller keeps running at the simulator
  rate. 500 Hz and 100 Hz fly in-distribution vehicles equally well (lemniscate RMSE 5.0 vs
  5.3 cm on 64 vehicles); 500 Hz is clearly better on the paper vehicle (9.2 vs 15.0 cm).
* **accelerometer filter**: 2nd-order Butterworth low-pass on the z specific force, 30 Hz
  cut-off, designed (bilinear transform with pre-warping, as ``scipy.signal.butter``) for the
  *policy* rate actually used, run once per policy step on the sampled reading, started at
  steady state on the first reading. ``accel_filter="wrapper"`` reproduces the published
  wrapper's filter instead, which feeds past *inputs* where a Butterworth feeds past
  outputs — in effect the 3-tap FIR y = b0 x_k + (b1 − a1) x_{k−1} + (b2 − a2) x_{k−2}
  designed for 100 Hz, started from zeros. ``accel_filter=False`` passes the raw reading.
  The choice makes no measurable difference (≤ 1 mm RMSE), even with 1 m/s² accelerometer
  noise: the policy leans little on this input.
* **high-level gains**: the ``baseline`` Cascade preset works. ``naive`` (no integral) leaves
  the policy's collective-thrust bias (it delivers a few to ~15 % more or less than a_cmd)
  uncorrected: 0.5–1 m errors. Attitude gains katt_xy above ~10/s (the wrapper's 1/0.05 s
  = 20/s) destabilise vehicles with motor time constants ≥ 0.02 s (16 in-distribution
  vehicles, lemniscate: katt_xy 8.4 → 0 failures, 12 → 1, 16 → 4, 20 → 8).

:func:`mjxsysid.theta.xadap_training_prior` (``get_prior("xadap")``) is a prior whose samples match the
released policy's training statistics (mean.csv/var.csv; README) — an in-distribution test set.
"""
from __future__ import annotations

import math
from pathlib import Path
from typing import NamedTuple

import jax
import jax.numpy as jnp
import numpy as np
from flax import struct

from mjxsysid.control.low_level import Command
from mjxsysid.policy.xadap.network import (
    ACTION_DIM,
    HISTORY_LEN,
    LATENT_DIM,
    PRECISIONS,
    STATE_DIM,
    XAdapWeights,
    build_history_input,
    load_npz,
    normalize_state,
    xadap_encoder,
    xadap_policy,
)
from mjxsysid.policy.xadap.onnx_import import load_xadap

__all__ = [
    "XAdapController",
    "XAdapCarry",
    "make_xadap_low_level",
    "butterworth2",
    "NN_TO_MJX",
    "ACCEL_FILTERS",
]

NN_TO_MJX = np.array([0, 3, 1, 2])
"""mjxsysid rotor i (FR, FL, BL, BR) is network motor NN_TO_MJX[i] (0 FR, 1 BL, 2 BR, 3 FL)."""

ACCEL_FILTERS = ("butter", "wrapper", "none")
DEFAULT_SIM_DT = 0.002  # mjxsysid.sim.SimConfig().dt: 500 Hz


def butterworth2(cutoff_hz: float, sample_hz: float) -> tuple[np.ndarray, np.ndarray]:
    """2nd-order low-pass Butterworth, bilinear transform with pre-warping (as
    ``scipy.signal.butter(2, cutoff_hz / (sample_hz / 2))``). Returns (b (3,), a (3,)), a[0] = 1."""
    if not 0.0 < cutoff_hz < 0.5 * sample_hz:
        raise ValueError(f"Butterworth cut-off {cutoff_hz} Hz must lie in (0, {0.5 * sample_hz}) "
                         f"Hz for a {sample_hz} Hz sample rate")
    k = math.tan(math.pi * cutoff_hz / sample_hz)
    q = math.sqrt(2.0)
    norm = 1.0 / (1.0 + q * k + k * k)
    b0 = k * k * norm
    b = np.array([b0, 2.0 * b0, b0])
    a = np.array([1.0, 2.0 * (k * k - 1.0) * norm, (1.0 - q * k + k * k) * norm])
    return b, a


class XAdapCarry(NamedTuple):
    """Per-episode memory of :class:`XAdapController` (add a leading batch axis under vmap).

    s_hist (100, 8), r_hist (100, 4): physical-unit state / raw-action histories, oldest first
    (the last 100 policy steps *before* the current one). r_last (4,): previous raw action.
    filt (2,): accelerometer filter state (Butterworth: transposed direct-form-II registers;
    wrapper: the two previous raw readings). count (): simulator steps taken (int32; the
    policy runs when count % decimation == 0). z (8,): current latent ẑ. motor (4,): held
    normalised motor command, mjxsysid order. fz (): last (filtered) specific force fed to π.
    """
    s_hist: jax.Array
    r_hist: jax.Array
    r_last: jax.Array
    filt: jax.Array
    count: jax.Array
    z: jax.Array
    motor: jax.Array
    fz: jax.Array


def _as_f32_weights(w: XAdapWeights) -> XAdapWeights:
    return jax.tree.map(lambda a: jnp.asarray(np.asarray(a, np.float32)), w)


@struct.dataclass
class XAdapController:
    """The released Xadap policy as a low-level controller (a pytree: ``weights`` are leaves).

    decimation: simulator steps per policy step (1: policy at the simulator rate, 500 Hz with
    the default simulator; 5: 100 Hz). sim_dt: simulator control period (s) the controller is
    built for (sets rate_hz = 1 / (sim_dt decimation), for which the filter is designed).
    accel_filter: "butter" | "wrapper" | "none". accel_cutoff_hz: Butterworth cut-off (Hz).
    All four are static (changing them re-traces).
    """
    weights: XAdapWeights
    decimation: int = struct.field(pytree_node=False, default=1)
    sim_dt: float = struct.field(pytree_node=False, default=DEFAULT_SIM_DT)
    accel_filter: str = struct.field(pytree_node=False, default="butter")
    accel_cutoff_hz: float = struct.field(pytree_node=False, default=30.0)
    precision: str = struct.field(pytree_node=False, default="highest")

    # ------------------------------------------------------------------ construction
    @classmethod
    def load(cls, weights, *, rate_hz: float = 500.0, sim_dt: float = DEFAULT_SIM_DT,
             accel_filter: bool | str = True,
             accel_cutoff_hz: float = 30.0, precision: str = "highest") -> "XAdapController":
        """Build from a directory of the released files (``encoder.onnx`` ...; needs ``onnx``),
        an ``.npz`` from :func:`~mjxsysid.policy.xadap.network.save_npz`, or :class:`XAdapWeights`.

        rate_hz: policy rate; must divide the simulator rate 1/sim_dt. accel_filter: True /
        "butter" (Butterworth designed for rate_hz), "wrapper" (the published wrapper's
        filter), False / "none".
        """
        if isinstance(weights, XAdapWeights):
            w = weights
        else:
            p = Path(weights).expanduser()
            w = load_npz(p) if (p.suffix == ".npz" or p.is_file()) else load_xadap(p)
        if not sim_dt > 0 or not rate_hz > 0:
            raise ValueError(f"rate_hz and sim_dt must be > 0, got {rate_hz}, {sim_dt}")
        ratio = 1.0 / (rate_hz * sim_dt)
        dec = int(round(ratio))
        if dec < 1 or abs(ratio - dec) > 1e-6 * max(1.0, ratio):
            raise ValueError(f"policy rate {rate_hz} Hz must divide the simulator rate "
                             f"{1.0 / sim_dt:g} Hz (sim_dt {sim_dt} s)")
        filt = {True: "butter", False: "none", None: "none"}.get(accel_filter, accel_filter)
        if filt not in ACCEL_FILTERS:
            raise ValueError(f"accel_filter must be True, False or one of {ACCEL_FILTERS}, "
                             f"got {accel_filter!r}")
        if filt == "butter":
            butterworth2(accel_cutoff_hz, rate_hz)  # validates the cut-off
        if precision not in PRECISIONS:
            raise ValueError(f"precision must be one of {PRECISIONS}, got {precision!r}")
        return cls(_as_f32_weights(w), decimation=dec, sim_dt=float(sim_dt), accel_filter=filt,
                   accel_cutoff_hz=float(accel_cutoff_hz), precision=precision)

    @property
    def rate_hz(self) -> float:
        return 1.0 / (self.sim_dt * self.decimation)

    # ------------------------------------------------------------------ interface
    def init(self, key=None) -> XAdapCarry:
        """Empty memory: zero histories (physical units), zero last action, ẑ = 0."""
        f = jnp.float32
        return XAdapCarry(
            s_hist=jnp.zeros((HISTORY_LEN, STATE_DIM), f),
            r_hist=jnp.zeros((HISTORY_LEN, ACTION_DIM), f),
            r_last=jnp.zeros(ACTION_DIM, f),
            filt=jnp.zeros(2, f),
            count=jnp.array(0, jnp.int32),
            z=jnp.zeros(LATENT_DIM, f),
            motor=jnp.zeros(4, f),
            fz=jnp.array(0.0, f),
        )

    def step(self, carry: XAdapCarry, imu, command: Command) -> tuple[XAdapCarry, jax.Array]:
        """imu (6,) [gyro, specific force], command -> (carry, motor_cmd (4,) in [0, 1])."""
        new = self._advance(carry, imu, command)
        return new, new.motor

    def _advance(self, carry: XAdapCarry, imu, command: Command, motor=None) -> XAdapCarry:
        """One simulator step: the policy runs every ``decimation`` steps (else the carry is
        held); ``motor``: a recorded command standing in for π's action (replay)."""
        imu = jnp.asarray(imu, jnp.float32)
        if self.decimation == 1:
            new = self._policy_step(carry, imu, command, motor)
        else:
            new = jax.lax.cond(carry.count % self.decimation == 0,
                               lambda c: self._policy_step(c, imu, command, motor), lambda c: c, carry)
        return new._replace(count=carry.count + 1)

    def latent(self, carry: XAdapCarry) -> jax.Array:
        """The current latent ẑ (8,) (φ of the history at the latest policy step)."""
        return carry.z

    def batched(self, n: int) -> "XAdapController":
        """n vehicles sharing these weights (nothing is per vehicle: see :meth:`batch_axes`)."""
        return self

    def batch_axes(self):
        """vmap axes for ``fly_batch``: every leaf (the weights) shared by the batch."""
        return jax.tree.map(lambda _: None, self)

    def replay(self, imu, a_cmd, omega_cmd, motor):
        """ẑ after every step of a recorded flight (T, 8): the history rebuilt from the logged
        IMU (T, 6), a_cmd (T,), omega_cmd (T, 3) and motor commands (T, 4) in [0, 1],
        mjxsysid order (they stand in for the policy's actions; mapped back to network order)."""
        xs = tuple(jnp.asarray(a, jnp.float32) for a in (imu, a_cmd, omega_cmd, motor))
        return np.asarray(_xadap_replay(self, xs))

    # ------------------------------------------------------------------ internals
    def _filter(self, carry: XAdapCarry, x):
        """Filtered z specific force and new filter state; starts at steady state (Butterworth)."""
        first = carry.count == 0
        if self.accel_filter == "none":
            return x, carry.filt
        if self.accel_filter == "butter":
            b, a = butterworth2(self.accel_cutoff_hz, self.rate_hz)
            b = b.astype(np.float32)
            a = a.astype(np.float32)
            z2_ss = (b[2] - a[2]) * x
            z1_ss = (b[1] - a[1]) * x + z2_ss
            z1 = jnp.where(first, z1_ss, carry.filt[0])
            z2 = jnp.where(first, z2_ss, carry.filt[1])
            y = b[0] * x + z1
            return y, jnp.stack([b[1] * x - a[1] * y + z2, b[2] * x - a[2] * y])
        # "wrapper": scipy butter(2, 30/50) coefficients, but the recursion reads past inputs
        # (its buffer is initialised to zeros): a 3-tap FIR with unit DC gain.
        b, a = butterworth2(30.0, 100.0)
        x1, x2 = carry.filt[0], carry.filt[1]
        y = b[0] * x + (b[1] - a[1]) * x1 + (b[2] - a[2]) * x2
        return y.astype(jnp.float32), jnp.stack([x, x1])

    def _policy_step(self, carry: XAdapCarry, imu, command: Command, motor=None) -> XAdapCarry:
        """One policy step; ``motor`` (4,) in [0, 1], mjxsysid order: a recorded command that
        replaces π's action in the history (replay)."""
        w = self.weights
        fz, filt = self._filter(carry, imu[5])
        a_cmd = jnp.reshape(jnp.asarray(command.a_cmd, jnp.float32), (1,))
        s = jnp.concatenate([imu[0:3], fz[None], jnp.asarray(command.omega_cmd, jnp.float32),
                             a_cmd])
        s_hist, r_hist = carry.s_hist, carry.r_hist
        z = xadap_encoder(w, build_history_input(w, s_hist, r_hist), self.precision)
        obs = normalize_state(w, jnp.concatenate([s, carry.r_last]))
        if motor is None:
            r = xadap_policy(w, jnp.concatenate([obs, z]), self.precision)
            motor = jnp.clip(0.5 * r + 0.5, 0.0, 1.0)[NN_TO_MJX]
        else:
            r = jnp.zeros(ACTION_DIM, jnp.float32).at[NN_TO_MJX].set(2.0 * motor - 1.0)
        return XAdapCarry(
            s_hist=jnp.concatenate([s_hist[1:], s[None]], 0),
            r_hist=jnp.concatenate([r_hist[1:], r[None]], 0),
            r_last=r, filt=filt, count=carry.count, z=z, motor=motor, fz=fz)


@jax.jit
def _xadap_replay(ctrl: XAdapController, xs):
    def body(carry, x):
        imu, a, w, u = x
        new = ctrl._advance(carry, imu, Command(a, w), u)
        return new, new.z

    return jax.lax.scan(body, ctrl.init(), xs)[1]


def make_xadap_low_level(weights_dir, batch_size: int, **kw) -> XAdapController:
    """:meth:`XAdapController.load` ``(weights_dir, **kw)`` for a batch of ``batch_size``
    vehicles sharing the weights, ready for ``fly_batch``.

    ``weights_dir``: directory of the released files, a converted ``.npz`` or
    :class:`XAdapWeights`. ``kw``: ``rate_hz`` (default 500), ``sim_dt`` (pass
    ``sim.config.dt`` for a non-default simulator), ``accel_filter``, ``accel_cutoff_hz``.
    Use with the ``baseline`` Cascade gains (see the module notes)."""
    return XAdapController.load(weights_dir, **kw).batched(int(batch_size))
