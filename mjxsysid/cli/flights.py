"""`mjxsysid demo` and `mjxsysid fly`: the quick start and scripted flights.

Each command's parser (``add_*``) stands beside its handler (``cmd_*``). Handlers import what
they run when they run: `mjxsysid --help` stays instant (no JAX or MuJoCo import).
"""
from __future__ import annotations

import sys
import time
from pathlib import Path

from mjxsysid.runtime import jsonout
from mjxsysid.cli._common import PRIOR_CHOICES, add_policy, nonneg, policy_ref, positive, prepare_render, triple


def add_demo(sub) -> None:
    d = sub.add_parser("demo", help="CPU demo on the paper's vehicle (plots, video, summary)")
    d.add_argument("--out", type=Path, default=Path("out/demo"), help="output folder (default out/demo)")
    d.add_argument("--no-video", action="store_true", help="skip the offscreen video")
    d.add_argument("--vehicles", type=int, default=16, help="prior vehicles in the comparison (default 16)")
    d.add_argument("--decoder-only", action="store_true",
                   help="skip the log-grounded posterior of the paper vehicle's flight (the decoders alone)")
    add_policy(d)

    d.set_defaults(handler=cmd_demo)


def cmd_demo(args) -> int:
    if not args.no_video:
        prepare_render()
    from mjxsysid.decoding.demo import run_demo
    run_demo(args.out, video=not args.no_video, n_vehicles=args.vehicles, policy=policy_ref(args),
             decoder_only=args.decoder_only)
    return 0


def add_fly(sub) -> None:
    f = sub.add_parser("fly", help="fly one vehicle under a controller and reference")
    f.add_argument("--vehicle", type=Path, default=None,
                   help="vehicle JSON file (default: the paper's hardware vehicle)")
    f.add_argument("--prior", choices=PRIOR_CHOICES, default=None,
                   help="instead of --vehicle: fly --vehicles vehicles drawn from this prior (seeded; "
                        "xadap: the released policy's training distribution)")
    f.add_argument("--vehicles", type=int, default=100, help="with --prior: how many (default 100)")
    f.add_argument("--controller", choices=("oracle", "k_theta", "nominal", "policy", "xadap"), default=None,
                   help="oracle: the lag-aware K_θ with the true θ (default without --policy); k_theta: the "
                        "paper's K_θ with the true θ (ignores the motor lag); nominal: K_θ with "
                        "the paper vehicle's θ; policy: the latent policy named by --policy (default "
                        "with --policy); xadap: short for --controller policy --policy xadap")
    add_policy(f)
    f.add_argument("--reference", choices=("hover", "lemniscate", "minsnap"), default="lemniscate")
    f.add_argument("--period", type=positive, default=10.0, help="lemniscate period, s (default 10)")
    f.add_argument("--duration", type=positive, default=None,
                   help="flight duration, s (default: one period / 5 s)")
    f.add_argument("--force-step", type=triple, default=(0.0, 0.0, 0.0), metavar="FX,FY,FZ",
                   help="constant world force, N, from --force-step-time on")
    f.add_argument("--force-step-time", type=nonneg, default=1.0, help="s (default 1)")
    f.add_argument("--force-sigma", type=nonneg, default=0.0,
                   help="std of an i.i.d. Gaussian world force per control step, N")
    f.add_argument("--gains", choices=("naive", "baseline"), default="baseline")
    f.add_argument("--seed", type=int, default=0)
    f.add_argument("--video", action="store_true", help="also render DIR/flight.mp4")
    f.add_argument("--out", type=Path, required=True, help="output folder")
    f.set_defaults(handler=cmd_fly)


def cmd_fly(args) -> int:
    if args.video:
        prepare_render()
    from mjxsysid import theta as P
    from mjxsysid.render.plots import plot_trajectory
    from mjxsysid.rollout.flight import fly_vehicles, one_flight, save_flight, write_metrics

    if args.controller is None:
        args.controller = "policy" if (args.policy or args.weights) else "oracle"
    if args.controller == "xadap":
        args.controller, args.policy = "policy", args.policy or "xadap"
        if args.policy != "xadap":
            raise ValueError(f"--controller xadap conflicts with --policy {args.policy}")
    if args.controller == "policy":
        args.policy = policy_ref(args)
    elif args.policy is not None or args.weights is not None:
        raise ValueError(f"--policy / --weights do not apply to --controller {args.controller}")
    if args.prior is not None:
        if args.vehicle is not None:
            raise ValueError("give either --vehicle or --prior, not both")
        if args.vehicles < 1:
            raise ValueError(f"--vehicles must be >= 1, got {args.vehicles}")
        return _fly_prior(args)
    theta = P.load_vehicle(args.vehicle) if args.vehicle else P.paper_hardware()
    out = args.out
    out.mkdir(parents=True, exist_ok=True)
    t0 = time.time()
    flight, m, duration = fly_vehicles(
        theta, controller=args.controller, reference=args.reference, period=args.period,
        duration=args.duration, gains=args.gains, force_step=args.force_step,
        force_step_time=args.force_step_time, force_sigma=args.force_sigma, seed=args.seed,
        policy=args.policy)
    save_flight(flight, theta, out / "flight.npz")
    one = one_flight(flight)
    from mjxsysid.logs.ulog_write import write_flight_logs
    write_flight_logs(one, out)
    info = {"vehicle": str(args.vehicle or "paper_hardware"), "controller": _ctrl_label(args),
            "reference": args.reference, "duration_s": duration, "gains": args.gains,
            "seed": args.seed}
    d = write_metrics(m, out / "metrics.json", extra=info)
    plot_trajectory(one.frame, out / "tracking.png", reference=one.ref_pos,
                    title=f"{_ctrl_label(args)}, {args.reference}, {Path(info['vehicle']).stem}")
    if args.video:
        from mjxsysid.render.video import render_rollout
        render_rollout(theta, one.frame, out / "flight.mp4", reference=one.ref_pos)
    print(jsonout.dumps({k: d[k] for k in ("pos_rmse_m", "max_pos_err_m", "heading_rmse_deg",
                                         "lateral_rmse_m", "vertical_rmse_m", "saturation_frac",
                                         "failed")}))
    print(f"wrote {out}/flight.npz, flight.ulg, flight.csv, tracking.png, metrics.json"
          + (", flight.mp4" if args.video else "") + f" ({time.time() - t0:.1f} s)", file=sys.stderr)
    return 0


def _ctrl_label(args) -> str:
    return f"policy {args.policy.label}" if args.controller == "policy" else f"{args.controller} K_θ"


def _fly_prior(args) -> int:
    """`fly --prior NAME --vehicles N`: a batch from the prior; summary + per-vehicle metrics."""
    import jax
    import numpy as np

    from mjxsysid import theta as P
    from mjxsysid.render.plots import plot_trajectory
    from mjxsysid.rollout.flight import fly_vehicles, one_flight, random_minsnaps, save_flight, write_metrics
    from mjxsysid.rollout.harness import metrics_to_host

    out = args.out
    out.mkdir(parents=True, exist_ok=True)
    theta = np.asarray(P.get_prior(args.prior).sample(jax.random.PRNGKey(args.seed), args.vehicles))
    refs = random_minsnaps(args.vehicles, args.seed, args.duration or 5.0) if args.reference == "minsnap" else None
    flight, m, duration = fly_vehicles(
        theta, controller=args.controller, reference=args.reference, period=args.period,
        duration=args.duration, gains=args.gains, force_step=args.force_step,
        force_step_time=args.force_step_time, force_sigma=args.force_sigma, seed=args.seed, refs=refs,
        policy=args.policy)
    save_flight(flight, theta, out / "flight.npz")
    info = {"prior": args.prior, "vehicles": args.vehicles, "controller": _ctrl_label(args),
            "reference": args.reference, "duration_s": duration, "gains": args.gains, "seed": args.seed,
            "per_vehicle": metrics_to_host(m), "theta": theta.tolist()}
    d = write_metrics(m, out / "metrics.json", index=None, extra=info)
    one = one_flight(flight)
    plot_trajectory(one.frame, out / "tracking.png", reference=one.ref_pos,
                    title=f"{_ctrl_label(args)}, {args.reference}, first of {args.vehicles} {args.prior}-prior vehicles")
    print(jsonout.dumps({k: d[k] for k in ("n", "success_rate", "pos_rmse_m", "heading_rmse_deg",
                                         "saturation_frac")}))
    print(f"wrote {out}/metrics.json (summary + per-vehicle), flight.npz and tracking.png (first vehicle)",
          file=sys.stderr)
    return 0


VIEW_TASKS = ("hover", "lemniscate", "minsnap", "force_step")  # = mjxsysid.envs.TASKS (not imported: --help stays light)


def add_view(sub) -> None:
    v = sub.add_parser("view", help="watch a policy fly one vehicle in dm_control's interactive viewer "
                                    "(needs a display and the dmc extra)")
    v.add_argument("--vehicle", type=Path, default=None, help="vehicle JSON (default: the paper vehicle)")
    v.add_argument("--task", choices=VIEW_TASKS, default="lemniscate")
    v.add_argument("--period", type=positive, default=10.0, help="lemniscate period, s (default 10)")
    v.add_argument("--duration", type=positive, default=None, help="episode length, s (default: the task's)")
    v.add_argument("--seed", type=int, default=0, help="min-snap path seed")
    add_policy(v)
    v.set_defaults(handler=cmd_view)


def has_display() -> bool:
    """An interactive window can open: macOS, or an X11 / Wayland display."""
    import os
    return sys.platform == "darwin" or bool(os.environ.get("DISPLAY") or os.environ.get("WAYLAND_DISPLAY"))


def cmd_view(args) -> int:
    if not has_display():
        vehicle = f" --vehicle {args.vehicle}" if args.vehicle else ""
        raise ValueError("no display (DISPLAY / WAYLAND_DISPLAY unset): the interactive viewer needs one; "
                         f"for a video instead: mjxsysid fly{vehicle} --controller policy --video --out DIR")
    try:
        from dm_control import viewer
    except ImportError:
        raise ValueError("mjxsysid view needs dm_control: pip install -e '.[dmc]'") from None
    from mjxsysid import theta as P
    from mjxsysid.envs import PolicyAgent, make_env
    theta = P.load_vehicle(args.vehicle) if args.vehicle else P.paper_hardware()
    env = make_env(theta, args.task, duration=args.duration, period=args.period, seed=args.seed)
    viewer.launch(env, policy=PolicyAgent(policy_ref(args)))
    return 0
