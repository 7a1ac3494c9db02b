"""`mjxsysid` command line: scripted experiment runs.

    mjxsysid demo [--out DIR]                      the CPU demo (quick start)
    mjxsysid fly --vehicle V.json --controller oracle|nominal --reference hover|lemniscate|minsnap
                 [--period S] [--duration S] [--force-step FX,FY,FZ] [--force-sigma S]
                 [--seed N] [--gains naive|baseline] [--video] --out DIR
    mjxsysid fly --prior default --vehicles 100 --controller oracle ...   a batch from the prior
    mjxsysid fly --policy xadap --weights DIR ...   any frozen latent policy (NAME or a path)
    mjxsysid view [--vehicle V.json] [--task hover|lemniscate|minsnap|force_step]   dm_control's viewer
    mjxsysid collect | train-cfm | evaluate-decoder | decode | replay | demo  [--policy NAME|PATH]
    mjxsysid check-log FILE [--segment T0:T1]   a flight log's checks alone (CSV or PX4 ULog); exit 2/1/0
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
from pathlib import Path

from mjxsysid.cli import decoders, experiment, flights, policy, probe, profile, release, studies, tune
from mjxsysid.xla_flags import use_fast_cpu_compile

COMMANDS = (
    flights.add_demo,
    flights.add_fly,
    flights.add_view,
    policy.add_train_policy,
    policy.add_evaluate_policy,
    decoders.add_collect,
    decoders.add_train_cfm,
    decoders.add_evaluate_decoder,
    studies.add_decode,
    studies.add_check_log,
    studies.add_calibrate_posterior,
    studies.add_replay,
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


def _start_processes(args) -> None:
    """Join a multi-process run if a cluster launcher started one (mjxsysid.distributed): every
    process computes the same gathered results; only process 0 writes ``--out`` (the others
    write to a scratch folder; train-policy guards its own writes and reads the shared run
    folder to resume)."""
    from mjxsysid import distributed
    if not distributed.maybe_initialize():
        return
    import jax
    if jax.process_index() > 0 and getattr(args, "out", None) is not None and args.command != "train-policy":
        import tempfile
        args.out = Path(tempfile.mkdtemp(prefix=f"mjxsysid_p{jax.process_index()}_"))


def _cpu_fingerprint() -> str:
    """'cpu-' and 10 hex digits of the CPU's model name and feature flags (Linux: /proc/cpuinfo;
    elsewhere the platform's processor string)."""
    import hashlib
    import platform
    text = platform.machine() + platform.processor()
    try:
        with open("/proc/cpuinfo") as f:
            lines = [ln for ln in f if ln.startswith(("model name", "flags", "Features", "CPU part"))]
        text += "".join(sorted(set(lines)))
    except OSError:
        pass
    return "cpu-" + hashlib.sha256(text.encode()).hexdigest()[:10]


def _compilation_cache() -> None:
    """JAX's persistent compilation cache for the command's programs: a command run again (another
    seed of the same config, an evaluation of another policy) loads what it compiled instead of
    compiling it again (a policy training's cold start on a GPU spends ~25 s compiling, BENCHMARKS.md).
    ``MJXSYSID_JAX_CACHE``: the folder (default ~/.cache/mjxsysid/jax/<this CPU's fingerprint>; ``0``:
    off). A cache the process already set (the tests' conftest) is kept.

    The default folder is per CPU model and instruction set: JAX's cache key does not hold the host's
    CPU features, so a home folder shared by two machines (a cluster's, a VM moved to another host)
    loaded CPU programs built for the other one — XLA then logs "Target machine feature ... is not
    supported on the host machine ... could lead to execution errors such as SIGILL"."""
    import os
    where = os.environ.get("MJXSYSID_JAX_CACHE",
                           str(Path.home() / ".cache" / "mjxsysid" / "jax" / _cpu_fingerprint()))
    if where == "0":
        return
    import jax
    if jax.config.jax_compilation_cache_dir:
        return
    jax.config.update("jax_compilation_cache_dir", where)
    jax.config.update("jax_persistent_cache_min_compile_time_secs", 1.0)   # what is worth a file


def main(argv=None) -> int:
    args = build_parser().parse_args(argv)
    # XLA:CPU's faster compiling (mjxsysid.xla_flags: ~30 % less compile time for a first run on a
    # CPU, same results to float rounding) unless XLA_FLAGS sets the flag itself; XLA reads it when
    # JAX starts its backend, so a process that already computed keeps its flags
    use_fast_cpu_compile()
    from mjxsysid.progress import set_quiet
    set_quiet(True if args.quiet else None)
    try:
        _compilation_cache()
        _start_processes(args)
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
    filtered from stderr (:func:`mjxsysid._quiet.filter_native_stderr`)."""
    from mjxsysid._quiet import filter_native_stderr
    filter_native_stderr()
    return main()


if __name__ == "__main__":
    sys.exit(entry())
