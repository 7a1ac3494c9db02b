"""One pool of processes for a call's host work: the logs' reductions, first and again under the checks.

A reduction of a log (:func:`mjxsysid.identify.logdata.prepare`) is many small NumPy calls, so threads wait on
each other's interpreter lock; beside an accelerator, a batch of logs is reduced on processes. The batched
posterior reduces each log three times over (once, then under the longer rate windows of
:mod:`mjxsysid.identify.windowcheck` and under the motor maps of :mod:`mjxsysid.identify.idlecheck`): one pool
for the whole call spawns its processes once, when first needed, instead of once per use.
"""
from __future__ import annotations

import os

MIN_PER_WORKER = 2
"""Processes serve a map only with at least this many items per process; fewer run here (or on threads)."""


class HostPool:
    """``workers`` processes (spawned, so that no JAX state is forked), started on the first :meth:`map` that
    needs them and stopped by :meth:`close` (or the ``with`` block). ``workers`` ≤ 1: every map runs in this
    process, or on threads where asked."""

    def __init__(self, workers: int = 1):
        if int(workers) < 1:
            raise ValueError(f"HostPool: workers must be ≥ 1, got {workers}")
        self.workers = int(workers)
        self._procs = None

    def processes(self, n: int) -> bool:
        """Whether a map of ``n`` items goes to the processes."""
        return self.workers > 1 and n >= MIN_PER_WORKER * self.workers

    def map(self, fn, *iterables, threads: bool = False, processes: bool | None = None) -> list:
        """[fn(*args) for args in zip(*iterables)], in order: on the processes (``processes``, by default
        :meth:`processes` of the items' count; ``fn`` a module-level function, its arguments and results
        picklable), else on a pool of threads where ``threads`` (for work that releases the interpreter lock,
        such as scipy's filters), else one by one here."""
        return self.later(fn, *iterables, threads=threads, processes=processes)()

    def later(self, fn, *iterables, threads: bool = False, processes: bool | None = None):
        """:meth:`map` started now, its results waited for later: -> a function that returns them. On
        processes or threads the work runs meanwhile (the next batch of reductions while the accelerator
        fits the last); one by one here, it runs when asked."""
        args = list(zip(*iterables))
        if not args:
            return list
        if self.workers > 1 and (self.processes(len(args)) if processes is None else processes):
            if self._procs is None:
                import multiprocessing
                from concurrent.futures import ProcessPoolExecutor
                self._procs = ProcessPoolExecutor(self.workers, mp_context=multiprocessing.get_context("spawn"))
            it = self._procs.map(fn, *zip(*args), chunksize=max(1, len(args) // (4 * self.workers)))
            return lambda: list(it)
        if threads and len(args) > 1:
            from concurrent.futures import ThreadPoolExecutor
            ex = ThreadPoolExecutor(max(1, min(os.cpu_count() or 1, 16, len(args))))
            it = ex.map(fn, *zip(*args))

            def wait():
                try:
                    return list(it)
                finally:
                    ex.shutdown()
            return wait
        return lambda: [fn(*a) for a in args]

    def close(self) -> None:
        """Stop the processes, if any were started."""
        if self._procs is not None:
            self._procs.shutdown()
            self._procs = None

    def __enter__(self):
        return self

    def __exit__(self, *exc):
        self.close()
