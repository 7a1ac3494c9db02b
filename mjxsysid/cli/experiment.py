"""`mjxsysid experiment NAME`: the paper's experiments.

Each command's parser (``add_*``) stands beside its handler (``cmd_*``). Handlers import what
they run when they run: `mjxsysid --help` stays instant (no JAX or MuJoCo import).
"""
from __future__ import annotations

import sys
from pathlib import Path

from mjxsysid.runtime import jsonout
from mjxsysid.cli._common import add_policy, policy_ref


def add_experiment(sub) -> None:
    ex = sub.add_parser("experiment", help="run one of the paper's experiments (results.json, results.md, PNGs)")
    ex.add_argument("name", help="tune-nominal | tune-slow | tune-lemniscate | robustness | payload | replay | probe-loop | "
                                 "probe-loop-seeds | lag-oracle | stress-prior-oracle | prediction-error | log-checks | "
                                 "long-flight-calibration | noise-sensitivity | rotorpy-noise | speed-table | sampler-reference")
    ex.add_argument("--quick", action="store_true", help="small CPU version (minutes; a smoke test)")
    ex.add_argument("--cpu", action="store_true",
                    help="tune-*: the full protocol with fewer vehicles and smaller ensembles (tens of minutes on a CPU)")
    ex.add_argument("--seed", type=int, default=None, help="default: the experiment's own (0 for most)")
    add_policy(ex)
    ex.add_argument("--decoders", type=Path, default=None,
                    help="folder with cfm.npz and regression.npz (default: the policy's shipped decoders)")
    ex.add_argument("--variant", default=None, metavar="V",
                    help="a protocol reported beside the default one (several joined by commas): heading_cost, "
                         "steady_rotor_state, true_rotor_state, baseline_start, protect, apply_best, "
                         "cem_3_iterations, horizon_1s (tune-*: see docs/fair_comparisons.md), no_lead_in "
                         "(tune-lemniscate), single_latent (robustness: the paper's single-latent CFM), accumulate "
                         "(probe-loop: each round fine-tunes the current policy on a re-scored replay buffer), widened "
                         "(probe-loop: a fair control on the default prior widened by the probe's reach, same budget), low "
                         "(noise-sensitivity: the levels below x 1), velocity (rotorpy-noise: the logs carry the body "
                         "velocity)")
    ex.add_argument("--inputs", type=Path, default=None, metavar="PATH",
                    help="experiments that read earlier runs: probe-loop-seeds (a probe-loop run), "
                         "long-flight-calibration (collect --seconds S pairs), speed-table (a folder of run folders)")
    ex.add_argument("--methods", default=None, metavar="M1,M2",
                    help="tune-*: the methods to fly (default: the experiment's own; naive, baseline, cfm, "
                         "nominal_cem, oracle_cem)")
    ex.add_argument("--logs", type=int, default=None, metavar="N",
                    help="sampler-reference: how many simulated logs (default 20; the noise levels in turn)")
    ex.add_argument("--chains", type=int, default=None, metavar="N", help="sampler-reference: NUTS chains per log (default 4)")
    ex.add_argument("--warmup", type=int, default=None, metavar="N",
                    help="sampler-reference: NUTS warm-up (window adaptation) steps per chain (default 1000)")
    ex.add_argument("--draws", type=int, default=None, metavar="N", help="sampler-reference: NUTS draws per chain (default 2000)")
    ex.add_argument("--out", type=Path, required=True)
    ex.set_defaults(handler=cmd_experiment)


def cmd_experiment(args) -> int:
    from mjxsysid.experiments import get_experiment
    run = get_experiment(args.name)
    if args.cpu and args.quick:
        raise ValueError("give either --quick or --cpu, not both")
    if args.cpu and not args.name.startswith("tune-"):
        raise ValueError(f"--cpu applies to the tune-* experiments, not {args.name}")
    kw = {"cpu": True} if args.cpu else {}
    if args.decoders is not None:
        import inspect
        if "decoders" not in inspect.signature(run).parameters:
            raise ValueError(f"experiment {args.name} does not take --decoders")
        if not args.decoders.is_dir():
            raise FileNotFoundError(f"--decoders: folder not found: {args.decoders}")
        kw["decoders"] = args.decoders
    if args.variant is not None:
        import inspect
        if "variant" not in inspect.signature(run).parameters:
            raise ValueError(f"experiment {args.name} has no variants")
        kw["variant"] = args.variant
    if args.methods is not None:
        if not args.name.startswith("tune-"):
            raise ValueError(f"--methods applies to the tune-* experiments, not {args.name}")
        from mjxsysid.tune.compare import check_methods
        kw["methods"] = check_methods(m.strip() for m in args.methods.split(",") if m.strip())
    if args.inputs is not None:
        import inspect
        if "inputs" not in inspect.signature(run).parameters:
            raise ValueError(f"experiment {args.name} does not take --inputs")
        kw["inputs"] = args.inputs
    for name in ("logs", "chains", "warmup", "draws"):
        if getattr(args, name) is not None:
            import inspect
            if name not in inspect.signature(run).parameters:
                raise ValueError(f"experiment {args.name} does not take --{name}")
            kw[name] = getattr(args, name)
    if args.seed is not None:
        kw["seed"] = args.seed
    res = run(args.out, quick=args.quick, policy=policy_ref(args), **kw)
    print(jsonout.dumps(res["numbers"].get("headline", {})))
    print(f"wrote {args.out}/results.json, results.md and figures ({res['wall_s']:.0f} s)", file=sys.stderr)
    return 0
