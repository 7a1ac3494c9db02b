"""Every measurement the docs quote, as a command: `mjxsysid experiment NAME [--quick] --out DIR`.

Every experiment is a function ``run(out: Path, *, quick: bool, policy: PolicyRef, seed: int,
progress: bool = True) -> dict`` in its own module; it computes its numbers and hands them to
:func:`mjxsysid.experiments.common.write_results`, which writes ``results.json`` (config,
seeds, policy / decoder hashes, device, wall time, numbers) and ``results.md`` (the paper's
table with our numbers beside it). PNGs go next to them. ``--quick`` is a small CPU version
(minutes); the full version is sized for one GPU. ``numbers['headline']`` (a few key figures)
is what the CLI prints. An experiment that reads earlier runs takes ``inputs`` (`--inputs PATH`);
``seed`` defaults to the experiment's own (0 for most).
"""
from __future__ import annotations

import functools
import importlib
import inspect
from pathlib import Path

EXPERIMENTS = {
    "tune-nominal": "mjxsysid.experiments.tuning:run_nominal",
    "tune-slow": "mjxsysid.experiments.tuning:run_slow",
    "tune-lemniscate": "mjxsysid.experiments.tuning:run_lemniscate",
    "robustness": "mjxsysid.experiments.robustness_envelopes:run",
    "payload": "mjxsysid.experiments.payload:run",
    "replay": "mjxsysid.experiments.action_replay:run",
    "probe-loop": "mjxsysid.experiments.probe_loop:run",
    "probe-loop-seeds": "mjxsysid.experiments.probe_loop_seeds:run",
    "lag-oracle": "mjxsysid.experiments.lag_oracle:run",
    "stress-prior-oracle": "mjxsysid.experiments.stress_prior_oracle:run",
    "prediction-error": "mjxsysid.experiments.prediction_error:run",
    "log-checks": "mjxsysid.experiments.log_checks:run",
    "long-flight-calibration": "mjxsysid.experiments.long_flight_calibration:run",
    "noise-sensitivity": "mjxsysid.experiments.noise_sensitivity:run",
    "rotorpy-noise": "mjxsysid.experiments.rotorpy_noise:run",
    "speed-table": "mjxsysid.experiments.speed_table:run",
    "sampler-reference": "mjxsysid.experiments.sampler_reference:run",
}
"""name -> 'module:function' (imported lazily, so the CLI's --help stays instant)."""


def _plain(v):
    """An argument as JSON can hold it: numbers, strings, lists; anything else as its str."""
    if v is None or isinstance(v, (str, int, float, bool)):
        return v
    if isinstance(v, (list, tuple)):
        return [_plain(x) for x in v]
    if isinstance(v, dict):
        return {str(k): _plain(x) for k, x in v.items()}
    if hasattr(v, "kind") and hasattr(v, "weights"):                # a PolicyRef
        return {"kind": v.kind, "weights": str(v.weights)}
    return str(v)


def get_experiment(name: str):
    """The ``run`` function of experiment ``name``, wrapped so that its results.json records the
    call (``call``: experiment, function, every argument with the defaults filled in; ``seed``);
    a ValueError names the known ones."""
    from mjxsysid.experiments.common import CALL
    if name not in EXPERIMENTS:
        raise ValueError(f"unknown experiment {name!r}; choose from {', '.join(EXPERIMENTS)}")
    mod, fn_name = EXPERIMENTS[name].split(":")
    fn = getattr(importlib.import_module(mod), fn_name)

    @functools.wraps(fn)
    def run(out: Path, **kw):
        bound = inspect.signature(fn).bind(out, **kw)
        bound.apply_defaults()
        args = {k: _plain(v) for k, v in bound.arguments.items() if k != "progress"}
        token = CALL.set({"experiment": name, "function": EXPERIMENTS[name], "arguments": args})
        try:
            return fn(out, **kw)
        finally:
            CALL.reset(token)
    return run
