"""References made of references: :class:`Switch` (one of two, chosen per instance, for mixed
batches of types) and :class:`Delayed` (a hover lead-in before a reference)."""
from __future__ import annotations

import jax
import jax.numpy as jnp
from flax import struct

from mjxsysid.control.references.base import _DTYPE, RefPoint, _f32, _scalar


@struct.dataclass
class Switch:
    """One of two references of different types, chosen per instance by a flag, so that one
    batch can mix reference types (e.g. lemniscates and minimum-snap trajectories).

    ``at(t)`` evaluates both and returns ``second``'s point where ``use_second`` else
    ``first``'s (both are evaluated: cost of the two). Batch it like any reference: every
    leaf, ``use_second`` included, gains the leading (B,) axis (e.g. ``stack`` the two
    reference batches separately and pass ``use_second`` (B,)).

    Attributes:
      first, second: reference pytrees with ``at(t)``.
      use_second:    () bool.
    """

    first: object
    second: object
    use_second: jax.Array = False

    @property
    def duration(self):
        d1 = jnp.asarray(self.first.duration, _DTYPE)
        d2 = jnp.asarray(self.second.duration, _DTYPE)
        return jnp.where(self.use_second, d2, d1)

    def at(self, t) -> RefPoint:
        a, b = self.first.at(t), self.second.at(t)
        use = jnp.asarray(self.use_second, bool)
        return jax.tree.map(lambda x, y: jnp.where(use, y, x), a, b)


@struct.dataclass
class Delayed:
    """Hold ``inner``'s start point (zero velocity and higher derivatives, its initial yaw)
    for ``delay`` s, then fly ``inner`` shifted by ``delay``: a hover lead-in, as a real flight
    hovers after take-off before its trajectory starts.

    Attributes:
      inner: a reference pytree with ``at(t)`` and ``duration``.
      delay: () s, >= 0.
    """

    inner: object
    delay: jax.Array = 0.0

    @classmethod
    def make(cls, inner, delay: float) -> "Delayed":
        return cls(inner=inner, delay=_f32(_scalar(delay, "delay", nonneg=True)))

    @property
    def duration(self):
        return jnp.asarray(self.inner.duration, _DTYPE) + jnp.asarray(self.delay, _DTYPE)

    def at(self, t) -> RefPoint:
        t = jnp.asarray(t, _DTYPE)
        delay = jnp.asarray(self.delay, _DTYPE)
        p = self.inner.at(jnp.maximum(t - delay, 0.0))
        moving = t >= delay
        return p._replace(
            vel=jnp.where(moving, p.vel, 0.0), acc=jnp.where(moving, p.acc, 0.0),
            jerk=jnp.where(moving, p.jerk, 0.0), snap=jnp.where(moving, p.snap, 0.0),
            yaw_rate=jnp.where(moving, p.yaw_rate, 0.0))
