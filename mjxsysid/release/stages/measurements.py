"""The measurement stages: decoding under IMU noise, the tune-* experiments, the studies and
closed-loop fidelity, each with the release's policy and decoders."""
from __future__ import annotations

import json
from pathlib import Path

from mjxsysid.runtime import jsonout
from mjxsysid.release.provenance import call
from mjxsysid.release.runs import STUDY_RUNS, TUNE_RUNS, ExperimentRun
from mjxsysid.release.stages.registry import STAGES, ReleaseView, StageResult


_DECODED = ("decoders", "seq_decoder")


@STAGES.add(needs=_DECODED, outputs=("noise_sensitivity.json", "noise_sensitivity_low.json"), estimate_s=85,
            what="decoding under IMU noise (mjxsysid experiment noise-sensitivity's measurement)")
def noise(rel: ReleaseView, out: Path) -> StageResult:
    """The noise measurement ([noise_sensitivity][mjxsysid.uses.imu_noise.noise_sensitivity]) at
    each level set of the sizes (the docs' levels and the low ones), with the figure."""
    from mjxsysid.uses.imu_noise import DEFAULT_LEVELS, figure, noise_sensitivity
    sz = rel.sizes.noise.measurement()
    dec = rel.decoder_set()
    runs = {name: tuple(DEFAULT_LEVELS if levels is None else levels)
            for name, levels in rel.sizes.noise.levels.items()}
    figures, calls = {}, []
    for name, levels in runs.items():
        c = call(noise_sensitivity, policy=rel.policy_path, decoders=dec, seed=4242, levels=levels, **sz)
        res = noise_sensitivity(policy=rel.policy_path, decoders=dec, seed=4242, levels=levels, log=rel.log, **sz)
        (out / name).write_text(jsonout.dumps({**c, **res}, indent=1) + "\n")
        calls.append(c)
        figures[name] = {lv: {"flight_level_identifiable_within_5": v["flight_level"]["identifiable_90_within_5_points"],
                              "flight_level_params_within_5": v["flight_level"]["coverage_90_within_5_points"]}
                         for lv, v in res["levels"].items()}
    figure(json.loads((out / "noise_sensitivity.json").read_text()), out / "noise_sensitivity.png")
    return StageResult(calls=tuple(calls), config={**sz, "levels": {k: list(v) for k, v in runs.items()}},
                       figures=figures)


def experiments(rel: ReleaseView, out: Path, runs: tuple[ExperimentRun, ...]) -> StageResult:
    """Run the experiments ``runs`` with the release's policy and decoders into out/<folder>/,
    each skipped when its results.json exists (a finished run of an interrupted stage)."""
    from mjxsysid.experiments import get_experiment
    dec = rel.decoder_set()
    figures, calls = {}, []
    for r in runs:
        kw = {"decoders": dec}
        if r.variant:
            kw["variant"] = r.variant
        if r.methods:
            kw["methods"] = tuple(r.methods.split(","))
        fn = get_experiment(r.experiment)
        kw.update(quick=rel.sizes.quick, policy=rel.policy_path, seed=r.seed)
        calls.append(call(fn, out=out / r.folder, **kw))
        done = out / r.folder / "results.json"
        if done.is_file():
            rel.log(f"[release] {r.folder}: done before (results.json), kept")
            res = json.loads(done.read_text())
        else:
            rel.log(f"[release] experiment {r.experiment} → {out / r.folder}")
            res = fn(out / r.folder, progress=rel.progress_on(), **kw)
        figures[r.folder] = {"wall_s": res.get("wall_s"), **res["numbers"].get("headline", {})}
    return StageResult(calls=tuple(calls), config={"runs": [list(r) for r in runs], "quick": rel.sizes.quick},
                       figures=figures)


_TUNE_GPU_S = {"tune_nominal": 215, "tune_slow": 290, "tune_slow_more": 300, "tune_lemniscate": 420}
_TUNE_WHAT = {"tune_nominal": "experiment tune-nominal, --variant baseline_start, protect",
              "tune_slow": "experiment tune-slow, --variant heading_cost, baseline_start",
              "tune_slow_more": "experiment tune-slow --variant true_rotor_state, steady_rotor_state; --seed 7 "
                                "(and baseline_start)",
              "tune_lemniscate": "experiment tune-lemniscate, --variant no_lead_in (and baseline_start)"}


def _tune_stage(key: str):
    def run(rel: ReleaseView, out: Path) -> StageResult:
        return experiments(rel, out, TUNE_RUNS[key])
    run.__name__ = run.__qualname__ = key
    run.__doc__ = f"The {key.replace('_', '-')} runs of [TUNE_RUNS][mjxsysid.release.runs.TUNE_RUNS]."
    return run


for _key in TUNE_RUNS:
    STAGES.add(needs=_DECODED, outputs=tuple(f"{r.folder}/results.json" for r in TUNE_RUNS[_key]),
               estimate_s=_TUNE_GPU_S[_key], what=_TUNE_WHAT[_key])(_tune_stage(_key))


@STAGES.add(needs=_DECODED, outputs=tuple(f"{r.folder}/results.json" for r in STUDY_RUNS), estimate_s=260,
            what="experiment robustness (and --variant single_latent), replay, payload")
def studies(rel: ReleaseView, out: Path) -> StageResult:
    """robustness (flight-level decoder, and --variant single_latent), replay and payload."""
    return experiments(rel, out, STUDY_RUNS)


@STAGES.add(needs=_DECODED, outputs=("closed_loop_fidelity.json", "closed_loop_fidelity_same_flight.json"),
            estimate_s=130, what="closed-loop fidelity, held-out and same-flight identification")
def fidelity(rel: ReleaseView, out: Path) -> StageResult:
    """Closed-loop fidelity ([fidelity_benchmark][mjxsysid.uses.fidelity.fidelity_benchmark]) on a
    held-out identification flight and on the test flight itself."""
    from mjxsysid.cfm.sequence import SequenceDecoder
    from mjxsysid.uses.fidelity import fidelity_benchmark
    sz = rel.sizes.fidelity
    path = rel.decoder_set() / "cfm_seq.npz"
    dec = SequenceDecoder.load(path)
    figures, calls = {}, []
    for ident, name in (("held_out", "closed_loop_fidelity.json"), ("same", "closed_loop_fidelity_same_flight.json")):
        kw = {"vehicles": sz.vehicles, "models": sz.models, "duration": sz.duration, "identification": ident,
                  "policy": rel.policy_path}
        res = fidelity_benchmark(decoder=dec, log=rel.log, **kw)
        (out / name).write_text(jsonout.dumps(res, indent=2) + "\n")
        calls.append(call(fidelity_benchmark, decoder=path, **kw))
        figures[name] = {"mean_inside_decoded": res["mean"]["inside_decoded"],
                         "median_width_ratio": res["width_ratio_decoded_over_pm20"]["median"]}
    return StageResult(calls=tuple(calls), config={"vehicles": sz.vehicles, "models": sz.models,
                                                   "duration": sz.duration}, figures=figures)
