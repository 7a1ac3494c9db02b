"""`mjxsysid tune`: one vehicle with the online predictive tuner, methods compared.

Each command's parser (``add_*``) stands beside its handler (``cmd_*``). Handlers import what
they run when they run: `mjxsysid --help` stays instant (no JAX or MuJoCo import).
"""
from __future__ import annotations

import sys
import time
from pathlib import Path

from mjxsysid.runtime import jsonout
from mjxsysid.cli._common import add_policy, echo, policy_ref, positive, prepare_render


def add_tune(sub) -> None:
    tn = sub.add_parser("tune", help="fly a vehicle with the online predictive tuner and compare methods")
    tn.add_argument("--vehicle", type=Path, default=None, help="vehicle JSON (default: the paper vehicle)")
    tn.add_argument("--reference", choices=("lemniscate", "minsnap"), default="lemniscate")
    tn.add_argument("--period", type=positive, default=10.0, help="lemniscate period, s (default 10)")
    tn.add_argument("--duration", type=positive, default=None,
                    help="flight duration, s (default: one period / 5 s; --quick: 2 s)")
    tn.add_argument("--methods", default="naive,baseline,cfm,nominal_cem,oracle_cem",
                    help="comma-separated subset of naive,baseline,cfm,nominal_cem,oracle_cem")
    tn.add_argument("--models", type=int, default=None, help="K decoded models per update (default 16; quick 4)")
    tn.add_argument("--candidates", type=int, default=None, help="N candidate gains per CEM iteration (default 32; quick 8)")
    tn.add_argument("--iterations", type=int, default=None, help="CEM iterations per update (default 2)")
    tn.add_argument("--horizon", type=positive, default=None, help="predictive horizon, s (default 0.5; quick 0.3)")
    tn.add_argument("--rate", type=positive, default=10.0, help="tuner updates per second (default 10)")
    tn.add_argument("--quick", action="store_true", help="small settings for a CPU run of minutes")
    tn.add_argument("--seed", type=int, default=0)
    add_policy(tn)
    tn.add_argument("--decoders", type=Path, default=None, help="folder with cfm.npz (default: the policy's)")
    tn.add_argument("--video", action="store_true", help="also render the tuned vs untuned (naive) flight side by side")
    tn.add_argument("--out", type=Path, required=True)
    tn.set_defaults(handler=cmd_tune)


def cmd_tune(args) -> int:
    import dataclasses

    if args.video:
        prepare_render()
    from mjxsysid import theta as P
    from mjxsysid.experiments.tuning import FULL_TUNER, QUICK_TUNER
    from mjxsysid.render.tuning import plot_gains, plot_tracking
    from mjxsysid.rollout.flight import broadcast, make_reference
    from mjxsysid.sim import Quadrotor
    from mjxsysid.tune.compare import check_methods, compare_methods, results_dict
    from mjxsysid.tune.tuner import CEM_METHODS, METHOD_LABELS

    methods = check_methods(m.strip() for m in args.methods.split(",") if m.strip())
    base = QUICK_TUNER if args.quick else FULL_TUNER
    cem = base.cem
    if args.candidates is not None or args.iterations is not None:
        cem = dataclasses.replace(cem, **{k: v for k, v in (("candidates", args.candidates),
                                                            ("iterations", args.iterations)) if v is not None})
    over = {k: v for k, v in (("models", args.models), ("horizon", args.horizon), ("rate", args.rate)) if v is not None}
    cfg = dataclasses.replace(base, cem=cem, **over)
    theta = P.load_vehicle(args.vehicle) if args.vehicle else P.paper_hardware()
    duration = args.duration or (2.0 if args.quick else (args.period if args.reference == "lemniscate" else 5.0))
    if cfg.horizon > duration:
        raise ValueError(f"--horizon {cfg.horizon:g} s is longer than the flight ({duration:g} s)")
    policy = policy_ref(args)
    decoder = None
    if "cfm" in methods:
        from mjxsysid.cfm.load import load_decoders
        decoder = load_decoders(args.decoders, policy, warn=lambda m: print(m, file=sys.stderr))[0]
    ref, _ = make_reference(args.reference, period=args.period, duration=duration, seed=args.seed)
    sim = Quadrotor()
    steps = int(round(duration / sim.config.dt))
    args.out.mkdir(parents=True, exist_ok=True)
    t0 = time.time()
    res = compare_methods(theta[None], broadcast(ref, 1), steps=steps, methods=methods, cfg=cfg, policy=policy,
                          decoder=decoder, sim=sim, seed=args.seed,
                          log=lambda m: echo(m, file=sys.stderr))
    d = results_dict(res, index=0)
    info = {"vehicle": str(args.vehicle or "paper_hardware"), "reference": args.reference,
            "period_s": args.period, "duration_s": duration, "policy": policy.label, "seed": args.seed,
            "tuner": dataclasses.asdict(cfg), "wall_s": round(time.time() - t0, 1)}
    (args.out / "metrics.json").write_text(jsonout.dumps({**d, "config": info}, indent=2) + "\n")
    name = Path(info["vehicle"]).stem
    plot_gains(res, args.out / "gains.png", labels=METHOD_LABELS, tuned=CEM_METHODS, title=f"gains over time, {name}, {args.reference}")
    plot_tracking(res, args.out / "tracking.png", labels=METHOD_LABELS, title=f"tracking, {name}, {args.reference}")
    wrote = "metrics.json, gains.png, tracking.png"
    if args.video:
        _tune_video(res, theta, args.out)
        wrote += ", tuned_vs_untuned.mp4"
    print(jsonout.dumps({k: {m: v[m] for m in ("pos_rmse_m", "max_pos_err_m", "heading_rmse_deg", "failed")}
                      for k, v in d.items()}))
    print(f"wrote {args.out}/{wrote}", file=sys.stderr)
    return 0


def _tune_video(res, theta, out):
    """The tuned flight (CFM-tuned, else the first CEM method) beside the untuned (naive) one."""
    import tempfile

    from mjxsysid.render.video import render_rollout, side_by_side
    from mjxsysid.tune.tuner import CEM_METHODS, METHOD_LABELS
    tuned = next((m for m in ("cfm",) + CEM_METHODS if m in res), None)
    untuned = "naive" if "naive" in res else ("baseline" if "baseline" in res else None)
    if tuned is None or untuned is None:
        raise ValueError("--video needs a tuned method (cfm, nominal_cem or oracle_cem) and naive or baseline")
    with tempfile.TemporaryDirectory() as tmp:
        paths = []
        for m in (untuned, tuned):
            fl = res[m]["tuned"].flight
            frames = type(fl.frame)(*[a[0] for a in fl.frame])
            paths.append(render_rollout(theta, frames, Path(tmp) / f"{m}.mp4", width=480, height=360,
                                        reference=fl.ref_pos[0]))
        side_by_side(paths, out / "tuned_vs_untuned.mp4", labels=[METHOD_LABELS[untuned], METHOD_LABELS[tuned]])
