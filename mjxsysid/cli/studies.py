"""`mjxsysid decode | check-log | replay`: decoding a flight or a log, checking a log, and action replay.

Each command's parser (``add_*``) stands beside its handler (``cmd_*``). Handlers import what
they run when they run: `mjxsysid --help` stays instant (no JAX or MuJoCo import).
"""
from __future__ import annotations

import sys
from pathlib import Path

from mjxsysid import jsonout
from mjxsysid.cli._common import FLIGHT_NAMES, add_policy, echo, policy_ref, positive, prepare_render


def add_decode(sub) -> None:
    dc = sub.add_parser("decode", help="fly a vehicle (or replay a log) with the policy and decode its latent")
    dc.add_argument("--vehicle", type=Path, default=None, help="vehicle JSON (default: the paper vehicle)")
    dc.add_argument("--log", type=Path, nargs="+", default=None,
                    help="decode a recorded flight instead: a CSV (the contract: docs/decoding.md), a PX4 ULog "
                         "(docs/px4.md), a Crazyflie uSD log, a Betaflight blackbox, an ArduPilot DataFlash log or a ROS bag (docs/logs.md); "
                         "several files or a folder: each into OUT/NAME and one table, OUT/fleet.md")
    dc.add_argument("--segment", default=None, metavar="T0:T1",
                    help="with --log: decode only this part, in seconds (a ULog: since its start; default its armed, "
                         "airborne segment; a CSV: its t column)")
    dc.add_argument("--truth", type=Path, default=None,
                    help="with --log: the logged vehicle's JSON, if known (the summary then says whether "
                         "each true parameter is inside the decoded interval)")
    dc.add_argument("--reference", choices=("hover", "lemniscate", "minsnap"), default="lemniscate")
    dc.add_argument("--period", type=positive, default=10.0)
    dc.add_argument("--duration", type=positive, default=None)
    dc.add_argument("--samples", type=int, default=100, help="decoded models per latent (default 100)")
    dc.add_argument("--rate", type=positive, default=10.0, help="decoding rate, Hz (default 10)")
    dc.add_argument("--window", default="flight",
                    help="what each decoded posterior conditions on: 'flight' (default: every latent flown so far, "
                         "sequence decoder), 'instant' (the current latent only) or SECONDS (a sliding window)")
    add_policy(dc)
    dc.add_argument("--decoders", type=Path, default=None,
                    help="folder with cfm.npz and regression.npz, and cfm_seq.npz for --window flight|SECONDS "
                         "(default: the policy's shipped decoders)")
    dc.add_argument("--rates", choices=("windows", "innovations"), default=None,
                    help="with --log: the log-grounded likelihood's rate term (default windows; innovations: "
                         "unbiased in closed loop under white IMU noise, wrong under a rotor vibration; "
                         "docs/identify.md, 'The rate term, two ways')")
    dc.add_argument("--decoder-only", action="store_true",
                    help="with --log: report the decoders' posterior alone (default: the log-grounded posterior — "
                         "the log's IMU given its motor commands, the decoded samples as proposal — with the "
                         "decoders' beside it and the information gap; docs/identify.md)")
    dc.add_argument("--seed", type=int, default=0)
    dc.add_argument("--video", action="store_true", help="render the true vehicle with decoded ghosts")
    dc.add_argument("--out", type=Path, required=True)
    dc.set_defaults(handler=cmd_decode)


def cmd_decode(args) -> int:
    if args.video:
        prepare_render()
    from mjxsysid import theta as P
    from mjxsysid.studies.decode import run_decode
    from mjxsysid.studies.decode.run import printed_summary
    if args.log is not None and args.vehicle is not None:
        raise ValueError("give either --vehicle or --log, not both (the known vehicle of a log: --truth)")
    if args.truth is not None and args.log is None:
        raise ValueError("--truth needs --log (a flown --vehicle is its own truth)")
    truth = None if args.truth is None else P.load_vehicle(args.truth)
    from mjxsysid.studies.decode import parse_window
    window = parse_window(args.window)
    if args.segment is not None and args.log is None:
        raise ValueError("--segment needs --log")
    if args.rates is not None and (args.log is None or args.decoder_only):
        raise ValueError("--rates needs --log and the log-grounded posterior (not --decoder-only)")
    if args.log is not None:
        from mjxsysid.studies.decode.fleet import expand_logs
        logs = expand_logs(args.log)
        if len(logs) > 1:
            return _decode_fleet(args, logs, truth, window)
        args.log = logs[0]
    theta = None if args.log else (P.load_vehicle(args.vehicle) if args.vehicle else P.paper_hardware())
    existed = Path(args.out).exists()
    try:
        summary = run_decode(args.out, theta=theta, log=args.log, reference=args.reference, period=args.period,
                             duration=args.duration, samples=args.samples, rate=args.rate, policy=policy_ref(args),
                             decoders=args.decoders, seed=args.seed, video=args.video, window=window, truth=truth,
                             echo=lambda m: echo(m, file=sys.stderr), segment=args.segment,
                             decoder_only=args.decoder_only, rates=args.rates)
    except BaseException:
        if not existed and Path(args.out).is_dir():   # no half-written output folder of this run left behind
            import shutil
            shutil.rmtree(args.out, ignore_errors=True)
        raise
    print(jsonout.dumps(printed_summary(summary)))
    print(f"wrote {args.out}/decoded.npz, summary.json, marginals.png, decoded_over_time.png"
          + (", marginals_decoder_only.png, information_gap.png" if "_log_grounded" in summary else "")
          + (", decoded.mp4" if args.video else ""), file=sys.stderr)
    return 0


def _decode_fleet(args, logs, truth, window) -> int:
    """``decode --log`` of several logs: each into OUT/NAME (a refused log: its reason in the table)."""
    from mjxsysid.logs.checks.findings import LogError
    from mjxsysid.progress import progress
    from mjxsysid.studies.decode import run_decode
    from mjxsysid.studies.decode.fleet import fleet_markdown, fleet_row
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    rows = []
    for log in progress(logs, desc="logs"):
        try:
            summary = run_decode(out / log.stem, theta=None, log=log, reference=args.reference, period=args.period,
                                 duration=args.duration, samples=args.samples, rate=args.rate, policy=policy_ref(args),
                                 decoders=args.decoders, seed=args.seed, video=args.video, window=window, truth=truth,
                                 echo=lambda m: echo(m, file=sys.stderr), segment=args.segment,
                                 decoder_only=args.decoder_only, rates=args.rates)
            rows.append(fleet_row(log.name, summary))
        except (ValueError, LogError, ImportError, OSError) as e:
            rows.append(fleet_row(log.name, None, str(e).splitlines()[0]))
    (out / "fleet.json").write_text(jsonout.dumps(rows, indent=1) + "\n")
    table = fleet_markdown(rows)
    (out / "fleet.md").write_text("# Fleet\n\n" + table)
    print(table)
    print(f"wrote {out}/fleet.md, fleet.json and a folder per log", file=sys.stderr)
    return 0 if any("error" not in r for r in rows) else 2


def add_check_log(sub) -> None:
    ck = sub.add_parser("check-log", help="the physical plausibility checks of a flight log alone (CSV or PX4 ULog)")
    ck.add_argument("log", type=Path, metavar="FILE",
                    help="a flight-log CSV (docs/decoding.md) or a PX4 ULog .ulg (docs/px4.md)")
    ck.add_argument("--segment", default=None, metavar="T0:T1",
                    help="check only this part, in seconds (a ULog: since its start; default its armed, airborne "
                         "segment; a CSV: its t column)")
    ck.add_argument("--prior", default="wide_actuators",
                    help="the decoders' training prior the log-only vehicle estimates are compared with "
                         "(default wide_actuators, the shipped decoders'; 'none': not compared)")
    ck.add_argument("--json", action="store_true", help="print the findings and estimates as JSON instead of a table")
    ck.set_defaults(handler=cmd_check_log)


def cmd_check_log(args) -> int:
    """Exit 2 on an error finding, 1 on a warning or out-of-prior finding, 0 on none."""
    from mjxsysid.logs import checks as L
    from mjxsysid.logs.csvlog import read_any_log
    rec = read_any_log(args.log, args.segment)
    found = L.check_log(rec)
    est = None
    if not any(f.level == "error" for f in found):
        est = L.estimate_vehicle(rec)
        if args.prior.lower() != "none":
            found += L.prior_check(rec, args.prior, est)
    src = rec.get("source")
    if args.json:
        tau = L.motor_time_constant(est) if est else (None, None)
        print(jsonout.dumps({"findings": [f.as_dict() for f in found], "estimates": est,
                          "notes": [tau[1]] if est and tau[0] is None else [], "source": src,
                          "resampled": rec.get("resampled")}, indent=2))
    else:
        t = rec["t"]
        print(f"{args.log}: {len(t)} rows, {t[-1] - t[0] + 0.002:.2f} s"
              + (f" ({src['format']}, segment {src['segment']['t0']:.3f}–{src['segment']['t1']:.3f} s: "
                 f"{src['segment']['why']})" if src else ""))
        for k, how in (rec.get("resampled") or {}).items():
            print(f"  {k}: {how}")
        if est:
            tau, why = L.motor_time_constant(est)
            print(f"estimates: thrust-to-weight {est['thrust_to_weight']:.3g}, motor time constant "
                  + (f"{tau * 1e3:.3g} ms" if tau is not None else "not estimable")
                  + f", weakest motor {est['min_motor_effectiveness']:.2g}, IMU noise {est['gyro_noise']:.2g} rad/s "
                    f"/ {est['accel_noise']:.2g} m/s²")
            if tau is None:
                print(f"note: {why}")
        if not found:
            print("no findings")
        else:
            rows = [(f.level.replace("_", " "), f.column, f.message) for f in found]
            w0, w1 = max(len(r[0]) for r in rows), max(len(r[1]) for r in rows)
            print(f"{'level':<{w0}}  {'columns':<{w1}}  message")
            for lv, col, msg in rows:
                print(f"{lv:<{w0}}  {col:<{w1}}  {msg}")
    levels = {f.level for f in found}
    return 2 if "error" in levels else 1 if levels & {"warning", "out_of_prior"} else 0


def add_replay(sub) -> None:
    rp = sub.add_parser("replay", help="action replay: K_θ̂ from decoded θ̂ vs the policy's motor commands")
    add_policy(rp)
    rp.add_argument("--decoders", type=Path, default=None,
                    help="folder with cfm.npz and regression.npz (default: the policy's shipped decoders)")
    rp.add_argument("--flights", default=",".join(FLIGHT_NAMES),
                    help=f"comma-separated subset of {','.join(FLIGHT_NAMES)} (default: all)")
    rp.add_argument("--vehicles", type=int, default=0,
                    help="also replay this many vehicles of the policy's own prior (default 0: paper vehicle only)")
    rp.add_argument("--samples", type=int, default=16, help="CFM samples per update for the mean action (default 16)")
    rp.add_argument("--rate", type=positive, default=10.0, help="decoder update rate, Hz (default 10)")
    rp.add_argument("--cutoff", type=positive, default=5.0, help="low-pass cut-off for the PCC, Hz (default 5)")
    rp.add_argument("--seed", type=int, default=0)
    rp.add_argument("--out", type=Path, required=True)
    rp.set_defaults(handler=cmd_replay)


def cmd_replay(args) -> int:
    from mjxsysid.studies.replay import run_replay
    flights = tuple(f.strip() for f in args.flights.split(",") if f.strip())
    res = run_replay(args.out, policy=policy_ref(args), decoders=args.decoders, vehicles=args.vehicles,
                     flights=flights, rate=args.rate, samples=args.samples, cutoff_hz=args.cutoff,
                     seed=args.seed, log=lambda m: echo(m, file=sys.stderr))
    print(jsonout.dumps({n: e["paper_vehicle"] for n, e in res["flights"].items()}))
    print(f"wrote {args.out}/replay.json, replay.md, replay_summary.png, replay_<flight>.png", file=sys.stderr)
    return 0


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
                    help="--collect: IMU noise levels, comma-separated (mjxsysid.studies.noise.LEVELS)")
    cp.add_argument("--seed", type=int, default=5, help="--collect: the vehicles' and flights' seed")
    cp.add_argument("--flights", default="lemniscate:10",
                    help="--collect: the flights, comma-separated: lemniscate:PERIOD, minsnap:SECONDS, hover:SECONDS "
                         "(default lemniscate:10)")
    cp.add_argument("--shard", default=None, metavar="I/K", help="--collect: every K-th vehicle from the I-th")
    cp.add_argument("--time-budget", type=positive, default=None, metavar="S",
                    help="--collect: start no new flight after S seconds (rows so far are kept)")
    cp.add_argument("--table", type=Path, default=None,
                    help="--evaluate: the table (default the shipped one)")
    cp.add_argument("--record", action="store_true",
                    help="--evaluate: write the mean coverage per level into the table's provenance")
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
                         references=tuple(args.flights.split(",")), controller=args.controller)
        echo(f"{len(res['rows'])} rows -> {args.collect}")
    elif args.fit:
        out = args.out or SHIPPED
        table = pc.fit_file(args.fit, out, note=args.note)
        echo(f"calibration of {table['logs']} logs -> {out}")
    else:
        if args.out is None:
            raise ValueError("--evaluate needs --out FOLDER")
        res = pc.report(args.evaluate, args.table, args.out, record=args.record)
        echo((args.out / "evaluation.md").read_text())
        echo(f"{res['rows']} held-out rows -> {args.out}")
    return 0
