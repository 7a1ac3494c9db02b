"""The decoder stages: collect (θ, ẑ) pairs and latent trajectories with the release's policy,
train the single-latent and flight-level decoders on them, evaluate their calibration."""
from __future__ import annotations

import dataclasses
from pathlib import Path

from mjxsysid.release.layout import link
from mjxsysid.release.provenance import call
from mjxsysid.release.sizes import PairSizes
from mjxsysid.release.stages.registry import STAGES, ReleaseView, StageResult



def imu_config(rel: ReleaseView):
    """The simulator of the pairs (a SimConfig): the policy's training IMU randomisation when its
    config has it (``env.randomize_imu``), else a clean IMU (the shipped decoders' pairs)."""
    from mjxsysid.runtime.checkpoint import load_meta
    from mjxsysid.sim import SimConfig
    env = (load_meta(rel.policy_path).get("config") or {}).get("env", {})
    if not env.get("randomize_imu"):
        return SimConfig()
    from mjxsysid.policy.adaptive.config import IMU_FIELDS
    return SimConfig(**{k: env.get(k, getattr(SimConfig(), k)) for k in IMU_FIELDS})


def _collect(rel: ReleaseView, out: Path, *, seconds: float | None, sizes: PairSizes) -> StageResult:
    from mjxsysid.dataset.collect import collect, imu_settings, load_pairs
    from mjxsysid.policy.interface import file_sha256
    sim = imu_config(rel)
    kw = {"policy": rel.policy_path, "n_train": sizes.train, "n_test": sizes.test, "seed": 0, "batch": sizes.batch,
              "seconds": seconds, "sim_config": sim}
    path = collect(out, log=rel.log, **kw)
    arrays, meta = load_pairs(path)
    return StageResult(calls=(call(collect, out=out, **kw),),
                       config={"train": sizes.train, "test": sizes.test, "batch": sizes.batch, "seconds": seconds,
                               "prior": meta.get("prior"), "imu": imu_settings(sim)},
                       figures={"failed_train": int(arrays["failed_train"].sum()),
                                "failed_test": int(arrays["failed_test"].sum()), "pairs_sha256": file_sha256(path)})


def _train(rel: ReleaseView, pairs: Path, out: Path, kinds: tuple[str, ...], seq_cfg: dict | None = None) -> StageResult:
    from mjxsysid.cfm.pipeline import train_decoders
    from mjxsysid.cfm.train import CFMConfig
    cfg = dataclasses.replace(CFMConfig(), **rel.sizes.cfm)
    res = train_decoders(pairs, out, cfg, kinds=kinds, seq_cfg=seq_cfg, log=rel.log, resume=True)
    return StageResult(calls=(call(train_decoders, pairs=pairs, out=out, cfg=cfg, kinds=kinds, seq_cfg=seq_cfg,
                                   resume=True),),
                       config={"cfm": dataclasses.asdict(cfg), "seq_cfg": seq_cfg},
                       figures={k: {kk: v[kk] for kk in ("wall_s", "final_train_loss", "final_val_loss")}
                                for k, v in res.items()})


@STAGES.add(needs=("policy",), outputs=("pairs.npz",), estimate_s=20, what="collect --single-latent (θ, ẑ) pairs")
def pairs(rel: ReleaseView, out: Path) -> StageResult:
    """Single-latent (θ, ẑ) pairs, as the shipped cfm.json's (``collect --single-latent``)."""
    return _collect(rel, out, seconds=None, sizes=rel.sizes.pairs)


@STAGES.add(needs=("pairs",), outputs=("cfm.npz", "regression.npz"), estimate_s=40,
            what="train-cfm --kinds cfm,regression")
def decoders(rel: ReleaseView, out: Path) -> StageResult:
    """CFM and Regression (``train-cfm --kinds cfm,regression``) on the single-latent pairs."""
    return _train(rel, rel.stage_dir("pairs") / "pairs.npz", out, ("cfm", "regression"))


@STAGES.add(needs=("policy",), outputs=("pairs.npz",), estimate_s=30, what="collect 10 s latent trajectories")
def seq_pairs(rel: ReleaseView, out: Path) -> StageResult:
    """Flights of random manoeuvres with ẑ at 10 Hz (``collect --seconds``)."""
    return _collect(rel, out, seconds=rel.sizes.seq_seconds, sizes=rel.sizes.seq_pairs)


@STAGES.add(needs=("seq_pairs",), outputs=("cfm_seq.npz",), estimate_s=35,
            what="train-cfm --kinds cfm_seq (the flight-level decoder)")
def seq_decoder(rel: ReleaseView, out: Path) -> StageResult:
    """The flight-level decoder (``train-cfm --kinds cfm_seq``) on the latent trajectories."""
    return _train(rel, rel.stage_dir("seq_pairs") / "pairs.npz", out, ("cfm_seq",), seq_cfg=dict(rel.sizes.seq_cfg))


@STAGES.add(needs=("decoders", "seq_decoder"), outputs=("single/decoder_eval.json", "flight/decoder_eval.json"),
            estimate_s=55, what="evaluate-decoder: CFM + Regression, and the flight-level decoder")
def decoder_eval(rel: ReleaseView, out: Path) -> StageResult:
    """``evaluate-decoder`` of CFM + Regression on the single-latent pairs (single/) and of the
    flight-level decoder, with the release's CFM as its single-latent reference, on the
    trajectories (flight/)."""
    from mjxsysid.cfm.pipeline import evaluate_decoders
    from mjxsysid.dataset.collect import paper_vehicle_latents
    sz = rel.sizes
    single, flight = out / "single", out / "flight"
    for f in ("cfm.npz", "regression.npz"):
        link(rel.stage_dir("decoders") / f, single / f)
    link(rel.stage_dir("seq_decoder") / "cfm_seq.npz", flight / "cfm_seq.npz")
    link(rel.stage_dir("decoders") / "cfm.npz", flight / "cfm.npz")
    zhat, traj = paper_vehicle_latents(rel.policy_path, instant=sz.paper_flight, flight=sz.paper_flight)
    kw = {"n_cases": sz.eval_cases, "n_samples": sz.eval_samples}
    rep = evaluate_decoders(single, rel.stage_dir("pairs") / "pairs.npz", paper_zhat=zhat, log=rel.log, **kw)
    seq = evaluate_decoders(flight, rel.stage_dir("seq_pairs") / "pairs.npz", paper_traj=traj, log=rel.log,
                            **kw)["sequence"]
    return StageResult(
        calls=(call(paper_vehicle_latents, policy=rel.policy_path, instant=sz.paper_flight, flight=sz.paper_flight),
               call(evaluate_decoders, out=single, pairs=rel.stage_dir("pairs") / "pairs.npz", **kw),
               call(evaluate_decoders, out=flight, pairs=rel.stage_dir("seq_pairs") / "pairs.npz", **kw)),
        config={"cases": sz.eval_cases, "samples": sz.eval_samples, "paper_flight": sz.paper_flight},
        figures={"coverage_mean": rep["coverage_mean"], "calibrated_within_5_points": rep["calibrated_within_5_points"],
                 "energy_score": rep["energy_score"], "sequence_targets": seq["targets"],
                 "energy_ratio_flight_vs_single": seq["energy_ratio_flight_vs_single"]})
