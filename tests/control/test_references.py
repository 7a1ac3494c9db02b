"""Tests for mjxsysid.control.references (CPU, float32 in JAX, float64 for the host QP)."""

import math

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from mjxsysid.control.references import (
    Hover,
    Lemniscate,
    MinSnap,
    RefPoint,
    Steps,
    evaluate,
    integrated_squared_derivative,
    min_snap_coefficients,
    sample,
    stack,
)

DERIVS = ("vel", "acc", "jerk", "snap")


# ------------------------------------------------------------------------------------
# helpers
# ------------------------------------------------------------------------------------


def _autodiff_all(ref, t):
    """(pos, vel, acc, jerk, snap) of ref at t by nested jax.jacfwd of the position."""
    fs = [lambda s: ref.at(s).pos]
    for _ in range(4):
        fs.append(jax.jacfwd(fs[-1]))
    return tuple(f(t) for f in fs)


# one compilation per reference type/shape: vmapped over times, ref passed as argument
autodiff_derivs = jax.jit(jax.vmap(_autodiff_all, in_axes=(None, 0)))
jsample = jax.jit(sample)
jevaluate = jax.jit(evaluate)


def np_poly_deriv(c, tau, n):
    """float64 n-th tau-derivative of sum_j c[j] tau^j; c (8, 3)."""
    out = np.zeros(3)
    for j in range(n, c.shape[0]):
        out += math.perm(j, n) * c[j] * tau ** (j - n)
    return out


def np_eval(coeffs, durations, i, tau, n):
    """float64 n-th time derivative of segment i at normalised time tau."""
    return np_poly_deriv(coeffs[i], tau, n) / durations[i] ** n


def check_against_autodiff(ref, ts):
    ts = jnp.asarray(ts, jnp.float32)
    pt = jsample(ref, ts)
    ad = [np.asarray(a) for a in autodiff_derivs(ref, ts)]
    np.testing.assert_allclose(np.asarray(pt.pos), ad[0], rtol=0, atol=1e-6)
    for n, name in enumerate(DERIVS, start=1):
        analytic = np.asarray(getattr(pt, name))
        # float32: tolerance relative to the size of the derivative vector at each time.
        tol = 2e-4 * np.maximum(1.0, np.max(np.abs(ad[n]), axis=-1, keepdims=True))
        assert np.all(np.abs(analytic - ad[n]) <= tol), (name, np.asarray(ts), analytic, ad[n])


WP = np.array(
    [[0.0, 0.0, 1.0], [1.0, 0.5, 1.2], [0.2, 1.0, 0.8], [-0.8, 0.1, 1.4], [0.0, -0.6, 1.0]]
)
DUR = np.array([1.2, 0.7, 1.5, 1.0])


# ------------------------------------------------------------------------------------
# RefPoint / Hover / Steps
# ------------------------------------------------------------------------------------


@pytest.mark.parametrize(
    "ref",
    [
        Hover.make((1.0, 2.0, 3.0), 0.3),
        Steps.single((0, 0, 1), (1, 0, 1), 1.0),
        Lemniscate.make(),
        MinSnap.through(WP, DUR),
    ],
    ids=["hover", "steps", "lemniscate", "minsnap"],
)
def test_shapes_jit_sample(ref):
    pt = jax.jit(evaluate)(ref, 0.5)
    assert isinstance(pt, RefPoint)
    for name in ("pos", "vel", "acc", "jerk", "snap"):
        assert getattr(pt, name).shape == (3,)
        assert getattr(pt, name).dtype == jnp.float32
    assert pt.yaw.shape == () and pt.yaw_rate.shape == ()
    ts = jnp.linspace(0.0, 3.0, 7)
    s = jax.jit(sample)(ref, ts)
    assert s.pos.shape == (7, 3) and s.snap.shape == (7, 3) and s.yaw.shape == (7,)
    for k, t in enumerate(np.asarray(ts)):
        np.testing.assert_allclose(s.pos[k], jevaluate(ref, t).pos, atol=1e-6)
    with pytest.raises(ValueError, match="times"):
        sample(ref, jnp.zeros((2, 2)))


def test_hover_constant():
    ref = Hover.make((1.0, -2.0, 3.0), yaw=0.7)
    s = sample(ref, jnp.array([-1.0, 0.0, 100.0]))
    np.testing.assert_allclose(s.pos, np.tile([1.0, -2.0, 3.0], (3, 1)))
    np.testing.assert_allclose(s.yaw, 0.7)
    for name in DERIVS:
        np.testing.assert_array_equal(getattr(s, name), 0.0)
    assert np.isinf(float(ref.duration))
    with pytest.raises(ValueError, match="pos"):
        Hover.make((1.0, 2.0))


def test_steps():
    ref = Steps.make([1.0, 2.0, 4.0], [[0, 0, 1], [1, 0, 1], [1, 1, 2]], yaw=0.2)
    ts = jnp.array([-5.0, 0.99, 1.0, 1.5, 2.0, 3.9, 4.0, 50.0])
    expect = [[0, 0, 1]] * 2 + [[0, 0, 1]] * 2 + [[1, 0, 1]] * 2 + [[1, 1, 2]] * 2
    s = jax.jit(sample)(ref, ts)
    np.testing.assert_allclose(s.pos, expect)
    for name in DERIVS:
        np.testing.assert_array_equal(getattr(s, name), 0.0)
    np.testing.assert_allclose(s.yaw, 0.2)
    assert float(ref.duration) == 4.0

    one = Steps.single((0, 0, 1), (1, 2, 3), t_step=2.0)
    np.testing.assert_allclose(evaluate(one, 1.999).pos, [0, 0, 1])
    np.testing.assert_allclose(evaluate(one, 2.0).pos, [1, 2, 3])
    np.testing.assert_allclose(evaluate(one, -1.0).pos, [0, 0, 1])

    with pytest.raises(ValueError, match="non-decreasing"):
        Steps.make([2.0, 1.0], [[0, 0, 0], [1, 1, 1]])
    with pytest.raises(ValueError, match="positions"):
        Steps.make([0.0, 1.0], [[0, 0, 0]])
    with pytest.raises(ValueError, match="t_step"):
        Steps.single((0, 0, 1), (1, 0, 1), -1.0)
    with pytest.raises(ValueError, match="end"):
        Steps.single((0, 0, 1), (1, 0), 1.0)


# ------------------------------------------------------------------------------------
# Lemniscate
# ------------------------------------------------------------------------------------


def test_lemniscate_formula_and_derivatives():
    ref = Lemniscate.make(
        period=4.0, size=(1.5, 1.0, 0.4), center=(0.5, -0.5, 1.0), yaw_amplitude=0.6, yaw=0.1
    )
    w = 2 * np.pi / 4.0
    ts = np.array([0.0, 0.37, 1.9, 3.3])
    phi = w * ts
    expect = np.stack(
        [0.5 + 1.5 * np.sin(phi), -0.5 + 0.5 * np.sin(2 * phi), 1.0 + 0.4 * np.sin(3 * phi)], -1
    )
    np.testing.assert_allclose(jsample(ref, jnp.asarray(ts, jnp.float32)).pos, expect, atol=1e-6)
    np.testing.assert_allclose(ref.at(0.0).pos, [0.5, -0.5, 1.0], atol=1e-7)
    check_against_autodiff(ref, [0.0, 0.37, 1.1, 1.9, 2.6, 3.3, 5.05])
    # yaw_rate vs autodiff of yaw
    ts = jnp.array([0.2, 1.4, 3.0])
    yr = jax.vmap(jax.grad(lambda s: ref.at(s).yaw))(ts)
    np.testing.assert_allclose(jsample(ref, ts).yaw_rate, yr, atol=1e-5)
    np.testing.assert_allclose(ref.at(1.0).yaw, 0.1 + 0.6 * np.sin(w * 1.0), atol=1e-6)
    assert np.isinf(float(ref.duration))


def test_lemniscate_period_and_default_yaw():
    T = 7.5
    ref = Lemniscate.make(period=T)
    ts = jnp.linspace(0.0, T, 23)
    a, b, c = jsample(ref, ts), jsample(ref, ts + T), jsample(ref, ts + 10 * T)
    for name in ("pos",) + DERIVS:
        scale = max(1.0, float(np.max(np.abs(getattr(a, name)))))
        np.testing.assert_allclose(getattr(b, name), getattr(a, name), atol=1e-4 * scale)
        np.testing.assert_allclose(getattr(c, name), getattr(a, name), atol=1e-4 * scale)
    np.testing.assert_array_equal(a.yaw, 0.0)
    np.testing.assert_array_equal(a.yaw_rate, 0.0)
    # all three axes are excited (non-degenerate in x, y and z)
    assert np.all(np.ptp(np.asarray(a.pos), axis=0) > 0.25)


@pytest.mark.parametrize(
    "kwargs,name",
    [
        ({"period": 0.0}, "period"),
        ({"period": -1.0}, "period"),
        ({"period": float("nan")}, "period"),
        ({"size": (1.0, 1.0)}, "size"),
        ({"size": (1.0, -1.0, 0.3)}, "size"),
        ({"center": (0.0, 0.0)}, "center"),
        ({"yaw_amplitude": float("inf")}, "yaw_amplitude"),
    ],
)
def test_lemniscate_bad_args(kwargs, name):
    with pytest.raises(ValueError, match=name):
        Lemniscate.make(**kwargs)


# ------------------------------------------------------------------------------------
# MinSnap
# ------------------------------------------------------------------------------------


def test_minsnap_passes_through_waypoints():
    C = min_snap_coefficients(WP, DUR)
    assert C.shape == (4, 8, 3) and C.dtype == np.float64
    for i in range(4):  # float64 host solution
        np.testing.assert_allclose(np_eval(C, DUR, i, 0.0, 0), WP[i], atol=1e-9)
        np.testing.assert_allclose(np_eval(C, DUR, i, 1.0, 0), WP[i + 1], atol=1e-9)
    ref = MinSnap.through(WP, DUR, t0=0.5)
    knots = 0.5 + np.concatenate([[0.0], np.cumsum(DUR)])
    np.testing.assert_allclose(ref.knots, knots, atol=1e-6)
    assert ref.coeffs.shape == (4, 8, 3) and ref.knots.shape == (5,)
    np.testing.assert_allclose(float(ref.duration), DUR.sum(), rtol=1e-6)
    s = jsample(ref, jnp.asarray(knots, jnp.float32))  # float32 evaluation
    np.testing.assert_allclose(s.pos, WP, atol=1e-4)


def test_minsnap_continuity_float64():
    """Exact left/right limits at interior knots: continuous up to the 6th derivative."""
    C = min_snap_coefficients(WP, DUR)
    for k in range(1, 4):
        for n in range(0, 7):
            left = np_eval(C, DUR, k - 1, 1.0, n)
            right = np_eval(C, DUR, k, 0.0, n)
            scale = max(1.0, np.max(np.abs(left)))
            np.testing.assert_allclose(left, right, rtol=0, atol=1e-8 * scale, err_msg=f"knot {k}, order {n}")
    # static ends: vel, acc, jerk zero
    for n in (1, 2, 3):
        np.testing.assert_allclose(np_eval(C, DUR, 0, 0.0, n), 0.0, atol=1e-9)
        np.testing.assert_allclose(np_eval(C, DUR, 3, 1.0, n), 0.0, atol=1e-9)


def test_minsnap_continuity_float32():
    """pos..snap at t_k ± h (h = 1e-4) in float32 JAX.

    Tolerance for derivative n: |f_n(t+h) - f_n(t-h)| <= 2h max|f_{n+1}| for a C^(n+1)
    function; we use 3 h M_{n+1} (M from the float64 solution on both sides of the knot)
    plus the float32 evaluation error, bounded by 2e-6 * S_n with S_n = sum_j |coefficient
    of the n-th derivative| / T^n (Horner in [0, 1] has error <~ 8 eps_32 S_n; eps_32 =
    6e-8, x4 safety), plus the effect of rounding t (~2.4e-7 at t ~ 2-4 s) which is
    covered by the 3h vs 2h margin. A jump in f_n would be >> this tolerance.
    """
    C = min_snap_coefficients(WP, DUR)
    ref = MinSnap.through(WP, DUR)
    knots = np.concatenate([[0.0], np.cumsum(DUR)])
    h = 1e-4
    for k in range(1, 4):
        tk = knots[k]
        lo, hi = jevaluate(ref, jnp.float32(tk - h)), jevaluate(ref, jnp.float32(tk + h))
        for n, name in enumerate(("pos",) + DERIVS):
            M = max(
                np.max(np.abs(np_eval(C, DUR, seg, tau, n + 1)))
                for seg, tau in ((k - 1, 1.0), (k - 1, 1.0 - h / DUR[k - 1]), (k, 0.0), (k, h / DUR[k]))
            )
            S = max(
                np.sum(np.abs(C[seg, n:] * np.array([math.perm(j, n) for j in range(n, 8)])[:, None]))
                / DUR[seg] ** n
                for seg in (k - 1, k)
            )
            tol = 3 * h * M + 2e-6 * S
            diff = np.max(np.abs(np.asarray(getattr(hi, name)) - np.asarray(getattr(lo, name))))
            assert diff <= tol, f"knot {k} {name}: jump {diff:.3g} > tol {tol:.3g}"


def test_minsnap_ends_and_clamping():
    ref = MinSnap.through(WP, DUR)
    T = float(DUR.sum())
    pt = jsample(ref, jnp.array([0.0, T], jnp.float32))
    for name in ("vel", "acc", "jerk"):
        np.testing.assert_allclose(getattr(pt, name), 0.0, atol=1e-4)
    ts = np.array([-3.0, -1e-3, T + 1e-3, T + 10.0])
    pt = jsample(ref, jnp.asarray(ts, jnp.float32))
    np.testing.assert_allclose(pt.pos, np.where(ts[:, None] < 0, WP[0], WP[-1]), atol=1e-5)
    for name in DERIVS:
        np.testing.assert_array_equal(getattr(pt, name), 0.0)


def test_minsnap_derivatives_vs_autodiff():
    ref = MinSnap.through(WP, DUR)
    knots = np.concatenate([[0.0], np.cumsum(DUR)])
    ts = [0.1, 0.6, 1.5, 2.1, 3.0, 4.2]
    assert not np.any(np.isclose(np.array(ts)[:, None], knots[None, :], atol=1e-3))
    check_against_autodiff(ref, ts)
    # also against the float64 host polynomial
    C = min_snap_coefficients(WP, DUR)
    pts = jsample(ref, jnp.asarray(ts, jnp.float32))
    for k, t in enumerate(ts):
        i = int(np.searchsorted(knots, t, side="right") - 1)
        tau = (t - knots[i]) / DUR[i]
        for n, name in enumerate(("pos",) + DERIVS):
            ex = np_eval(C, DUR, i, tau, n)
            got = getattr(pts, name)[k]
            np.testing.assert_allclose(got, ex, atol=1e-4 * max(1.0, np.max(np.abs(ex))))


def test_minsnap_is_optimal():
    """Would fail if the QP were set up or solved wrongly."""
    C = min_snap_coefficients(WP, DUR)  # default: Hermite / interior-derivative solver
    J = integrated_squared_derivative(C, DUR, order=4)
    # (1) Two independent solvers agree: the KKT system with Mellinger & Kumar's C^4
    #     constraints, and the square C^6 system (C^6 is the natural optimality condition
    #     of minimum snap with free interior derivatives, so the optimum must satisfy it).
    Ck4 = min_snap_coefficients(WP, DUR, method="kkt", continuity_order=4)
    Ck6 = min_snap_coefficients(WP, DUR, method="kkt", continuity_order=6)
    np.testing.assert_allclose(C, Ck4, atol=1e-9 * np.max(np.abs(C)))
    np.testing.assert_allclose(C, Ck6, atol=1e-8 * np.max(np.abs(C)))
    # (2) Minimum-jerk 7th-order polynomials satisfy the same (C^4, waypoint, static-end)
    #     constraints but have more snap, and conversely less jerk.
    Cj = min_snap_coefficients(WP, DUR, method="kkt", continuity_order=4, cost_order=3)
    Jj = integrated_squared_derivative(Cj, DUR, order=4)
    assert np.max(np.abs(Cj - C)) > 1e-3  # genuinely different
    assert Jj > J * (1 + 1e-6), (Jj, J)
    assert integrated_squared_derivative(Cj, DUR, order=3) < integrated_squared_derivative(C, DUR, order=3)
    # (3) Every feasible perturbation along the line through both feasible solutions
    #     increases the snap cost, which is quadratic with its vertex at the optimum:
    #     J(C + e (Cj - C)) - J(C) = e^2 (Jj - J) (no linear term <=> first-order optimal).
    for eps in (-1.0, -0.1, -1e-3, 1e-3, 0.1, 1.0):
        Je = integrated_squared_derivative(C + eps * (Cj - C), DUR, order=4)
        assert Je > J, (eps, Je, J)
        np.testing.assert_allclose(Je - J, eps**2 * (Jj - J), rtol=1e-5)
    # (4) Random perturbations in the null space of the constraints (waypoints, static
    #     ends, C^4 at interior knots) all increase the cost.
    rng = np.random.default_rng(0)
    for _ in range(5):
        Cr = C + 0.1 * _feasible_direction(rng)
        assert integrated_squared_derivative(Cr, DUR, order=4) > J


def _feasible_direction(rng):
    """(4, 8, 3) random coefficient direction keeping the C^4 min-snap constraints of (WP, DUR)."""
    n = len(DUR)
    rows = []

    def row(parts):
        r = np.zeros(8 * n)
        for i, v in parts:
            r[8 * i : 8 * i + 8] += v
        rows.append(r)

    def drow(d, tau):
        return np.array([math.perm(j, d) * tau ** (j - d) if j >= d else 0.0 for j in range(8)])

    for i in range(n):
        row([(i, drow(0, 0.0))])
        row([(i, drow(0, 1.0))])
    for d in (1, 2, 3):
        row([(0, drow(d, 0.0))])
        row([(n - 1, drow(d, 1.0))])
    for i in range(n - 1):
        for d in range(1, 5):
            row([(i, drow(d, 1.0) / DUR[i] ** d), (i + 1, -drow(d, 0.0) / DUR[i + 1] ** d)])
    A = np.stack(rows)
    _, sv, vt = np.linalg.svd(A)
    Z = vt[np.sum(sv > 1e-10 * sv[0]) :].T  # null-space basis
    assert Z.shape[1] == 2 * (n - 1)
    return (Z @ rng.normal(size=(Z.shape[1], 3))).reshape(n, 8, 3)


def test_minsnap_badly_scaled_durations():
    """Durations differing by ~100x: the default solver still meets the constraints."""
    rng = np.random.default_rng(1)
    n = 30
    wp = rng.uniform(-1, 1, (n + 1, 3))
    dur = np.exp(rng.uniform(np.log(0.05), np.log(5.0), n))
    C = min_snap_coefficients(wp, dur)
    for i in range(n):
        np.testing.assert_allclose(np_eval(C, dur, i, 0.0, 0), wp[i], atol=1e-9)
        np.testing.assert_allclose(np_eval(C, dur, i, 1.0, 0), wp[i + 1], atol=1e-9)
    for k in range(1, n):  # C^3 by construction, C^4 from optimality
        for d in range(1, 5):
            left, right = np_eval(C, dur, k - 1, 1.0, d), np_eval(C, dur, k, 0.0, d)
            np.testing.assert_allclose(left, right, atol=1e-6 * max(1.0, np.max(np.abs(left))))
    for d in (1, 2, 3):
        np.testing.assert_allclose(np_eval(C, dur, 0, 0.0, d), 0.0, atol=1e-9)
        np.testing.assert_allclose(np_eval(C, dur, n - 1, 1.0, d), 0.0, atol=1e-9 * np.max(np.abs(C)))


def test_minsnap_single_segment():
    wp = np.array([[0.0, 0.0, 1.0], [1.0, -1.0, 2.0]])
    ref = MinSnap.through(wp, [2.0])
    # 7th-order "smoothstep" 35 s^4 - 84 s^5 + 70 s^6 - 20 s^7 between the endpoints
    s = 0.3
    blend = 35 * s**4 - 84 * s**5 + 70 * s**6 - 20 * s**7
    np.testing.assert_allclose(ref.at(0.6).pos, wp[0] + blend * (wp[1] - wp[0]), atol=1e-6)


def test_minsnap_random_deterministic_and_in_box():
    box = ((-2.0, -1.0, 0.5), (2.0, 1.0, 1.5))
    wp1, d1 = MinSnap.random_waypoints(7, n_segments=6, box=box, duration=8.0)
    wp2, d2 = MinSnap.random_waypoints(7, n_segments=6, box=box, duration=8.0)
    np.testing.assert_array_equal(wp1, wp2)
    np.testing.assert_array_equal(d1, d2)
    assert wp1.shape == (7, 3) and d1.shape == (6,)
    assert np.all(wp1 >= np.array(box[0])) and np.all(wp1 <= np.array(box[1]))
    np.testing.assert_allclose(d1.sum(), 8.0)
    # durations proportional to length (floor of 50% of the mean length by default)
    L = np.linalg.norm(np.diff(wp1, axis=0), axis=1)
    w = np.maximum(L, 0.5 * L.mean())
    np.testing.assert_allclose(d1, 8.0 * w / w.sum())
    _, d0 = MinSnap.random_waypoints(7, n_segments=6, box=box, duration=8.0, min_segment_fraction=0.0)
    np.testing.assert_allclose(d0, 8.0 * L / L.sum())
    wp3, _ = MinSnap.random_waypoints(8, n_segments=6, box=box, duration=8.0)
    assert not np.allclose(wp1, wp3)

    r1, r2 = MinSnap.random(7, 6, box, 8.0), MinSnap.random(7, 6, box, 8.0)
    for a, b in zip(jax.tree.leaves(r1), jax.tree.leaves(r2)):
        np.testing.assert_array_equal(a, b)
    s = jsample(r1, jnp.asarray(np.concatenate([[0.0], np.cumsum(d1)]), jnp.float32))
    np.testing.assert_allclose(s.pos, wp1, atol=1e-4)

    r = MinSnap.random(3, start=(0.1, 0.2, 0.3))
    np.testing.assert_allclose(r.at(0.0).pos, [0.1, 0.2, 0.3], atol=1e-6)
    np.testing.assert_allclose(float(r.duration), 5.0, rtol=1e-6)


@pytest.mark.parametrize(
    "call,name",
    [
        (lambda: MinSnap.through(WP, DUR[:3]), "durations"),
        (lambda: MinSnap.through(WP[:, :2], DUR), "waypoints"),
        (lambda: MinSnap.through(WP[:1], []), "waypoints"),
        (lambda: MinSnap.through(WP, np.array([1.0, 0.0, 1.0, 1.0])), "durations"),
        (lambda: MinSnap.through(WP, -DUR), "durations"),
        (lambda: MinSnap.through(np.full((5, 3), np.nan), DUR), "waypoints"),
        (lambda: MinSnap.random(0, duration=0.0), "duration"),
        (lambda: MinSnap.random(0, duration=-2.0), "duration"),
        (lambda: MinSnap.random(0, n_segments=0), "n_segments"),
        (lambda: MinSnap.random(0, n_segments=2.5), "n_segments"),
        (lambda: MinSnap.random(0, box=((1, 1, 1), (0, 0, 0))), "box"),
        (lambda: MinSnap.random(0, box=((0, 0), (1, 1))), "box"),
        (lambda: MinSnap.random(0, start=(0.0, 1.0)), "start"),
        (lambda: MinSnap.random(0, min_segment_fraction=-0.1), "min_segment_fraction"),
        (lambda: min_snap_coefficients(WP, DUR, method="qp"), "method"),
        (lambda: min_snap_coefficients(WP, DUR, cost_order=5), "cost_order"),
    ],
)
def test_minsnap_bad_args(call, name):
    with pytest.raises(ValueError, match=name):
        call()


def test_stacked_batch_jit_vmap_matches_individual():
    refs = [MinSnap.random(s, n_segments=4, duration=3.0 + s) for s in range(5)]
    batch = stack(refs)
    assert batch.coeffs.shape == (5, 4, 8, 3) and batch.knots.shape == (5, 5) and batch.yaw.shape == (5,)
    ts = jnp.linspace(-0.5, 8.5, 37)

    # (B,) refs x (T,) times
    f = jax.jit(jax.vmap(lambda r: sample(r, ts)))
    out = f(batch)
    assert out.pos.shape == (5, 37, 3)
    # one time per ref
    t1 = jnp.array([0.3, 1.7, 2.9, 4.4, 9.0])
    out1 = jax.jit(jax.vmap(evaluate))(batch, t1)
    for b, r in enumerate(refs):
        ind = jsample(r, ts)  # individual, un-stacked ref
        for name in RefPoint._fields:
            np.testing.assert_allclose(getattr(out, name)[b], getattr(ind, name), rtol=1e-5, atol=1e-5)
            single = getattr(r.at(t1[b]), name)
            np.testing.assert_allclose(getattr(out1, name)[b], single, rtol=1e-5, atol=1e-5)

    lem = stack([Lemniscate.make(period=p) for p in (3.0, 5.0)])
    o = jax.jit(jax.vmap(evaluate, in_axes=(0, None)))(lem, 1.0)
    np.testing.assert_allclose(o.pos[1], Lemniscate.make(period=5.0).at(1.0).pos, atol=1e-6)

    with pytest.raises(ValueError, match="same type"):
        stack([Hover.make(), Lemniscate.make()])
    with pytest.raises(ValueError, match="leaf shapes"):
        stack([MinSnap.random(0, n_segments=3), MinSnap.random(0, n_segments=4)])
    with pytest.raises(ValueError, match="non-empty"):
        stack([])


def test_minsnap_min_height_keeps_the_whole_path_above_the_floor():
    # seed 3 (start (0, 0, 1), 5 s) dips below the ground without the constraint
    free = [MinSnap.random(seed=s, duration=5.0, start=(0.0, 0.0, 1.0)) for s in range(40)]
    low = [s for s, r in enumerate(free) if r.lowest_height() < 0.2]
    assert low, "no low draw among 40 seeds: the test lost its subject"
    for s in low[:3]:
        r = MinSnap.random(seed=s, duration=5.0, start=(0.0, 0.0, 1.0), min_height=0.2)
        ts = np.linspace(0.0, 5.0, 2001)
        z = np.asarray(sample(r, ts).pos[:, 2])
        assert z.min() >= 0.2 - 1e-3
        np.testing.assert_allclose(np.asarray(r.at(0.0).pos), [0.0, 0.0, 1.0], atol=1e-6)
    # a draw that already stays above is unchanged
    ok = next(s for s, r in enumerate(free) if r.lowest_height() >= 0.2)
    a = MinSnap.random(seed=ok, duration=5.0, start=(0.0, 0.0, 1.0), min_height=0.2)
    np.testing.assert_array_equal(np.asarray(a.coeffs), np.asarray(free[ok].coeffs))
    with pytest.raises(ValueError, match="min_height"):
        MinSnap.random(seed=0, start=(0.0, 0.0, 0.1), min_height=0.2)
    with pytest.raises(ValueError, match="min_height"):
        MinSnap.random(seed=0, start=(0.0, 0.0, 1.0), min_height=0.99, max_tries=3)


def test_delayed_holds_the_start_then_flies_the_inner_reference():
    from mjxsysid.control.references import Delayed
    lem = Lemniscate.make(period=10.0)
    d = Delayed.make(lem, 2.0)
    before = d.at(1.0)
    np.testing.assert_allclose(np.asarray(before.pos), np.asarray(lem.at(0.0).pos), atol=1e-6)
    for k in ("vel", "acc", "jerk", "snap"):
        assert np.all(np.asarray(getattr(before, k)) == 0.0)
    after = d.at(5.5)
    np.testing.assert_allclose(np.asarray(after.pos), np.asarray(lem.at(3.5).pos), atol=1e-6)
    np.testing.assert_allclose(np.asarray(after.vel), np.asarray(lem.at(3.5).vel), atol=1e-6)
    batch = stack([Delayed.make(Lemniscate.make(period=p), 1.0) for p in (5.0, 10.0)])
    pts = jax.jit(jax.vmap(lambda r: r.at(3.0)))(batch)
    np.testing.assert_allclose(np.asarray(pts.pos[1]), np.asarray(Lemniscate.make(period=10.0).at(2.0).pos),
                               atol=1e-6)
    with pytest.raises(ValueError, match="delay"):
        Delayed.make(lem, -1.0)


def test_flight_minsnaps_scale_segments_with_duration_and_clear_the_ground():
    from mjxsysid.rollout.flight import make_reference, minsnap_segments, random_minsnaps
    assert [minsnap_segments(d) for d in (0.5, 2.0, 5.0, 12.0)] == [1, 2, 5, 5]
    ref, d = make_reference("minsnap", duration=2.0, seed=4)
    assert d == 2.0 and len(np.asarray(ref.durations)) == 2 and ref.lowest_height() >= 0.2 - 1e-3
    batch = random_minsnaps(3, 0, 2.0)
    assert np.asarray(batch.durations).shape == (3, 2)
