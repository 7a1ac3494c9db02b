"""`mjxsysid` command line: scripted experiment runs.

    mjxsysid demo [--out DIR]                      the CPU demo (quick start)
    mjxsysid fly --vehicle V.json --controller oracle|nominal --reference hover|lemniscate|minsnap
                 [--period S] [--duration S] [--force-step FX,FY,FZ] [--force-sigma S]
                 [--seed N] [--gains naive|baseline] [--video] --out DIR
    mjxsysid fly --prior default --vehicles 100 --controller oracle ...   a batch from the prior
    mjxsysid fly --policy xadap --weights DIR ...   any frozen latent policy (NAME or a path)
    mjxsysid view [--vehicle V.json] [--task hover|lemniscate|minsnap|force_step]   dm_control's viewer
    mjxsysid collect | train-cfm | evaluate-decoder | decode | replay | demo  [--policy NAME|PATH]
    mjxsysid check-log FILE [--segment T0:T1]   a flight log's checks alone (any format decode reads); exit 2/1/0
    mjxsysid export [--weights policy.npz] --out policy.onnx   the policy as ONNX, checked in onnxruntime
    mjxsysid release --out DIR [--stages S1,S2] [--list]   a release in resumable stages (docs/release.md)
    mjxsysid profile -- COMMAND ...   a command's compile time per JAX program (docs/cli.md)

Policies: ``--policy mjxsysid`` (the shipped one; the default), ``--policy xadap --weights DIR``
(the released Extreme-Adaptation policy: its folder or a converted .npz; $MJXSYSID_XADAP_DIR is
the fallback), or ``--policy PATH`` (recognised from its contents).

Errors in inputs (files, arguments) are reported in one line on stderr with exit status 2.
Heavy imports happen after argument parsing, so ``--help`` is instant.
"""
from __future__ import annotations

import argparse
import sys

from mjxsysid.cli import (decoders, decoding, experiment, flights, identify, logs, policy, probe, profile, release, tune,
                          uses)
from mjxsysid.runtime.startup import compilation_cache, start_processes
from mjxsysid.runtime.xla_flags import GPU_LOOP_GRAPHS, QUICK_FIRST_RUN, use_fast_cpu_compile, use_xla_flags

COMMANDS = (
    flights.add_demo,
    flights.add_fly,
    flights.add_view,
    policy.add_train_policy,
    policy.add_evaluate_policy,
    decoders.add_collect,
    decoders.add_train_cfm,
    decoders.add_evaluate_decoder,
    decoding.add_decode,
    logs.add_check_log,
    identify.add_calibrate_posterior,
    uses.add_replay,
    tune.add_tune,
    probe.add_probe,
    experiment.add_experiment,
    policy.add_export,
    release.add_release,
    profile.add_profile,
)
"""Each command's parser builder, in the order `mjxsysid --help` lists them."""


def build_parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(prog="mjxsysid", description=__doc__.split("\n\n")[0])
    sub = p.add_subparsers(dest="command", required=True)
    for add in COMMANDS:
        add(sub)
    for sp in sub.choices.values():
        sp.add_argument("-q", "--quiet", action="store_true",
                        help="no progress bars or progress messages (results and errors still print)")
    return p


POSTERIOR_COMMANDS = ("decode", "calibrate-posterior")
"""The commands whose GPU work is the log-grounded posterior, batched over logs. ``release`` and ``experiment``
also train and fly, whose programs were not measured with the flag: they keep XLA's default."""


def command_xla_flags(command: str) -> tuple[str, ...]:
    """The XLA flags ``command`` adds to :func:`~mjxsysid.runtime.xla_flags.FAST_CPU_COMPILE`'s: the demo's
    quicker first run (``QUICK_FIRST_RUN``: compiling is most of it), the posterior's loops as CUDA graphs on a
    GPU (``GPU_LOOP_GRAPHS``, :data:`POSTERIOR_COMMANDS`)."""
    return (QUICK_FIRST_RUN if command == "demo" else ()) + (GPU_LOOP_GRAPHS if command in POSTERIOR_COMMANDS else ())


def main(argv=None) -> int:
    args = build_parser().parse_args(argv)
    # XLA:CPU's faster compiling (mjxsysid.runtime.xla_flags: ~30 % less compile time for a first run on a
    # CPU, same results to float rounding) unless XLA_FLAGS sets the flag itself; XLA reads it when
    # JAX starts its backend, so a process that already computed keeps its flags
    use_fast_cpu_compile()
    use_xla_flags(command_xla_flags(args.command))
    from mjxsysid.runtime.progress import set_quiet
    set_quiet(True if args.quiet else None)
    try:
        compilation_cache()
        start_processes(args)
        return args.handler(args)
    except (ValueError, OSError) as e:  # bad inputs (FileNotFoundError is an OSError)
        print(f"mjxsysid {args.command}: error: {e}", file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        again = (" (run the same command again to resume from the last checkpoint)"
                 if args.command in ("train-policy", "train-cfm") else "")
        print(f"mjxsysid {args.command}: interrupted{again}", file=sys.stderr)
        return 130
    finally:
        set_quiet(None)


def entry() -> int:
    """The `mjxsysid` console command: :func:`main` with XLA:CPU's spurious cache-loader lines
    filtered from stderr (:func:`mjxsysid.runtime.quiet.filter_native_stderr`)."""
    from mjxsysid.runtime.quiet import filter_native_stderr
    filter_native_stderr()
    return main()


if __name__ == "__main__":
    sys.exit(entry())
