"""Minimum-snap references (Mellinger & Kumar 2011): the host-side QP in float64 NumPy
(:func:`min_snap_coefficients`) and :class:`MinSnap`, piecewise 7th-order polynomials
evaluated in float32 JAX."""
from __future__ import annotations

import math

import jax
import jax.numpy as jnp
import numpy as np
import scipy.linalg
from flax import struct

from mjxsysid.control.references.base import _DTYPE, RefPoint, _f32, _np_array, _scalar

_ORDER = 7  # polynomial degree


_NC = _ORDER + 1  # coefficients per segment and axis


def _falling(j: int, n: int) -> float:
    """j! / (j-n)! (0 if n > j)."""
    if n > j:
        return 0.0
    return float(math.prod(range(j - n + 1, j + 1)))


# _FALL[n, j] = j!/(j-n)!: coefficient j of the n-th derivative of tau^j (times tau^(j-n)).
_FALL = np.array([[_falling(j, n) for j in range(_NC)] for n in range(_NC)])


def _deriv_row(n: int, tau: float) -> np.ndarray:
    """(8,) row r with r @ c = d^n/dtau^n sum_j c_j tau^j at tau."""
    r = np.zeros(_NC)
    for j in range(n, _NC):
        r[j] = _FALL[n, j] * tau ** (j - n)
    return r


def _cost_hessian(order: int) -> np.ndarray:
    """(8, 8) H with c^T H c = int_0^1 (d^order/dtau^order p(tau))^2 dtau."""
    H = np.zeros((_NC, _NC))
    for i in range(order, _NC):
        for j in range(order, _NC):
            H[i, j] = _FALL[order, i] * _FALL[order, j] / (i + j - 2 * order + 1)
    return H


def _check_waypoints_durations(waypoints, durations) -> tuple[np.ndarray, np.ndarray]:
    wp = _np_array(waypoints, "waypoints", ndim=2)
    if wp.shape[1] != 3 or wp.shape[0] < 2:
        raise ValueError(f"waypoints must have shape (N+1, 3) with N >= 1, got {wp.shape}")
    n = wp.shape[0] - 1
    d = _np_array(durations, "durations", ndim=1)
    if d.shape != (n,):
        raise ValueError(
            f"durations must have shape (N,) = ({n},) for {n + 1} waypoints, got {d.shape}"
        )
    if np.any(d <= 0):
        raise ValueError(f"durations must all be > 0, got {d}")
    return wp, d


def min_snap_coefficients(
    waypoints,
    durations,
    *,
    method: str = "hermite",
    continuity_order: int = 4,
    cost_order: int = 4,
) -> np.ndarray:
    """Host-side float64 solve of the minimum-snap QP (Mellinger & Kumar 2011).

    Segment ``i`` on axis ``a`` is ``p(tau) = sum_j C[i, j, a] tau^j`` with normalised time
    ``tau = (t - t_i) / T_i`` in [0, 1]; the physical n-th derivative is
    ``p^(n)(tau) / T_i^n``. The QP (the three axes are independent) is::

        minimise   sum_i  int_0^{T_i} |d^cost_order p_i / dt^cost_order|^2 dt
                 = sum_i  T_i^(1 - 2 cost_order) c_i^T H c_i
        subject to p_i(0) = waypoints[i],  p_i(1) = waypoints[i+1]     (all segments)
                   vel = acc = jerk = 0 at the first and last waypoint   (static ends)
                   derivatives 1..continuity_order continuous at the N-1 interior knots.

    Two closed-form solvers of the same problem (they agree to ~1e-10; tested):

    ``method="kkt"``: the KKT linear system ``[[2Q, A^T], [A, 0]] [c; λ] = [0; b]`` in
    the 8N monomial coefficients, with the constraints above (``continuity_order`` 3..6),
    solved by null-space elimination (QR of the row-equilibrated A^T, then a
    Jacobi-scaled Cholesky of the reduced Hessian). Its constraint residual reaches
    ~1e-7 when segment durations differ by more than ~10x (then it is still far below
    float32 resolution, but it raises if the residual exceeds 1e-8 * max|waypoint|).

    ``method="hermite"`` (default; Richter, Bry & Roy 2013): the unknowns are the
    velocity, acceleration and jerk at the N-1 interior knots; each segment is the
    7th-order Hermite interpolant of (pos, vel, acc, jerk) at its two ends, so C^3
    continuity, waypoints and static ends hold by construction, and the cost is an
    unconstrained, block-tridiagonal positive-definite quadratic in 3(N-1) unknowns
    per axis, solved by Jacobi-scaled Cholesky. Much better conditioned.

    Both give the same trajectory: the minimum-snap optimum over C^3 (or C^4, as in
    Mellinger & Kumar) piecewise 7th-order polynomials is automatically C^6 at interior
    knots (its natural optimality condition; checked in the tests), so it also equals the
    solution of the square system obtained with ``method="kkt", continuity_order=6``
    (then nothing is left to optimise). ``cost_order=3`` gives the minimum-jerk
    7th-order alternative (used in the tests as a feasible, non-optimal comparison);
    for ``cost_order != 4`` the natural-continuity argument does not hold, so "hermite"
    (C^3) and "kkt" (C^continuity_order) then solve different problems.

    Costs and derivatives are expressed in units of the mean segment duration for
    conditioning.

    Args:
      waypoints: (N+1, 3) waypoint positions [m], N >= 1.
      durations: (N,) segment durations [s], all > 0.
      method: "hermite" (default) or "kkt".
      continuity_order: (kkt only) highest derivative made continuous at interior knots
        (3..6; "hermite" is C^3 by construction).
      cost_order: derivative whose integrated square is minimised (1..4; 4 = snap).
    Returns:
      (N, 8, 3) float64 coefficients in normalised time (ascending powers of tau).
    Raises:
      ValueError for bad shapes/values; numpy.linalg.LinAlgError if the solve is
      numerically unreliable.
    """
    wp, dur = _check_waypoints_durations(waypoints, durations)
    if isinstance(continuity_order, bool) or continuity_order not in (3, 4, 5, 6):
        raise ValueError(f"continuity_order must be in 3..6, got {continuity_order!r}")
    if isinstance(cost_order, bool) or cost_order not in (1, 2, 3, 4):
        raise ValueError(f"cost_order must be in 1..4, got {cost_order!r}")
    if method == "hermite":
        return _min_snap_hermite(wp, dur, int(cost_order))
    if method == "kkt":
        return _min_snap_kkt(wp, dur, int(continuity_order), int(cost_order))
    raise ValueError(f"method must be 'hermite' or 'kkt', got {method!r}")


def _jacobi_cholesky_solve(Hm: np.ndarray, g: np.ndarray, dur: np.ndarray) -> np.ndarray:
    """Solve Hm x = g (Hm SPD) with symmetric Jacobi scaling."""
    dj = 1.0 / np.sqrt(np.diag(Hm))
    try:
        xs = scipy.linalg.solve(dj[:, None] * Hm * dj[None, :], dj[:, None] * g, assume_a="pos")
        return dj[:, None] * xs
    except np.linalg.LinAlgError as e:
        raise np.linalg.LinAlgError(
            "min-snap Hessian is numerically singular; segment durations differ too "
            f"much (min {dur.min():.3g} s, max {dur.max():.3g} s)"
        ) from e


# Hermite basis: rows r_0(0), r_1(0), r_2(0), r_3(0), r_0(1), r_1(1), r_2(1), r_3(1) map
# coefficients to end tau-derivatives; its inverse maps end tau-derivatives to coefficients.
_HERMITE_MINV = np.linalg.inv(np.stack([_deriv_row(d, tau) for tau in (0.0, 1.0) for d in range(4)]))


def _min_snap_hermite(wp: np.ndarray, dur: np.ndarray, cost_order: int) -> np.ndarray:
    n = wp.shape[0] - 1
    t_ref = float(np.mean(dur))
    rel = t_ref / dur  # (N,) T_ref / T_i
    G = _HERMITE_MINV.T @ _cost_hessian(cost_order) @ _HERMITE_MINV  # (8, 8)
    nx = 3 * (n - 1)  # unknowns x_k = (v T_ref, a T_ref^2, j T_ref^3) at interior knots
    # End tau-derivatives of segment i: e_i = B_i x + F_i (per axis), with
    # e = [p(0), T v(0), T^2 a(0), T^3 j(0), p(1), T v(1), T^2 a(1), T^3 j(1)].
    Bs, Fs = [], []
    for i in range(n):
        B = np.zeros((8, max(nx, 1)))
        F = np.zeros((8, 3))
        F[0], F[4] = wp[i], wp[i + 1]
        for end, k in ((0, i), (1, i + 1)):  # knot k at this end of segment i
            if 1 <= k <= n - 1:
                for d in (1, 2, 3):
                    B[4 * end + d, 3 * (k - 1) + d - 1] = rel[i] ** (-d)
        Bs.append(B)
        Fs.append(F)
    w = rel ** (2 * cost_order - 1)  # cost of segment i (units of T_ref): w_i e^T G e
    c = np.zeros((n, _NC, 3))
    if nx > 0:
        Hm = sum(w[i] * Bs[i].T @ G @ Bs[i] for i in range(n))
        g = -sum(w[i] * Bs[i].T @ G @ Fs[i] for i in range(n))
        x = _jacobi_cholesky_solve(Hm, g, dur)  # (nx, 3)
    else:
        x = np.zeros((1, 3))
    for i in range(n):
        c[i] = _HERMITE_MINV @ (Bs[i] @ x + Fs[i])
    if not np.all(np.isfinite(c)):
        raise np.linalg.LinAlgError("min-snap solve produced non-finite coefficients")
    return c


def _min_snap_kkt(wp: np.ndarray, dur: np.ndarray, continuity_order: int, cost_order: int) -> np.ndarray:
    n = wp.shape[0] - 1
    nv = _NC * n
    t_ref = float(np.mean(dur))
    rel = t_ref / dur  # (N,) T_ref / T_i

    H = _cost_hessian(cost_order)
    Q = np.zeros((nv, nv))
    for i in range(n):
        sl = slice(_NC * i, _NC * (i + 1))
        Q[sl, sl] = rel[i] ** (2 * cost_order - 1) * H

    rows, rhs = [], []

    def add(row_parts, value):
        r = np.zeros(nv)
        for i, vec in row_parts:
            r[_NC * i : _NC * (i + 1)] += vec
        rows.append(r)
        rhs.append(value)

    zero3 = np.zeros(3)
    for i in range(n):  # positions at both ends of each segment
        add([(i, _deriv_row(0, 0.0))], wp[i])
        add([(i, _deriv_row(0, 1.0))], wp[i + 1])
    for d in (1, 2, 3):  # static ends
        add([(0, _deriv_row(d, 0.0))], zero3)
        add([(n - 1, _deriv_row(d, 1.0))], zero3)
    for i in range(n - 1):  # continuity at interior knots, in units of T_ref^d
        for d in range(1, int(continuity_order) + 1):
            left = rel[i] ** d * _deriv_row(d, 1.0)
            right = -(rel[i + 1] ** d) * _deriv_row(d, 0.0)
            add([(i, left), (i + 1, right)], zero3)

    A = np.stack(rows)  # (m, nv)
    b = np.stack(rhs)  # (m, 3)
    row_scale = np.max(np.abs(A), axis=1, keepdims=True)  # row equilibration
    A, b = A / row_scale, b / row_scale
    m = A.shape[0]
    # KKT system [[2Q, A^T], [A, 0]] [c; λ] = [0; b], solved by null-space elimination
    # (better conditioned than a direct LU of the KKT matrix when durations differ a lot):
    # A^T = [Y Z] [R; 0]  =>  c = Y R^-T b + Z y,   (Z^T Q Z) y = -Z^T Q (Y R^-T b).
    Qf, Rf = np.linalg.qr(A.T, mode="complete")
    Y, Z, R1 = Qf[:, :m], Qf[:, m:], Rf[:m]
    c = Y @ scipy.linalg.solve_triangular(R1, b, trans="T")
    if m < nv:  # degrees of freedom left to the optimisation
        Hz = Z.T @ Q @ Z  # reduced Hessian, positive definite
        y = _jacobi_cholesky_solve(Hz, -Z.T @ (Q @ c), dur)
        c = c + Z @ y
    resid = np.max(np.abs(row_scale * (A @ c - b)))
    scale = max(1.0, float(np.max(np.abs(wp))))
    if not np.all(np.isfinite(c)) or resid > 1e-8 * scale:
        raise np.linalg.LinAlgError(
            f"min-snap KKT solve inaccurate (constraint residual {resid:.3g}); try method='hermite'"
        )
    return c.reshape(n, _NC, 3)


def integrated_squared_derivative(coeffs, durations, order: int = 4) -> float:
    """Host-side float64 ``sum_axes sum_i int_0^{T_i} |d^order p_i/dt^order|^2 dt``.

    Args:
      coeffs: (N, 8, 3) normalised-time coefficients (as from :func:`min_snap_coefficients`).
      durations: (N,) segment durations [s].
      order: derivative order (4 = snap).
    """
    c = np.asarray(coeffs, np.float64)
    dur = np.asarray(durations, np.float64)
    H = _cost_hessian(order)
    return float(
        sum(dur[i] ** (1 - 2 * order) * np.einsum("ja,jk,ka->", c[i], H, c[i]) for i in range(c.shape[0]))
    )


def _horner_derivs(c: jax.Array, tau: jax.Array, max_order: int = 4) -> list[jax.Array]:
    """Derivatives 0..max_order w.r.t. tau of ``sum_j c[j] tau^j`` by Horner's method.

    c: (8, 3); tau: (); returns list of (3,) arrays.
    """
    out = []
    for n in range(max_order + 1):
        d = c[n:] * jnp.asarray(_FALL[n, n:, None], c.dtype)  # (8-n, 3)
        acc = d[-1]
        for k in range(d.shape[0] - 2, -1, -1):
            acc = acc * tau + d[k]
        out.append(acc)
    return out


@struct.dataclass
class MinSnap:
    """Piecewise 7th-order minimum-snap trajectory through N+1 waypoints (N segments).

    Segment ``i`` covers ``knots[i] <= t <= knots[i+1]`` with duration
    ``T_i = durations[i]``; with ``tau = (t - knots[i]) / T_i``,
    ``pos(t) = sum_j coeffs[i, j] tau^j`` and ``d^n pos/dt^n = p^(n)(tau) / T_i^n``,
    evaluated with Horner's method in float32. The trajectory is static at both ends
    (zero vel/acc/jerk) and C^6 at interior knots. Before ``knots[0]`` it holds the first
    waypoint and after ``knots[-1]`` the last, with all derivatives zero.

    Build with :meth:`through` or :meth:`random` (coefficients are solved on the host in
    float64 by :func:`min_snap_coefficients`). Batches must share N.

    Attributes:
      coeffs:    (N, 8, 3) coefficients in normalised time, ascending powers.
      knots:     (N+1,) segment start times, plus the final time [s].
      durations: (N,) segment durations [s] (float64 differences cast to float32, more
                 accurate than differencing the float32 knots).
      yaw:       () constant yaw [rad].
      duration:  () total duration ``knots[-1] - knots[0]`` [s].
    """

    coeffs: jax.Array
    knots: jax.Array
    durations: jax.Array
    yaw: jax.Array = 0.0
    duration: jax.Array = 0.0

    @classmethod
    def through(cls, waypoints, durations, yaw: float = 0.0, t0: float = 0.0) -> "MinSnap":
        """Minimum-snap trajectory through ``waypoints`` (N+1, 3) with segment
        ``durations`` (N,) (all > 0), starting at time ``t0``, constant ``yaw``."""
        wp, dur = _check_waypoints_durations(waypoints, durations)
        y = _scalar(yaw, "yaw")
        t0 = _scalar(t0, "t0")
        c = min_snap_coefficients(wp, dur)
        knots = t0 + np.concatenate([[0.0], np.cumsum(dur)])
        return cls(
            coeffs=_f32(c),
            knots=_f32(knots),
            durations=_f32(dur),
            yaw=_f32(y),
            duration=_f32(np.sum(dur)),
        )

    @staticmethod
    def random_waypoints(
        seed: int,
        n_segments: int = 5,
        box=((-1.0, -1.0, 0.5), (1.0, 1.0, 1.5)),
        duration: float = 5.0,
        start=None,
        min_segment_fraction: float = 0.5,
    ) -> tuple[np.ndarray, np.ndarray]:
        """Waypoints (N+1, 3) and durations (N,) used by :meth:`random` (float64)."""
        if isinstance(n_segments, bool) or int(n_segments) != n_segments or n_segments < 1:
            raise ValueError(f"n_segments must be an integer >= 1, got {n_segments!r}")
        n_segments = int(n_segments)
        bx = _np_array(box, "box", shape=(2, 3))
        lo, hi = bx
        if np.any(hi < lo):
            raise ValueError(
                f"box must be ((xmin, ymin, zmin), (xmax, ymax, zmax)) with min <= max, got {bx}"
            )
        total = _scalar(duration, "duration", positive=True)
        frac = _scalar(min_segment_fraction, "min_segment_fraction", nonneg=True)
        rng = np.random.default_rng(seed)
        wp = rng.uniform(lo, hi, size=(n_segments + 1, 3))
        if start is not None:
            wp[0] = _np_array(start, "start", shape=(3,))
        lengths = np.linalg.norm(np.diff(wp, axis=0), axis=1)
        mean = float(np.mean(lengths))
        weights = np.maximum(lengths, frac * mean) if mean > 0 else np.ones(n_segments)
        if np.any(weights <= 0):
            raise ValueError(
                "min_segment_fraction = 0 and coincident consecutive waypoints give a zero-duration segment"
            )
        dur = total * weights / np.sum(weights)
        return wp, dur

    @classmethod
    def random(
        cls,
        seed: int,
        n_segments: int = 5,
        box=((-1.0, -1.0, 0.5), (1.0, 1.0, 1.5)),
        duration: float = 5.0,
        start=None,
        yaw: float = 0.0,
        min_segment_fraction: float = 0.5,
        min_height: float | None = None,
        max_tries: int = 100,
    ) -> "MinSnap":
        """Seeded random minimum-snap trajectory (deterministic for a seed).

        ``n_segments + 1`` waypoints are drawn with ``numpy.random.default_rng(seed)``
        uniformly in ``box = (lo (3,), hi (3,))`` (the first one is replaced by ``start``
        if given, which may lie outside the box). Segment durations are proportional to
        segment length and sum to ``duration``, except that every segment is allotted
        at least the time of ``min_segment_fraction`` x the mean segment length
        (``0`` = purely proportional). The floor matters: a very short segment between
        long ones makes the minimum-snap solution overshoot far out of the box with very
        large accelerations (defaults, 200 seeds: peak |acc| 99th percentile 14 m/s^2 and
        worst excursion 2.1 m outside the xy box with the 0.5 floor, vs 40 m/s^2 and 6.8 m
        with a 0.1 floor). Only the waypoints are guaranteed to be in the box; the
        trajectory between them may leave it.

        ``min_height`` (m): keep the whole trajectory (not only its waypoints) at or above this
        height, e.g. clear of the ground: a draw whose path dips lower is redrawn (seeds
        ``seed``, then ``(seed, 1)``, ``(seed, 2)``, … up to ``max_tries``; a draw that stays
        above is the same as without ``min_height``). Without it, about 1 in 10 default draws
        from ``start=(0, 0, 1)`` dips below z = 0.
        """
        if min_height is None:
            wp, dur = cls.random_waypoints(seed, n_segments, box, duration, start, min_segment_fraction)
            return cls.through(wp, dur, yaw=yaw)
        h = _scalar(min_height, "min_height")
        if start is not None and _np_array(start, "start", shape=(3,))[2] < h:
            raise ValueError(f"start height {start[2]} is below min_height {h}")
        lowest = np.inf
        for attempt in range(int(max_tries)):
            sd = seed if attempt == 0 else np.random.SeedSequence([int(seed), attempt])
            wp, dur = cls.random_waypoints(sd, n_segments, box, duration, start, min_segment_fraction)
            ref = cls.through(wp, dur, yaw=yaw)
            z = ref.lowest_height()
            if z >= h:
                return ref
            lowest = min(lowest, z)
        raise ValueError(f"no min-snap draw of seed {seed} stayed above min_height {h} m in {max_tries} tries "
                         f"(lowest point {lowest:.2f} m): lower min_height or raise the box")

    def lowest_height(self, samples_per_segment: int = 100) -> float:
        """Lowest z (m) of the trajectory, sampled ``samples_per_segment`` times per segment."""
        n = len(np.asarray(self.durations))
        ts = np.linspace(0.0, float(self.duration), n * samples_per_segment + 1)
        return float(_lowest_z(self, jnp.asarray(ts, _DTYPE)))

    def at(self, t) -> RefPoint:
        """Evaluate at scalar time ``t`` [s]."""
        t = jnp.asarray(t, _DTYPE)
        knots = jnp.asarray(self.knots, _DTYPE)
        coeffs = jnp.asarray(self.coeffs, _DTYPE)
        durs = jnp.asarray(self.durations, _DTYPE)
        n = coeffs.shape[0]
        i = jnp.clip(jnp.searchsorted(knots, t, side="right", method="compare_all") - 1, 0, n - 1)
        T = durs[i]
        tau = jnp.clip((t - knots[i]) / T, 0.0, 1.0)
        p, d1, d2, d3, d4 = _horner_derivs(coeffs[i], tau)
        inv = 1.0 / T
        active = (t >= knots[0]) & (t <= knots[-1])
        scale = jnp.where(active, 1.0, 0.0).astype(_DTYPE)
        vel = d1 * (inv * scale)
        acc = d2 * (inv**2 * scale)
        jerk = d3 * (inv**3 * scale)
        snap = d4 * (inv**4 * scale)
        yaw = jnp.asarray(self.yaw, _DTYPE) + jnp.zeros_like(t)
        return RefPoint(p, vel, acc, jerk, snap, yaw, jnp.zeros_like(t))


@jax.jit
def _lowest_z(ref, ts):
    """min over the (T,) times ``ts`` of ``ref``'s z (one compile per segment count and T)."""
    return jnp.min(jax.vmap(ref.at)(ts).pos[:, 2])
