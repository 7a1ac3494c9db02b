"""What the command groups share: argument types, the --policy/--weights pair, messages."""
from __future__ import annotations

import argparse
from pathlib import Path

PRIOR_CHOICES = ("default", "slow_actuators", "wide_actuators", "xadap", "stress", "stress_wide")
FLIGHT_NAMES = ("lemniscate_5s", "lemniscate_10s", "lemniscate_15s", "hover")  # replay.FLIGHTS (light import)


def triple(text: str):
    try:
        vals = [float(x) for x in text.split(",")]
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected three comma-separated numbers FX,FY,FZ, got {text!r}")
    if len(vals) != 3:
        raise argparse.ArgumentTypeError(f"expected three comma-separated numbers FX,FY,FZ, got {text!r}")
    return tuple(vals)


def positive(text: str):
    try:
        v = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected a number, got {text!r}")
    if not v > 0:
        raise argparse.ArgumentTypeError(f"must be > 0, got {text}")
    return v


def nonneg(text: str):
    try:
        v = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected a number, got {text!r}")
    if not v >= 0:
        raise argparse.ArgumentTypeError(f"must be >= 0, got {text}")
    return v


def add_policy(p, what="the frozen latent policy"):
    p.add_argument("--policy", default=None, metavar="NAME|PATH",
                   help=f"{what}: mjxsysid (shipped, default), xadap (with --weights DIR), or a path")
    p.add_argument("--weights", type=Path, default=None,
                   help="weights of the named policy (mjxsysid: policy.npz or run folder; xadap: the "
                        "folder of the released files or a converted .npz)")


def policy_ref(args):
    from mjxsysid.policy.interface import resolve_policy
    return resolve_policy(args.policy or "mjxsysid", args.weights)


def echo(msg, file=None):
    from mjxsysid.runtime.progress import echo
    echo(msg, file=file)


def prepare_render():
    from mjxsysid.render.gl import headless_env
    headless_env()
