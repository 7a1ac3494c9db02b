"""The stage registry: a stage is a function ``run(release, out) -> StageResult`` declared with
its needs, outputs and GPU time by :meth:`Registry.add`; the registry keeps them in the order
they were declared (the release order)."""
from __future__ import annotations

import dataclasses
from collections.abc import Callable, Iterator, Mapping
from pathlib import Path
from typing import Any, Protocol


@dataclasses.dataclass(frozen=True)
class StageResult:
    """What a stage returns, for its record entry.

    Attributes:
        calls: the library calls it made, in order (each
            [provenance.call][mjxsysid.release.provenance.call]'s dict: the function and its arguments).
        config: the sizes and settings it ran with.
        figures: its key outputs.
    """
    calls: tuple = ()
    config: Mapping[str, Any] = dataclasses.field(default_factory=dict)
    figures: Mapping[str, Any] = dataclasses.field(default_factory=dict)


@dataclasses.dataclass(frozen=True)
class Stage:
    """One step of a release: ``run(release, out)`` writes into ``out`` (DIR/<name>/) and returns
    a :class:`StageResult`. ``needs``: stages that must be done first; ``outputs``: files
    (relative to ``out``) whose existence a done record is checked against; ``estimate_s``: GPU
    time on one H100 (s), from BENCHMARKS.md and the recorded wall times; ``what``: one line for
    the log; ``after``: stages not required, but whose run after this one makes it stale
    (``ship`` after ``tables``)."""
    name: str
    run: Callable
    needs: tuple = ()
    outputs: tuple = ()
    estimate_s: float = 0.0
    what: str = ""
    after: tuple = ()


class ReleaseView(Protocol):
    """What a stage reads of the release that runs it
    ([Release][mjxsysid.release.runner.Release] implements it; tests pass stubs)."""
    out: Path
    options: Any
    sizes: Any
    log: Callable[[str], None]
    ship_to: Path | None
    docs_root: Path | None
    allow_partial: bool

    @property
    def policy_path(self) -> Path: ...

    @property
    def decoder_set(self) -> Any: ...

    @property
    def progress_on(self) -> bool: ...

    def stage_dir(self, name: str) -> Path: ...

    def entry(self, name: str) -> dict: ...

    def status(self, name: str) -> str: ...

    def done(self, name: str) -> bool: ...


class Registry:
    """Stages in declaration order, looked up by name."""

    def __init__(self):
        self._stages: dict[str, Stage] = {}

    def add(self, *, name: str | None = None, needs=(), outputs=(), estimate_s: float, what: str, after=()):
        """Decorator: register ``fn`` as the stage ``name`` (default: the function's name)."""
        def register(fn: Callable) -> Callable:
            self.register(Stage(name or fn.__name__, fn, tuple(needs), tuple(outputs), estimate_s, what,
                                tuple(after)))
            return fn
        return register

    def register(self, stage: Stage) -> None:
        if stage.name in self._stages:
            raise ValueError(f"stage {stage.name!r} registered twice")
        self._stages[stage.name] = stage

    def __iter__(self) -> Iterator[Stage]:
        return iter(self._stages.values())

    def __len__(self) -> int:
        return len(self._stages)

    def __getitem__(self, name: str) -> Stage:
        return self._stages[name]

    def names(self) -> tuple[str, ...]:
        return tuple(self._stages)


STAGES = Registry()
"""Every stage of a release, in release order (filled by the modules of this package)."""
