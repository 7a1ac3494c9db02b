"""Programs compiled ahead: a cold run's largest compiles start on a background thread as soon as their shapes
are known, and overlap the work that comes before their first call.

A cold ``decode --log`` of a 10 s log on 2 cores spent 12 s tracing and compiling NUTS's program and 8 s the
SMC's, on the main thread after the mode. The log's shapes fix both programs before the mode is found, so
:class:`Ahead` compiles them meanwhile: ``jit(f).lower(*args).compile()`` fills the cache that the later call
``jit(f)(*args)`` reads. The caller :meth:`~Ahead.wait` s for a program before its first call rather than compile
it a second time. What it gains is the main thread's Python (the mode's fits and checks) overlapping the compiles:
XLA:CPU's compile of one program already takes both cores of a 2-core machine (a cold decode 0.93× as long); on a
GPU host's many cores, more (998 logs 351 → 303 s; BENCHMARKS.md).

The policy trainer compiles its first step and its iteration side by side on two such threads
(:meth:`~mjxsysid.policy.adaptive.trainer.Trainer.start_compile`), and calls the executables they return
(:meth:`Ahead.result`).

A program compiled ahead is the one the call would compile: the thread enters the caller's matmul precision
(the only thread-local JAX setting this package sets). A failure there costs only the time: the call compiles
the program itself, and raises what it raises.
"""
from __future__ import annotations

import logging
import os
import time
from concurrent.futures import ThreadPoolExecutor

import jax
import numpy as np

ENV = "MJXSYSID_COMPILE_AHEAD"
"""Set to 0 to compile every program on its first call instead (the default: ahead): the posterior's and the
policy trainer's. ``MJXSYSID_BACKGROUND_COMPILE``, the trainer's older name for it, is read too."""

_log = logging.getLogger(__name__)


def enabled() -> bool:
    """Whether programs are compiled ahead (:data:`ENV`)."""
    return all(os.environ.get(k, "1").strip().lower() not in ("0", "false", "no", "off")
               for k in (ENV, "MJXSYSID_BACKGROUND_COMPILE"))


class Ahead:
    """Background threads (``threads``, one by default) that compile programs in the order they are submitted;
    a no-op where :func:`enabled` is false. Use as a context manager: leaving it ends the threads (:meth:`close`).
    ``seconds``: each finished compile's wall time, by name."""

    def __init__(self, on: bool | None = None, threads: int = 1):
        self.on = enabled() if on is None else bool(on)
        self._pool = ThreadPoolExecutor(threads, thread_name_prefix="mjxsysid-ahead") if self.on else None
        self._jobs: dict = {}
        self.seconds: dict = {}

    def __contains__(self, name) -> bool:
        return name in self._jobs

    def submit(self, name, compile_fn) -> None:
        """Run ``compile_fn()`` (it lowers and compiles a program, and may return it) on a thread, as ``name``
        (hashable: a :func:`signature` of the call's arguments keeps programs of other shapes apart); a name
        already submitted is not submitted again."""
        if not self.on or name in self._jobs:
            return
        precision = jax.config.jax_default_matmul_precision

        def job():
            t0 = time.perf_counter()
            with jax.default_matmul_precision(precision):
                out = compile_fn()
            self.seconds[name] = time.perf_counter() - t0
            return out
        self._jobs[name] = self._pool.submit(job)

    def result(self, name):
        """Block until ``name`` is compiled -> what its ``compile_fn`` returned (None: never submitted); raises
        what it raised."""
        job = self._jobs.pop(name, None)
        return None if job is None else job.result()

    def wait(self, name) -> bool:
        """Block until ``name`` is compiled -> whether it was (False: never submitted, or it failed: the caller's
        call compiles the program itself and raises what is real)."""
        if name not in self._jobs:
            return False
        try:
            self.result(name)
        except Exception as e:  # noqa: BLE001 - the call compiles it and raises what is real
            _log.debug("compiling %s ahead failed: %r", name, e)
            return False
        return True

    def close(self) -> None:
        """Drop the programs not yet started (nothing called for them), wait for the one compiling, and end the
        thread."""
        if self._pool is not None:
            self._pool.shutdown(wait=True, cancel_futures=True)
        self._jobs.clear()

    def __enter__(self):
        return self

    def __exit__(self, *exc):
        self.close()


def signature(*args) -> tuple:
    """What a jitted call's program depends on in ``args``: their tree, each array's shape and dtype (as jit
    sees it: float64 is float32 unless x64 is on), and any other leaf's value."""
    leaves, tree = jax.tree.flatten(args)
    return str(tree), tuple((np.shape(x), str(jax.dtypes.canonicalize_dtype(x.dtype))) if hasattr(x, "dtype")
                            else repr(x) for x in leaves)


__all__ = ["Ahead", "ENV", "enabled", "signature"]
