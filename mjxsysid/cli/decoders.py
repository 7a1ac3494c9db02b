"""`mjxsysid collect | train-cfm | evaluate-decoder`: (θ, ẑ) pairs and the decoders trained on them.

Each command's parser (``add_*``) stands beside its handler (``cmd_*``). Handlers import what
they run when they run: `mjxsysid --help` stays instant (no JAX or MuJoCo import).
"""
from __future__ import annotations

import sys
from pathlib import Path

from mjxsysid.runtime import jsonout
from mjxsysid.cli._common import PRIOR_CHOICES, add_policy, echo, policy_ref, positive


def add_collect(sub) -> None:
    c = sub.add_parser("collect", help="collect (θ, ẑ) pairs from a frozen policy in closed-loop flight")
    c.add_argument("--out", type=Path, required=True, help="writes OUT/pairs.npz")
    add_policy(c)
    c.add_argument("--train", type=int, default=20_000, help="training pairs (default 20000)")
    c.add_argument("--test", type=int, default=2_000, help="held-out pairs (default 2000)")
    c.add_argument("--prior", choices=PRIOR_CHOICES, default=None,
                   help="vehicle prior (default: the one its shipped decoders are trained on: wide_actuators "
                        "for mjxsysid (its training prior with τ_m up to 0.10 s), xadap for xadap)")
    c.add_argument("--batch", type=int, default=2_000, help="vehicles per batched flight")
    c.add_argument("--seed", type=int, default=0)
    c.add_argument("--seconds", type=positive, default=10.0,
                   help="flight length, s: the latent is recorded at 10 Hz over it (default 10)")
    c.add_argument("--manoeuvres", default="lemniscate,minsnap,hover_step",
                   help="comma-separated manoeuvres drawn per vehicle (default: lemniscate,minsnap,hover_step)")
    c.add_argument("--single-latent", action="store_true",
                   help="the shipped single-latent pairs instead: 1.5 s lemniscates, ẑ at the end, no trajectories")
    c.add_argument("--imu-noise", type=float, nargs=2, default=(0.0, 0.0), metavar=("GYRO", "ACCEL"),
                   help="white IMU noise per 2 ms sample, rad/s and m/s² (default none)")
    c.add_argument("--imu-bias", type=float, nargs=2, default=(0.0, 0.0), metavar=("GYRO", "ACCEL"),
                   help="std of a per-flight IMU bias, rad/s and m/s² (default none)")
    c.add_argument("--imu-vibration", type=float, nargs=2, default=(0.0, 0.0), metavar=("GYRO", "ACCEL"),
                   help="std of rotor vibration on the IMU, rad/s and m/s² (default none)")
    c.add_argument("--randomize-imu", action="store_true",
                   help="the --imu-* values are maxima: each flight draws its own levels in [0, 1] x them")
    c.add_argument("--imu-clean-fraction", type=float, default=0.0, metavar="F",
                   help="with --randomize-imu: this share of flights has a clean IMU (default 0)")
    c.set_defaults(handler=cmd_collect)


def imu_config(args):
    """The simulator config of ``--imu-noise/--imu-bias/--imu-vibration/--randomize-imu``."""
    from mjxsysid.sim import SimConfig
    kw = {}
    for flag, names in (("imu_noise", ("gyro_noise", "accel_noise")), ("imu_bias", ("gyro_bias", "accel_bias")),
                        ("imu_vibration", ("gyro_vibration", "accel_vibration"))):
        for name, v in zip(names, getattr(args, flag)):
            if not v >= 0:
                raise ValueError(f"--{flag.replace('_', '-')} must be >= 0 (rad/s, m/s²), got {v}")
            kw[name] = float(v)
    f = float(getattr(args, "imu_clean_fraction", 0.0))
    if not 0.0 <= f <= 1.0:
        raise ValueError(f"--imu-clean-fraction must be in [0, 1], got {f}")
    if f > 0 and not args.randomize_imu:
        raise ValueError("--imu-clean-fraction needs --randomize-imu (it is a share of the per-flight draws)")
    return SimConfig(**kw, randomize_imu=bool(args.randomize_imu), imu_clean_fraction=f)


def cmd_collect(args) -> int:
    from mjxsysid.dataset.collect import collect
    ref = policy_ref(args)
    echo(f"collecting {args.train} + {args.test} (θ, ẑ) pairs with {ref.label}")
    manoeuvres = tuple(m.strip() for m in args.manoeuvres.split(",") if m.strip())
    path = collect(args.out, policy=ref, n_train=args.train,
                   n_test=args.test, prior=args.prior, seed=args.seed, batch=args.batch,
                   seconds=None if args.single_latent else args.seconds, manoeuvres=manoeuvres,
                   sim_config=imu_config(args), log=echo)
    print(f"wrote {path}", file=sys.stderr)
    return 0


def add_train_cfm(sub) -> None:
    tc = sub.add_parser("train-cfm", help="train the CFM and Regression decoders on (θ, ẑ) pairs")
    tc.add_argument("--pairs", type=Path, required=True, help="pairs.npz from `mjxsysid collect` (or its folder)")
    tc.add_argument("--out", type=Path, required=True,
                    help="writes OUT/cfm.npz, OUT/regression.npz (and OUT/cfm_seq.npz, see --kinds)")
    tc.add_argument("--epochs", type=int, default=None, help="override CFMConfig.epochs (default 100)")
    tc.add_argument("--width", type=int, default=None, help="override CFMConfig.width (default 512)")
    tc.add_argument("--batch", type=int, default=None, help="override CFMConfig.batch (default 256)")
    tc.add_argument("--seed", type=int, default=None,
                    help="override CFMConfig.seed (default 0): the decoders' initialisation, minibatch order and "
                         "validation split")
    tc.add_argument("--no-resume", action="store_true",
                    help="start afresh even if OUT holds checkpoints or decoders of an earlier run")
    tc.add_argument("--kinds", default=None,
                    help="comma-separated decoders to train: cfm, regression, cfm_seq (default: all three when "
                         "the pairs hold latent trajectories, else cfm,regression)")
    tc.add_argument("--seq-epochs", type=int, default=None, help="epochs of the sequence decoder (default: --epochs)")
    tc.add_argument("--coords", choices=("theta", "identifiable"), default=None,
                    help="coordinates the decoders learn in: identifiable (default: a log-linear reparametrisation "
                         "with log thrust-to-weight and log angular authorities as axes) or theta (normalised θ)")
    add_policy(tc, "check that the pairs come from this policy")
    tc.set_defaults(handler=cmd_train_cfm)


def cmd_train_cfm(args) -> int:
    import dataclasses

    from mjxsysid.cfm.pipeline import train_decoders
    from mjxsysid.cfm.train import CFMConfig
    if args.policy is not None or args.weights is not None:
        from mjxsysid.dataset.collect import load_pairs
        want = policy_ref(args)
        got = load_pairs(args.pairs)[1].get("weights_sha256")
        if got != want.sha256():
            raise ValueError(f"{args.pairs}: these pairs were not collected with {want.label}")
    over = {k: v for k, v in (("epochs", args.epochs), ("width", args.width), ("batch", args.batch),
                              ("seed", args.seed), ("coords", args.coords)) if v is not None}
    cfg = dataclasses.replace(CFMConfig(), **over)
    kinds = None if args.kinds is None else tuple(k.strip() for k in args.kinds.split(",") if k.strip())
    seq_cfg = {"epochs": args.seq_epochs} if args.seq_epochs is not None else None
    res = train_decoders(args.pairs, args.out, cfg, kinds=kinds, seq_cfg=seq_cfg, log=echo,
                         resume=not args.no_resume)
    print(jsonout.dumps({k: {kk: v[kk] for kk in ("wall_s", "final_train_loss", "final_val_loss", "steps_per_s")}
                      for k, v in res.items()}))
    return 0


def add_evaluate_decoder(sub) -> None:
    ed = sub.add_parser("evaluate-decoder", help="calibration of the decoders on held-out pairs")
    ed.add_argument("--decoders", type=Path, required=True,
                    help="folder with cfm.npz and regression.npz and/or cfm_seq.npz (the sequence decoder; "
                         "a cfm.npz alone is only its single-latent reference)")
    ed.add_argument("--pairs", type=Path, required=True)
    ed.add_argument("--cases", type=int, default=1000)
    ed.add_argument("--no-paper-flight", action="store_true",
                    help="skip flying the paper vehicle (its posterior plots / 10 s lemniscate figures)")
    ed.add_argument("--samples", type=int, default=200)
    add_policy(ed, "policy whose latent of the paper vehicle is decoded for the marginals plot "
                    "(default: the one that made the pairs)")
    ed.set_defaults(handler=cmd_evaluate_decoder)


def cmd_evaluate_decoder(args) -> int:
    from mjxsysid.cfm.pipeline import evaluate_decoders
    from mjxsysid.dataset.collect import load_pairs, paper_vehicle_latents
    from mjxsysid.policy.interface import resolve_policy
    if args.policy is None and args.weights is None:
        meta = load_pairs(args.pairs)[1]
        kind = meta.get("policy", meta.get("controller", "mjxsysid"))  # older pairs: "controller"
        w = meta.get("weights")
        if w is not None and not Path(w).exists():
            if kind != "mjxsysid":
                raise ValueError(f"{args.pairs} was collected with {kind} weights at {w}, not found here: "
                                 f"pass --policy {kind} --weights PATH")
            w = None
        ref = resolve_policy(kind, w)
    else:
        ref = policy_ref(args)
    paper_zhat = paper_traj = None
    if not args.no_paper_flight:   # the paper vehicle: ẑ after 1.5 s; ẑ at 10 Hz over a 10 s lemniscate
        paper_zhat, paper_traj = paper_vehicle_latents(
            ref, instant=(args.decoders / "cfm.npz").is_file() and (args.decoders / "regression.npz").is_file(),
            flight=(args.decoders / "cfm_seq.npz").is_file())
    rep = evaluate_decoders(args.decoders, args.pairs, n_cases=args.cases, n_samples=args.samples,
                            paper_zhat=paper_zhat, paper_traj=paper_traj, log=echo)
    brief = {}
    if "energy_score" in rep:
        brief = {"coverage_mean": rep["coverage_mean"], "calibrated": rep["calibrated_within_5_points"],
                 "energy_score": rep["energy_score"], "c2st": rep["c2st_nearby_latents"]["mean_accuracy"]}
    if "sequence" in rep:
        sq = rep["sequence"]
        brief["sequence"] = {"energy_score": {k: v["energy_score"] for k, v in sq["windows"].items()},
                             "energy_ratio_flight_vs_single": sq["energy_ratio_flight_vs_single"],
                             "targets": sq["targets"],
                             "paper_vehicle": sq.get("paper_vehicle", {}).get("targets")}
    print(jsonout.dumps(brief))
    figs = ", sbc_ranks.png" + (", paper_vehicle_posterior.png" if paper_zhat is not None else "") if "energy_score" in rep else ""
    print(f"wrote {args.decoders}/decoder_eval.json{figs}", file=sys.stderr)
    return 0
