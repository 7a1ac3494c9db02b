"""Plugin: the JAX settings of the whole suite (XLA optimisations, persistent compilation cache,
the garbage collector's thresholds), applied when pytest loads it, before any test imports JAX code."""
import contextlib
import gc
import os

import jax

from support.paths import ROOT

# Compiles dominate CPU test time (about 80 %). The tier compiles with XLA's optimisations off
# (JAX_DISABLE_MOST_OPTIMIZATIONS: about 20 % less CPU; the tests check behaviour, thresholds and
# equalities between two compiled paths, never bits of an optimised build). Set it to 0 to run
# the tier as users' code runs. Exported here, so the CLI subprocesses and notebook kernels that
# tests start compile the same way.
os.environ.setdefault("JAX_DISABLE_MOST_OPTIMIZATIONS", "1")
_XLA_OPTIMISATIONS_OFF = os.environ["JAX_DISABLE_MOST_OPTIMIZATIONS"] not in ("0", "false", "False")
jax.config.update("jax_disable_most_optimizations", _XLA_OPTIMISATIONS_OFF)
if _XLA_OPTIMISATIONS_OFF:
    # XLA's CPU code generation through its older elemental emitters: about 40 % less compile CPU
    # than the default MLIR fusion emitters (benchmarks/xla_cpu_flags.py) for the same results.
    # Read when JAX starts its CPU backend, so set here, before any test computes; inherited by
    # the subprocesses the tests start.
    # And two xdist workers share two cores: each runs XLA's operations on one thread. Two pairs of
    # fresh-clone tiers, in both orders: 6:45 -> 6:08 and 6:16 -> 6:06 (user CPU 730 -> 684, 697 -> 690 s).
    # A value the user set for either flag stays.
    from mjxsysid.runtime.xla_flags import FAST_CPU_COMPILE, ONE_EIGEN_THREAD, use_xla_flags
    use_xla_flags(FAST_CPU_COMPILE + ONE_EIGEN_THREAD)


_BACKEND_LEVEL = [None]   # LLVM optimisation level forced on every compile while set (xla_optimised)


def _with_backend_level(get_compile_options):
    def wrapped(*args, **kwargs):
        opts = get_compile_options(*args, **kwargs)
        if _BACKEND_LEVEL[0] is not None:
            opts.executable_build_options.debug_options.xla_backend_optimization_level = _BACKEND_LEVEL[0]
        return opts
    return wrapped


from jax._src import compiler as _jax_compiler  # JAX's private compile options: tests only

_jax_compiler.get_compile_options = _with_backend_level(_jax_compiler.get_compile_options)


@contextlib.contextmanager
def xla_optimised():
    """Compile with XLA's optimisations inside (for the few tests whose time is spent running a
    long training loop rather than compiling it: unoptimised, they would run 2-3x slower), LLVM at
    level 1: nearly as fast to run as XLA's default level and faster to compile (BENCHMARKS.md)."""
    jax.config.update("jax_disable_most_optimizations", False)
    _BACKEND_LEVEL[0] = 1
    try:
        yield
    finally:
        _BACKEND_LEVEL[0] = None
        jax.config.update("jax_disable_most_optimizations", _XLA_OPTIMISATIONS_OFF)


# The compiled programs kept across runs: the suite's cache, also for the `mjxsysid` commands the tests run as subprocesses (the CLI's own
# default is ~/.cache/mjxsysid/jax/<CPU fingerprint>). A folder per CPU model and instruction set, as the CLI's: a checkout
# moved to another host does not load programs built for the old one's CPU.
from mjxsysid.runtime.startup import cpu_fingerprint  # noqa: E402

os.environ.setdefault("MJXSYSID_JAX_CACHE", str(ROOT / ".jax_cache" / cpu_fingerprint()))
if os.environ["MJXSYSID_JAX_CACHE"] != "0":            # "0": off, as for the CLI (not a folder named 0)
    jax.config.update("jax_compilation_cache_dir", os.environ["MJXSYSID_JAX_CACHE"])
jax.config.update("jax_persistent_cache_min_compile_time_secs", 0.5)
jax.config.update("jax_persistent_cache_min_entry_size_bytes", 0)
# Python's cyclic garbage collector: a worker's heap (JAX's traces, jaxprs and caches) makes every
# full collection cost up to 0.35 s, and the default thresholds ran 16 of them in 52 s of
# test_api/test_notebooks/test_decode (-n 0); with these, 3 (the collector's time there 4.4 -> 2.3 s,
# 1.6 s of it the notebooks' own resets, now skipped: _reset_shell). Memory stays bounded (the
# collector still runs; the tier's peak 4.4-4.6 GB against 4.3 GB before).
gc.set_threshold(10_000, 20, 100)


