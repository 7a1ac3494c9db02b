"""`mjxsysid profile -- COMMAND ...`: where a command's time goes (compiling vs running, per program)."""
from __future__ import annotations

import argparse
import sys
from pathlib import Path

from mjxsysid.runtime import jsonout


def add_profile(sub) -> None:
    pr = sub.add_parser("profile", help="run another mjxsysid command and report its compile time per JAX program",
                        description="Runs `mjxsysid COMMAND ...` in this process and prints the wall time, the share "
                                    "spent compiling (tracing, lowering, XLA) and the programs that cost most. "
                                    "Cold (a first run) with MJXSYSID_JAX_CACHE pointing to an empty folder; "
                                    "benchmarks/first_contact.py profiles the first-contact paths cold and warm.")
    pr.add_argument("--top", type=int, default=12, help="how many programs to list (default 12)")
    pr.add_argument("--json", type=Path, default=None, metavar="FILE", help="also write the profile as JSON")
    pr.add_argument("cmd", nargs=argparse.REMAINDER, metavar="COMMAND ...",
                    help="the mjxsysid command and its arguments (after --)")
    pr.set_defaults(handler=cmd_profile)


def cmd_profile(args) -> int:
    cmd = args.cmd[1:] if args.cmd[:1] == ["--"] else args.cmd
    if not cmd:
        raise ValueError("profile: name the command to run, e.g. `mjxsysid profile -- demo --out out/demo`")
    if cmd[0] == "profile":
        raise ValueError("profile: cannot profile itself")
    from mjxsysid.cli import main
    from mjxsysid.runtime.profiling import compile_profile
    with compile_profile() as prof:
        rc = main(cmd)
    print(f"\nmjxsysid {' '.join(cmd)} -> exit {rc}", file=sys.stderr)
    print(prof.table(args.top), file=sys.stderr)
    if args.json is not None:
        args.json.parent.mkdir(parents=True, exist_ok=True)
        args.json.write_text(jsonout.dumps({"command": cmd, "exit": rc, **prof.summary(args.top)}, indent=1))
    return rc
