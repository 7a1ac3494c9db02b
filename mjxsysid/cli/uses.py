"""`mjxsysid replay`: action replay of decoded models against the policy's motors.

Each command's parser (``add_*``) stands beside its handler (``cmd_*``); a handler imports what it
runs when it runs, so `mjxsysid --help` stays instant.
"""
from __future__ import annotations

import sys
from pathlib import Path

from mjxsysid.runtime import jsonout
from mjxsysid.cli._common import FLIGHT_NAMES, add_policy, echo, policy_ref, positive


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
    from mjxsysid.uses.replay import run_replay
    flights = tuple(f.strip() for f in args.flights.split(",") if f.strip())
    res = run_replay(args.out, policy=policy_ref(args), decoders=args.decoders, vehicles=args.vehicles,
                     flights=flights, rate=args.rate, samples=args.samples, cutoff_hz=args.cutoff,
                     seed=args.seed, log=lambda m: echo(m, file=sys.stderr))
    print(jsonout.dumps({n: e["paper_vehicle"] for n, e in res["flights"].items()}))
    print(f"wrote {args.out}/replay.json, replay.md, replay_summary.png, replay_<flight>.png", file=sys.stderr)
    return 0
