"""Hovers: is the authorities' false precision the likelihood's or the sampler's? Vehicles of a prior, the
lag-aware oracle, a clean IMU, one flight; per log the raw posterior (refine=False, defaults otherwise), and
the profile log-likelihood of the roll authority log A_x (the other coordinates and the bias re-fitted by
Levenberg–Marquardt at the mode's σ, δ and weights) against the SMC's 90 % band and the Laplace sd.

    python benchmarks/hover_profile.py --vehicles 6 --of 12 --flight hover:8
"""
from __future__ import annotations

import argparse

import numpy as np


def profile(data, mode, weights, j: int, grid) -> np.ndarray:
    """The log-likelihood at mode (21,) with coordinate j of v held at each value of grid (K,), the others
    re-fitted (warm-started from the mode outwards) -> Δ log-likelihood (K,) from the mode's."""
    import jax
    import jax.numpy as jnp
    import optimistix as optx
    from mjxsysid.identify import logspace as L
    from mjxsysid.identify.likelihood import log_likelihood
    from mjxsysid.identify.mode import _ls_residuals
    ld, ls = jnp.asarray(mode[L.X_LOG_DISCREPANCY]), jnp.asarray(mode[L.X_LOG_NOISE])
    zm = np.asarray(L.z_from_y(L.y_from_x(mode)))
    free = np.array([k for k in range(len(zm)) if k != j])

    def full(zf, a):
        return jnp.zeros(len(zm)).at[free].set(zf).at[j].set(a)

    @jax.jit
    def fit(zf0, a):
        res = lambda zf, args: _ls_residuals(full(zf, args[0]), args[1:])   # noqa: E731
        return optx.least_squares(res, optx.LevenbergMarquardt(rtol=1e-8, atol=1e-8), zf0,
                                  args=(a, data, ld, ls), max_steps=400, throw=False).value

    def ll(z):
        return float(log_likelihood(L.x_from_y(L.y_from_z(z, ls), ld), data, jnp.asarray(weights, jnp.float32)))

    ll0, out = ll(jnp.asarray(zm)), np.zeros(len(grid))
    for side in (grid >= zm[j], grid < zm[j]):
        zf = jnp.asarray(zm[free])
        for k in sorted(np.flatnonzero(side), key=lambda k: abs(grid[k] - zm[j])):
            zf = fit(zf, jnp.float32(grid[k]))
            out[k] = ll(full(zf, grid[k])) - ll0
    return out


def main():
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--vehicles", type=int, default=6)
    ap.add_argument("--of", type=int, default=12, help="vehicles drawn (the first --vehicles flown): "
                    "motor_map.py --vehicles 12 draws the same")
    ap.add_argument("--prior", default="wide_actuators")
    ap.add_argument("--seed", type=int, default=12)
    ap.add_argument("--flight", default="hover:8")
    a = ap.parse_args()
    import jax
    from mjxsysid import theta as P
    from mjxsysid.experiments.posterior_calibration import parse_reference
    from mjxsysid.identify import log_grounded_posterior
    from mjxsysid.identify import logspace as L
    from mjxsysid.identify.calibrate import raw_bands
    from mjxsysid.identify.coords import PHYSICAL_PRIOR, visible_from_theta
    from mjxsysid.identify.logdata import prepare
    from mjxsysid.identify.mode import _laplace, _ls_jacobian
    from mjxsysid.rollout.flight import flight_log, fly_vehicles
    from mjxsysid.sim import Quadrotor, SimConfig
    from mjxsysid.uses.imu_noise import LEVELS
    th = np.asarray(P.get_prior(a.prior).sample(jax.random.PRNGKey(a.seed), max(a.of, a.vehicles)))[:a.vehicles]
    fl, m, _ = fly_vehicles(th, controller="oracle", sim=Quadrotor(SimConfig(**LEVELS["clean"])), seed=a.seed,
                            **parse_reference(a.flight))
    j = L.LOG_AUTH_X
    print("| vehicle | A_x truth / median | raw 90 % band (log width) | Laplace 90 % (log width) | "
          "profile Δll at the truth | profile range within 1.35 nats (log width) |")
    print("|---|---|---|---|---|---|")
    for i in np.flatnonzero(~np.asarray(m["failed"], bool)):
        d = prepare(flight_log(fl.frame, i))
        post = log_grounded_posterior(d, refine=False, calibration=None, seed=int(i))
        tv = float(np.asarray(visible_from_theta(th[i][None]))[0, j])
        b = raw_bands(post["v_raw"])[:, j]
        mode = np.asarray(post["mode"], np.float32)
        zm = L.z_from_y(L.y_from_x(mode))
        lap = _laplace(L.y_from_x(mode), np.asarray(_ls_jacobian(zm, (d, mode[L.X_LOG_DISCREPANCY],
                                                                      mode[L.X_LOG_NOISE]), post["weights"])),
                       d, PHYSICAL_PRIOR)
        sd = float(np.sqrt((lap.chol @ lap.chol.T)[j, j])) / 2.0          # without LAPLACE_WIDEN
        grid = np.unique(np.r_[np.linspace(min(tv, mode[j]) - 0.3, max(tv, mode[j]) + 0.3, 15), tv])
        prof = profile(d, mode, post["weights"], j, grid)
        inside = grid[prof >= prof.max() - 1.35]
        print(f"| {i} | {np.exp(b[1] - tv):.2f} | {b[0]:.3f}–{b[2]:.3f} ({b[2] - b[0]:.3f}) | ±{1.645 * sd:.3f} "
              f"({3.29 * sd:.3f}) | {prof[grid == tv][0] - prof.max():+.2f} | {inside.min():.3f}–{inside.max():.3f} "
              f"({inside.max() - inside.min():.3f}{', the grid' if len(inside) == len(grid) else ''}) |", flush=True)


if __name__ == "__main__":
    main()
