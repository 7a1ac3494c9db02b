"""Provenance: the library calls a stage made (the function and its arguments, as recorded in
release.json), and the provenance JSON shipped beside policy and decoder weights."""
from __future__ import annotations

import dataclasses
import json
from collections.abc import Callable, Mapping
from pathlib import Path
from typing import Any


def jsonable(x: Any) -> Any:
    """``x`` as JSON values: paths and callables as strings, dataclasses and mappings as objects,
    tuples as lists, numpy scalars as numbers."""
    if isinstance(x, (str, int, float, bool)) or x is None:
        return x
    if isinstance(x, Path):
        return str(x)
    if dataclasses.is_dataclass(x) and not isinstance(x, type):
        return {f.name: jsonable(getattr(x, f.name)) for f in dataclasses.fields(x)}
    if isinstance(x, Mapping):
        return {str(k): jsonable(v) for k, v in x.items()}
    if isinstance(x, (list, tuple)):
        return [jsonable(v) for v in x]
    if hasattr(x, "item") and getattr(x, "shape", None) == ():
        return x.item()
    if callable(x):
        return qualname(x)
    return repr(x)


def qualname(fn: Callable) -> str:
    """``module.qualname`` of a function."""
    return f"{fn.__module__}.{fn.__qualname__}"


def call(fn: Callable, **kwargs) -> dict:
    """The record of one library call: ``{"call": "module.function", "args": {keyword: value}}``
    (the values as JSON, :func:`jsonable`)."""
    return {"call": qualname(fn), "args": jsonable(kwargs)}


def device_name() -> str:
    """The JAX device this process runs on, in words."""
    from mjxsysid.experiments.common import device_info
    d = device_info()
    return f"{d['device_kind']} ({d['platform']}, {d['device_count']} device(s)), jax {d['jax']}"


def code_commit() -> str | None:
    """The commit of the code (``$MJXSYSID_COMMIT``, else git's, else None)."""
    from mjxsysid.experiments.common import git_commit
    return git_commit()


def policy_provenance(weights, evaluation: dict, *, train_log=None, command: str, note: str | None = None,
                      commit: str | None = None) -> dict:
    """policy.json beside shipped policy weights: what, the command, config, seed, commit,
    device, wall time, env steps, mean training speed, normaliser, final training stats and the
    evaluation (``evaluate-policy``'s eval.json), read from the files given."""
    from mjxsysid.runtime.checkpoint import load_meta
    meta = load_meta(weights)
    sps = None
    if train_log is not None and Path(train_log).exists():
        rows = [json.loads(x) for x in Path(train_log).read_text().splitlines() if x.strip()]
        sps = sum(r["steps_per_s"] for r in rows[1:]) / max(len(rows) - 1, 1) if rows else None
    prov = {"what": "unified latent-conditioned adaptive policy (μ, φ, π, aux decoder)", "command": command,
            "config": meta.get("config"), "seed": (meta.get("config") or {}).get("seed"),
            "commit": commit if commit is not None else code_commit(),
            "device": meta.get("device"), "jax": meta.get("jax"), "wall_s": meta.get("wall_s"),
            "env_steps": meta.get("env_steps"), "mean_train_steps_per_s": sps,
            "normalizer": meta.get("normalizer"), "final_train_stats": meta.get("final_stats"),
            "evaluation": evaluation, "evaluation_command": "mjxsysid evaluate-policy --vehicles 1000 --out OUT"}
    if note:
        prov["note"] = note
    return prov


def decoder_provenance(path, kind: str, evaluation: dict, *, what: str = "of the shipped policy's latent",
                       command: str, evaluation_command: str | None, note: str | None = None,
                       commit: str | None = None) -> dict:
    """cfm.json / regression.json / cfm_seq.json beside shipped decoders: what, the command,
    config, seed, commit, device, wall time, losses, the data they were trained on and the
    evaluation (``evaluate-decoder``'s decoder_eval.json: all of it for cfm, energy score and
    RMSE for regression, its ``sequence`` part for cfm_seq)."""
    from mjxsysid.cfm.sample import Decoder
    from mjxsysid.cfm.sequence import SequenceDecoder
    dec = SequenceDecoder.load(path) if kind == "cfm_seq" else Decoder.load(path)
    m = dec.meta
    desc = "p(θ | ẑ_1..ẑ_W) (flight-level, W = 1 latent up to a whole flight)" if kind == "cfm_seq" else "p(θ | ẑ)"
    prov = {"what": f"{kind} decoder {desc} {what}", "command": command,
            "config": {k: getattr(dec.cfg, k) for k in dec.cfg.__dataclass_fields__},
            "seed": dec.cfg.seed, "commit": commit if commit is not None else code_commit(),
            "device": f"{m.get('device')}, jax {m.get('jax')}",
            "wall_s": m.get("wall_s"), "steps_per_s": m.get("steps_per_s"),
            "final_train_loss": m.get("final_train_loss"), "final_val_loss": m.get("final_val_loss"),
            "data": m.get("data"), **({"early_stopping": m["early_stopping"]} if "early_stopping" in m else {}),
            "stored_dtype": "float16 (evaluated after rounding)",
            "evaluation": evaluation.get("sequence") if kind == "cfm_seq" else evaluation if kind == "cfm" else {
                "energy_score": evaluation.get("energy_score"), "rmse_norm": evaluation.get("rmse_norm")}}
    if evaluation_command is not None:
        prov["evaluation_command"] = evaluation_command
    if kind == "cfm_seq":
        prov.update(n_params=m.get("n_params"), val_loss_min=m.get("val_loss_min"),
                    val_loss_argmin_epoch=m.get("val_loss_argmin_epoch"))
    if note:
        prov["note"] = note
    return prov
