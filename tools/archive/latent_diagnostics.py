"""CPU diagnostics behind the latent trials (issue 11 §2): where the vehicle information is lost.

    python tools/latent_diagnostics.py --out docs/runs/policy/latent_diagnostics.json [--policy P.npz ...]

1. Linear probes from μ's latent z^θ = μ(θ_norm) (no flight, 5,000 prior vehicles) and, as the
   ceiling, from θ_norm itself, to log T/W, log κ, log angular authority (3), log τ_m.
2. The same probes from the best 8-d *linear* compression of θ_norm (its top 8 principal
   components): what a latent shaped by the 19-entry reconstruction loss can be expected to keep.
3. Probes from ẑ after 1.4 s of the training commands (600 vehicles) to log κ, to the yaw-axis
   authority κ k_t Ω_max² / J_zz that the yaw response actually shows, and to log T/W.
"""
from __future__ import annotations

import argparse
import json
from pathlib import Path

import jax
import jax.numpy as jnp
import numpy as np

from mjxsysid import theta as P
from mjxsysid.policy.adaptive import networks as N
from mjxsysid.policy.adaptive.config import EnvConfig
from mjxsysid.policy.adaptive.env import TrainEnv
from mjxsysid.policy.adaptive.evaluate import env_rollout, linear_probe_r2
from mjxsysid.policy.adaptive.losses import IDENT_TARGET_NAMES, identifiable_log
from mjxsysid.policy.adaptive.weights import load_policy_params


def main(argv=None) -> int:
    ap = argparse.ArgumentParser()
    ap.add_argument("--out", type=Path, required=True)
    ap.add_argument("--policy", type=Path, nargs="+",
                    default=[Path("mjxsysid/pretrained/policy.npz"),
                             Path("docs/runs/archive/latent_trials/latent_trial_rec_ident_only_policy.npz")])
    args = ap.parse_args(argv)
    r = lambda a: [round(float(x), 3) for x in a]
    out = {"targets": list(IDENT_TARGET_NAMES)}
    th = P.DEFAULT_PRIOR.sample(jax.random.PRNGKey(5), 5000)
    g = np.asarray(identifiable_log(th))
    norm = P.prior_normalizer("default")
    y = np.asarray(norm.normalize(th), np.float64)
    out["probe_from_theta_norm"] = r(linear_probe_r2(y, g))
    yc = y - y.mean(0)
    _, s, vt = np.linalg.svd(yc, full_matrices=False)
    ev = s ** 2 / (s ** 2).sum()
    out["pca_explained_variance"] = r(ev)
    out["probe_from_top8_pcs"] = r(linear_probe_r2(yc @ vt[:8].T, g))
    env = TrainEnv(EnvConfig(episode_steps=701))
    roll = env_rollout  # jitted inside, environments sharded over the devices
    out["policies"] = {}
    for path in args.policy:
        params, meta = load_policy_params(path)
        nz = P.Normalizer(jnp.asarray(meta["normalizer"]["shift"]), jnp.asarray(meta["normalizer"]["scale"]))
        z = np.asarray(N.Networks().encode(params, nz.normalize(th)))
        res = roll(env, params, jax.random.PRNGKey(0), 600, 700, False)
        t = np.asarray(res["theta"], np.float64)
        kt, om, jzz, kap = t[:, P.KT], t[:, P.OMEGA_MAX], t[:, 6], t[:, P.KTAU] / t[:, P.KT]
        tgt = np.stack([np.log(kap), np.log(kap * kt * om ** 2 / jzz), np.log(P.thrust_to_weight(t))], 1)
        out["policies"][str(path)] = {
            "probe_from_z_theta": r(linear_probe_r2(z, g)),
            "probe_from_zhat_training_commands": dict(zip(
                ["log_kappa", "log_yaw_authority_kappa_kt_Om2_over_Jzz", "log_thrust_to_weight"],
                r(linear_probe_r2(np.asarray(res["zhat"]), tgt))))}
        print(path, out["policies"][str(path)], flush=True)
    args.out.write_text(json.dumps(out, indent=1) + "\n")
    print(json.dumps({k: v for k, v in out.items() if k != "policies"}))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
