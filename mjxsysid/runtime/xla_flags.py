"""XLA flags for compiling on the CPU: :func:`with_fast_cpu_compile` adds the ones that make XLA:CPU
compile faster, for runs where compiling dominates (the test tier, a first command on a laptop).

XLA reads ``XLA_FLAGS`` once, when JAX starts its CPU backend: set it before anything computes.
"""
from __future__ import annotations

FAST_CPU_COMPILE = ("--xla_cpu_use_fusion_emitters=false",)
"""XLA:CPU's older elemental IR emitters instead of its MLIR fusion emitters: about 40 % less
compile CPU for this project's programs at the same results (benchmarks/xla_cpu_flags.py)."""

QUICK_FIRST_RUN = ("--xla_backend_optimization_level=1",)
"""LLVM at level 1 instead of XLA's default: for a command whose first run is mostly compiling (the demo:
cold 51 -> 47 s, warm 25 -> 26 s on 2 cores; under `mjxsysid profile` compiling 34.1 -> 28.6 s, running
19.6 -> 21.7 s: BENCHMARKS.md).
Programs that run long (training, experiments) keep the default: level 1 runs a flight 25-50 % slower."""

ONE_EIGEN_THREAD = ("--xla_cpu_multi_thread_eigen=false",)
"""XLA:CPU's operations on one thread: for several processes sharing the cores (the test tier's
xdist workers), whose per-process pools of one thread per core only contend with each other."""

GPU_LOOP_GRAPHS = ("--xla_gpu_enable_command_buffer=FUSION,CUBLAS,CUBLASLT,CUSTOM_CALL,CUDNN,WHILE,CONDITIONAL",)
"""XLA:GPU's CUDA graphs (command buffers) for while loops and conditionals too, besides its default kinds: a
batch of NUTS's chains is a loop of small kernels, one launch each. On one H200 (jax 0.11): 512 logs' first
attempt, warm, 28.4 -> 23.8 s, the draws a default-flag run gives (a fresh compile gives one of two sets, under
either flag); 999 logs with the defaults, cold, 374 -> 351 s (NUTS 228 -> 202 s;
docs/runs/measurements/log-grounded/batched/gpu_loop_graphs.json). Set by ``decode``, ``calibrate-posterior``
(``cli.POSTERIOR_COMMANDS``) and the scripts that run the posterior on a GPU; XLA:CPU ignores it."""


REMOVED_IN_JAXLIB = {"--xla_cpu_use_fusion_emitters": (0, 11)}
"""Flags XLA no longer knows from a jaxlib version on (XLA exits on an unknown flag, "Unknown flag in
XLA_FLAGS": with jaxlib 0.11.2 one of these in XLA_FLAGS stops every CLI command)."""


def _jaxlib_version() -> tuple[int, ...]:
    from importlib.metadata import PackageNotFoundError, version
    try:
        return tuple(int(x) for x in version("jaxlib").split(".")[:2] if x.isdigit())
    except PackageNotFoundError:
        return (0,)


def known_flags(add: tuple[str, ...], jaxlib: tuple[int, ...] | None = None) -> tuple[str, ...]:
    """The flags of ``add`` that the installed jaxlib (or ``jaxlib``, a version tuple) still knows."""
    v = _jaxlib_version() if jaxlib is None else tuple(jaxlib)
    return tuple(f for f in add if v < REMOVED_IN_JAXLIB.get(f.split("=", 1)[0], (10**6,)))


def with_xla_flags(flags: str, add: tuple[str, ...]) -> str:
    """``flags`` (an ``XLA_FLAGS`` string) with the flags of ``add`` appended; a flag the string
    already sets (to any value) is left as it is."""
    have = {f.split("=", 1)[0] for f in flags.split()}
    extra = [f for f in add if f.split("=", 1)[0] not in have]
    return " ".join(flags.split() + extra)


def with_fast_cpu_compile(flags: str = "") -> str:
    """``flags`` with :data:`FAST_CPU_COMPILE` added (:func:`with_xla_flags`)."""
    return with_xla_flags(flags, FAST_CPU_COMPILE)


def use_xla_flags(add: tuple[str, ...] = FAST_CPU_COMPILE) -> None:
    """Add ``add`` to this process's ``XLA_FLAGS`` (and so to the subprocesses it starts), keeping
    any value already set for the same flag; takes effect only if JAX has not started its CPU
    backend yet."""
    import os
    os.environ["XLA_FLAGS"] = with_xla_flags(os.environ.get("XLA_FLAGS", ""), known_flags(add))


def use_fast_cpu_compile() -> None:
    """:func:`use_xla_flags` of :data:`FAST_CPU_COMPILE` (what every CLI command does first)."""
    use_xla_flags(FAST_CPU_COMPILE)
