"""Helpers shared by the benchmark scripts (run as ``python benchmarks/NAME.py``: this folder is
on ``sys.path``). Sharding a draw and flying it at a noise level live in the package
(:mod:`mjxsysid.experiments.log_grounded_coverage`), re-exported here."""
from __future__ import annotations

import json
import sys
import time
from pathlib import Path

from mjxsysid.experiments import log_grounded_coverage as _cov

level_flights = _cov.level_flights


def wall_times(fn, repeats: int) -> list[float]:
    """Wall times (s) of ``repeats`` calls of ``fn()`` (which blocks on its result)."""
    out = []
    for _ in range(repeats):
        t = time.perf_counter()
        fn()
        out.append(time.perf_counter() - t)
    return out


def write_json(path: Path, res: dict) -> None:
    """Write a benchmark's result JSON (creating its folder) and say so on stderr."""
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text(json.dumps(res, indent=2) + "\n")
    print(f"wrote {path}", file=sys.stderr)


def write_results(folder, stem: str, res: dict, lines: list[str]) -> None:
    """A benchmark's result as FOLDER/STEM.json (valid JSON: :func:`mjxsysid.runtime.jsonout.write_json`) and
    FOLDER/STEM.md (its table ``lines``), creating the folder."""
    from mjxsysid.runtime.jsonout import write_json as write_valid_json
    dst = Path(folder)
    dst.mkdir(parents=True, exist_ok=True)
    write_valid_json(dst / f"{stem}.json", res, indent=1)
    (dst / f"{stem}.md").write_text("\n".join(lines) + "\n")


def emit(folder, stem: str, res: dict, lines: list[str]) -> dict:
    """Print a benchmark's table ``lines`` and, where ``folder`` is given, write it (:func:`write_results`) -> res."""
    print("\n".join(lines))
    if folder:
        write_results(folder, stem, res, lines)
    return res


def config_overrides(pairs: list[str]) -> dict:
    """``KEY=VALUE`` strings (``--set``) -> a dict of TrainConfig overrides, values read as JSON
    (``true``, ``2``, ``0.1``) or else kept as strings."""
    out = {}
    for p in pairs:
        key, sep, value = p.partition("=")
        if not sep or not key:
            raise SystemExit(f"--set: expected KEY=VALUE, got {p!r}")
        try:
            out[key] = json.loads(value)
        except json.JSONDecodeError:
            out[key] = value
    return out


def merge_paths(merge: list[str]):
    """``--merge OUT SHARD.json ...`` -> (OUT, [SHARD, ...]) as paths; fewer than two exit with the usage."""
    if len(merge) < 2:
        raise SystemExit("--merge OUT SHARD.json [SHARD.json ...]")
    return Path(merge[0]), [Path(p) for p in merge[1:]]


def shard(theta, spec: str | None, seed: int):
    """:func:`mjxsysid.experiments.log_grounded_coverage.shard`, a malformed ``--shard`` exiting with its message."""
    try:
        return _cov.shard(theta, spec, seed)
    except ValueError as e:
        raise SystemExit(str(e)) from None
