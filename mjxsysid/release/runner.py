"""Opening, planning and running a release: :class:`Release` over its record
([record][mjxsysid.release.record]), its plan ([plan][mjxsysid.release.plan]) and the registered
stages ([stages][mjxsysid.release.stages])."""
from __future__ import annotations

import dataclasses
import shutil
import time
import traceback
from collections.abc import Callable
from pathlib import Path

from mjxsysid.runtime.progress import echo
from mjxsysid.runtime.progress import stages as stage_bar
from mjxsysid.release import plan as planner
from mjxsysid.release.layout import link
from mjxsysid.release.provenance import code_commit, device_name
from mjxsysid.release.record import Record, now
from mjxsysid.release.sizes import SCALES, SIZES
from mjxsysid.release.stages import STAGES
from mjxsysid.release.stages.policy import DEFAULT_POLICY_CONFIG
from mjxsysid.release.stages.registry import Stage, StageResult


@dataclasses.dataclass(frozen=True)
class Options:
    """What defines a release, recorded in release.json when it starts: ``scale`` ('full' or
    'tiny'), ``policy_config`` (the TrainConfig JSON the policy stage trains with; None: the
    packaged [DEFAULT_POLICY_CONFIG][mjxsysid.release.stages.policy.DEFAULT_POLICY_CONFIG]) and
    ``from_policy`` (a policy.npz the policy stage adopts instead of training, or None)."""
    scale: str = "full"
    policy_config: str | None = None
    from_policy: str | None = None


class Release:
    """The release in ``out``: its record (``out/release.json``) and its stages.

    Args:
        out: the release folder (OUT/<stage>/ and OUT/release.json).
        options: the [Options][mjxsysid.release.runner.Options] fields given for this call, as a
            dict (or an Options: all of them); a new release takes them over the defaults, a
            started one checks them against the recorded ones (a difference is a ValueError
            naming the option).
        ship_to: the root of the tree the ``ship`` stage copies into (a checkout); default
            ``out/ship`` for a tiny release, none for a full one (its ship stage then refuses).
        docs_root: the checkout whose generated pages the ``tables`` stage regenerates (its
            docs/ pages and docs/runs/ files under the release's own); default ``ship_to`` where
            given.
        stages: the stage list (tests inject stubs); ``device`` / ``commit``: callables recorded
            per stage.
    """

    def __init__(self, out, options: Options | dict | None = None, *, ship_to=None, docs_root=None, stages=None,
                 log=echo, device: Callable[[], str] = device_name, commit: Callable[[], str | None] = code_commit):
        self.out = Path(out)
        if self.out.exists() and not self.out.is_dir():
            raise ValueError(f"--out {self.out}: is a file, not a release folder")
        self.stages: tuple[Stage, ...] = tuple(STAGES if stages is None else stages)
        self.by_name = {s.name: s for s in self.stages}
        self.log = log or (lambda m: None)
        self._device, self._commit = device, commit
        self._record = Record(self.out)
        given = dataclasses.asdict(options) if isinstance(options, Options) else dict(options or {})
        unknown = sorted(set(given) - {f.name for f in dataclasses.fields(Options)})
        if unknown:
            raise ValueError(f"unknown release option(s) {unknown}")
        recorded = self.record.get("options")
        if recorded is None:
            self.options = Options(**given)
        else:
            self.options = Options(**recorded)
            for k, v in given.items():
                if v != recorded.get(k):
                    raise ValueError(f"{self.out}: this release was started with {k} = {recorded.get(k)!r}, "
                                     f"not {v!r} (start a new release in another folder)")
        if self.options.scale not in SCALES:
            raise ValueError(f"scale must be one of {SCALES}, got {self.options.scale!r}")
        self.ship_to = Path(ship_to) if ship_to is not None else (
            self.out / "ship" if self.options.scale == "tiny" else None)
        self.docs_root = Path(docs_root) if docs_root is not None else (Path(ship_to) if ship_to is not None else None)
        self.sizes = SIZES[self.options.scale]
        self.allow_partial = False   # set by run(): ship what the done stages wrote

    # -- record ---------------------------------------------------------------------------
    @property
    def record(self) -> dict:
        """The record (release.json's dict)."""
        return self._record.data

    def _header(self) -> dict:
        return {"release": self.out.name, "options": dataclasses.asdict(self.options),
                "order": [s.name for s in self.stages]}

    def save(self) -> None:
        """Write the record (the one on disk with this process's stage entries merged in)."""
        self._record.save(self._header())

    def stage_dir(self, name: str) -> Path:
        return self.out / name

    def entry(self, name: str) -> dict:
        return self._record.entry(name)

    def _have(self, stage: str, path: str) -> bool:
        return (self.stage_dir(stage) / path).exists()

    def status(self, name: str) -> str:
        """The stage's status ([plan.status][mjxsysid.release.plan.status])."""
        return planner.status(self.stages, self.record["stages"], name, self._have)

    def done(self, name: str) -> bool:
        return self.status(name) == "done"

    def plan(self, select=None, force=(), allow_partial: bool = False) -> list[str]:
        """The stages to run ([plan.plan][mjxsysid.release.plan.plan])."""
        return planner.plan(self.stages, self.record["stages"], self._have, select, force, allow_partial)

    # -- run ------------------------------------------------------------------------------
    def run(self, select=None, force=(), allow_partial: bool = False) -> list[str]:
        """Run the planned stages (see :meth:`plan`) in order, recording each; a failing stage is
        recorded as failed and its exception re-raised (the stages after it do not run). Returns
        the names of the stages that ran."""
        todo = self.plan(select, force, allow_partial)
        forced = set(planner.stage_names(force, list(self.by_name), "--force"))
        self.allow_partial = allow_partial
        if not todo:
            self.log(f"release {self.out}: nothing to run (every selected stage is done; --force STAGE reruns one)")
            self.save()
            return []
        self.log(f"release {self.out} ({self.options.scale}): stages {', '.join(todo)}")
        ran = []
        with stage_bar(todo, desc="release") as bar:
            for name in todo:
                bar.start(name)
                self._run_one(self.by_name[name], fresh=name in forced)
                ran.append(name)
        return ran

    def _run_one(self, stage: Stage, *, fresh: bool) -> None:
        out = self.stage_dir(stage.name)
        if fresh and out.exists():
            shutil.rmtree(out)
        out.mkdir(parents=True, exist_ok=True)
        prev = self.entry(stage.name)
        entry = {"status": "started", "run": 0, "started": now(),
                 "attempts": int(prev.get("attempts", 0)) + 1, "commit": self._commit(), "device": self._device()}
        self._record.begin(stage.name, entry, self._header())
        self.log(f"[release] {stage.name}: {stage.what} (≈ {stage.estimate_s / 60:.1f} min on an H100)")
        t0 = time.time()
        try:
            res = stage.run(self, out) or StageResult()
        except BaseException as e:
            entry.update(status="failed", ended=now(), wall_s=round(time.time() - t0, 1),
                         error=f"{type(e).__name__}: {e}", traceback=traceback.format_exc(limit=8))
            self.save()
            raise
        missing = [f for f in stage.outputs if not (out / f).exists()]
        if missing:
            entry.update(status="failed", ended=now(), wall_s=round(time.time() - t0, 1),
                         error=f"outputs missing: {', '.join(missing)}")
            self.save()
            raise RuntimeError(f"stage {stage.name}: finished without writing {', '.join(missing)}")
        entry.update(status="done", ended=now(), wall_s=round(time.time() - t0, 1),
                     calls=list(res.calls), config=dict(res.config), outputs=list(stage.outputs),
                     figures=dict(res.figures))
        entry.pop("error", None)
        entry.pop("traceback", None)
        self.save()
        self.log(f"[release] {stage.name}: done in {entry['wall_s']:.0f} s")

    # -- listing --------------------------------------------------------------------------
    def table(self) -> str:
        """The stages with their status, recorded times and the H100 estimate (``--list``)."""
        policy = self.options.from_policy or self.options.policy_config or f"{DEFAULT_POLICY_CONFIG.name} (default)"
        rows = [f"release {self.out} ({self.options.scale}; policy: {policy})",
                f"{'stage':21s} {'status':10s} {'wall':>8s} {'H100 est.':>9s}  {'ended':25s} needs"]
        for s in self.stages:
            e = self.entry(s.name)
            wall = f"{e['wall_s']:.0f} s" if e.get("wall_s") is not None else "–"
            rows.append(f"{s.name:21s} {self.status(s.name):10s} {wall:>8s} {s.estimate_s / 60:>7.1f} m  "
                        f"{e.get('ended', '–'):25s} {','.join(s.needs) or '–'}")
        total = sum(s.estimate_s for s in self.stages)
        spent = sum(self.entry(s.name).get("wall_s") or 0 for s in self.stages if self.done(s.name))
        rows.append(f"estimated GPU time {total / 60:.0f} min on an H100; recorded wall time of done stages "
                    f"{spent / 60:.1f} min")
        return "\n".join(rows)

    # -- what the stages share ------------------------------------------------------------
    @property
    def policy_path(self) -> Path:
        return self.stage_dir("policy") / "policy.npz"

    def decoder_set(self) -> Path:
        """DIR/decoder_set/: cfm.npz and regression.npz of the decoders stage and cfm_seq.npz of
        the seq_decoder stage, hard-linked (copied where links fail) into one folder, as the
        experiments take them (``decoders=DIR``)."""
        d = self.out / "decoder_set"
        d.mkdir(parents=True, exist_ok=True)
        for src in (self.stage_dir("decoders") / "cfm.npz", self.stage_dir("decoders") / "regression.npz",
                    self.stage_dir("seq_decoder") / "cfm_seq.npz"):
            link(src, d / src.name)
        return d

    def progress_on(self) -> bool:
        """Whether the experiments report progress (not ``--quiet``)."""
        from mjxsysid.runtime.progress import quiet
        return not quiet()


def run_release(out, *, select=None, force=(), allow_partial: bool = False, options: Options | None = None,
                ship_to=None, docs_root=None, stages=None, log=echo, **kw) -> Release:
    """Open (or start) the release in ``out`` and run the planned stages (:meth:`Release.run`);
    returns the [Release][mjxsysid.release.runner.Release]."""
    rel = Release(out, options, ship_to=ship_to, docs_root=docs_root, stages=stages, log=log, **kw)
    rel.run(select, force, allow_partial)
    return rel
