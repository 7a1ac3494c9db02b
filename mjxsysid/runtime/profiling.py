"""Where a command's time goes: JAX's compiles (tracing, lowering, XLA) against the rest, per program.

    with compile_profile() as prof:
        ...                                  # anything that jits
    print(prof.table())                      # wall, compile share, the programs that cost most

The numbers come from JAX's own monitoring events (``jax.monitoring``: the trace, MLIR-lowering
and backend-compile durations JAX records for every program it builds, with the program's name), so
nothing is patched. A persistent-cache hit still counts its load under "compile" (it is usually
~1 % of a real compile) and is counted in ``cache_hits``. ``mjxsysid profile -- COMMAND ...`` runs
a command under it; ``benchmarks/first_contact.py`` profiles the first-contact paths cold and warm.
"""
from __future__ import annotations

import contextlib
import dataclasses
import time

EVENTS = {
    "/jax/core/compile/jaxpr_trace_duration": "trace",
    "/jax/core/compile/jaxpr_to_mlir_module_duration": "lower",
    "/jax/core/compile/backend_compile_duration": "compile",
}
"""JAX's compile-duration events -> the step of a build they time."""
_HIT = "/jax/compilation_cache/cache_hits"


def program_name(event_kw: dict) -> str:
    """The program a compile event belongs to. JAX names the trace by the function (``f``) and
    the lowering and XLA compile by the jitted program (``jit(f)``): both count as ``f``."""
    name = str(event_kw.get("fun_name", "?"))
    return name[4:-1] if name.startswith("jit(") and name.endswith(")") else name


@dataclasses.dataclass
class Program:
    """One program name's compile time: every build of it summed (``builds``: backend compiles)."""
    name: str
    trace: float = 0.0
    lower: float = 0.0
    compile: float = 0.0
    builds: int = 0

    @property
    def total(self) -> float:
        return self.trace + self.lower + self.compile


@dataclasses.dataclass
class Profile:
    """What :func:`compile_profile` measured (seconds)."""
    wall: float = 0.0
    programs: dict = dataclasses.field(default_factory=dict)
    cache_hits: int = 0

    @property
    def compile_s(self) -> float:
        return sum(p.total for p in self.programs.values())

    @property
    def builds(self) -> int:
        return sum(p.builds for p in self.programs.values())

    def summary(self, top: int = 10) -> dict:
        """A JSON-able summary: wall, compile and run seconds, programs built, the ``top`` programs."""
        rows = sorted(self.programs.values(), key=lambda p: -p.total)
        return {"wall_s": round(self.wall, 2), "compile_s": round(self.compile_s, 2),
                "other_s": round(self.wall - self.compile_s, 2), "programs": len(self.programs),
                "builds": self.builds, "cache_hits": self.cache_hits,
                "top": [{"name": p.name, "builds": p.builds, "trace_s": round(p.trace, 2), "lower_s": round(p.lower, 2),
                         "compile_s": round(p.compile, 2)} for p in rows[:top]]}

    def table(self, top: int = 10) -> str:
        s = self.summary(top)
        lines = [(f"wall {s['wall_s']:.1f} s: compiling {s['compile_s']:.1f} s (trace + lower + XLA), the rest "
                  f"{s['other_s']:.1f} s; {s['programs']} programs, {s['builds']} builds, "
                  f"{s['cache_hits']} persistent-cache hits"),
                 f"{'program':<48} {'builds':>6} {'trace':>7} {'lower':>7} {'XLA':>7}"]
        for r in s["top"]:
            lines.append(f"{r['name'][:48]:<48} {r['builds']:>6} {r['trace_s']:>7.2f} {r['lower_s']:>7.2f} "
                         f"{r['compile_s']:>7.2f}")
        return "\n".join(lines)


@contextlib.contextmanager
def compile_profile():
    """Collect JAX's compile events inside the block -> :class:`Profile` (filled in on exit)."""
    import jax.monitoring as mon
    prof = Profile()

    def on_duration(event, duration, **kw):
        kind = EVENTS.get(event)
        if kind is None:
            return
        name = program_name(kw)
        p = prof.programs.setdefault(name, Program(name))
        setattr(p, kind, getattr(p, kind) + duration)
        p.builds += kind == "compile"

    def on_event(event, **kw):
        if event == _HIT:
            prof.cache_hits += 1

    mon.register_event_duration_secs_listener(on_duration)
    mon.register_event_listener(on_event)
    t0 = time.perf_counter()
    try:
        yield prof
    finally:
        prof.wall = time.perf_counter() - t0
        mon.unregister_event_duration_listener(on_duration)
        mon.unregister_event_listener(on_event)
