"""The policy stages: train (or adopt) the policy, and evaluate it."""
from __future__ import annotations

import shutil
from pathlib import Path

from mjxsysid.release.provenance import call
from mjxsysid.release.stages.registry import STAGES, ReleaseView, StageResult


DEFAULT_POLICY_CONFIG = Path(__file__).resolve().parents[1] / "configs" / "policy_release.json"
"""The policy stage's TrainConfig overrides unless a release names its own: the default config
with sensor randomisation (package data)."""
ADOPTED_PROVENANCE = "adopted_policy.json"
"""The adopted policy's provenance JSON, kept by the policy stage of a ``--from-policy`` release."""


def config_path(path) -> Path:
    """The policy config a release trains with: ``path`` as given (absolute, or relative to the
    working directory), or :data:`DEFAULT_POLICY_CONFIG` for None."""
    return DEFAULT_POLICY_CONFIG if path is None else Path(path)


def train_config(rel: ReleaseView) -> dict:
    """The TrainConfig dict the policy stage trains with: the default config with the overrides
    of the release's policy config, and the sizes' ``train`` overrides on top (a tiny release:
    warm-started from the shipped policy unless the config names one)."""
    from mjxsysid.policy.adaptive.config import TrainConfig, config_with_overrides
    cfg = config_with_overrides(config_path(rel.options.policy_config))
    if rel.sizes.train:
        from mjxsysid.policy.interface import PRETRAINED_DIR
        cfg.update(rel.sizes.train, init_from=cfg.get("init_from") or str(PRETRAINED_DIR / "policy.npz"))
    TrainConfig.from_dict(cfg)   # checked here: a bad key fails before anything trains
    return cfg


@STAGES.add(outputs=("policy.npz",), estimate_s=130,
            what="train the policy (train-policy --config), or adopt --from-policy")
def policy(rel: ReleaseView, out: Path) -> StageResult:
    """Train the policy (it checkpoints and resumes itself), or adopt ``options.from_policy``."""
    from mjxsysid.runtime.checkpoint import load_meta
    from mjxsysid.policy.interface import file_sha256
    if rel.options.from_policy:
        src = Path(rel.options.from_policy)
        if not src.is_file():
            raise FileNotFoundError(f"--from-policy: policy weights not found: {src}")
        shutil.copyfile(src, out / "policy.npz")
        if src.with_suffix(".json").is_file():   # how it was trained: kept for the shipped provenance
            shutil.copyfile(src.with_suffix(".json"), out / ADOPTED_PROVENANCE)
        meta = load_meta(out / "policy.npz")
        return StageResult(calls=(call(shutil.copyfile, src=src, dst=out / "policy.npz"),),
                           config={"adopted_from": str(src), "sha256": file_sha256(out / "policy.npz"),
                                   "train_config": meta.get("config")},
                           figures={"trained_wall_s": meta.get("wall_s"), "trained_on": meta.get("device")})
    from mjxsysid.policy.adaptive.config import TrainConfig
    from mjxsysid.policy.adaptive.train import train
    cfg_dict = train_config(rel)
    res = train(TrainConfig.from_dict(cfg_dict), out, resume=True, log=rel.log)
    stats = res["stats"]
    return StageResult(calls=(call(train, cfg=cfg_dict, out_dir=out, resume=True),), config=cfg_dict,
                       figures={"train_wall_s": res["wall_s"], "sha256": file_sha256(out / "policy.npz"),
                                **{k: stats[k] for k in ("reward", "rate_err", "thrust_err", "latent_err_rel",
                                                         "latent_min_std") if k in stats}})


def _previous_policy() -> Path | None:
    from mjxsysid.policy.interface import PRETRAINED_DIR
    p = PRETRAINED_DIR / "policy.npz"
    return p if p.is_file() else None


@STAGES.add(needs=("policy",), outputs=("eval.json", "heldout/results.json"), estimate_s=115,
            what="evaluate-policy (1,000 vehicles) and --held-out against the shipped policy")
def policy_eval(rel: ReleaseView, out: Path) -> StageResult:
    """``evaluate-policy`` at the release size (eval.json) and ``evaluate-policy --held-out`` of
    the release's policy against the shipped (previous) one (heldout/results.*)."""
    from mjxsysid.runtime import jsonout
    from mjxsysid.experiments.heldout import SETS
    from mjxsysid.experiments.heldout import run as heldout_run
    from mjxsysid.policy.adaptive.evaluate import evaluate_policy
    from mjxsysid.policy.interface import file_sha256
    sz = rel.sizes
    ev = evaluate_policy(rel.policy_path, n=sz.eval_vehicles, seed=0, log=rel.log)
    (out / "eval.json").write_text(jsonout.dumps(ev, indent=2) + "\n")
    policies = {"release": str(rel.policy_path)}
    prev = _previous_policy()
    if prev is not None and file_sha256(prev) != file_sha256(rel.policy_path):
        policies["previous"] = str(prev)
    sets = sz.heldout_sets or SETS
    ho = heldout_run(out / "heldout", policies, sets=sets, vehicles=sz.heldout_vehicles,
                     period=sz.heldout_period, seed=0, progress=rel.progress_on())
    lem, lat = ev["lemniscate"], ev["latent"]
    return StageResult(
        calls=(call(evaluate_policy, path=rel.policy_path, n=sz.eval_vehicles, seed=0),
               call(heldout_run, out=out / "heldout", policies=policies, sets=sets, vehicles=sz.heldout_vehicles,
                    period=sz.heldout_period, seed=0)),
        config={"vehicles": sz.eval_vehicles, "heldout": {"policies": policies, "sets": list(sets),
                                                          "vehicles": sz.heldout_vehicles,
                                                          "period_s": sz.heldout_period}},
        figures={"success": lem["policy"]["success_rate"],
                 "rmse_ratio_over_oracle": lem.get("rmse_ratio_policy_over_oracle"),
                 "z_err_rel": lat["z_err_rel"],
                 "probe_r2_thrust_to_weight": lat["probe_r2_identifiable"].get("nominal_thrust_to_weight"),
                 "heldout_targets_met": {k: v["all"] for k, v in ho["numbers"]["targets"].items()}})
