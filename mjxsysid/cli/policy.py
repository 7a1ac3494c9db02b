"""`mjxsysid train-policy | evaluate-policy | export`: the adaptive policy.

Each command's parser (``add_*``) stands beside its handler (``cmd_*``). Handlers import what
they run when they run: `mjxsysid --help` stays instant (no JAX or MuJoCo import).
"""
from __future__ import annotations

import sys
from pathlib import Path

from mjxsysid.runtime import jsonout
from mjxsysid.cli._common import add_policy, echo, policy_ref, positive


def add_train_policy(sub) -> None:
    t = sub.add_parser("train-policy", help="train the unified adaptive policy (GPU recommended)")
    t.add_argument("--config", type=Path, default=None,
                   help="JSON file of TrainConfig overrides (default: the shipped policy's config)")
    t.add_argument("--out", type=Path, default=Path("runs/policy"), help="run folder (checkpoints, log, policy.npz)")
    t.add_argument("--iterations", type=int, default=None, help="override config.iterations")
    t.add_argument("--num-envs", type=int, default=None, help="override config.num_envs")
    t.add_argument("--seed", type=int, default=None, help="override config.seed")
    t.add_argument("--no-resume", action="store_true", help="start afresh even if DIR/checkpoint.npz exists")
    t.add_argument("--focus", type=Path, default=None,
                   help="weak.npz of `mjxsysid probe`: its systems are mixed into the training vehicles")
    t.add_argument("--focus-weight", type=float, default=None,
                   help="fraction of episodes flying a focus system, in [0, 1] (default: config env.focus_weight, 0.3)")
    t.set_defaults(handler=cmd_train_policy)


def cmd_train_policy(args) -> int:
    from mjxsysid.policy.adaptive.config import TrainConfig, config_with_overrides
    from mjxsysid.policy.adaptive.train import train
    cfg_dict = config_with_overrides(args.config)
    for k, v in (("iterations", args.iterations), ("num_envs", args.num_envs), ("seed", args.seed)):
        if v is not None:
            cfg_dict[k] = v
    if args.focus is not None:
        cfg_dict["focus"] = str(args.focus)
    if args.focus_weight is not None:
        if not 0.0 <= args.focus_weight <= 1.0:
            raise ValueError(f"--focus-weight must be in [0, 1], got {args.focus_weight}")
        cfg_dict["env"] = dict(cfg_dict["env"], focus_weight=args.focus_weight)
    if cfg_dict.get("focus") is not None:
        from mjxsysid.policy.adaptive.focus import load_weak
        n = len(load_weak(cfg_dict["focus"])[0])     # checked before anything trains
        echo(f"focus: {n} weak systems from {cfg_dict['focus']}, {cfg_dict['env']['focus_weight']:.0%} of episodes")
    try:
        cfg = TrainConfig.from_dict(cfg_dict)
    except TypeError as e:  # e.g. an unknown key of the env section
        raise ValueError(f"{args.config or 'training config'}: {e}") from None
    echo(f"training: {cfg.num_envs} envs × {cfg.unroll} steps × {cfg.iterations} iterations "
          f"= {cfg.num_envs * cfg.unroll * cfg.iterations / 1e6:.1f} M env steps -> {args.out}")
    res = train(cfg, args.out, resume=not args.no_resume, log=echo)
    print(jsonout.dumps({"wall_s": res["wall_s"], **{k: res["stats"][k] for k in
                      ("reward", "rate_err", "thrust_err", "latent_err_rel", "latent_min_std")}}))
    print(f"wrote {args.out}/policy.npz", file=sys.stderr)
    return 0


def add_evaluate_policy(sub) -> None:
    e = sub.add_parser("evaluate-policy", help="evaluate an adaptive policy (tracking, lemniscate, latent health)")
    e.add_argument("--weights", action="append", default=None, metavar="[LABEL=]PATH",
                   help="policy.npz or run folder (default: shipped); mjxsysid's policies only (training "
                   "diagnostics need its μ encoder). With --held-out: repeat it to compare several policies")
    e.add_argument("--vehicles", type=int, default=None,
                   help="vehicles (default 1000; --held-out: per set, default 64)")
    e.add_argument("--seed", type=int, default=0)
    e.add_argument("--fast", action="store_true", help="the quick latent/lemniscate evaluation of training "
                   "trials (probes on 2 x VEHICLES, lemniscate on VEHICLES)")
    e.add_argument("--held-out", action="store_true",
                   help="every policy and the oracle on the default, stress and stress_wide priors and the "
                   "held-out families (theta.HELDOUT_FAMILIES): OUT/results.json and results.md")
    e.add_argument("--sets", default=None, metavar="S1,S2",
                   help="--held-out: the sets to fly (default: all of them)")
    e.add_argument("--period", type=positive, default=10.0, help="--held-out: the lemniscate's period (s)")
    e.add_argument("--out", type=Path, required=True, help="writes OUT/eval.json (--held-out: OUT/results.*)")
    e.set_defaults(handler=cmd_evaluate_policy)


def cmd_evaluate_policy(args) -> int:
    if args.held_out:
        return _held_out(args)
    if args.sets is not None:
        raise ValueError("--sets applies to --held-out only")
    if args.weights is not None and len(args.weights) > 1:
        raise ValueError("--weights: one policy (several only with --held-out)")
    args.weights = None if args.weights is None else Path(args.weights[0])
    args.vehicles = 1000 if args.vehicles is None else args.vehicles
    from mjxsysid.policy.adaptive.evaluate import evaluate_policy
    if args.vehicles < 10:
        raise ValueError(f"--vehicles must be >= 10 (linear probes need data), got {args.vehicles}")
    args.out.mkdir(parents=True, exist_ok=True)
    if args.fast:
        from mjxsysid.policy.adaptive.controller import PolicyController
        from mjxsysid.policy.adaptive.evaluate import fast_eval
        ctrl = PolicyController.load(args.weights)
        res = fast_eval(ctrl.params, n_probe=2 * args.vehicles, n_lem=args.vehicles, seed=args.seed,
                        phi_every=ctrl.phi_every, log=echo)
        (args.out / "eval.json").write_text(jsonout.dumps(res, indent=2) + "\n")
        print(jsonout.dumps(res["summary"]))
        print(f"wrote {args.out}/eval.json", file=sys.stderr)
        return 0
    res = evaluate_policy(args.weights, n=args.vehicles, seed=args.seed, log=echo)
    (args.out / "eval.json").write_text(jsonout.dumps(res, indent=2) + "\n")
    lem = res["lemniscate"]
    print(jsonout.dumps({"success_policy": lem["policy"]["success_rate"],
                      "pos_rmse_policy": lem["policy"]["pos_rmse_m"]["mean"],
                      "pos_rmse_oracle": lem["oracle"]["pos_rmse_m"]["mean"],
                      "rmse_ratio": lem.get("rmse_ratio_policy_over_oracle"),
                      "z_err_rel": res["latent"]["z_err_rel"]}))
    print(f"wrote {args.out}/eval.json", file=sys.stderr)
    return 0


def _held_out(args) -> int:
    from mjxsysid.experiments.heldout import SETS, parse_policies, run
    if args.fast:
        raise ValueError("give either --held-out or --fast, not both")
    vehicles = 64 if args.vehicles is None else args.vehicles
    if vehicles < 1:
        raise ValueError(f"--vehicles must be >= 1, got {vehicles}")
    sets = SETS if args.sets is None else tuple(s.strip() for s in args.sets.split(",") if s.strip())
    res = run(args.out, parse_policies(args.weights), sets=sets, vehicles=vehicles, period=args.period,
              seed=args.seed)
    print(jsonout.dumps({k: v["all"] for k, v in res["numbers"]["targets"].items()}))
    print(f"wrote {args.out}/results.json and results.md ({res['wall_s']:.0f} s)", file=sys.stderr)
    return 0


def add_export(sub) -> None:
    xp = sub.add_parser("export", help="write the policy as ONNX (fixed batch 1 + dynamic batch), check it in onnxruntime")
    add_policy(xp, "the policy to export")
    xp.add_argument("--out", type=Path, required=True,
                    help="NAME.onnx (batch 1); also writes NAME_dynamic.onnx, NAME.onnx.json, NAME_testvectors.npz")
    xp.add_argument("--seconds", type=positive, default=0.5,
                    help="closed-loop flight of the paper vehicle whose inputs check the files (default 0.5)")
    xp.add_argument("--calls", type=int, default=2000, help="onnxruntime calls per latency median (default 2000)")
    xp.set_defaults(handler=cmd_export)


def cmd_export(args) -> int:
    from mjxsysid.policy.export.run import ExportConfig, check_out
    check_out(args.out)
    if args.calls < 10:
        raise ValueError(f"--calls must be >= 10, got {args.calls}")
    if args.seconds < 0.1:
        raise ValueError(f"--seconds must be >= 0.1 (the check needs ẑ refreshes), got {args.seconds}")
    ref = policy_ref(args)
    if ref.kind != "mjxsysid":
        raise ValueError(f"--policy {ref.kind}: the released Xadap policy already is ONNX (encoder.onnx, "
                         f"mlp.onnx); export writes mjxsysid's own policy")
    try:
        import jax2onnx  # noqa: F401
        import onnxruntime  # noqa: F401
    except ImportError as e:
        raise ValueError(f"export needs jax2onnx and onnxruntime ({e.name} missing): "
                         f"pip install 'mjxsysid[export]'") from None
    from mjxsysid.policy.export.run import run_export
    cfg = ExportConfig(flight_seconds=args.seconds, latency_calls=args.calls)
    d = run_export(ref, args.out, cfg, log=lambda m: print(m, file=sys.stderr, flush=True))
    par, lat = d["parity"], d["latency"]["batch_1"]
    print(jsonout.dumps({"max_abs_diff": par["max_abs_diff"], "parity_ok": par["ok"],
                      "latency_us_batch1": lat["step_us"]["median_us"],
                      "latency_us_batch1_refresh": lat["refresh_step_us"]["median_us"],
                      "latency_us_batch1_mean": lat["mean_per_step_us"]}))
    print(f"onnxruntime vs JAX controller on {par['steps']} recorded steps: max abs diff "
          f"{par['max_abs_diff']:.2e} (target <= {par['tolerance']:g}); latency per step, batch 1: "
          f"{lat['step_us']['median_us']:.1f} µs, with the ẑ refresh {lat['refresh_step_us']['median_us']:.1f} µs "
          f"(median of {args.calls}; {d['latency']['runtime']})", file=sys.stderr)
    if not par["ok"]:
        print(f"mjxsysid export: parity target missed ({par['max_abs_diff']:.2e} > {par['tolerance']:g})",
              file=sys.stderr)
        return 1
    return 0
