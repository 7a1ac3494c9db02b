"""Closed-form references: :class:`Hover`, :class:`Steps` and the 3-D figure-eight
:class:`Lemniscate` with analytic derivatives up to snap."""
from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np
from flax import struct

from mjxsysid.control.references.base import _DTYPE, _INF, RefPoint, _f32, _np_array, _scalar, _zeros3


@struct.dataclass
class Hover:
    """Constant position and yaw; all derivatives zero.

    Attributes:
      pos:      (3,) hover position [m].
      yaw:      ()   yaw [rad].
      duration: ()   ``inf`` (infinite reference).
    """

    pos: jax.Array
    yaw: jax.Array = 0.0
    duration: jax.Array = _INF

    @classmethod
    def make(cls, pos=(0.0, 0.0, 1.0), yaw: float = 0.0) -> "Hover":
        """Validated constructor. ``pos`` (3,), ``yaw`` scalar."""
        p = _np_array(pos, "pos", shape=(3,))
        y = _scalar(yaw, "yaw")
        return cls(pos=_f32(p), yaw=_f32(y), duration=_f32(_INF))

    def at(self, t) -> RefPoint:
        """Evaluate at scalar time ``t`` [s]."""
        t = jnp.asarray(t, _DTYPE)
        z = _zeros3(t)
        pos = jnp.asarray(self.pos, _DTYPE) + z
        yaw = jnp.asarray(self.yaw, _DTYPE) + jnp.zeros_like(t)
        return RefPoint(pos, z, z, z, z, yaw, jnp.zeros_like(t))


@struct.dataclass
class Steps:
    """Piecewise-constant position steps; all derivatives zero.

    ``pos(t) = positions[k]`` for ``times[k] <= t < times[k+1]``; before ``times[0]``
    the reference holds ``positions[0]``, after ``times[-1]`` it holds ``positions[-1]``.

    Attributes:
      times:     (K,)   non-decreasing switch times [s].
      positions: (K, 3) positions [m].
      yaw:       ()     constant yaw [rad].
      duration:  ()     ``times[-1]`` (time of the last switch; held afterwards).
    """

    times: jax.Array
    positions: jax.Array
    yaw: jax.Array = 0.0
    duration: jax.Array = 0.0

    @classmethod
    def make(cls, times, positions, yaw: float = 0.0) -> "Steps":
        """Validated constructor. ``times`` (K,) non-decreasing, ``positions`` (K, 3)."""
        ts = _np_array(times, "times", ndim=1)
        if ts.shape[0] < 1:
            raise ValueError("times must contain at least one time")
        ps = _np_array(positions, "positions", shape=(ts.shape[0], 3))
        if np.any(np.diff(ts) < 0):
            raise ValueError(f"times must be non-decreasing, got {ts}")
        y = _scalar(yaw, "yaw")
        return cls(times=_f32(ts), positions=_f32(ps), yaw=_f32(y), duration=_f32(ts[-1]))

    @classmethod
    def single(cls, start, end, t_step: float, yaw: float = 0.0) -> "Steps":
        """One step from ``start`` (3,) to ``end`` (3,) at time ``t_step`` >= 0."""
        s = _np_array(start, "start", shape=(3,))
        e = _np_array(end, "end", shape=(3,))
        ts = _scalar(t_step, "t_step", nonneg=True)
        return cls.make(times=[0.0, ts], positions=np.stack([s, e]), yaw=yaw)

    def at(self, t) -> RefPoint:
        """Evaluate at scalar time ``t`` [s]."""
        t = jnp.asarray(t, _DTYPE)
        times = jnp.asarray(self.times, _DTYPE)
        positions = jnp.asarray(self.positions, _DTYPE)
        k = jnp.searchsorted(times, t, side="right", method="compare_all") - 1
        k = jnp.clip(k, 0, times.shape[0] - 1)
        z = _zeros3(t)
        yaw = jnp.asarray(self.yaw, _DTYPE) + jnp.zeros_like(t)
        return RefPoint(positions[k], z, z, z, z, yaw, jnp.zeros_like(t))


# Per-axis harmonic k_i and amplitude factor g_i of the figure eight:
#   p_i(t) = center_i + g_i * size_i * sin(k_i * w * t)
_LEM_HARMONIC = (1.0, 2.0, 3.0)


_LEM_GAIN = (1.0, 0.5, 1.0)


@struct.dataclass
class Lemniscate:
    """Periodic 3-D figure eight (lemniscate of Gerono with a vertical weave).

    With ``w = 2π / period`` and ``φ = w t``::

        x(t) = cx + ax      sin(φ)
        y(t) = cy + ay / 2  sin(2φ)
        z(t) = cz + az      sin(3φ)
        yaw(t) = yaw + yaw_amplitude sin(φ)

    i.e. every axis is ``c_i + A_i sin(k_i φ)`` with ``k = (1, 2, 3)``,
    ``A = (ax, ay/2, az)``, whose n-th derivative is exactly
    ``A_i (k_i w)^n sin(k_i φ + n π/2)``. (x, y) is the lemniscate of Gerono (x in
    [-ax, ax], y in [-ay/2, ay/2]); the third harmonic in z (in [-az, az]) makes the curve
    non-planar and decorrelated from x and y, so all three axes are excited. It starts
    at ``center`` at t = 0 (with non-zero velocity; no smooth start). Note the z
    derivatives scale with ``3^n``: for the default size (0.3 m) and period (10 s) peak
    |z acc| = 1.07 m/s^2 vs |x acc| = 0.39 m/s^2.

    Time is wrapped with ``mod(t, period)`` before forming the phase, so float32
    precision does not degrade for large ``t``.

    Attributes:
      center:        (3,) centre [m].
      size:          (3,) ``(ax, ay, az)`` [m] as in the formula above.
      period:        ()   period T [s] (> 0).
      yaw:           ()   constant yaw offset [rad].
      yaw_amplitude: ()   amplitude of the yaw oscillation [rad] (0 = constant yaw).
      duration:      ()   ``inf`` (periodic, infinite).
    """

    center: jax.Array
    size: jax.Array
    period: jax.Array
    yaw: jax.Array = 0.0
    yaw_amplitude: jax.Array = 0.0
    duration: jax.Array = _INF

    @classmethod
    def make(
        cls,
        period: float = 10.0,
        size=(1.0, 1.0, 0.3),
        center=(0.0, 0.0, 1.0),
        yaw_amplitude: float = 0.0,
        yaw: float = 0.0,
    ) -> "Lemniscate":
        """Validated constructor.

        Args:
          period: period [s], finite and > 0.
          size: (3,) ``(ax, ay, az)`` [m], finite and >= 0.
          center: (3,) centre [m], finite.
          yaw_amplitude: yaw oscillation amplitude [rad], finite.
          yaw: constant yaw offset [rad], finite.
        Raises:
          ValueError naming the offending argument.
        """
        T = _scalar(period, "period", positive=True)
        s = _np_array(size, "size", shape=(3,))
        if np.any(s < 0):
            raise ValueError(f"size must be >= 0 on every axis, got {s}")
        c = _np_array(center, "center", shape=(3,))
        ya = _scalar(yaw_amplitude, "yaw_amplitude")
        y0 = _scalar(yaw, "yaw")
        return cls(
            center=_f32(c),
            size=_f32(s),
            period=_f32(T),
            yaw=_f32(y0),
            yaw_amplitude=_f32(ya),
            duration=_f32(_INF),
        )

    def at(self, t) -> RefPoint:
        """Evaluate at scalar time ``t`` [s] (analytic derivatives up to snap)."""
        t = jnp.asarray(t, _DTYPE)
        period = jnp.asarray(self.period, _DTYPE)
        w = 2.0 * jnp.pi / period
        phi = w * jnp.mod(t, period)  # d(mod)/dt = 1 almost everywhere
        k = jnp.asarray(_LEM_HARMONIC, _DTYPE)
        amp = jnp.asarray(_LEM_GAIN, _DTYPE) * jnp.asarray(self.size, _DTYPE)
        kw = k * w
        s, c = jnp.sin(k * phi), jnp.cos(k * phi)
        # d^n/dt^n sin(k φ) = (k w)^n sin(k φ + n π/2): the sequence s, c, -s, -c, s.
        pos = jnp.asarray(self.center, _DTYPE) + amp * s
        vel = amp * kw * c
        acc = -amp * kw**2 * s
        jerk = -amp * kw**3 * c
        snap = amp * kw**4 * s
        ya = jnp.asarray(self.yaw_amplitude, _DTYPE)
        yaw = jnp.asarray(self.yaw, _DTYPE) + ya * jnp.sin(phi)
        yaw_rate = ya * w * jnp.cos(phi)
        return RefPoint(pos, vel, acc, jerk, snap, yaw, yaw_rate)
