"""The posterior calibration's rows on the device machine, piece by piece: pieces of the release stage's sets
(``FULL_CALIBRATION``, :func:`mjxsysid.release.stages.calibration.pieces`) collected in one process (one set of
compiles), each written as OUT/rows/<set>.<i>of<k>.json with the stage's ``release`` section, or as ``.partial``
where the deadline cut it. A device call is 10 minutes: about 600 logs a call on one H200. The slow and motor
sets (a 20 s lemniscate and a hover; 320 logs a piece) are slower: two processes on `nvidia-h200-x2` compiled
for 193-203 s each, then 64 resumed logs took about 260 s; a fresh piece's first batch (256, or 160 logs) did
not finish within one call there (2026-11-29). Run a fresh one alone on one GPU, or with a smaller
``posterior_calibration.BATCH``.
A piece whose ``.partial`` file is in OUT/rows/ already resumes: only the logs it lacks are identified
(``--resume-from DIR`` puts the partial pieces landed in DIR there first, so a piece longer than a call
finishes over several).

    PYTHONPATH=$PWD/.site:$PWD MJXSYSID_COMMIT=<sha> python tools/calibration_pieces.py $OUT 550 \\
        rows/vel_ms.1of4.json,rows/novel_ms.1of4.json [--resume-from .carry/resume]
    python tools/calibration_pieces.py --todo docs/runs/measurements/log-grounded/nuts-calibration/rows

    python tools/calibration_pieces.py --land FILES_OR_FOLDERS    # the device's rows into the committed folders

``--land``: each piece's rows (plain, .partial, gzipped or xz) written compact into :data:`ROWS` (features
rounded to 4 decimals, xz): train/, held_out/ (:data:`HELD_OUT`) or misfit/ (:data:`MISFIT`) by its set; a
piece cut by the deadline says so (``partial``). The same piece in another form there is replaced, but
never a whole piece by a partial one.

``--todo DIR``: the pieces not yet in DIR (its train/, held_out/ and misfit/ folders, plain or compressed), with
their logs.
Never point a JAX cache at OUT: the device returns a limited number of files. The tool turns JAX's persistent
cache on (``MJXSYSID_JAX_CACHE``, e.g. /tmp/jaxcache): a call that tars it into one file of OUT (5.4 MB xz for the
min-snap pieces) and a next call that carries and unpacks it compile 24 s instead of 114 s a piece (2026-11-30):
``tools/gpu_pieces.sh`` does both, one process a GPU.
"""
from __future__ import annotations

import json
import sys
import time
from pathlib import Path

T0 = time.perf_counter()
ROWS = Path("docs/runs/measurements/log-grounded/nuts-calibration/rows")
"""The committed rows of NUTS's table (:mod:`tools.refit_calibration`)."""
HELD_OUT = {"test_vel", "test_novel"}
"""The sets held out from fitting."""
MISFIT = {"motor"}
"""The sets flown with another command→speed map: evaluated apart."""
MIN_LEFT_S = 200.0
"""No piece starts with less time left: its batch of logs is cut as a whole by the device call's limit and
returns no rows (pieces of 160–224 logs took 133–259 s on one H200; 2026-11-29, two pieces started with about
70 s left were lost)."""


def todo(folder: Path) -> list[tuple[str, int]]:
    """The pieces (row file, logs) of FULL_CALIBRATION not in ``folder`` (a complete piece's file, plain or
    compressed, in one of its subfolders; a file marked ``partial`` is not complete)."""
    from mjxsysid.experiments.posterior_calibration import ROW_SUFFIXES, read_json
    from mjxsysid.release.sizes import FULL_CALIBRATION
    from mjxsysid.release.stages.calibration import pieces

    def complete(p: Path) -> bool:
        return "partial" not in p.name and "partial" not in read_json(p)
    have = {p.name.split(".json")[0] for p in folder.rglob("*.json*") if p.name.endswith(ROW_SUFFIXES) and complete(p)}
    out = []
    for kind, name, s, levels, shard, f in pieces(FULL_CALIBRATION):
        if Path(f).name.split(".json")[0] not in have:
            out.append((f, s.logs(len(levels)) // FULL_CALIBRATION.shards))
    return out


def resume_into(out: Path, want: list[str], folder: Path) -> list[str]:
    """Write each piece of ``want`` that ``folder`` holds as partial (a ``.partial`` file, or one marked
    ``partial``: :func:`land`'s, any form) to ``out``/<piece>.partial, which collect_piece resumes; the pieces."""
    from mjxsysid.experiments.posterior_calibration import ROW_SUFFIXES, read_json
    found = []
    for f in want:
        name = Path(f).name.split(".json")[0]
        for p in sorted(folder.rglob(name + ".json*")):
            d = json.loads(p.read_text()) if p.name.endswith(".partial") else (
                read_json(p) if p.name.endswith(ROW_SUFFIXES) else None)
            if d is not None and (p.name.endswith(".partial") or "partial" in d):
                d.pop("partial", None)
                (out / (f + ".partial")).parent.mkdir(parents=True, exist_ok=True)
                (out / (f + ".partial")).write_text(json.dumps(d, separators=(",", ":")) + "\n")
                print(f"{f}: resuming at {len(d['rows'])} rows from {p}", flush=True)
                found.append(f)
                break
    return found


def collect_pieces(out: Path, deadline_s: float, want: list[str], resume_from: Path | None = None) -> None:
    """Collect the pieces ``want`` (row files of :func:`~mjxsysid.release.stages.calibration.pieces`) into
    ``out`` (:func:`~mjxsysid.release.stages.calibration.collect_piece`, the shipped policy where a set flies
    one) until ``deadline_s`` seconds after start; ``resume_from``: a folder whose partial pieces are resumed
    (:func:`resume_into`)."""
    import types
    from mjxsysid.release.provenance import code_commit, device_name
    from mjxsysid.release.sizes import FULL_CALIBRATION
    from mjxsysid.release.stages.calibration import collect_piece, pieces
    from mjxsysid.runtime.profiling import compile_profile
    from mjxsysid.runtime.startup import compilation_cache
    compilation_cache()                               # MJXSYSID_JAX_CACHE: a later call loads what this one compiled
    table = {p[5]: p for p in pieces(FULL_CALIBRATION)}
    unknown = [w for w in want if w not in table]
    if unknown:
        raise SystemExit(f"unknown pieces {unknown}; known: {sorted(table)}")
    if resume_from is not None:
        resume_into(out, want, resume_from)
    rel = types.SimpleNamespace(policy_path=None, log=lambda m: print(m, flush=True))
    device, commit = device_name(), code_commit()
    for f in want:
        left = deadline_s - (time.perf_counter() - T0)
        if left < MIN_LEFT_S:
            print(f"deadline: {f} not started ({left:.0f} s left)", flush=True)
            continue
        t = time.perf_counter()
        with compile_profile() as prof:
            collect_piece(rel, out, table[f], device, commit, time_budget_s=left - 15)
        done = (out / f).is_file()
        n = len(json.loads((out / f if done else out / (f + ".partial")).read_text())["rows"])
        dt = time.perf_counter() - t
        print(prof.table(), flush=True)
        print(f"{f}: {n} rows in {dt:.0f} s ({n / max(dt, 1):.2f} logs/s){'' if done else ' (cut by the deadline)'}",
              flush=True)


def _rounded(x):
    if isinstance(x, float):
        return round(x, 4)
    if isinstance(x, list):
        return [_rounded(v) for v in x]
    if isinstance(x, dict):
        return {k: _rounded(v) for k, v in x.items()}
    return x


def land(sources: list[Path], rows: Path = ROWS) -> list[Path]:
    """Write each piece's row file among ``sources`` (files, or folders searched for ``<set>.<i>of<k>.json*``)
    compact into ``rows``/<train|held_out|misfit>/<piece>.json.xz, replacing that piece's other forms there;
    the paths written."""
    import lzma
    from mjxsysid.experiments.posterior_calibration import ROW_SUFFIXES, read_json
    files = [f for p in sources for f in (sorted(p.rglob("*.json*")) if p.is_dir() else [p])
             if "of" in f.name and f.name.split(".json")[1] in ("", ".partial", ".gz", ".xz")]
    written = []
    for f in files:
        d = json.loads(f.read_text()) if f.name.endswith(".partial") else read_json(f)
        if not d.get("rows"):
            print(f"skipped {f}: no rows", flush=True)
            continue
        for r in d["rows"]:
            r["features"] = _rounded(r["features"])
        if f.name.endswith(".partial"):
            d["partial"] = f"the first {len(d['rows'])} logs of the piece: the device call's limit cut the rest"
        name = f.name.split(".json")[0]
        set_ = name.split(".")[0]
        dest = rows / ("held_out" if set_ in HELD_OUT else "misfit" if set_ in MISFIT else "train") / (name + ".json.xz")
        dest.parent.mkdir(parents=True, exist_ok=True)
        have = [o for o in dest.parent.glob(name + ".json*") if o.resolve() != f.resolve()
                and o.name.endswith(ROW_SUFFIXES) and "partial" not in read_json(o)]
        if "partial" in d and have:
            print(f"skipped {f}: partial, and {have[0]} holds the whole piece", flush=True)
            continue
        text = json.dumps(d, separators=(",", ":")).encode()
        for old in dest.parent.glob(name + ".json*"):
            if old != dest and old.resolve() != f.resolve():
                old.unlink()
        dest.write_bytes(lzma.compress(text, preset=9 | lzma.PRESET_EXTREME))
        if f.resolve() != dest.resolve() and f.resolve().parent == dest.parent.resolve():
            f.unlink()                                # the same piece in another form, in place
        written.append(dest)
        print(f"{f} -> {dest}: {len(d['rows'])} rows{' (partial)' if 'partial' in d else ''}", flush=True)
    return written


def main(argv: list[str]) -> None:
    from mjxsysid.runtime.xla_flags import GPU_LOOP_GRAPHS, use_xla_flags
    use_xla_flags(GPU_LOOP_GRAPHS)                      # as `mjxsysid calibrate-posterior` runs it
    if argv[:1] == ["--land"]:
        if len(argv) < 2:
            raise SystemExit(__doc__)
        land([Path(a) for a in argv[1:]])
        return
    if argv[:1] == ["--todo"]:
        left = todo(Path(argv[1]))
        for f, n in left:
            print(f"{f}  {n} logs")
        print(f"{len(left)} pieces, {sum(n for _, n in left)} logs")
        return
    resume = None
    if "--resume-from" in argv:
        k = argv.index("--resume-from")
        resume, argv = Path(argv[k + 1]), argv[:k] + argv[k + 2:]
    if len(argv) != 3:
        raise SystemExit(__doc__)
    collect_pieces(Path(argv[0]), float(argv[1]), argv[2].split(","), resume)


if __name__ == "__main__":
    main(sys.argv[1:])
