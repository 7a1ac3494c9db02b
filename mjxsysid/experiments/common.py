"""What every experiment writes: results.json and results.md, with provenance."""
from __future__ import annotations

import contextvars
import platform
import subprocess
import time
from pathlib import Path

import numpy as np

from mjxsysid.runtime import jsonout
from mjxsysid.policy.interface import file_sha256

CALL: contextvars.ContextVar[dict | None] = contextvars.ContextVar("experiment_call", default=None)
"""The experiment call in progress ({experiment, function, arguments}), set by the function
:func:`mjxsysid.experiments.get_experiment` returns; :func:`write_results` records it."""


def git_commit() -> str | None:
    """HEAD of the checkout mjxsysid runs from, with ``+dirty`` when the package's tracked files
    differ from it (a working tree copied onto its base commit, as the GPU machine gets it, ran
    code that HEAD does not name); None outside a git checkout. $MJXSYSID_COMMIT overrides it."""
    import os
    if os.environ.get("MJXSYSID_COMMIT"):
        return os.environ["MJXSYSID_COMMIT"]
    try:
        root = Path(__file__).resolve().parents[2]
        out = subprocess.run(["git", "-C", str(root), "rev-parse", "HEAD"], capture_output=True,
                             text=True, timeout=5)
        head = out.stdout.strip() or None
        if head is None:
            return None
        st = subprocess.run(["git", "-C", str(root), "status", "--porcelain", "--untracked-files=no", "--",
                             "mjxsysid"], capture_output=True, text=True, timeout=10)
        return head + ("+dirty" if st.returncode == 0 and st.stdout.strip() else "")
    except (OSError, subprocess.SubprocessError):
        return None


def device_info() -> dict:
    import jax
    d = jax.devices()[0]
    return {"platform": d.platform, "device_kind": getattr(d, "device_kind", str(d)),
            "device_count": jax.device_count(), "jax": jax.__version__, "host": platform.node()}


def to_jsonable(x):
    """numpy / jax scalars and arrays -> plain Python (NaN/inf -> None)."""
    if isinstance(x, dict):
        return {str(k): to_jsonable(v) for k, v in x.items()}
    if isinstance(x, (list, tuple)):
        return [to_jsonable(v) for v in x]
    if isinstance(x, Path):
        return str(x)
    if hasattr(x, "shape") or isinstance(x, (np.generic, float, int, bool)):
        a = np.asarray(x)
        if a.dtype == bool:
            return a.tolist()
        if a.dtype.kind in "iu":
            return a.tolist()
        if a.dtype.kind == "f":
            if a.ndim == 0:
                return float(a) if np.isfinite(a) else None
            return [to_jsonable(v) for v in a]
        return a.tolist()
    return x


def mean_std(v) -> dict:
    """Mean ± std (and n) of finite values; None where there are none."""
    v = np.asarray(v, np.float64).ravel()
    v = v[np.isfinite(v)]
    if v.size == 0:
        return {"mean": None, "std": None, "n": 0}
    return {"mean": float(v.mean()), "std": float(v.std()), "n": int(v.size)}


def fmt_ms(d: dict | None, digits: int = 3) -> str:
    """{'mean', 'std'} -> '0.123 ± 0.045' (or '–')."""
    if not d or d.get("mean") is None:
        return "–"
    return f"{d['mean']:.{digits}f} ± {d['std']:.{digits}f}"


def markdown_table(header: list[str], rows: list[list]) -> str:
    lines = ["| " + " | ".join(header) + " |", "|" + "---|" * len(header)]
    lines += ["| " + " | ".join(str(c) for c in r) + " |" for r in rows]
    return "\n".join(lines) + "\n"


def write_results(out, name: str, *, config: dict, seeds: dict, numbers: dict, table_md: str,
                  t0: float, policy=None, decoders=None, notes: str = "") -> dict:
    """Write OUT/results.json and OUT/results.md; returns the JSON dict.

    policy: a :class:`~mjxsysid.policy.interface.PolicyRef` (its kind and weights hash are
    recorded); decoders: the folder of the decoders used (their file hash is recorded). The
    experiment's seed and its exact call (every argument, defaults included) are recorded as
    ``seed`` and ``call`` when it runs through :func:`mjxsysid.experiments.get_experiment`.
    """
    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    call = CALL.get()
    prov = {"experiment": name, "seed": call["arguments"].get("seed") if call else seeds.get("seed"),
            "call": call, "config": config, "seeds": seeds, "commit": git_commit(),
            "device": device_info(), "wall_s": round(time.time() - t0, 2),
            "date": time.strftime("%Y-%m-%d %H:%M:%S %Z")}
    if policy is not None:
        prov["policy"] = {"kind": policy.kind, "weights": str(policy.weights), "sha256": policy.sha256()}
    if decoders is not None:
        d = Path(decoders)
        prov["decoders"] = {"dir": str(d), "cfm_sha256": file_sha256(d / "cfm.npz")
                            if (d / "cfm.npz").is_file() else None}
    res = {**prov, "numbers": numbers}
    (out / "results.json").write_text(jsonout.dumps(to_jsonable(res), indent=2) + "\n")
    head = (f"# {name}\n\n{'quick (small CPU) run' if config.get('quick') else 'full run'}, "
            f"{prov['device']['device_kind']} ({prov['device']['platform']}), {prov['date']}, "
            f"{prov['wall_s']:.0f} s, commit {str(prov['commit'])[:10]}\n\n")
    (out / "results.md").write_text(head + table_md + ("\n" + notes.strip() + "\n" if notes else ""))
    return res


def leaf_table(numbers: dict, *, limit: int = 200) -> str:
    """A markdown table of every numeric leaf of ``numbers`` ('a / b / c' paths), for the
    measurements that have no table of their own; at most ``limit`` rows."""
    rows = []

    def walk(prefix, v):
        if isinstance(v, dict):
            for k, x in v.items():
                walk(f"{prefix} / {k}" if prefix else str(k), x)
        elif isinstance(v, (bool, np.bool_)):
            rows.append([prefix, str(bool(v))])
        elif isinstance(v, (int, float, np.integer, np.floating)):
            rows.append([prefix, f"{float(v):.4g}"])

    walk("", numbers)
    return markdown_table(["quantity", "value"], rows[:limit])
