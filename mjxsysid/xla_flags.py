"""XLA flags for compiling on the CPU: :func:`with_fast_cpu_compile` adds the ones that make XLA:CPU
compile faster, for runs where compiling dominates (the test tier, a first command on a laptop).

XLA reads ``XLA_FLAGS`` once, when JAX starts its CPU backend: set it before anything computes.
"""
from __future__ import annotations

FAST_CPU_COMPILE = ("--xla_cpu_use_fusion_emitters=false",)
"""XLA:CPU's older elemental IR emitters instead of its MLIR fusion emitters: about 40 % less
compile CPU for this project's programs at the same results (benchmarks/xla_cpu_flags.py)."""


def with_fast_cpu_compile(flags: str = "") -> str:
    """``flags`` (an ``XLA_FLAGS`` string) with :data:`FAST_CPU_COMPILE` added; a flag the string
    already sets (to any value) is left as it is."""
    have = {f.split("=", 1)[0] for f in flags.split()}
    extra = [f for f in FAST_CPU_COMPILE if f.split("=", 1)[0] not in have]
    return " ".join(flags.split() + extra)


def use_fast_cpu_compile() -> None:
    """Add :data:`FAST_CPU_COMPILE` to this process's ``XLA_FLAGS`` (and so to the subprocesses it
    starts); takes effect only if JAX has not started its CPU backend yet."""
    import os
    os.environ["XLA_FLAGS"] = with_fast_cpu_compile(os.environ.get("XLA_FLAGS", ""))
