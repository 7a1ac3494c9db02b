"""The posterior calibration stage: collect simulated logs' rows, fit the calibration table
(:mod:`mjxsysid.identify.calibrate`) on the training sets, evaluate it on the held-out sets."""
from __future__ import annotations

import json
import os
import time
from pathlib import Path

from mjxsysid.release.provenance import call, jsonable
from mjxsysid.release.record import now
from mjxsysid.release.sizes import FULL_CALIBRATION, CalibrationSet, CalibrationSizes
from mjxsysid.release.stages.registry import STAGES, ReleaseView, StageResult

LOGS_PER_S = 1.1
"""Rows collected per second on one H200 GPU (the log-grounded posterior with NUTS refinement and the model
checks, docs/identify.md): the stage's GPU estimate. Pieces of 224 logs in one batch (padded to 256), flying
included, one process on a GPU of `nvidia-h200-x2`, 2026-11-30: 198 s (1.13 logs/s) with the compilation cache of
earlier calls carried and NUTS's program compiled, 169 s (1.32) with every program cached (BENCHMARKS.md). A piece
of 320 logs (the slow and motor sets) may not fit one 10-minute call: it resumes (:func:`collect_piece`)."""
TABLE = "posterior_calibration.json"
"""The fitted table in the stage folder (shipped as mjxsysid/pretrained/posterior_calibration.json)."""
ROWS = "rows"
"""The stage folder's subfolder of row files, one per set and shard (:func:`pieces`)."""


def pieces(cal: CalibrationSizes) -> list[tuple[str, str, CalibrationSet, tuple[str, ...], str | None, str]]:
    """The collections of a calibration, in order: (kind 'train', 'held_out' or 'misfit', set name, set,
    levels, shard 'i/k' or None, row file relative to the stage folder: rows/<set>.json, or
    rows/<set>.<i>of<k>.json with shards)."""
    out = []
    for kind, sets, levels in (("train", cal.train, cal.train_levels), ("held_out", cal.held_out, cal.held_out_levels),
                               ("misfit", cal.misfit, cal.train_levels)):
        for name, s in sets.items():
            for i in range(cal.shards):
                shard = None if cal.shards == 1 else f"{i}/{cal.shards}"
                f = f"{ROWS}/{name}.json" if shard is None else f"{ROWS}/{name}.{i}of{cal.shards}.json"
                out.append((kind, name, s, tuple(levels), shard, f))
    return out


def estimate_s(cal: CalibrationSizes = FULL_CALIBRATION) -> float:
    """GPU seconds on one H200 at :data:`LOGS_PER_S` (the logs flown, before failed flights)."""
    return sum(cal.logs()) / LOGS_PER_S


def _kwargs(rel: ReleaseView, s: CalibrationSet, levels, shard) -> dict:
    """collect's keyword arguments for one piece (the release's policy where the set flies it)."""
    kw = {"vehicles": s.vehicles, "seed": s.seed, "levels": tuple(levels), "references": tuple(s.flights),
          "controller": s.controller, "aero": s.aero, "velocity": s.velocity, "shard": shard}
    if s.controller == "policy":
        kw["policy"] = rel.policy_path
    if (s.motor_idle, s.motor_kappa) != (0.0, 1.0):          # the other sets' calls as they were recorded
        kw |= {"motor_idle": s.motor_idle, "motor_kappa": s.motor_kappa}
    if s.paths != 1:
        kw["paths"] = s.paths
    return kw


def collect_piece(rel: ReleaseView, out: Path, piece, device: str | None, commit: str | None,
                  time_budget_s: float | None = None) -> tuple[dict, bool]:
    """Collect one piece's rows into its file (written under a .partial name, renamed when complete,
    with a ``release`` section: wall time, device, commit, end time, the rows resumed); a complete file is kept;
    ``time_budget_s``: collect's (a piece it cuts stays .partial, its rows kept, and the next call resumes it:
    it identifies only the logs the .partial file lacks).
    Returns (the call's record, whether it ran)."""
    from mjxsysid.experiments.posterior_calibration import collect, read_json
    _, name, s, levels, shard, f = piece
    kw = _kwargs(rel, s, levels, shard)
    dst = out / f
    record = call(collect, out=dst, **kw)
    if dst.is_file():
        rel.log(f"[release] posterior_calibration: {f} collected before, kept")
        return record, False
    dst.parent.mkdir(parents=True, exist_ok=True)
    tmp = dst.with_name(dst.name + ".partial")
    rel.log(f"[release] posterior_calibration: collecting {name}" + (f" shard {shard}" if shard else "")
            + f" ({s.logs(len(levels)) // (1 if shard is None else int(shard.split('/')[1]))} logs) → {f}")
    t0 = time.time()
    resumed = 0
    if tmp.is_file():
        resumed = len(read_json(tmp)["rows"])
        rel.log(f"[release] posterior_calibration: {f} resumed at {resumed} rows")
    res = collect(out=tmp, time_budget_s=time_budget_s, resume=True, **kw)
    res["release"] = {"wall_s": round(time.time() - t0, 1), "device": device, "commit": commit, "ended": now(),
                      "resumed_rows": resumed}
    tmp.write_text(json.dumps(res, separators=(",", ":")) + "\n")
    if not res.get("cut_by_budget"):
        os.replace(tmp, dst)
    return record, True


def _nuts_table(train: list[Path], path: Path, cal: CalibrationSizes, commit, device, command: str) -> dict | None:
    """The table at ``path`` with a table of its own for NUTS-refined posteriors (the rows whose chains mixed,
    :func:`mjxsysid.identify.calibrate.for_method`), written there; None (the pooled table alone) where they
    are too few for the sizes' window."""
    from mjxsysid.experiments.posterior_calibration import fit_file
    try:
        return fit_file(train, path, bins=cal.bins, min_group=cal.min_group, method="smc_nuts", base=path,
                        window_logs=cal.window_logs,
                        command=command + " (NUTS's table: the rows whose chains mixed)",
                        provenance={"commit": commit, "device": device})
    except ValueError:
        return None


MISFIT = "misfit"
"""The stage folder's subfolder of the misfit sets' evaluation (:attr:`CalibrationSizes.misfit`)."""


@STAGES.add(needs=("policy",), outputs=(TABLE, "evaluation.json", "evaluation.md"), estimate_s=estimate_s(),
            what="calibrate-posterior: collect the training and held-out rows, fit the table, evaluate it "
                 "(resumes by set and shard)")
def posterior_calibration(rel: ReleaseView, out: Path) -> StageResult:
    """Collect every set's rows (:func:`collect_piece`; a complete row file is kept, so a call cut
    off resumes at the piece it was collecting), fit the table on the training rows
    (:func:`mjxsysid.identify.calibration_fit.fit` at the sizes' bins and min_group) into
    out/posterior_calibration.json with its provenance (the sets, sizes, calls, commit, device,
    wall times), and evaluate it on the held-out rows
    (:func:`mjxsysid.experiments.posterior_calibration.report`: out/evaluation.json, evaluation.md,
    coverage_width.png, ranks.png; the mean coverage per level recorded in the provenance of each sampler's
    table), and on the misfit sets' rows apart (out/misfit/, never recorded in the table)."""
    from mjxsysid.experiments.posterior_calibration import fit_file, mean_coverage, report
    from mjxsysid.release.provenance import code_commit, device_name
    cal = rel.sizes.calibration
    entry = rel.entry("posterior_calibration")
    device = entry.get("device") or device_name()
    commit = entry.get("commit") or code_commit()
    t0 = time.time()
    calls, ran = [], []
    todo = pieces(cal)
    for p in todo:
        c, did = collect_piece(rel, out, p, device, commit)
        calls.append(c)
        if did:
            ran.append(p[5])
    train = [out / p[5] for p in todo if p[0] == "train"]
    held = [out / p[5] for p in todo if p[0] == "held_out"]
    misfit = [out / p[5] for p in todo if p[0] == "misfit"]
    calls.append(call(fit_file, paths=train, out=out / TABLE, bins=cal.bins, min_group=cal.min_group))
    collected = {p[5]: json.loads((out / p[5]).read_text()).get("release", {}) for p in todo}
    table = fit_file(train, out / TABLE, bins=cal.bins, min_group=cal.min_group,
                     command=f"mjxsysid release --out {rel.out.name} --stages posterior_calibration", provenance={
                         "what": "the log-grounded posterior's calibration table, fitted on simulated logs "
                                 "(identify.calibration_fit.fit)",
                         "commit": commit, "device": device, "scale": rel.options.scale, "sizes": jsonable(cal),
                         "calls": list(calls), "collected": collected,
                         "collect_wall_s": round(sum(v.get("wall_s") or 0 for v in collected.values()), 1)})
    nuts = _nuts_table(train, out / TABLE, cal, commit, device, table["provenance"]["command"])
    if nuts is not None:
        table["by_method"] = nuts["by_method"]
    rows = table["provenance"]["rows"]
    (out / TABLE).write_text(json.dumps(table, indent=1) + "\n")
    res = report(held, out / TABLE, out, record=True)
    cov = mean_coverage(res["calibrated"])
    calls.append(call(report, paths=held, table_path=out / TABLE, out=out, record=True))
    apart = {}
    if misfit:
        calls.append(call(report, paths=misfit, table_path=out / TABLE, out=out / MISFIT))
        apart = mean_coverage(report(misfit, out / TABLE, out / MISFIT)["calibrated"])
    return StageResult(
        calls=tuple(calls),
        config={"sizes": jsonable(cal), "collected_now": ran},
        figures={"train_logs": rows, "held_out_logs": res["rows"], "mean_coverage": cov, "misfit_mean_coverage": apart,
                 "mean_coverage_raw": mean_coverage(res["raw"]),
                 "wall_s_this_call": round(time.time() - t0, 1)})
