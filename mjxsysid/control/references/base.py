"""The reference interface: the point a reference gives at a time (:class:`RefPoint`), the
host-side validation its constructors share, and evaluating, sampling and stacking references."""

from __future__ import annotations

from typing import NamedTuple, Sequence

import jax
import jax.numpy as jnp
import numpy as np

_DTYPE = jnp.float32
_INF = float("inf")


class RefPoint(NamedTuple):
    """Reference flat output and its time derivatives at one time.

    Shapes are for a single evaluation; under ``vmap`` every leaf gains the leading batch
    dimensions (e.g. :func:`sample` returns ``pos`` of shape ``(T, 3)`` and ``yaw`` of
    shape ``(T,)``).

    Attributes:
      pos:      (3,) position [m].
      vel:      (3,) velocity [m/s].
      acc:      (3,) acceleration [m/s^2].
      jerk:     (3,) jerk [m/s^3].
      snap:     (3,) snap [m/s^4].
      yaw:      ()   yaw [rad].
      yaw_rate: ()   yaw rate [rad/s].
    """

    pos: jax.Array
    vel: jax.Array
    acc: jax.Array
    jerk: jax.Array
    snap: jax.Array
    yaw: jax.Array
    yaw_rate: jax.Array


# --------------------------------------------------------------------------------------
# host-side validation helpers
# --------------------------------------------------------------------------------------


def _np_array(x, name: str, shape: tuple | None = None, ndim: int | None = None) -> np.ndarray:
    """float64 NumPy copy of ``x``; checks shape (``None`` entries = any) and finiteness."""
    try:
        a = np.asarray(x, dtype=np.float64)
    except (TypeError, ValueError) as e:
        raise ValueError(f"{name} must be numeric, got {x!r}") from e
    if ndim is not None and a.ndim != ndim:
        raise ValueError(f"{name} must have {ndim} dimension(s), got shape {a.shape}")
    if shape is not None:
        if a.ndim != len(shape) or any(s is not None and s != d for s, d in zip(shape, a.shape)):
            want = "(" + ", ".join("*" if s is None else str(s) for s in shape) + ")"
            raise ValueError(f"{name} must have shape {want}, got {a.shape}")
    if not np.all(np.isfinite(a)):
        raise ValueError(f"{name} must be finite, got {a!r}")
    return a


def _scalar(x, name: str, *, positive: bool = False, nonneg: bool = False) -> float:
    a = _np_array(x, name, shape=())
    v = float(a)
    if positive and not v > 0.0:
        raise ValueError(f"{name} must be > 0, got {v}")
    if nonneg and not v >= 0.0:
        raise ValueError(f"{name} must be >= 0, got {v}")
    return v


def _f32(x) -> jax.Array:
    return jnp.asarray(x, dtype=_DTYPE)


def _zeros3(t: jax.Array) -> jax.Array:
    del t
    return jnp.zeros((3,), dtype=_DTYPE)


# --------------------------------------------------------------------------------------
# module-level helpers
# --------------------------------------------------------------------------------------


def evaluate(ref, t) -> RefPoint:
    """``ref.at(t)`` for a scalar time ``t`` (jit/vmap-safe)."""
    return ref.at(t)


def sample(ref, times) -> RefPoint:
    """Evaluate ``ref`` at every time of the (T,) vector ``times``.

    Returns a RefPoint whose leaves have a leading (T,) axis: pos (T, 3), yaw (T,), ...
    """
    times = jnp.asarray(times, _DTYPE)
    if times.ndim != 1:
        raise ValueError(f"times must be a 1-D (T,) vector, got shape {times.shape}")
    return jax.vmap(ref.at)(times)


def stack(refs: Sequence):
    """Stack references of the same type and leaf shapes into one batched pytree.

    Host-side helper: ``jax.tree.map(lambda *x: jnp.stack(x), *refs)`` after checking that
    all references have the same type and leaf shapes (e.g. MinSnaps with the same number
    of segments, Steps with the same number of steps). Every leaf gains a leading (B,) axis,
    ready for ``jax.vmap(evaluate)(batch, t)``.
    """
    refs = list(refs)
    if not refs:
        raise ValueError("refs must be a non-empty sequence of references")
    typ = type(refs[0])
    for k, r in enumerate(refs):
        if type(r) is not typ:
            raise ValueError(
                f"refs must all have the same type; refs[0] is {typ.__name__}, "
                f"refs[{k}] is {type(r).__name__}"
            )
    shapes0 = jax.tree.map(jnp.shape, refs[0])
    for k, r in enumerate(refs[1:], start=1):
        shapes = jax.tree.map(jnp.shape, r)
        if shapes != shapes0:
            raise ValueError(
                f"refs must have identical leaf shapes to be stacked; refs[0] has {shapes0}, "
                f"refs[{k}] has {shapes}"
            )
    return jax.tree.map(lambda *x: jnp.stack([jnp.asarray(v, _DTYPE) for v in x]), *refs)
