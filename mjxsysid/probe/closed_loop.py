"""The probe's score and the probe itself.

Badness of a latent z: decode it into ``samples`` physical systems (the policy's CFM), fly each
with the policy and with the oracle (K_θ with its own θ) on the probe's reference, and average
over the systems: a policy failure counts ``fail_badness``; otherwise the policy's position RMSE
over the oracle's (1 = as good as the oracle). A system the oracle cannot fly either counts
``infeasible_badness`` (0 by default): nothing shows the policy is weak there, and training on
systems no controller flies only costs the next policy. Latents whose decoded systems the
policy flies much worse than the oracle are weak regions; the systems written to ``weak.npz``
are those the oracle flies.

How the probe reaches past the policy's training prior: the decoders are trained on a wider prior
than the policy (``wide_actuators``: τ_m up to 0.10 s against the policy's 0.02-0.04 s), so a
latent can decode into slower motors than the policy was trained on; and stretches of the
anchors (s up to ``stretch_max``) move latents beyond those of the prior's vehicles, where the
decoder extrapolates its θ within the support it was trained on.
"""
from __future__ import annotations

import dataclasses
import json
import time
from pathlib import Path
from typing import Callable

import jax
import numpy as np

from mjxsysid.runtime import jsonout
from mjxsysid import theta as P
from mjxsysid.cfm.load import load_decoders
from mjxsysid.dataset.collect import latents_in_flight
from mjxsysid.policy.adaptive.focus import save_weak
from mjxsysid.policy.interface import resolve_policy
from mjxsysid.probe.search import SearchConfig, latent_search
from mjxsysid.render.probe import QUANTITIES, plot_weak_vs_prior, quantities
from mjxsysid.rollout.flight import fly_vehicles

REFERENCES = ("lemniscate", "minsnap", "force_step")


@dataclasses.dataclass(frozen=True)
class ProbeConfig:
    """reference: what the decoded systems fly (lemniscate of ``period`` s, a random min-snap, or
    hover with a [1, 1, 0] N × m / m_paper force step at 1 s), ``duration`` s; samples: decoded
    systems per latent; anchors: prior vehicles whose latents (after ``anchor_steps`` control
    steps of the decoders' data flight) anchor the search; weak_samples:
    decoded systems per weak latent written to weak.npz; fail_badness: what a policy failure
    counts (an RMSE ratio otherwise)."""
    reference: str = "lemniscate"
    period: float = 5.0
    duration: float = 5.0
    samples: int = 8
    anchors: int = 256
    anchor_steps: int = 750
    prior: str = "default"
    weak_samples: int = 16
    fail_badness: float = 5.0
    infeasible_badness: float = 0.0
    seed: int = 0
    search: SearchConfig = SearchConfig()

    def __post_init__(self):
        if self.reference not in REFERENCES:
            raise ValueError(f"unknown probe reference {self.reference!r}; choose from {REFERENCES}")
        if not (self.period > 0 and self.duration > 0):
            raise ValueError("period and duration must be > 0 s")
        if self.samples < 1 or self.anchors < 2 or self.weak_samples < 1:
            raise ValueError("samples >= 1, anchors >= 2 and weak_samples >= 1 required")

    @classmethod
    def quick(cls, **kw) -> "ProbeConfig":
        """Minutes on a CPU: 2 s flights, 2 systems per latent, 8 candidates × 2 iterations."""
        base = dict(period=5.0, duration=2.0, samples=2, anchors=16, anchor_steps=150, weak_samples=4,
                    search=SearchConfig(population=8, iterations=2, keep=4))
        return cls(**{**base, **kw})


def closed_loop_badness(zs, *, decoder, key, samples: int, fly: Callable, fail_badness: float = 5.0,
                        infeasible_badness: float = 0.0):
    """zs (N, z_dim) -> badness (N,) and the decoded systems θ (N, samples, 19). ``fly``:
    θ (n, 19) -> (policy failed (n,), policy RMSE (n,), oracle RMSE (n,), NaN where the oracle
    failed). A system the oracle fails on counts ``infeasible_badness``, whatever the policy did
    (no oracle to compare with)."""
    zs = np.asarray(zs, np.float32)
    th = np.asarray(decoder.sample_theta(zs, key, samples))                    # (N, S, 19)
    flat, _ = P.project_valid(th.reshape(-1, P.N_PARAMS))
    bad = system_badness(*fly(np.asarray(flat, np.float32)), fail_badness=fail_badness,
                         infeasible_badness=infeasible_badness).reshape(len(zs), samples)
    return bad.mean(1), np.asarray(flat).reshape(th.shape)


def system_badness(failed, rmse_policy, rmse_oracle, *, fail_badness: float = 5.0,
                   infeasible_badness: float = 0.0) -> np.ndarray:
    """Per system (n,): ``infeasible_badness`` where the oracle failed (its RMSE NaN), else
    ``fail_badness`` where the policy failed, else the policy's RMSE over the oracle's."""
    failed, rmse_p, rmse_o = (np.asarray(a, np.float64) for a in (failed, rmse_policy, rmse_oracle))
    flown = np.isfinite(rmse_o)
    ratio = rmse_p / np.maximum(np.where(flown, rmse_o, 1.0), 1e-3)
    return np.where(~flown, infeasible_badness, np.where(failed > 0.5, fail_badness, ratio))


def make_fly(policy, cfg: ProbeConfig) -> Callable:
    """The probe's flights: θ (n, 19) with the resolved ``policy`` and with the oracle."""
    ref = "hover" if cfg.reference == "force_step" else cfg.reference

    def fly(theta):
        kw = dict(reference=ref, period=cfg.period, duration=cfg.duration, seed=cfg.seed)
        if cfg.reference == "force_step":
            # [1, 1, 0] N × m / m_paper per vehicle: the same acceleration for every system
            kw.update(force_step=np.array([1.0, 1.0, 0.0]) * theta[:, P.MASS, None] / P.PAPER_HARDWARE[P.MASS],
                      force_step_time=1.0)
        _, mp, _ = fly_vehicles(theta, controller="policy", policy=policy, **kw)
        _, mo, _ = fly_vehicles(theta, controller="oracle", **kw)
        rmse_o = np.where(np.asarray(mo["failed"]) > 0.5, np.nan, np.asarray(mo["pos_rmse_m"]))
        return np.asarray(mp["failed"]), np.asarray(mp["pos_rmse_m"]), rmse_o

    return fly


def run_probe(out, cfg: ProbeConfig = ProbeConfig(), *, policy="mjxsysid", weights=None, decoders=None,
              echo=print) -> dict:
    """Probe a frozen policy: anchors (latents of ``cfg.anchors`` prior vehicles flown with it),
    the latent search with the closed-loop badness, then out/weak.npz (the weak latents'
    decoded systems), results.json / results.md and weak_vs_prior.png."""
    t0 = time.time()
    out = Path(out)
    ref = resolve_policy(policy, weights)
    cfm, _ = load_decoders(decoders, ref, warn=echo)
    out.mkdir(parents=True, exist_ok=True)
    key = jax.random.PRNGKey(cfg.seed)
    prior = P.get_prior(cfg.prior)
    theta_a = np.asarray(prior.sample(jax.random.fold_in(key, 1), cfg.anchors))
    z_a, failed_a = latents_in_flight(ref, theta_a, jax.random.fold_in(key, 2), steps=cfg.anchor_steps)
    anchors = z_a[~failed_a]
    if len(anchors) < 2:
        raise RuntimeError(f"probe: the policy lost {int(failed_a.sum())} of the {cfg.anchors} anchor flights; "
                           f"too few latents to anchor the search")
    echo(f"probe: {len(anchors)} anchor latents of {cfg.anchors} prior vehicles; searching "
         f"{cfg.search.iterations} × {cfg.search.population} candidates × {cfg.samples} decoded systems")
    fly = make_fly(ref, cfg)
    calls = [0]

    def score(z):
        calls[0] += 1
        return closed_loop_badness(z, decoder=cfm, key=jax.random.fold_in(key, 100 + calls[0]), samples=cfg.samples,
                                   fly=fly, fail_badness=cfg.fail_badness,
                                   infeasible_badness=cfg.infeasible_badness)[0]

    base = score(anchors[np.random.default_rng(cfg.seed).integers(0, len(anchors), cfg.search.population)])
    res = latent_search(score, anchors, cfg.search,
                        progress=lambda it, best: echo(f"  iteration {it + 1}/{cfg.search.iterations}: best badness {best:.2f}"))
    weak_theta = np.asarray(cfm.sample_theta(res["z"], jax.random.fold_in(key, 3), cfg.weak_samples))
    weak_theta, _ = P.project_valid(weak_theta.reshape(-1, P.N_PARAMS))
    weak_z = np.repeat(res["z"], cfg.weak_samples, 0)
    failed_w, _, rmse_ow = fly(np.asarray(weak_theta, np.float32))    # keep what the oracle flies
    flyable = np.isfinite(np.asarray(rmse_ow))
    if not flyable.any():
        raise RuntimeError(f"probe: the oracle flies none of the {len(weak_theta)} decoded weak systems; "
                           f"nothing to train on (try another --reference or more --samples)")
    lost = int((np.asarray(failed_w)[flyable] > 0.5).sum())
    echo(f"probe: {int(flyable.sum())} of {len(weak_theta)} decoded weak systems are flown by the oracle; "
         f"the policy loses {lost} of those")
    weak_theta, weak_z = np.asarray(weak_theta)[flyable], weak_z[flyable]
    meta = {"found_by": "mjxsysid probe", "policy": ref.label, "config": _jsonable(dataclasses.asdict(cfg)),
            "badness": res["score"].tolist()}
    save_weak(out / "weak.npz", weak_theta, zhat=weak_z, meta=meta)
    prior_theta = np.asarray(prior.sample(jax.random.fold_in(key, 4), 4000))
    plot_weak_vs_prior(weak_theta, prior_theta, out / "weak_vs_prior.png")
    qw, qp = quantities(weak_theta), quantities(prior_theta)
    summary = {name: {"weak_median": float(np.median(qw[:, j])), "weak_q05": float(np.percentile(qw[:, j], 5)),
                      "weak_q95": float(np.percentile(qw[:, j], 95)), "prior_median": float(np.median(qp[:, j])),
                      "prior_q05": float(np.percentile(qp[:, j], 5)), "prior_q95": float(np.percentile(qp[:, j], 95))}
               for j, name in enumerate(QUANTITIES)}
    result = {"config": meta["config"], "policy": ref.label, "anchors_flown": int(cfg.anchors),
              "anchors_used": int(len(anchors)), "anchor_badness_mean": float(np.mean(base)),
              "weak_badness": res["score"].tolist(), "history": res["history"], "weak_systems": int(len(weak_theta)),
              "weak_decoded": int(len(flyable)), "weak_policy_failures": lost,
              "quantities": summary, "device": str(jax.devices()[0]), "wall_s": time.time() - t0}
    (out / "results.json").write_text(jsonout.dumps(result, indent=1) + "\n")
    (out / "results.md").write_text(_markdown(result))
    return result


def _jsonable(d):
    return json.loads(json.dumps(d, default=lambda o: list(o) if isinstance(o, tuple) else str(o)))


def _markdown(r: dict) -> str:
    lines = ["# probe", "", f"{r['policy']}; {r['anchors_used']} anchor latents; {r['wall_s']:.0f} s on {r['device']}", "",
             f"Badness (policy RMSE / oracle RMSE over the decoded systems; a policy failure counts "
             f"{r['config']['fail_badness']}): anchors {r['anchor_badness_mean']:.2f} on average, the weak latents "
             f"{', '.join(f'{b:.2f}' for b in r['weak_badness'][:8])}. A system the oracle cannot fly counts "
             f"{r['config']['infeasible_badness']}. Decoded weak systems: {r['weak_decoded']}, of which the oracle "
             f"flies {r['weak_systems']} (kept; the policy loses {r['weak_policy_failures']} of them).", "",
             "| quantity | weak systems: median (5–95 %) | training prior: median (5–95 %) |", "|---|---|---|"]
    for name, q in r["quantities"].items():
        lines.append(f"| {name} | {q['weak_median']:.3g} ({q['weak_q05']:.3g} – {q['weak_q95']:.3g}) "
                     f"| {q['prior_median']:.3g} ({q['prior_q05']:.3g} – {q['prior_q95']:.3g}) |")
    lines += ["", "`weak.npz`: the decoded weak systems, input of `mjxsysid train-policy --focus`. Picture: weak_vs_prior.png.", ""]
    return "\n".join(lines)
