"""Which stages of a release are done and which run next: pure functions of the stage list, the
record's stage entries and which declared outputs exist.

``stages``: the [Stage][mjxsysid.release.stages.registry.Stage]s in release order; ``entries``:
the record's ``stages`` dict (name → entry); ``have(stage, path)``: whether the stage's output
``path`` (relative to its folder) exists.
"""
from __future__ import annotations

from collections.abc import Callable, Sequence

Have = Callable[[str, str], bool]


def status(stages: Sequence, entries: dict, name: str, have: Have) -> str:
    """'done', 'stale' (done, but a dependency ran after it, ``run`` being the record's count of
    stage runs, or is no longer done; or a stage it comes ``after`` ran after it), 'incomplete'
    (recorded done, an output missing), 'failed', 'started' (running now, or an interrupted call:
    it runs again, resuming where its code can) or 'pending'."""
    e = entries.get(name, {})
    st = e.get("status", "pending")
    if st != "done":
        return st
    stage = next(s for s in stages if s.name == name)
    if any(not have(name, f) for f in stage.outputs):
        return "incomplete"
    for dep in stage.needs:
        d = entries.get(dep, {})
        if d.get("status") != "done" or d.get("run", 0) > e.get("run", 0):
            return "stale"
    if any(entries.get(dep, {}).get("run", 0) > e.get("run", 0) for dep in stage.after):
        return "stale"
    return "done"


def stage_names(given, known: Sequence[str], what: str) -> list[str]:
    """The stage names of ``given`` (names or comma-separated lists of them); an unknown one is
    a ValueError naming ``what`` (the option) and the known stages."""
    out = []
    for n in given or ():
        for part in str(n).split(","):
            part = part.strip()
            if not part:
                continue
            if part not in known:
                raise ValueError(f"{what}: unknown stage {part!r}; stages: {', '.join(known)}")
            out.append(part)
    return out


def plan(stages: Sequence, entries: dict, have: Have, select=None, force=(),
         allow_partial: bool = False) -> list[str]:
    """The stages to run, in release order: ``select`` (names; default every stage) not done,
    plus ``force``d ones and the chosen stages downstream of a stage that runs. Raises ValueError
    for an unknown stage, a dependency neither done nor selected, ``ship`` with an earlier stage
    not done (unless ``allow_partial`` with ship selected explicitly), and ``allow_partial``
    without ``ship`` selected."""
    known = [s.name for s in stages]
    by_name = {s.name: s for s in stages}

    def done(n):
        return status(stages, entries, n, have) == "done"

    chosen = stage_names(select, known, "--stages") if select else known
    forced = stage_names(force, known, "--force")
    chosen = set(chosen) | set(forced)
    if allow_partial and not (select and "ship" in stage_names(select, known, "--stages")):
        raise ValueError("--allow-partial applies to an explicit --stages ship only")
    todo = []
    for s in stages:   # a chosen stage runs if forced, not done, or downstream of one that runs
        if s.name in chosen and (s.name in forced or not done(s.name) or any(d in todo for d in s.needs)):
            todo.append(s.name)
    for name in todo:
        for dep in by_name[name].needs:
            if dep not in todo and not done(dep):
                raise ValueError(f"stage {name!r} needs stage {dep!r}, which is "
                                 f"{status(stages, entries, dep, have)}: run `--stages {dep}` first (or include it)")
    if "ship" in todo and not allow_partial:
        missing = [n for n in known if n != "ship" and n not in todo and not done(n)]
        if missing:
            raise ValueError(f"cannot ship: stage(s) {', '.join(missing)} not done (run them, or ship "
                             f"what exists with --stages ship --allow-partial)")
    return todo
