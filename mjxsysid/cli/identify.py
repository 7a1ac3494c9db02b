"""`mjxsysid calibrate-posterior`: the log-grounded posterior's calibration by simulation (collect, fit, evaluate).

Each command's parser (``add_*``) stands beside its handler (``cmd_*``); a handler imports what it
runs when it runs, so `mjxsysid --help` stays instant.
"""
from __future__ import annotations

from pathlib import Path

from mjxsysid.cli._common import echo, positive


def add_calibrate_posterior(sub) -> None:
    cp = sub.add_parser("calibrate-posterior",
                        help="calibrate the log-grounded posterior's bands by simulation: collect rows, fit the "
                             "table, evaluate it on held-out rows (docs/identify.md)")
    mode = cp.add_mutually_exclusive_group(required=True)
    mode.add_argument("--collect", type=Path, metavar="OUT.json",
                      help="fly and identify simulated vehicles (raw posterior), write one row per log")
    mode.add_argument("--fit", type=Path, nargs="+", metavar="ROWS",
                      help="fit the table on these row files or folders (written to --out)")
    mode.add_argument("--evaluate", type=Path, nargs="+", metavar="ROWS",
                      help="evaluate --table on these held-out rows (written to the folder --out)")
    cp.add_argument("--prior", default="wide_actuators", help="--collect: a prior or a held-out family")
    cp.add_argument("--controller", choices=("oracle", "policy"), default="oracle",
                    help="--collect: who flies the vehicles (default the lag-aware oracle; policy: the shipped one)")
    cp.add_argument("--vehicles", type=int, default=64, help="--collect: vehicles drawn (default 64)")
    cp.add_argument("--levels", default="clean,x1,x5_white,x5_vibration,x20",
                    help="--collect: IMU noise levels, comma-separated (mjxsysid.uses.imu_noise.LEVELS)")
    cp.add_argument("--seed", type=int, default=5, help="--collect: the vehicles' and flights' seed")
    cp.add_argument("--aero", action="store_true",
                    help="--collect: fly with rotor aerodynamics (SimConfig.aero: RotorPy's rotor drag, induced inflow, "
                         "parasitic drag and translational lift, scaled to the vehicle)")
    cp.add_argument("--motor-idle", type=float, default=0.0, metavar="SHARE",
                    help="--collect: fly with an idle offset in the static motor map, a share of the maximum rotor "
                         "speed (SimConfig.motor_idle; default 0)")
    cp.add_argument("--motor-kappa", type=float, default=1.0, metavar="K",
                    help="--collect: the static motor map's curvature (SimConfig.motor_kappa, 0–2; 1 linear, the "
                         "default; 0 a square root; 2 a square)")
    cp.add_argument("--no-velocity", action="store_true",
                    help="--collect: drop the logs' body velocity (logs without a state estimate: the drag unmodelled)")
    cp.add_argument("--flights", default="lemniscate:10",
                    help="--collect: the flights, comma-separated: lemniscate:PERIOD, minsnap:SECONDS, hover:SECONDS "
                         "(default lemniscate:10)")
    cp.add_argument("--paths", type=int, default=1, metavar="K",
                    help="--collect: fly each flight's vehicles in K groups, each drawing its own path (min-snap: one "
                         "path per group; default 1, every vehicle the same path at a level)")
    cp.add_argument("--shard", default=None, metavar="I/K", help="--collect: every K-th vehicle from the I-th")
    cp.add_argument("--time-budget", type=positive, default=None, metavar="S",
                    help="--collect: start no new flight after S seconds (rows so far are kept)")
    cp.add_argument("--table", type=Path, default=None,
                    help="--evaluate: the table (default the shipped one)")
    cp.add_argument("--record", action="store_true",
                    help="--evaluate: write the mean coverage per level into the table's provenance")
    cp.add_argument("--method", choices=("smc", "smc_nuts"), default=None,
                    help="--fit: fit on the rows of this sampler only (smc_nuts: NUTS's mixed chains) and add the "
                         "table to --base as that sampler's own")
    cp.add_argument("--base", type=Path, default=None,
                    help="--fit --method: the table it is added to (default the shipped one)")
    cp.add_argument("--note", default="", help="--fit: where and how the rows were collected (the provenance)")
    cp.add_argument("--out", type=Path, default=None,
                    help="--fit: the table's path (default the shipped one); --evaluate: a folder")
    cp.set_defaults(handler=cmd_calibrate_posterior)


def cmd_calibrate_posterior(args) -> int:
    from mjxsysid.experiments import posterior_calibration as pc
    from mjxsysid.identify.calibrate import SHIPPED
    if args.collect:
        res = pc.collect(prior=args.prior, vehicles=args.vehicles, levels=tuple(args.levels.split(",")),
                         seed=args.seed, shard=args.shard, out=args.collect, time_budget_s=args.time_budget,
                         references=tuple(args.flights.split(",")), controller=args.controller, aero=args.aero,
                         velocity=not args.no_velocity, motor_idle=args.motor_idle, motor_kappa=args.motor_kappa,
                         paths=args.paths)
        echo(f"{len(res['rows'])} rows -> {args.collect}")
    elif args.fit:
        out = args.out or SHIPPED
        table = pc.fit_file(args.fit, out, note=args.note, method=args.method, base=args.base)
        sub = table["by_method"][args.method] if args.method else table
        echo(f"calibration of {sub['logs']} logs" + (f" ({args.method}'s table)" if args.method else "") + f" -> {out}")
    else:
        if args.out is None:
            raise ValueError("--evaluate needs --out FOLDER")
        res = pc.report(args.evaluate, args.table, args.out, record=args.record)
        echo((args.out / "evaluation.md").read_text())
        echo(f"{res['rows']} held-out rows -> {args.out}")
    return 0
