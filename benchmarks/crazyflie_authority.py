"""Crazyflie's three flights: does the likelihood itself prefer their roll/pitch authorities and τ_m, or do the
chains sit on a narrow mode of a flat one? Per log its posterior (the defaults, no decoded proposal), then the
profile log-target of log τ_m and log A_x (the other visible coordinates and the bias re-fitted exactly for the
Student-t residuals, at the mode's σ, δ and weights), each log's target at the others' (τ_m, A_x, A_y)
with the rest re-fitted, and the target's maximum with rate windows of other lengths.

    python benchmarks/crazyflie_authority.py --logs /work/shared/data/logs/crazyflie/log{10,15,16}.bin
"""
from __future__ import annotations

import argparse
from pathlib import Path

import numpy as np

THRESHOLD = 1.353
"""Nats below the profile's maximum that bound a 90 % interval (χ²₁'s 90 % quantile / 2)."""


def t_residuals(z, data, ld, ls, weights):
    """Signed residuals (R,) whose half sum of squares is −log target at z (13,) = [v, bias] with σ, δ and the
    weights fixed (up to a constant): r √(w (ν + 1) log(1 + r² / ν) / r²) per Student-t residual r (standardised),
    the bias's prior as r / sd."""
    import jax.numpy as jnp
    from mjxsysid.identify import logspace as L
    from mjxsysid.identify.likelihood import NU, residuals
    from mjxsysid.identify.target import ACC_BIAS_SD
    rg, sg, ra, sa = residuals(L.x_from_y(L.y_from_z(z, ls), ld), data)
    w = data.use * weights

    def t(r, s, wc):
        q = r / s
        q2 = q * q
        safe = jnp.where(q2 > 1e-6, q2, 1.0)
        g = jnp.where(q2 > 1e-6, jnp.log1p(safe / NU) / safe, 1.0 / NU - q2 / (2 * NU * NU))   # log(1 + q²/ν) / q²
        return q * jnp.sqrt(wc * (NU + 1) * g)
    return jnp.concatenate([t(rg, sg, w[L.GYRO]).ravel(), t(ra, sa, w[L.ACC_Z]), z[L.Z_BIAS, None] / ACC_BIAS_SD])


def make_fit(data, mode, weights):
    """-> (fit, target, 13): fit(z_free (F,), fixed values (k,), fixed indices (k,)) the free coordinates of z
    that maximise the target (Levenberg–Marquardt on :func:`t_residuals`, inside the prior's box and J's
    triangle inequality; A_z always free) and the full z (13,); target(z) the log target at z (σ, δ, weights
    the mode's)."""
    import functools
    import jax
    import jax.numpy as jnp
    import optimistix as optx
    from mjxsysid.identify import logspace as L
    from mjxsysid.identify.coords import PHYSICAL_PRIOR as prior
    from mjxsysid.identify.target import ACC_BIAS_SD, log_target
    ld, ls = jnp.asarray(mode[L.X_LOG_DISCREPANCY]), jnp.asarray(mode[L.X_LOG_NOISE])
    w = jnp.asarray(weights, jnp.float32)
    n = L.N_Z

    b_lo, b_hi = (np.r_[b, s * 3.0 * ACC_BIAS_SD] for b, s in zip(prior.v_bounds(), (-1, 1)))
    lo, hi = (jnp.asarray(b_lo + e * (b_hi - b_lo), jnp.float32) for e in (1e-4, 1 - 1e-4))

    @functools.partial(jax.jit, static_argnames="fixed")
    def _fit(uf0, vals, d, fixed):
        free = jnp.asarray(tuple(k for k in range(n) if k not in fixed))

        def full(uf):          # J's triangle inequality: A_z from 1 / (1/A_x + 1/A_y) up
            z = jnp.zeros(n).at[free].set(jax.nn.sigmoid(uf)).at[jnp.asarray(fixed)].set(vals)
            z = jnp.where(jnp.isin(jnp.arange(n), free), lo + (hi - lo) * z, z)
            tri = -jnp.log(jnp.exp(-z[L.LOG_AUTH_X]) + jnp.exp(-z[L.LOG_AUTH_Y])) + 1e-4
            return z.at[L.LOG_AUTH_Z].set(tri + (hi[L.LOG_AUTH_Z] - tri) * (z[L.LOG_AUTH_Z] - lo[L.LOG_AUTH_Z])
                                          / (hi - lo)[L.LOG_AUTH_Z])
        res = lambda uf, dd: t_residuals(full(uf), dd, ld, ls, w)   # noqa: E731
        uf = optx.least_squares(res, optx.LevenbergMarquardt(rtol=1e-9, atol=1e-9), uf0, args=d, max_steps=600,
                                throw=False).value
        return uf, full(uf)

    def fit(zf0, vals, fixed):
        """Free coordinates (F,) -> re-fitted (F,), the full z (13,): inside the prior's box (a logistic map)."""
        free = [k for k in range(n) if k not in fixed]
        lo_f = np.array(lo, np.float64)
        z_all = np.zeros(n)
        z_all[free], z_all[list(fixed)] = zf0, vals
        lo_f[L.LOG_AUTH_Z] = -np.log(np.exp(-z_all[L.LOG_AUTH_X]) + np.exp(-z_all[L.LOG_AUTH_Y])) + 1e-4
        p = np.clip((np.asarray(zf0, np.float64) - lo_f[free]) / (np.asarray(hi) - lo_f)[free], 1e-4, 1 - 1e-4)
        uf, z = _fit(jnp.asarray(np.log(p / (1 - p)), jnp.float32), jnp.asarray(vals, jnp.float32), data, fixed=fixed)
        return np.asarray(z)[free], z

    def target(z):
        return float(log_target(np.asarray(L.y_from_z(np.asarray(z, np.float32), np.asarray(ls)))[None], data,
                                np.asarray(ld), np.asarray(w))[0])
    return fit, target, n


def profile(data, mode, weights, js: tuple, grid) -> np.ndarray:
    """The target with the coordinates ``js`` of z held at each row of grid (K, len(js)), the others re-fitted
    (warm-started outwards from the mode's values) -> Δ log target (K,) from the mode's own fit."""
    from mjxsysid.identify import logspace as L
    fit, target, n = make_fit(data, mode, weights)
    zm = np.asarray(L.z_from_y(L.y_from_x(mode)), np.float32)
    free = [k for k in range(n) if k not in js]
    zf0, z0 = fit(zm[free], zm[list(js)], tuple(js))
    t0 = max(target(z0), target(zm))
    grid = np.atleast_2d(np.asarray(grid, np.float32).T).T
    out = np.zeros(len(grid))
    dist = np.linalg.norm(grid - zm[list(js)], axis=1)
    for side in (grid[:, 0] >= zm[js[0]], grid[:, 0] < zm[js[0]]):
        zf = zf0
        for k in sorted(np.flatnonzero(side), key=lambda k: dist[k]):
            zf, z = fit(zf, grid[k], tuple(js))
            out[k] = target(z) - t0
    return out


def student_t_fit(data, seed: int = 0) -> np.ndarray:
    """The target's maximum z (13,) of a log: the library's mode (:func:`~mjxsysid.identify.inference.find_mode`, a
    Gaussian least-squares fit, from its usual 12 starts) re-fitted for the Student-t residuals at its σ, δ and
    weights (the bias held)."""
    from mjxsysid.identify import logspace as L
    from mjxsysid.identify.coords import PHYSICAL_PRIOR
    from mjxsysid.identify.inference import _starts, find_mode
    x, _, w, _, _ = find_mode(data, _starts(data, None, np.random.default_rng(seed), PHYSICAL_PRIOR, 12))
    fit, _, _ = make_fit(data, np.asarray(x, np.float32), w)
    zm = np.asarray(L.z_from_y(L.y_from_x(np.asarray(x, np.float32))))
    return np.asarray(fit(zm[:L.Z_BIAS], zm[[L.Z_BIAS]], (L.Z_BIAS,))[1])


def interval(grid, prof, threshold: float = THRESHOLD) -> tuple[float, float, bool]:
    """The grid's span (exp'd) where prof ≥ max − threshold, and whether it reaches the grid's edge."""
    inside = prof >= prof.max() - threshold
    g = np.exp(grid[inside])
    return float(g.min()), float(g.max()), bool(inside[0] or inside[-1])


def main():
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--logs", nargs="+", required=True)
    ap.add_argument("--points", type=int, default=17)
    ap.add_argument("--window-steps", type=int, nargs="+", default=[5, 10, 25, 50],
                    help="half-window lengths (control steps) of the window sweep")
    ap.add_argument("--out", default=None, help="write the numbers as JSON here")
    a = ap.parse_args()
    import json
    from mjxsysid.identify import log_grounded_posterior
    from mjxsysid.identify import logspace as L
    from mjxsysid.identify.logdata import prepare
    from mjxsysid.logs.csvlog import read_any_log
    names = [Path(p).stem for p in a.logs]
    datas, posts = {}, {}
    for name, p in zip(names, a.logs):
        datas[name] = prepare(read_any_log(p))
        posts[name] = log_grounded_posterior(datas[name], seed=0)
    keys = {"tau_m_ms": L.LOG_TAU_M, "A_x": L.LOG_AUTH_X, "A_y": L.LOG_AUTH_Y}
    res = {}
    print("| log | quantity | mode | profile 90 % (Δ ≤ 1.35 nats) | raw 90 % band | calibrated 90 % band |")
    print("|---|---|---|---|---|---|")
    for name in names:
        post, d = posts[name], datas[name]
        mode, w = np.asarray(post["mode"], np.float32), np.asarray(post["weights"], np.float32)
        res[name] = {"weights": w.tolist(), "method": post["method"], "mode": mode.tolist()}
        for q, j in keys.items():
            if q == "A_y":
                continue
            s = 1e3 if q == "tau_m_ms" else 1.0
            grid = mode[j] + np.linspace(-1.6, 1.6, a.points)
            prof = profile(d, mode, w, (j,), grid)
            lo, hi, edge = interval(grid, prof)
            raw, cal = (np.exp(np.percentile(post[k][:, j], [5, 95])) * s for k in ("v_raw", "v"))
            res[name][q] = {"grid": np.exp(grid).tolist(), "profile": prof.tolist(), "interval": [lo * s, hi * s],
                            "raw": raw.tolist(), "calibrated": cal.tolist()}
            print(f"| {name} | {q} | {np.exp(mode[j]) * s:.3g} | {lo * s:.3g}–{hi * s:.3g}{' (edge)' if edge else ''} "
                  f"| {raw[0]:.3g}–{raw[1]:.3g} | {cal[0]:.3g}–{cal[1]:.3g} |", flush=True)
    js = (L.LOG_TAU_M, L.LOG_AUTH_X, L.LOG_AUTH_Y)
    print("\n| log | at the mode of | Δ log target (nats, weighted) |")
    print("|---|---|---|")
    for name in names:
        mode, w = (np.asarray(posts[name][k], np.float32) for k in ("mode", "weights"))
        for other in names:
            if other != name:
                at = np.asarray(posts[other]["mode"], np.float32)[list(js)]
                dl = float(profile(datas[name], mode, w, js, at[None])[0])
                res[name].setdefault("cross", {})[other] = dl
                print(f"| {name} | {other} (τ_m {np.exp(at[0]) * 1e3:.3g} ms, A_x {np.exp(at[1]):.3g}, "
                      f"A_y {np.exp(at[2]):.3g}) | {dl:+.1f} |", flush=True)
    print("\n| log | window (ms) | τ_m (ms) | A_x | A_y |")
    print("|---|---|---|---|---|")
    for name, p in zip(names, a.logs):
        for ws in a.window_steps:
            z = student_t_fit(prepare(read_any_log(p), window_steps=ws))
            res[name].setdefault("windows", {})[ws] = np.exp(z[list(js)]).tolist()
            print(f"| {name} | {4 * ws} | {np.exp(z[L.LOG_TAU_M]) * 1e3:.3g} | {np.exp(z[L.LOG_AUTH_X]):.3g} "
                  f"| {np.exp(z[L.LOG_AUTH_Y]):.3g} |", flush=True)
    if a.out:
        Path(a.out).write_text(json.dumps(res, indent=1))


if __name__ == "__main__":
    main()
