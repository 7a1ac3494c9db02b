"""docs/runs/README.md: what each folder of docs/runs/ holds, generated from a checkout's tree
(``python tools/fair_tables.py`` rewrites it with the other generated pages, ``--check`` checks it).

docs/runs/ has four folders: ``release/`` (exactly what the last `mjxsysid release` shipped,
replaced whole by its ship stage), ``measurements/<experiment>/`` (runs of the experiments and
benchmarks the docs quote), ``candidates/<date>_<name>/`` (measured, not shipped: JSON and
figures, no weights) and ``archive/`` (superseded and trial runs, one line each in
archive/INDEX.md). Weights live in mjxsysid/pretrained/ only; where an unshipped ``NAME.npz``
was, ``NAME_meta.json`` keeps its metadata and sha256.
"""
from __future__ import annotations

from pathlib import Path

from mjxsysid.experiments import EXPERIMENTS
from mjxsysid.release.layout import RUNS

PAGE = f"{RUNS}/README.md"
"""The page (relative to a checkout's root)."""
FOLDERS = {
    "release": "exactly what the last `mjxsysid release` shipped (its ship stage replaces the folder whole): "
               "the run files per kind and the release's record, `release.json`",
    "measurements": "one folder per experiment or benchmark the docs quote: `mjxsysid experiment NAME` (a run "
                    "of it writes results.json with the seed and the exact call; the files committed here before "
                    "the experiments existed keep their script's name and format, its command inside) or the "
                    "script named",
    "candidates": "measured, not shipped (`<date>_<name>/`): JSON and figures, no weights",
    "archive": "superseded and trial runs, one line each in [archive/INDEX.md](archive/INDEX.md)",
}
"""The four folders, in order, and what each holds."""
MEASUREMENTS = {
    "benchmarks": "`python benchmarks/NAME.py`: tuner latency, scaling, the training profile, device agreement, "
                  "first contact, decoding long logs",
    "held-out": "`mjxsysid evaluate-policy --held-out --weights …` on several policies: `probing/` (256 vehicles a "
                "set), `probing_1000/`, `probing_acc/`",
    "lag-oracle": "K_θ against the lag-aware oracle, with each design choice taken out, on four priors",
    "log-checks": "the flight-log checks: false alarms on correct logs, each mistake caught, IMU-noise estimates",
    "log-grounded": "`python benchmarks/log_grounded.py`: the log-grounded posterior's calibration (`families/`: the held-out families) and cost; `fidelity/`, `robustness/`, `tuning/`: closed-loop fidelity, the robustness envelopes and the tuner with its draws (`benchmarks/closed_loop_fidelity.py --posterior`, `mjxsysid experiment robustness --variant`, `mjxsysid experiment tune-slow --variant log_grounded`); `sysid/`: `mujoco.sysid` side by side (`benchmarks/sysid_side_by_side.py`); `sampler-reference/`: the SMC against a long NUTS run (`mjxsysid experiment sampler-reference`)",
    "long-flight-calibration": "flight-level decoding on 60 s flights: three windows' calibration",
    "nobc": "the policy trained without imitation (tools/archive/fair_baselines.sh nobc): evaluation, decoders, "
            "replay",
    "prediction-error": "the tuner's predictive rollouts against the flight, with the true θ",
    "probe": "`mjxsysid probe` and one focused retraining (`train-policy --focus`)",
    "probe-loop": "probe → retrain → evaluate → probe again, against the fair controls",
    "probe-loop-accumulate": "`mjxsysid experiment probe-loop --variant accumulate`, training seeds 0 and 1",
    "probe-loop-seeds": "the probe loop's round-2 policy and control retrained with training seed 1",
    "real-logs": "`decode --log` of the real samples in ../shared/data/logs (the logs themselves are not shipped): "
                 "`crazyflie-same-vehicle/`, a Crazyflie's three flights decoded as one vehicle (`--same-vehicle`)",
    "rotorpy-noise": "sim-to-sim: the shipped policy in RotorPy under IMU noise, each flight decoded",
    "speed-table": "wall time against quality of policy-training configurations, over its run folders",
    "stress-prior-oracle": "where the oracle still flies: the stress prior's edges one at a time",
    "xadap": "the released XAdap policy (tools/archive/fair_baselines.sh xadap): decoders, replay, flights",
}
"""Measurement folder -> what it holds; a registered experiment's folder also names its command."""
CANDIDATES = {
    "sensor_randomized": "a release's stages on a policy trained with IMU-noise randomisation "
                         "(tools/configs/policy_sensor_randomized.json; docs/noise.md)",
    "clean_share": "the same with 30 % clean episodes (tools/configs/policy_release_clean_share.json; docs/noise.md)",
}
"""Candidate name (after the date) -> what it is."""


def _subfolders(d: Path) -> list[Path]:
    return sorted(p for p in d.iterdir() if p.is_dir()) if d.is_dir() else []


def page(root) -> str:
    """The Markdown of docs/runs/README.md for the docs/runs/ tree of the checkout at ``root``."""
    runs = Path(root) / RUNS
    lines = ["# docs/runs", "", "<!-- generated by `python tools/fair_tables.py`: do not edit by hand -->",
             "", "Four folders; a reader never needs the commit log to tell a shipped number from a trial. "
             "Weights live in `mjxsysid/pretrained/` only: where an unshipped `NAME.npz` was, `NAME_meta.json` "
             "keeps its metadata and sha256 (the file is in git history).", ""]
    for top, what in FOLDERS.items():
        lines += [f"## `{top}/`", "", what[0].upper() + what[1:] + ".", ""]
        d = runs / top
        if top == "release":
            for kind in _subfolders(d):
                subs = ", ".join(f"`{p.name}/`" for p in _subfolders(kind))
                files = ", ".join(f"`{p.name}`" for p in sorted(kind.iterdir()) if p.is_file())
                lines.append(f"- `{kind.name}/`: " + "; ".join(x for x in (subs, files) if x))
        elif top == "measurements":
            lines += ["| folder | what it holds |", "|---|---|"]
            for m in _subfolders(d):
                what = MEASUREMENTS.get(m.name, "(not described: add it to MEASUREMENTS)")
                cmd = f"`mjxsysid experiment {m.name}`: " if m.name in EXPERIMENTS else ""
                lines.append(f"| [`{m.name}/`](measurements/{m.name}/) | {cmd}{what} |")
        elif top == "candidates":
            for c in _subfolders(d):
                date, _, name = c.name.partition("_")
                lines.append(f"- [`{c.name}/`](candidates/{c.name}/) ({date}): "
                             f"{CANDIDATES.get(name, '(not described: add it to CANDIDATES)')}")
        else:
            lines.append(", ".join(f"`{p.name}/`" for p in _subfolders(d)))
        lines.append("")
    return "\n".join(lines)
