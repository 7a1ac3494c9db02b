"""`mjxsysid experiment probe-loop`: probe → retrain → evaluate → probe again.

1. Evaluate the given policy (default: the shipped one) against the oracle (K_θ with the true θ)
   on (a) the default prior, (b) the stress prior (``theta.STRESS_PRIOR``: thrust-to-weight
   1.5–2.5, τ_m 0.04–0.06 s, η down to 0.5, 2× the roll/pitch external torque), (c) the paper
   vehicle and (d) the first, wider stress prior (``stress_wide``: τ_m to 0.12 s, where the
   fixed-gain oracle itself fails; reported both ways), each flying a 10 s lemniscate; and the
   latent's linear-probe R² on the default prior (thrust-to-weight, angular authority).
2. Round 1: probe it (:func:`mjxsysid.probe.run_probe`) -> ``probe/weak.npz`` (decoded systems
   the oracle flies), and train a policy afresh with the same config and budget as the shipped
   one, a fraction ``focus_weight`` of episodes on those systems (``probed``).
3. Round r = 2..``rounds``: decoders for round r − 1's policy (collect + train + calibration, the
   shipped protocol), probe that policy with them (``probe_round{r}``), and train the next
   policy (``probed{r}``) on the weak systems of rounds 1..r together.
4. The control (``uniform``): the same config and budget, the same fraction of episodes on
   systems drawn uniformly from the stress prior, without probing — so the table shows what
   probing adds over naive widening.
5. Every policy evaluated like the given one and on every round's weak systems; decoders for
   the last policy and one more probe of it (do the weak regions shrink or soften?).

**Accumulating variant** (``LoopConfig.accumulate``, ``--variant accumulate``): each round
fine-tunes the current policy (warm start from its weights, ``TrainConfig.init_from``) instead of
training afresh, on a mixture of the default prior and a replay buffer of every round's weak
systems, each drawn with probability ∝ how badly the current policy flies it (its badness, re-scored
every round on the probe's reference: ``replay_round{r}.json`` holds the scores,
``replay_round{r}.npz`` the ``replay_draws`` weighted draws training reads). The control is
unchanged (trained afresh, one budget).

Success: the fraction of vehicles the policy did not lose. RMSE ratio: the policy's mean
position RMSE over the oracle's, on the vehicles both flew to the end.

Every stage writes its result under OUT before the next starts; a rerun with the same OUT and
config reuses what is there (training resumes from its checkpoint), so the loop can be run in
pieces (e.g. across GPU sessions of 10 minutes).
"""
from __future__ import annotations

import dataclasses
import json
import sys
import time
from pathlib import Path

import jax
import numpy as np

from mjxsysid.runtime import jsonout
from mjxsysid import theta as P
from mjxsysid.cfm.pipeline import WITHIN_5_POINTS, evaluate_decoders, train_decoders
from mjxsysid.cfm.train import CFMConfig
from mjxsysid.dataset.collect import collect, latents_in_flight
from mjxsysid.experiments.common import fmt_ms, markdown_table, to_jsonable, write_results
from mjxsysid.experiments.heldout import compare_with_oracle
from mjxsysid.policy.adaptive.config import EnvConfig, TrainConfig
from mjxsysid.policy.adaptive.env import TrainEnv
from mjxsysid.policy.adaptive.evaluate import env_rollout, latent_of_rollout
from mjxsysid.policy.adaptive.focus import load_weak, replay_resample, save_weak
from mjxsysid.policy.adaptive.losses import IDENT_TARGET_NAMES, identifiable_log
from mjxsysid.policy.adaptive.train import train
from mjxsysid.policy.interface import resolve_policy
from mjxsysid.probe import ProbeConfig, make_fly, run_probe, system_badness
from mjxsysid.render.probe import plot_probe_loop
from mjxsysid.rollout.flight import fly_vehicles

SETS = ("default", "stress", "paper", "stress_wide")


@dataclasses.dataclass(frozen=True)
class LoopConfig:
    """vehicles: per evaluation set (the paper vehicle is one); period: the lemniscate (s);
    focus_weight: the fraction of training episodes on weak (or, for the control, stress-prior)
    systems; control_systems: how many stress-prior systems the control draws; train: overrides
    of the shipped TrainConfig (the budget: iterations, num_envs, ...); latent_vehicles: vehicles
    of the latent probe (0: skip);
    rounds: probe → retrain rounds (round r > 1 probes round r − 1's policy with decoders trained
    for it); final_probe: decoders for the last policy and one more probe of it (fewer or
    milder weak regions?); pairs: (train, test) pairs collected for those decoders, ẑ read
    after collect_steps control steps (the shipped decoders': 750, 1.5 s); decoder: overrides
    of CFMConfig; accumulate: each round fine-tunes the current policy on a replay buffer of
    every round's weak systems weighted by the current policy's badness on each (module notes),
    replay_draws of them written for training."""
    vehicles: int = 1000
    period: float = 10.0
    focus_weight: float = 0.3
    control_systems: int = 4096
    probe: ProbeConfig = ProbeConfig()
    train: tuple = ()
    latent_vehicles: int = 1000
    rounds: int = 3
    final_probe: bool = True
    pairs: tuple = (20_000, 2_000)
    collect_steps: int = 750
    decoder: tuple = ()
    accumulate: bool = False
    replay_draws: int = 4096
    widened: bool = False


VARIANTS = ("accumulate", "widened")
"""``accumulate``: each round fine-tunes the current policy on a re-scored replay buffer;
``widened``: a second control, the default prior widened in every direction by as far as the
probe reached (:func:`probe_reach`, :func:`mjxsysid.theta.widened_prior`), trained with the
probed policy's whole budget (a fair control: it knows nothing of where the policy is weak)."""
FULL = LoopConfig()
QUICK = LoopConfig(vehicles=8, period=5.0, control_systems=64, probe=ProbeConfig.quick(),
                   train=(("iterations", 4), ("num_envs", 64), ("unroll", 16), ("epochs", 2), ("minibatches", 4),
                          ("log_every", 1), ("checkpoint_every", 2)),
                   latent_vehicles=64, pairs=(256, 64), collect_steps=150, decoder=(("epochs", 2), ("width", 64), ("blocks", 2)))


def train_config(cfg: LoopConfig, seed: int, focus=None, init_from=None, iterations: int | None = None) -> TrainConfig:
    """What every policy of the loop is trained with: the shipped TrainConfig with ``cfg.train``'s
    overrides, ``seed``, and a fraction ``cfg.focus_weight`` of episodes on the systems of the
    weak-system file ``focus``; ``init_from``: the policy.npz it starts from (None: afresh);
    ``iterations``: another length than the config's (the widened control's whole budget)."""
    over = {} if iterations is None else {"iterations": int(iterations)}
    base = TrainConfig.from_dict({**TrainConfig().to_dict(), **dict(cfg.train), "seed": seed,
                                  "focus": None if focus is None else str(focus),
                                  "init_from": None if init_from is None else str(init_from), **over})
    return dataclasses.replace(base, env=dataclasses.replace(base.env, focus_weight=cfg.focus_weight))


REACH_QUANTILE = 0.05
"""Systems' tails (5 % and 95 %) that :func:`probe_reach` compares with the prior's extremes."""


def probe_reach(systems, prior="default", n: int = 20_000, seed: int = 0) -> dict:
    """How far (natural-log units) the probe's systems (n, 19) reach past ``prior`` along what a
    flight reveals — log thrust-to-weight, log κ, log angular authorities, log τ_m: per quantity the
    larger of (the prior's minimum − the systems' 5 % quantile) and (their 95 % quantile − the
    prior's maximum), 0 where they stay inside; ``amount``: the largest, the widening of
    :func:`mjxsysid.theta.widened_prior` for the fair control."""
    systems = np.asarray(systems, np.float64)
    if systems.ndim != 2 or systems.shape[1] != P.N_PARAMS or len(systems) == 0:
        raise ValueError(f"probe_reach: systems must have shape (n, {P.N_PARAMS}), n >= 1; got {systems.shape}")
    ref = np.asarray(identifiable_log(P.get_prior(prior).sample(jax.random.PRNGKey(seed), n)))
    got = np.asarray(identifiable_log(systems.astype(np.float32)))
    lo = ref.min(0) - np.quantile(got, REACH_QUANTILE, axis=0)
    hi = np.quantile(got, 1 - REACH_QUANTILE, axis=0) - ref.max(0)
    per = np.maximum(0.0, np.maximum(lo, hi))
    names = [n.removeprefix("log_") for n in IDENT_TARGET_NAMES]
    return {"per_quantity": dict(zip(names, per.tolist())), "amount": float(per.max()), "systems": len(systems)}


def control_budget(cfg: LoopConfig, base: TrainConfig, given_weights) -> tuple[int, str | None]:
    """(iterations, init_from) of the widened control: the last probed policy's whole training —
    ``rounds`` fine-tunes of ``base.iterations`` from the given policy (``accumulate``), or one
    training of ``base.iterations`` from scratch."""
    if cfg.accumulate:
        return base.iterations * cfg.rounds, str(given_weights)
    return base.iterations, None


def evaluate_on(policy, theta, *, period: float, seed: int = 0) -> dict:
    """The policy and the oracle on θ (n, 19), a ``period`` s lemniscate, one period
    (:func:`~mjxsysid.experiments.heldout.compare_with_oracle`)."""
    _, mp, _ = fly_vehicles(theta, controller="policy", policy=policy, reference="lemniscate", period=period, seed=seed)
    _, mo, _ = fly_vehicles(theta, controller="oracle", reference="lemniscate", period=period, seed=seed)
    return compare_with_oracle(mp, mo)


def latent_probe(policy, n: int, seed: int = 0, steps: int = 1000) -> dict | None:
    """Linear-probe R² of the policy's latent on ``n`` default-prior vehicles flying the training
    commands (as ``mjxsysid evaluate-policy``); None for a policy not trained by mjxsysid."""
    if policy.kind != "mjxsysid" or n < 8:
        return None
    env = TrainEnv(EnvConfig(episode_steps=steps + 1))
    lat = latent_of_rollout(env_rollout(env, policy.load().params, jax.random.PRNGKey(seed), n, steps, False))
    idn = lat["probe_r2_identifiable"]
    return {"r2_thrust_to_weight": idn["nominal_thrust_to_weight"],
            "r2_authority": float(np.mean([idn[f"angular_authority[{i}]"] for i in range(3)])),
            "r2_tau_m": lat["probe_r2_theta"]["motor_time_constant"], "z_err_rel": lat["z_err_rel"]}


def eval_sets(policy, cfg: LoopConfig, seed: int) -> dict:
    key = jax.random.PRNGKey(seed + 17)
    th = {s: np.asarray(P.get_prior(s).sample(jax.random.fold_in(key, i), cfg.vehicles))
          for i, s in enumerate(SETS) if s != "paper"}
    th["paper"] = P.PAPER_HARDWARE[None]
    res = {s: evaluate_on(policy, th[s], period=cfg.period, seed=seed) for s in SETS}
    res["latent"] = latent_probe(policy, cfg.latent_vehicles, seed)
    return res


def badness_of(policy, theta, probe_cfg: ProbeConfig):
    """Per system of θ (n, 19), flown on the probe's reference: the badness (n,)
    (:func:`~mjxsysid.probe.system_badness`), whether the policy failed (n,), whether the oracle flew (n,)."""
    failed, rmse_p, rmse_o = make_fly(policy, probe_cfg)(np.asarray(theta, np.float32))
    bad = system_badness(failed, rmse_p, rmse_o, fail_badness=probe_cfg.fail_badness,
                         infeasible_badness=probe_cfg.infeasible_badness)
    return bad, np.asarray(failed) > 0.5, np.isfinite(np.asarray(rmse_o))


def on_weak_systems(policy, weak_theta, probe_cfg: ProbeConfig) -> dict:
    """The policy on the probe's weak systems (its reference): badness (mean and per system
    summary), how many it loses."""
    bad, failed, flown = badness_of(policy, weak_theta, probe_cfg)
    return {"n": int(len(weak_theta)), "badness_mean": float(bad.mean()), "badness_median": float(np.median(bad)),
            "policy_failures": int(failed[flown].sum()), "oracle_flies": int(flown.sum())}


def replay_focus(policy, buffer, probe_cfg: ProbeConfig, draws: int, seed: int, path) -> dict:
    """Re-score a replay buffer θ (m, 19) under the current ``policy`` (its badness per system)
    and write ``draws`` systems drawn ∝ badness to the focus file ``path``; returns the scores'
    summary (systems no controller flies score 0 and are never drawn)."""
    bad, failed, flown = badness_of(policy, buffer, probe_cfg)
    if not bad.sum() > 0:
        raise ValueError(f"replay buffer of {len(bad)} systems: none has a positive badness (the oracle flies none?)")
    save_weak(path, replay_resample(buffer, bad, draws, seed),
              meta={"found_by": "mjxsysid probe (replay buffer of every round, drawn ∝ badness)",
                    "buffer": int(len(bad)), "scored_by": policy.label})
    return {"badness": bad, "badness_mean": float(bad.mean()), "policy_failures": int(failed[flown].sum()),
            "oracle_flies": int(flown.sum())}


class _Stages:
    """Each stage's result as OUT/stages/NAME.json, reused when there (the loop resumes)."""

    def __init__(self, out: Path, log):
        self.dir, self.log, self.wall = out / "stages", log, {}
        self.dir.mkdir(parents=True, exist_ok=True)

    def __call__(self, name: str, fn):
        path = self.dir / f"{name}.json"
        if path.is_file():
            self.log(f"probe-loop: {name}: reusing {path}")
            rec = json.loads(path.read_text())
        else:
            t = time.time()
            rec = {"result": to_jsonable(fn()), "wall_s": None}
            rec["wall_s"] = time.time() - t
            path.write_text(jsonout.dumps(rec, indent=1) + "\n")
        self.wall[name] = rec["wall_s"]
        return rec["result"]


def _check_config(out: Path, cfg_dict: dict, resume: bool):
    """Refuse to resume a run of another config in ``out`` (LoopConfig keys missing from its
    loop_config.json read as their defaults; the saved probe's seed reads as the loop's seed,
    the one the probe runs on, whatever the file records for it)."""
    path = out / "loop_config.json"
    if path.is_file() and resume:
        saved = json.loads(path.read_text())
        if isinstance(saved.get("probe"), dict) and "seed" in saved:
            saved["probe"] = {**saved["probe"], "seed": saved["seed"]}
        defaults = to_jsonable(dataclasses.asdict(LoopConfig()))
        if {**{k: v for k, v in defaults.items() if k not in saved}, **saved} != cfg_dict:
            raise ValueError(f"{out} holds a probe-loop run with another config or policy; use a new --out")
    else:
        path.write_text(jsonout.dumps(cfg_dict, indent=1) + "\n")


def _pname(r: int) -> str:
    """The round-r probed policy's folder and key: probed, probed2, probed3, ..."""
    return "probed" if r == 1 else f"probed{r}"


def _probe_dir(r: int) -> str:
    """Round r's probe folder (round r probes the policy of round r − 1)."""
    return "probe" if r == 1 else f"probe_round{r}"


def run(out, *, quick: bool = False, policy=None, seed: int = 0, progress: bool = True, decoders=None,
        cfg: LoopConfig | None = None, resume: bool = True, variant: str | None = None) -> dict:
    """``cfg.rounds`` rounds of probe → retrain (each round's policy trained afresh on all weak
    systems found so far; ``variant='accumulate'``: fine-tuned from the current one on the
    re-scored replay buffer), the uniform control, every policy evaluated, and a last probe of the
    last policy with its own decoders; returns the results dict."""
    t0 = time.time()
    out = Path(out)
    log = (lambda m: print(m, file=sys.stderr, flush=True)) if progress else (lambda m: None)
    cfg = cfg or (QUICK if quick else FULL)
    for v in ([] if variant is None else [x.strip() for x in str(variant).split(",") if x.strip()]):
        if v not in VARIANTS:
            raise ValueError(f"probe-loop: unknown variant {v!r}; choose from {VARIANTS}")
        cfg = dataclasses.replace(cfg, **{v: True})
    if cfg.replay_draws < 1:
        raise ValueError(f"replay_draws must be >= 1, got {cfg.replay_draws}")
    if not 0.0 < cfg.focus_weight <= 1.0:
        raise ValueError(f"focus_weight must be in (0, 1], got {cfg.focus_weight}")
    if cfg.rounds < 1:
        raise ValueError(f"rounds must be >= 1, got {cfg.rounds}")
    ref = resolve_policy(policy or "mjxsysid")
    if (cfg.accumulate or cfg.widened) and ref.kind != "mjxsysid":
        raise ValueError(f"probe-loop --variant accumulate/widened trains from or beside the given policy: it must be "
                         f"an mjxsysid policy, got {ref.kind}")
    cfg = dataclasses.replace(cfg, probe=dataclasses.replace(cfg.probe, seed=seed))   # the probe runs on the loop's seed
    cfg_dict = to_jsonable({"quick": quick, "seed": seed, "policy": ref.label, "policy_sha256": ref.sha256(),
                            "decoders": None if decoders is None else str(decoders), **dataclasses.asdict(cfg)})
    out.mkdir(parents=True, exist_ok=True)
    _check_config(out, cfg_dict, resume)
    stage = _Stages(out, log)
    probe_cfg = cfg.probe
    base = train_config(cfg, seed)
    refs, ev, probes, calib, replay = {"given": ref}, {}, {}, {}, {}

    def trained(name: str, focus: Path, init_from=None, iterations=None):
        def _train():
            tc = train_config(cfg, seed, focus, init_from, iterations)
            log(f"probe-loop: training the {name} policy ({tc.iterations} iterations, {cfg.focus_weight:.0%} of "
                f"episodes on {focus.name}{'' if init_from is None else ', from ' + str(init_from)})")
            return train(tc, out / name, log=log)["wall_s"]
        stage(f"train_{name}", _train)
        refs[name] = resolve_policy(out / name / "policy.npz")
        ev[name] = stage(f"eval_{name}", lambda: eval_sets(refs[name], cfg, seed))

    def own_decoders(name: str) -> Path:
        """Decoders for the policy ``name`` (the shipped protocol) and their calibration."""
        dec = out / name / "decoders"
        n_train, n_test = cfg.pairs
        stage(f"pairs_{name}", lambda: str(collect(dec / "data", policy=refs[name], n_train=n_train, n_test=n_test,
                                                   seed=seed, steps=cfg.collect_steps, log=log)))
        dcfg = dataclasses.replace(CFMConfig(), **dict(cfg.decoder))
        stage(f"decoders_{name}", lambda: {k: {kk: v[kk] for kk in ("wall_s", "final_val_loss")} for k, v in
                                           train_decoders(dec / "data", dec, dcfg, kinds=("cfm", "regression"),
                                                          log=log).items()})

        def _calibrate():
            z, _ = latents_in_flight(refs[name], np.repeat(P.PAPER_HARDWARE[None], 2, 0), jax.random.PRNGKey(0))
            rep = evaluate_decoders(dec, dec / "data", paper_zhat=z[0], log=log, n_cases=min(1000, n_test),
                                    n_samples=200)
            return {k: rep[k] for k in ("coverage_identifiable", "coverage_mean", "calibrated_within_5_points",
                                        "energy_score")}
        calib[name] = stage(f"calibration_{name}", _calibrate)
        return dec

    def probed_by(r: int, name: str, dec):
        log(f"probe-loop: probe round {r} ({refs[name].label})")
        probes[r] = stage(_probe_dir(r) if r > 1 else "probe",
                          lambda: run_probe(out / _probe_dir(r), probe_cfg, policy=refs[name], decoders=dec, echo=log))

    log(f"probe-loop: evaluating {ref.label} on {cfg.vehicles} vehicles of each set")
    ev["given"] = stage("eval_given", lambda: eval_sets(ref, cfg, seed))
    prev, weak_sets = "given", []
    for r in range(1, cfg.rounds + 1):
        probed_by(r, prev, decoders if r == 1 else own_decoders(prev))
        weak_sets.append(load_weak(out / _probe_dir(r) / "weak.npz")[0])
        focus = out / _probe_dir(r) / "weak.npz"
        if cfg.accumulate:  # fine-tune the current policy on every round's systems, re-scored under it
            buf, path = np.concatenate(weak_sets), out / f"replay_round{r}.npz"
            replay[r] = stage(f"replay_round{r}", lambda: replay_focus(refs[prev], buf, probe_cfg, cfg.replay_draws,
                                                                       seed + r, path))
            trained(_pname(r), path, init_from=refs[prev].weights)
            prev = _pname(r)
            continue
        if r > 1:   # the weak systems of every round so far: the next policy must not forget the earlier ones
            focus = save_weak(out / f"focus_round{r}.npz", np.concatenate(weak_sets),
                              meta={"found_by": f"mjxsysid probe, rounds 1-{r}"})
        trained(_pname(r), focus)
        prev = _pname(r)
    stress = np.asarray(P.get_prior("stress").sample(jax.random.PRNGKey(seed + 29), cfg.control_systems))
    save_weak(out / "uniform_stress.npz", stress, meta={"found_by": "uniform draws of the stress prior (control)"})
    trained("uniform", out / "uniform_stress.npz")
    reach = None
    if cfg.widened:   # the fair control: as far as the probe reached, in every direction, with the same budget
        reach = stage("probe_reach", lambda: probe_reach(np.concatenate(weak_sets), seed=seed))
        wide = P.widened_prior(P.DEFAULT_PRIOR, reach["amount"])
        draws = np.asarray(wide.sample(jax.random.PRNGKey(seed + 31), cfg.control_systems))
        save_weak(out / "widened_default.npz", draws,
                  meta={"found_by": f"uniform draws of the default prior widened by {reach['amount']:.3f} (log) in every "
                                    "direction: the probe's reach (fair control)"})
        iters, init = control_budget(cfg, base, ref.weights)
        trained("widened", out / "widened_default.npz", init_from=init, iterations=iters)
    on_weak = {r: {p: stage(f"weak_{p}" if r == 1 else f"weak{r}_{p}",
                            lambda p=p, r=r: on_weak_systems(refs[p], weak_sets[r - 1], probe_cfg)) for p in refs}
               for r in range(1, cfg.rounds + 1)}
    if cfg.final_probe:
        probed_by(cfg.rounds + 1, prev, own_decoders(prev))

    final = _pname(cfg.rounds)
    numbers = {"evaluation": ev, "final_policy": final, "probes": {r: _probe_summary(p) for r, p in probes.items()},
               "calibration": calib, "on_weak_systems": on_weak, "stage_wall_s": stage.wall}
    if reach is not None:
        numbers["probe_reach"] = reach
    if replay:
        numbers["replay"] = {r: {k: v for k, v in rec.items() if k != "badness"} for r, rec in replay.items()}
    numbers["headline"] = {f"{p}_{s}_rmse_ratio": ev[p][s]["rmse_ratio"] for p in ev for s in ("default", "stress")}
    numbers["headline"].update({f"{p}_stress_success": ev[p]["stress"]["success_policy"] for p in ev})
    numbers["targets"] = _targets(ev, final, calib.get(final))
    plot_probe_loop(ev, on_weak, out / "probe_loop.png")
    return write_results(out, "probe-loop", config=cfg_dict, seeds={"seed": seed}, numbers=numbers,
                         table_md=_table(ev, ref.label, on_weak, probes, calib, cfg.rounds), t0=t0, policy=ref,
                         notes=_notes(numbers, base, cfg))


def _probe_summary(p: dict) -> dict:
    return {k: p.get(k) for k in ("anchor_badness_mean", "weak_badness", "weak_systems", "weak_decoded",
                                  "weak_policy_failures", "quantities", "wall_s")}


def _ratio(e):
    return np.inf if e["rmse_ratio"] is None else e["rmse_ratio"]


def _targets(ev: dict, final: str, calib: dict | None) -> dict:
    pr, un = ev[final], ev["uniform"]
    t = {"stress_success_ge_0.99": pr["stress"]["success_policy"] >= 0.99,
         "stress_rmse_le_1.3x_oracle": _ratio(pr["stress"]) <= 1.3,
         "probed_beats_uniform_on_stress": _ratio(pr["stress"]) < _ratio(un["stress"]),
         "default_success_ge_0.99": pr["default"]["success_policy"] >= 0.99,
         "default_rmse_le_1.05x_oracle": _ratio(pr["default"]) <= 1.05}
    if "widened" in ev:
        t["probed_beats_widened_on_stress"] = _ratio(pr["stress"]) < _ratio(ev["widened"]["stress"])
    if pr.get("latent"):
        t["default_twr_r2_ge_0.9"] = pr["latent"]["r2_thrust_to_weight"] >= 0.9
    if calib:
        cov = calib["coverage_identifiable"]
        t["decoders_identifiable_90pct_within_5_points"] = all(abs(v[1] - 0.9) <= WITHIN_5_POINTS for v in cov.values())
    return t


def _label(p: str, given: str) -> str:
    if p == "given":
        return f"given ({given})"
    if p == "uniform":
        return "stress-prior draws (control that knows the test)"
    if p == "widened":
        return "default prior widened by the probe's reach (fair control, same budget)"
    r = 1 if p == "probed" else int(p[len("probed"):])
    return f"probed + retrained, round {r}"


def _table(ev, label, on_weak, probes, calib, rounds) -> str:
    rows = []
    for p in ev:
        for s in SETS:
            e = ev[p][s]
            rows.append([_label(p, label), s, f"{e['success_policy']:.1%} (oracle {e['success_oracle']:.1%})",
                         fmt_ms(e["pos_rmse_policy"]), fmt_ms(e["pos_rmse_oracle"]),
                         "–" if e["rmse_ratio"] is None else f"{e['rmse_ratio']:.2f}×"])
    md = markdown_table(["policy", "vehicles", "success", "pos RMSE m (both flew)", "oracle pos RMSE m", "ratio"], rows)
    rows = []
    for p in ev:
        lat = ev[p].get("latent")
        rows.append([_label(p, label), "–" if not lat else f"{lat['r2_thrust_to_weight']:.3f}",
                     "–" if not lat else f"{lat['r2_authority']:.3f}"]
                    + [f"{on_weak[r][p]['badness_mean']:.2f} ({on_weak[r][p]['policy_failures']}/"
                       f"{on_weak[r][p]['oracle_flies']} lost)" for r in sorted(on_weak)])
    md += ("\n\nLatent (default prior, training commands), and each policy on each probe round's weak systems "
           "(mean badness; lost of those the oracle flies):\n\n")
    md += markdown_table(["policy", "R² thrust-to-weight", "R² angular authority"]
                         + [f"round-{r} weak systems" for r in sorted(on_weak)], rows)
    rows = []
    for r, pr in sorted(probes.items()):
        who = "given" if r == 1 else _pname(r - 1)
        q = pr["quantities"]
        rows.append([str(r), _label(who, label), f"{pr['anchor_badness_mean']:.2f}", _first(pr["weak_badness"]),
                     f"{pr['weak_systems']}/{pr.get('weak_decoded', pr['weak_systems'])}",
                     f"{q['thrust-to-weight']['weak_median']:.2f}", f"{q['motor time constant τ_m (s)']['weak_median']:.3f}",
                     f"{q['weakest motor η_min']['weak_median']:.2f}", f"{q['mass (kg)']['weak_median']:.3f}"])
    md += "\n\nProbe rounds (same search budget; round r > 1 with the probed policy's own decoders):\n\n"
    md += markdown_table(["round", "policy probed", "anchors' badness", "best weak latents", "weak systems kept",
                          "T/W (median)", "τ_m s", "η_min", "mass kg"], rows)
    if calib:
        md += "\n\nDecoders of the probed policies (the shipped protocol; the shipped decoders: 0.858 / 0.925 / " \
              "0.847 / 0.846 / 0.853, 19/19):\n\n"
        md += markdown_table(["policy", "90 % coverage: T/W, κ, authority x/y/z", "parameters within ±5 points at 90 %"],
                             [[_label(p, label), " / ".join(f"{v[1]:.3f}" for v in c["coverage_identifiable"].values()),
                               f"{c['calibrated_within_5_points']['90%']}/{c['calibrated_within_5_points']['of']}"]
                              for p, c in calib.items()])
    return md + "\n"


def _first(b, k=4):
    return ", ".join(f"{x:.2f}" for x in b[:k])


def _notes(numbers, base, cfg) -> str:
    how = ("round r fine-tuned from round r − 1's policy (round 1 from the given one) on a replay buffer of the weak "
           "systems of rounds 1..r, drawn ∝ the current policy's badness on each; control: uniform stress-prior draws, "
           "trained from scratch" if cfg.accumulate else
           "round r: the decoded weak systems of rounds 1..r that the oracle flies; control: uniform stress-prior "
           "draws; every one trained from scratch")
    return (f"Every retrained policy: the shipped config, {base.iterations} iterations × {base.num_envs} envs, "
            f"{cfg.focus_weight:.0%} of episodes on its systems ({how}). Targets (for "
            f"{numbers['final_policy']}): "
            + ", ".join(f"{k} {'met' if v else 'missed'}" for k, v in numbers["targets"].items()) + ".")
