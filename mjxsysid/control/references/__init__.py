"""Reference trajectories for quadrotor tracking, as pure functions of time.

Every reference is a :func:`flax.struct.dataclass` pytree whose numeric parameters are
array leaves, with a method ``at(t) -> RefPoint`` that is pure ``jax.numpy`` (no Python
branching on traced values), so it can be evaluated inside ``jax.jit``, differentiated, and
``vmap``-ped over time and/or over a stacked batch of references of the same type and
the same leaf shapes (see :func:`stack`).

Conventions: world frame ENU-like (z up), metres, seconds, yaw in radians. All arrays
evaluated inside JAX are float32 (jax x64 disabled); the minimum-snap QP is solved on the
host in float64 NumPy and only its coefficients are cast to float32.

Types
-----
:class:`Hover`       constant position and yaw.
:class:`Steps`       piecewise-constant position steps (derivatives zero).
:class:`Lemniscate`  periodic 3-D figure eight with analytic derivatives up to snap.
:class:`MinSnap`     piecewise 7th-order minimum-snap polynomials (Mellinger & Kumar 2011)
                     through waypoints, static at both ends.
:class:`Switch`      one of two references, chosen per instance (mixed batches of types).
:class:`Delayed`     a hover lead-in, then another reference.

Modules: :mod:`.base` (RefPoint, evaluate / sample / stack), :mod:`.analytic` (Hover, Steps,
Lemniscate), :mod:`.minsnap` (the QP and MinSnap), :mod:`.compose` (Switch, Delayed).

Example::

    ref = MinSnap.random(seed=0)
    pts = sample(ref, jnp.linspace(0.0, ref.duration, 200))   # RefPoint, leaves (200, ...)
    batch = stack([MinSnap.random(s) for s in range(8)])      # leaves (8, ...)
    p = jax.jit(jax.vmap(evaluate))(batch, jnp.full(8, 1.3))  # RefPoint, leaves (8, ...)
"""
from mjxsysid.control.references.analytic import Hover, Lemniscate, Steps
from mjxsysid.control.references.base import RefPoint, evaluate, sample, stack
from mjxsysid.control.references.compose import Delayed, Switch
from mjxsysid.control.references.minsnap import MinSnap, integrated_squared_derivative, min_snap_coefficients

__all__ = ["RefPoint", "Hover", "Steps", "Lemniscate", "MinSnap", "Switch", "Delayed", "evaluate", "sample",
           "stack", "min_snap_coefficients", "integrated_squared_derivative"]
