"""`mjxsysid decode`: a flight or one or more logs, decoded (and grounded in each log).

Each command's parser (``add_*``) stands beside its handler (``cmd_*``); a handler imports what it
runs when it runs, so `mjxsysid --help` stays instant.
"""
from __future__ import annotations

import sys
from pathlib import Path

from mjxsysid.runtime import jsonout
from mjxsysid.cli._common import add_policy, echo, policy_ref, positive, prepare_render


def add_decode(sub) -> None:
    dc = sub.add_parser("decode", help="fly a vehicle (or replay a log) with the policy and decode its latent")
    dc.add_argument("--vehicle", type=Path, default=None, help="vehicle JSON (default: the paper vehicle)")
    dc.add_argument("--log", type=Path, nargs="+", default=None,
                    help="decode a recorded flight instead: a CSV (the contract: docs/decoding.md), a PX4 ULog "
                         "(docs/px4.md), a Crazyflie uSD log, a Betaflight blackbox, an ArduPilot DataFlash log, a ROS bag or a PX4 CSV "
                         "table of data-driven-dynamics (docs/logs.md); "
                         "several files or a folder: each into OUT/NAME and one table, OUT/fleet.md")
    dc.add_argument("--same-vehicle", action="store_true",
                    help="with several logs: they are flights of one vehicle; a command→speed map one flight "
                         "shows holds for all (each flagged flight's bands hold its value under every such map), "
                         "and fleet.md names the quantities whose bands exclude each other from one log to another")
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
    dc.add_argument("--no-refine", action="store_true",
                    help="with --log: keep the SMC's draws where the log-grounded posterior falls back to its SMC "
                         "(default: refined by short NUTS chains; faster, its bands too narrow on a clean log; "
                         "docs/identify.md, 'The SMC refined by NUTS')")
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
    from mjxsysid.decoding import run_decode
    from mjxsysid.decoding.command import printed_summary
    if args.log is not None and args.vehicle is not None:
        raise ValueError("give either --vehicle or --log, not both (the known vehicle of a log: --truth)")
    if args.truth is not None and args.log is None:
        raise ValueError("--truth needs --log (a flown --vehicle is its own truth)")
    truth = None if args.truth is None else P.load_vehicle(args.truth)
    from mjxsysid.decoding import parse_window
    window = parse_window(args.window)
    if args.segment is not None and args.log is None:
        raise ValueError("--segment needs --log")
    if args.rates is not None and (args.log is None or args.decoder_only):
        raise ValueError("--rates needs --log and the log-grounded posterior (not --decoder-only)")
    if args.same_vehicle and args.log is None:
        raise ValueError("--same-vehicle needs --log with several logs")
    if args.no_refine and (args.log is None or args.decoder_only):
        raise ValueError("--no-refine needs --log and the log-grounded posterior (not --decoder-only)")
    if args.log is not None:
        from mjxsysid.decoding.fleet import expand_logs
        logs = expand_logs(args.log)
        if args.same_vehicle and len(logs) < 2:
            raise ValueError(f"--same-vehicle compares several logs; --log names {len(logs)}")
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
                             decoder_only=args.decoder_only, rates=args.rates,
                             refine=False if args.no_refine else None)
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
    from mjxsysid.runtime.progress import progress
    from mjxsysid.decoding import run_decode
    from mjxsysid.decoding.fleet import (disagreements, disagreements_markdown, fleet_markdown, fleet_row,
                                         lacks_shared, shared_maps, shared_maps_markdown)
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)

    def one(log, maps=None) -> dict:
        try:
            summary = run_decode(out / log.stem, theta=None, log=log, reference=args.reference, period=args.period,
                                 duration=args.duration, samples=args.samples, rate=args.rate, policy=policy_ref(args),
                                 decoders=args.decoders, seed=args.seed, video=args.video, window=window, truth=truth,
                                 echo=lambda m: echo(m, file=sys.stderr), segment=args.segment,
                                 decoder_only=args.decoder_only, rates=args.rates,
                                 refine=False if args.no_refine else None, shared_maps=maps)
            return fleet_row(log.name, summary)
        except (ValueError, LogError, ImportError, OSError) as e:
            return fleet_row(log.name, None, str(e).splitlines()[0])
    rows = [one(log) for log in progress(logs, desc="logs")]
    maps, again = (shared_maps(rows) if args.same_vehicle else ()), []
    redo = [i for i, r in enumerate(rows) if lacks_shared(r, maps)]
    for i in progress(redo, desc="logs, with the vehicle's motor maps"):     # the map is the vehicle's (fleet.py)
        rows[i] = one(logs[i], maps)
        again.append(logs[i].name)
    (out / "fleet.json").write_text(jsonout.dumps(rows, indent=1) + "\n")
    table = fleet_markdown(rows)
    if args.same_vehicle:
        found = disagreements(rows)
        table += shared_maps_markdown(maps, again) + "\n" + disagreements_markdown(found)
        if found:
            echo(f"warning: {len(found)} pairs of bands exclude each other across these flights of one vehicle "
                 "(fleet.md)", file=sys.stderr)
    (out / "fleet.md").write_text("# Fleet\n\n" + table)
    print(table)
    print(f"wrote {out}/fleet.md, fleet.json and a folder per log", file=sys.stderr)
    return 0 if any("error" not in r for r in rows) else 2
