"""Wall time against quality of policy-training configurations: a table and a figure.

    mjxsysid experiment speed-table --inputs docs/runs/measurements/speed-table --out docs/runs/measurements/speed-table

Each run folder (as `tools/archive/gpu_speed.sh` leaves them) holds ``policy.npz`` (or its metadata alone as
``policy_meta.json``, as kept in docs/runs) (its metadata: the
config, wall time and, where recorded, the phase timings), ``train.txt`` (the command's wall time,
``command_wall_s``) and ``eval_fast/eval.json`` (``mjxsysid evaluate-policy --fast``). The
reference evaluation (the shipped policy's, same command) is a row without a training.
Runs whose names differ only in ``_seedN`` are seeds of one configuration: the summary table and
the figure give each configuration's mean and range. A run's ``decoders*/decoder_eval.json`` (the
release's CFM and Regression trained on its pairs, one folder per decoder seed) add the decoders'
calibration (parameters within ±5 points of 90 % coverage) and energy score; ``shipped_decoders/``
gives the reference's. ``cold_start/``: timing-only runs (cold_start/<run>/, a policy's metadata
and train.txt, no evaluation) as OUT/cold_start.md, where each start-up second went.
Writes OUT/speed.json, OUT/speed.md (the summary, then every run) and OUT/speed.png (the tracking
ratio and the decoders' energy score against wall time).
"""
from __future__ import annotations

import json
import re
import time
from pathlib import Path

from mjxsysid.runtime import jsonout
from mjxsysid.experiments.common import write_results


def run_row(d: Path) -> dict:
    if (d / "policy.npz").is_file():
        from mjxsysid.runtime.checkpoint import load_meta
        meta = load_meta(d / "policy.npz")
    else:   # runs kept in docs/runs without their weights: the metadata alone
        meta = json.loads((d / "policy_meta.json").read_text())
    cfg = meta["config"]
    ev = json.loads((d / "eval_fast" / "eval.json").read_text())
    m = re.search(r"command_wall_s (\d+) ms", (d / "train.txt").read_text()) if (d / "train.txt").exists() else None
    sm = ev["summary"]
    lat = ev.get("latent", {})
    return {"name": d.name, **latent_cols(lat), "decoders": decoder_evals(d), "num_envs": cfg["num_envs"], "unroll": cfg["unroll"], "iterations": cfg["iterations"],
            "epochs": cfg["epochs"], "minibatches": cfg["minibatches"], "seed": cfg["seed"],
            "reset_per_unroll": cfg.get("reset_per_unroll", False), "lr_decay": cfg.get("lr_decay", False),
            "sensor_randomized": bool(cfg["env"].get("randomize_imu", False)),
            "env_steps": meta.get("env_steps"), "updates": cfg["iterations"] * cfg["epochs"] * cfg["minibatches"],
            "train_wall_s": meta.get("wall_s"), "command_wall_s": int(m.group(1)) / 1e3 if m else None,
            "timing": meta.get("timing"), "device": meta.get("device"),
            # the card: the policy's metadata (train-policy records it), else device.txt beside the run
            "device_kind": meta.get("device_kind") or ((d / "device.txt").read_text().strip()
                                                        if (d / "device.txt").is_file() else None),
            "success": sm["success_policy"], "rmse_ratio": sm["rmse_ratio"],
            "r2_tw_cmds": sm["train_cmds"]["r2_thrust_to_weight"], "r2_tw_flight": sm["flight"]["r2_thrust_to_weight"]}


def latent_cols(lat: dict) -> dict:
    """The latent's health in an ``evaluate-policy --fast`` result: ‖z^θ − ẑ‖ over the spread of z^θ
    and the linear probe's R² of τ_m (the hardest parameter the tuner needs)."""
    return {"z_err_rel": lat.get("z_err_rel"),
            "r2_tau_m": (lat.get("probe_r2_theta") or {}).get("motor_time_constant")}


def decoder_evals(d: Path) -> list[dict]:
    """Each ``decoders*/decoder_eval.json`` under run folder ``d``: CFM parameters within ±5 points
    of 90 % coverage (of 19) and its energy score."""
    out = []
    for f in sorted(d.glob("decoders*/decoder_eval.json")):
        ev = json.loads(f.read_text())
        out.append({"folder": f.parent.name, "within_90": ev["calibrated_within_5_points"]["90%"],
                    "of": ev["calibrated_within_5_points"]["of"], "energy": ev["energy_score"]["cfm"]})
    return out


def decoder_cell(decs: list[dict]) -> str:
    if not decs:
        return "—"
    w = [x["within_90"] for x in decs]
    e = [x["energy"] for x in decs]
    span = lambda v, f: format(v[0], f) if len(v) == 1 else f"{format(min(v), f)}–{format(max(v), f)}"
    return f"{span(w, 'd')}/{decs[0]['of']}, energy {span(e, '.3f')} ({len(decs)} training{'s' if len(decs) > 1 else ''})"


def reference_row(name: str, path: Path) -> dict:
    ev = json.loads(path.read_text())
    sm = ev["summary"]
    return {"name": name, **latent_cols(ev.get("latent", {})), "decoders": [], "success": sm["success_policy"], "rmse_ratio": sm["rmse_ratio"],
            "r2_tw_cmds": sm["train_cmds"]["r2_thrust_to_weight"], "r2_tw_flight": sm["flight"]["r2_thrust_to_weight"]}


def fmt(x, spec):
    return "—" if x is None else format(x, spec)


def table(rows: list[dict]) -> str:
    head = ("| run | envs × unroll × iterations | epochs × minibatches (updates) | episode starts | env steps | "
            "learning rate | device | training loop | command (compile, start-up incl.) | success | RMSE / oracle | "
            "R² T/W (cmds / flight) | ‖z−ẑ‖ / spread | R² τ_m | decoders: CFM within ±5 pts at 90 %, energy |\n"
            "|---|---|---|---|---|---|---|---|---|---|---|---|---|---|---|\n")
    out = []
    for r in rows:
        if "num_envs" not in r:
            out.append(f"| {r['name']} | | | | | | | | | {r['success']:.1%} | {r['rmse_ratio']:.3f} | "
                       f"{r['r2_tw_cmds']:.3f} / {r['r2_tw_flight']:.3f} | {fmt(r.get('z_err_rel'), '.3f')} | "
                       f"{fmt(r.get('r2_tau_m'), '.2f')} | {decoder_cell(r.get('decoders', []))} |")
            continue
        out.append(f"| {r['name']} | {r['num_envs']} × {r['unroll']} × {r['iterations']} | {r['epochs']} × "
                   f"{r['minibatches']} ({r['updates'] / 1e3:.0f} k) | "
                   f"{'once per unroll' if r['reset_per_unroll'] else 'every step'} | {r['env_steps'] / 1e6:.0f} M | "
                   f"{'linear decay' if r['lr_decay'] else 'constant'} | {r.get('device_kind') or '—'} | "
                   f"{fmt(r['train_wall_s'], '.0f')} s | {fmt(r['command_wall_s'], '.0f')} s | {r['success']:.1%} | "
                   f"{r['rmse_ratio']:.3f} | {r['r2_tw_cmds']:.3f} / {r['r2_tw_flight']:.3f} | "
                   f"{fmt(r.get('z_err_rel'), '.3f')} | {fmt(r.get('r2_tau_m'), '.2f')} | {decoder_cell(r.get('decoders', []))} |")
    return head + "\n".join(out) + "\n"


def family(name: str) -> str:
    """A run's configuration: its name without ``_seedN`` (seeds of one config share a family)."""
    return re.sub(r"_seed\d+$", "", name)


def families(rows: list[dict]) -> dict[str, list[dict]]:
    out: dict[str, list[dict]] = {}
    for r in rows:
        out.setdefault(family(r["name"]), []).append(r)
    return out


def summary(rows: list[dict]) -> str:
    """One line per configuration: its seeds' spread of wall time and quality."""
    head = ("| configuration | runs | command wall (mean, range) | training loop (mean) | RMSE / oracle: mean (range) | "
            "runs ≤ 1.05 | success (lowest) | R² T/W cmds (lowest) | ‖z−ẑ‖ / spread (mean) | R² τ_m (mean) | "
            "decoders: CFM within ±5 pts at 90 %, energy |\n|---|---|---|---|---|---|---|---|---|---|---|\n")
    out = []
    for fam, rs in families(rows).items():
        cmd = [r["command_wall_s"] for r in rs if r.get("command_wall_s") is not None]
        loop = [r["train_wall_s"] for r in rs if r.get("train_wall_s") is not None]
        q = [r["rmse_ratio"] for r in rs]
        out.append(f"| {fam} | {len(rs)} | " + (f"{sum(cmd) / len(cmd):.0f} s ({min(cmd):.0f}–{max(cmd):.0f})" if cmd else "—")
                   + f" | {(f'{sum(loop) / len(loop):.0f} s' if loop else '—')} | {sum(q) / len(q):.3f} ({min(q):.3f}–{max(q):.3f}) | "
                   f"{sum(x <= 1.05 for x in q)}/{len(q)} | {min(r['success'] for r in rs):.1%} | "
                   f"{min(r['r2_tw_cmds'] for r in rs):.3f} | {mean_of(rs, 'z_err_rel', '.3f')} | "
                   f"{mean_of(rs, 'r2_tau_m', '.2f')} | {decoder_cell([x for r in rs for x in r.get('decoders', [])])} |")
    return head + "\n".join(out) + "\n"


def mean_of(rs: list[dict], key: str, spec: str) -> str:
    v = [r[key] for r in rs if r.get(key) is not None]
    return format(sum(v) / len(v), spec) if v else "—"


def cold_start(root: Path) -> str:
    """Where each timing run's start-up went (``root/<run>/``: policy_meta.json and train.txt): the command's wall time, the Trainer's construction, each program's compile (in
    background threads, side by side), the wait for the first iteration, the loop."""
    head = ("| run | card | command | construct | compiles (background) | setup (to the loop) | first iteration | "
            "loop (all iterations) |\n|---|---|---|---|---|---|---|---|\n")
    out = []
    for d in sorted(p for p in root.iterdir() if p.is_dir()):
        meta = json.loads((d / "policy_meta.json").read_text())
        t = meta["timing"]
        m = re.search(r"command_wall_s (\d+) ms", (d / "train.txt").read_text())
        comp = ", ".join(f"{k[:-len('_compile_s')]} {v:.1f}" for k, v in t.items() if k.endswith("_compile_s"))
        out.append(f"| {d.name} | {meta.get('device_kind', '—')} | {int(m.group(1)) / 1e3:.1f} s | {t['construct_s']:.1f} s | "
                   f"{comp} s | {t['setup_s']:.1f} s | {t['first_iteration_s']:.1f} s | {t['loop_s']:.1f} s |")
    return head + "\n".join(out) + "\n"


def figure(rows: list[dict], path: Path) -> None:
    """Per configuration, against the training command's wall time: the tracking ratio (left; its
    runs as small dots at their command time or, without one, at the configuration's mean, and the
    mean with the seeds' range as bars) and the energy score of the CFM decoders trained on its
    policies (right; each decoder training a dot; the references' range as a band). Success is in
    the title where every run reached it."""
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    fig, ax = plt.subplots(1, 2, figsize=(12, 4.6))
    cmap = plt.get_cmap("tab20")
    for i, (fam, rs) in enumerate(families(rows).items()):
        cmd = [r["command_wall_s"] for r in rs if r.get("command_wall_s") is not None]
        e = [x["energy"] for r in rs if r.get("command_wall_s") is None for x in r.get("decoders", [])]
        if e:     # decoders of a policy without a command time (a reference): their range as a band
            ax[1].axhspan(min(e) - 0.002, max(e) + 0.002, color="0.6", alpha=0.4,
                          label=f"{fam} policy's decoders ({len(e)} trainings)")
        if not cmd:
            continue
        c = cmap(i % 20)
        xm = sum(cmd) / len(cmd)
        v = [r["rmse_ratio"] for r in rs]
        xs = [r["command_wall_s"] if r.get("command_wall_s") is not None else xm for r in rs]
        ax[0].plot(xs, v, ".", c=c, alpha=0.5)
        ym = sum(v) / len(v)
        ax[0].errorbar([xm], [ym], yerr=[[ym - min(v)], [max(v) - ym]], xerr=[[xm - min(cmd)], [max(cmd) - xm]],
                       fmt="o", c=c, capsize=3, label=f"{fam} ({len(rs)} run{'s' if len(rs) > 1 else ''})")
        pts = [(r["command_wall_s"], x["energy"]) for r in rs if r.get("command_wall_s") is not None
               for x in r.get("decoders", [])]
        if pts:
            ax[1].plot(*zip(*pts), "o", c=c, label=fam)
    ax[0].axhline(1.05, c="r", lw=1)
    ok = all(r["success"] >= 0.99 for r in rows)
    ax[0].set(xlabel="training command wall time (s, compile and start-up included)", ylabel="RMSE / oracle (lemniscate)",
              title="tracking on the default prior (target ≤ 1.05)" + ("; every run ≥ 99 % success" if ok else ""))
    ax[1].set(xlabel="training command wall time (s)", ylabel="CFM energy score (lower: sharper, closer)",
              title="decoders trained on each policy's pairs (the release's)")
    for a in ax:
        a.axvline(60, c="r", lw=1, ls=":")
    ax[0].legend(fontsize=6.5, loc="upper right", ncol=2)
    ax[1].legend(fontsize=7, loc="upper right")
    fig.suptitle("mean and range over seeds (bars), each run a dot; runs without a command time drawn at their "
                 "configuration's mean time; the dotted line: 60 s", fontsize=8)
    fig.tight_layout()
    fig.savefig(path, dpi=110)


def run(out, *, quick=False, policy=None, seed=0, progress=True, inputs=None) -> dict:
    """The table and figure of the run folders under ``inputs`` (required; each subfolder with
    eval_fast/eval.json and policy.npz or policy_meta.json is a run, in name order), with
    ``inputs/shipped_eval_fast.json`` as the reference row 'shipped' (its decoders:
    ``inputs/shipped_decoders/``) and ``inputs/cold_start/`` as OUT/cold_start.md where present.
    Writes OUT/speed.json, speed.md, speed.png and results.json. Trains and flies nothing
    (``quick``, ``policy``, ``seed`` are not used)."""
    if inputs is None:
        raise ValueError("speed-table needs --inputs DIR (a folder of tools/archive/gpu_speed.sh run folders)")
    t0 = time.time()
    inputs, out = Path(inputs), Path(out)
    rows = []
    if (inputs / "shipped_eval_fast.json").is_file():
        rows.append(dict(reference_row("shipped", inputs / "shipped_eval_fast.json"),
                         decoders=decoder_evals(inputs / "shipped_decoders")))
    for d in sorted(p for p in inputs.iterdir() if p.is_dir()):
        if any((d / f).is_file() for f in ("policy.npz", "policy_meta.json")) and (d / "eval_fast" / "eval.json").is_file():
            rows.append(run_row(d))
    out.mkdir(parents=True, exist_ok=True)
    (out / "speed.json").write_text(jsonout.dumps(rows, indent=2) + "\n")
    (out / "speed.md").write_text(summary(rows) + "\n" + table(rows))
    figure(rows, out / "speed.png")
    if progress:
        print(summary(rows) + "\n" + table(rows))
    if (inputs / "cold_start").is_dir():
        text = cold_start(inputs / "cold_start")
        (out / "cold_start.md").write_text(text)
        if progress:
            print(text)
    return write_results(out, "speed-table", config={"inputs": str(inputs), "runs": len(rows)}, seeds={},
                         numbers={"rows": rows, "headline": {"runs": len(rows)}}, table_md=summary(rows), t0=t0)
