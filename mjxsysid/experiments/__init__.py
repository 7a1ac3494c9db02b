"""The paper's experiments as commands (`mjxsysid experiment NAME [--quick] --out DIR`).

Every experiment is a function ``run(out: Path, *, quick: bool, policy: PolicyRef, seed: int,
progress: bool = True) -> dict`` in its own module; it computes its numbers and hands them to
:func:`mjxsysid.experiments.common.write_results`, which writes ``results.json`` (config,
seeds, policy / decoder hashes, device, wall time, numbers) and ``results.md`` (the paper's
table with our numbers beside it). PNGs go next to them. ``--quick`` is a small CPU version
(minutes); the full version is sized for one GPU. ``numbers['headline']`` (a few key figures)
is what the CLI prints.
"""
from __future__ import annotations

import importlib

EXPERIMENTS = {
    "tune-nominal": "mjxsysid.experiments.tuning:run_nominal",
    "tune-slow": "mjxsysid.experiments.tuning:run_slow",
    "tune-lemniscate": "mjxsysid.experiments.tuning:run_lemniscate",
    "robustness": "mjxsysid.experiments.robustness:run",
    "payload": "mjxsysid.experiments.payload:run",
    "replay": "mjxsysid.experiments.replay:run",
    "probe-loop": "mjxsysid.experiments.probe_loop:run",
}
"""name -> 'module:function' (imported lazily, so the CLI's --help stays instant)."""


def get_experiment(name: str):
    """The ``run`` function of experiment ``name``; a ValueError names the known ones."""
    if name not in EXPERIMENTS:
        raise ValueError(f"unknown experiment {name!r}; choose from {', '.join(EXPERIMENTS)}")
    mod, fn = EXPERIMENTS[name].split(":")
    return getattr(importlib.import_module(mod), fn)
