"""A release in one command (``mjxsysid release --out DIR``): the policy, its decoders and their
calibration, every experiment whose numbers the docs quote, the generated docs tables and the
shipped files, as an ordered list of named, resumable stages.

Each stage writes into ``DIR/<stage>/`` and is recorded in ``DIR/release.json``: status (done or
failed), wall seconds, start and end time, commit, device, the command and config it ran, and
its key figures. A stage recorded done whose declared outputs exist is skipped when the release
runs again, so a release runs in pieces (``stages=["policy"]``, then ``["pairs", "decoders"]``,
…), each small enough for one ten-minute call on a GPU; ``force`` reruns a stage from scratch.
A done stage whose dependency ran after it is *stale* (its inputs changed) and runs again.
Options that define the release (its scale, the policy's config or the adopted policy) are
recorded when it starts and may not change afterwards.

The stages (:data:`STAGES`, in order) call the library, never a subprocess: the policy
(:func:`mjxsysid.policy.train.train`, or an adopted policy.npz), its evaluation and the held-out
evaluation against the previously shipped policy, single-latent pairs, CFM and Regression
decoders, flight-level pairs and decoder, their calibration, decoding under IMU noise, the
tune-* experiments with their fair variants, robustness, action replay, payload, closed-loop
fidelity, the docs tables (tools/fair_tables.py, docs/noise.md) and shipping. ``scale="tiny"``
shrinks every stage to CPU seconds (what the tests run); it ships into ``DIR/ship`` unless told
otherwise, never into the checkout.

The stage functions and the docs-table tools are imported when they run (``--list`` and the
plan checks stay instant, with no JAX import); tools/ and docs/ are read from the source
checkout this package runs from.
"""
from __future__ import annotations

import contextlib
import dataclasses
import datetime
import importlib.util
import json
import os
import shutil
import time
import traceback
from pathlib import Path
from typing import Callable

from mjxsysid.progress import echo, stages as stage_bar

ROOT = Path(__file__).resolve().parents[1]
"""The source checkout: tools/, docs/ and the default place to ship into."""
DEFAULT_POLICY_CONFIG = "tools/configs/policy_release.json"
"""The policy stage's TrainConfig overrides (relative paths: to the working directory, else to ROOT)."""
RECORD = "release.json"
ADOPTED_PROVENANCE = "adopted_policy.json"
"""The adopted policy's provenance JSON, kept by the policy stage of a ``--from-policy`` release."""
SCALES = ("full", "tiny")

TINY_TRAIN = dict(num_envs=64, unroll=16, iterations=4, epochs=2, minibatches=4, log_every=1, checkpoint_every=2,
                  warmup=0.3, ramp=0.3)
"""TrainConfig sizes of a tiny release (tests/test_policy.py's tiny trainer, 4 iterations), warm-started
from the shipped policy (``init_from``) so that the tiny policy still flies and the later stages have
flights to decode."""

SIZES = {
    "full": dict(eval_vehicles=1000, heldout_vehicles=256, heldout_sets=None, heldout_period=10.0,
                 pairs=(20_000, 2_000, 2_000), seq_pairs=(20_000, 2_000, 5_500), seq_seconds=10.0,
                 cfm={}, seq_cfg={"epochs": 100}, eval_cases=1000, eval_samples=200, paper_flight=True,
                 noise=dict(vehicles=128, seconds=4.0, samples=100), quick=False,
                 fidelity=dict(vehicles=20, models=100, duration=4.0)),
    "tiny": dict(eval_vehicles=10, heldout_vehicles=2, heldout_sets=("default", "weak_motor"), heldout_period=5.0,
                 pairs=(32, 8, 40), seq_pairs=(32, 8, 40), seq_seconds=2.0,
                 cfm=dict(width=32, blocks=1, time_dim=16, epochs=2, batch=16),
                 seq_cfg=dict(epochs=2, set_width=16, heads=2, cond_dim=8),
                 eval_cases=8, eval_samples=20, paper_flight=False,
                 noise=dict(vehicles=4, seconds=1.0, samples=8), quick=True,
                 fidelity=dict(vehicles=2, models=2, duration=1.0)),
}
"""Per scale: the sizes every stage runs at (full: the shipped protocols; tiny: CPU seconds)."""


@dataclasses.dataclass(frozen=True)
class Stage:
    """One step of a release: ``run(release, out)`` writes into ``out`` (DIR/<name>/) and returns
    its record fields: ``command`` (the CLI equivalent, a string), ``config`` (a dict) and
    ``figures`` (its key outputs, a dict). ``needs``: stages that must be done first;
    ``outputs``: files (relative to ``out``) whose existence a done record is checked against;
    ``estimate_s``: GPU time on one H100 (s), from BENCHMARKS.md and the recorded wall times;
    ``after``: stages not required, but whose run after this one makes it stale (``ship`` after
    ``tables``)."""
    name: str
    run: Callable
    needs: tuple = ()
    outputs: tuple = ()
    estimate_s: float = 0.0
    what: str = ""
    after: tuple = ()


@dataclasses.dataclass(frozen=True)
class Options:
    """What defines a release, recorded in release.json when it starts: ``scale`` ('full' or
    'tiny'), ``policy_config`` (the TrainConfig JSON the policy stage trains with) and
    ``from_policy`` (a policy.npz the policy stage adopts instead of training, or None)."""
    scale: str = "full"
    policy_config: str = DEFAULT_POLICY_CONFIG
    from_policy: str | None = None


def config_path(path) -> Path:
    """A config path as given: absolute, or relative to the working directory where it exists
    there, else to :data:`ROOT` (so the default resolves from anywhere)."""
    p = Path(path)
    return p if p.is_absolute() or p.exists() else ROOT / p


# ----------------------------------------------------------------------------------------
# the release: record, plan, run
# ----------------------------------------------------------------------------------------

def _now() -> str:
    return datetime.datetime.now(datetime.timezone.utc).isoformat(timespec="seconds")


def _device() -> str:
    from mjxsysid.experiments.common import device_info
    d = device_info()
    return f"{d['device_kind']} ({d['platform']}, {d['device_count']} device(s)), jax {d['jax']}"


def _commit() -> str | None:
    from mjxsysid.experiments.common import git_commit
    return git_commit()


class Release:
    """The release in ``out``: its record (``out/release.json``) and its stages.

    ``options``: the :class:`Options` fields given for this call, as a dict (or an Options: all
    of them); a new release takes them over the defaults, a started one checks them against the
    recorded ones (a difference is a ValueError naming the option). ``ship_to``: the tree the ``ship`` stage copies into
    (default: this checkout for a full release, ``out/ship`` for a tiny one). ``stages``: the
    stage list (tests inject stubs); ``device`` / ``commit``: callables recorded per stage."""

    def __init__(self, out, options: Options | None = None, *, ship_to=None, stages=None, log=echo,
                 device: Callable[[], str] = _device, commit: Callable[[], str | None] = _commit):
        self.out = Path(out)
        if self.out.exists() and not self.out.is_dir():
            raise ValueError(f"--out {self.out}: is a file, not a release folder")
        self.stages = tuple(STAGES if stages is None else stages)
        self.by_name = {s.name: s for s in self.stages}
        self.log = log or (lambda m: None)
        self._device, self._commit = device, commit
        self._mine: set[str] = set()   # stages this process ran: the only entries its saves write
        self.record = self._load()
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
            self.out / "ship" if self.options.scale == "tiny" else ROOT)
        self.sizes = SIZES[self.options.scale]
        self.allow_partial = False   # set by run(): ship what the done stages wrote

    # -- record ---------------------------------------------------------------------------
    def _load(self) -> dict:
        path = self.out / RECORD
        if not path.exists():
            return {"stages": {}}
        try:
            rec = json.loads(path.read_text())
        except (json.JSONDecodeError, UnicodeDecodeError) as e:
            raise ValueError(f"{path}: not valid JSON ({e})") from None
        if not isinstance(rec, dict) or not isinstance(rec.get("stages", {}), dict):
            raise ValueError(f"{path}: not a release record (expected an object with 'stages')")
        rec.setdefault("stages", {})
        return rec

    @contextlib.contextmanager
    def _locked(self):
        """The record's lock (``DIR/release.lock``, an advisory ``flock``): processes running other
        stages of one release at once (one per GPU) read, merge and write the record in turn."""
        self.out.mkdir(parents=True, exist_ok=True)
        with open(self.out / (RECORD + ".lock"), "a") as fh:
            try:
                import fcntl
            except ImportError:   # no flock (Windows): one process per release
                yield
                return
            fcntl.flock(fh, fcntl.LOCK_EX)
            try:
                yield
            finally:
                fcntl.flock(fh, fcntl.LOCK_UN)

    def _merge(self) -> None:
        """Take the record on disk (another process may have run stages since this one read it),
        keeping this process's own stage entries and the larger run count. Call with the lock."""
        if not (self.out / RECORD).exists():
            return
        disk = self._load()
        for name in self._mine:
            disk["stages"][name] = self.record["stages"][name]
        disk["runs"] = max(int(disk.get("runs", 0)), int(self.record.get("runs", 0)))
        self.record = disk

    def _write(self) -> None:
        self.record.update(release=self.out.name, options=dataclasses.asdict(self.options),
                           order=[s.name for s in self.stages])
        self.record.setdefault("created", _now())
        tmp = self.out / f"{RECORD}.{os.getpid()}.tmp"
        tmp.write_text(json.dumps(self.record, indent=2, ensure_ascii=False) + "\n")
        os.replace(tmp, self.out / RECORD)

    def save(self) -> None:
        """Write the record: the one on disk with this process's stage entries merged in (so
        several processes can run different stages of one release at once)."""
        with self._locked():
            self._merge()
            self._write()

    def _begin(self, name: str, entry: dict) -> None:
        """Record ``name`` as started with the next run number (atomic across processes)."""
        with self._locked():
            self._merge()
            self.record["runs"] = int(self.record.get("runs", 0)) + 1
            entry["run"] = self.record["runs"]
            self.record["stages"][name] = entry
            self._mine.add(name)
            self._write()

    def stage_dir(self, name: str) -> Path:
        return self.out / name

    def entry(self, name: str) -> dict:
        return self.record["stages"].get(name, {})

    def status(self, name: str) -> str:
        """'done', 'stale' (done, but a dependency ran after it, ``run`` being the record's
        count of stage runs, or is no longer done), 'incomplete'
        (recorded done, an output missing), 'failed', 'started' (running now, or an interrupted
        call: it runs again, resuming where its code can) or 'pending'."""
        e = self.entry(name)
        st = e.get("status", "pending")
        if st != "done":
            return st
        stage = self.by_name[name]
        if any(not (self.stage_dir(name) / f).exists() for f in stage.outputs):
            return "incomplete"
        for dep in stage.needs:   # a dependency that ran (or is running) after this stage, or not done
            d = self.entry(dep)
            if d.get("status") != "done" or d.get("run", 0) > e.get("run", 0):
                return "stale"
        if any(self.entry(dep).get("run", 0) > e.get("run", 0) for dep in stage.after):
            return "stale"
        return "done"

    def done(self, name: str) -> bool:
        return self.status(name) == "done"

    # -- plan -----------------------------------------------------------------------------
    def _names(self, names, what: str) -> list[str]:
        out = []
        for n in names or ():
            for part in str(n).split(","):
                part = part.strip()
                if not part:
                    continue
                if part not in self.by_name:
                    raise ValueError(f"{what}: unknown stage {part!r}; stages: {', '.join(self.by_name)}")
                out.append(part)
        return out

    def plan(self, select=None, force=(), allow_partial: bool = False) -> list[str]:
        """The stages to run, in release order: ``select`` (names; default every stage) not done,
        plus ``force``d ones and the chosen stages downstream of a stage that runs. Raises ValueError for an unknown stage, a dependency neither done nor
        selected, ``ship`` with an earlier stage not done (unless ``allow_partial`` with ship
        selected explicitly), and ``allow_partial`` without ``ship`` selected."""
        chosen = self._names(select, "--stages") if select else [s.name for s in self.stages]
        forced = self._names(force, "--force")
        chosen = set(chosen) | set(forced)
        if allow_partial and not (select and "ship" in self._names(select, "--stages")):
            raise ValueError("--allow-partial applies to an explicit --stages ship only")
        todo = []
        for s in self.stages:   # a chosen stage runs if forced, not done, or downstream of one that runs
            if s.name in chosen and (s.name in forced or not self.done(s.name) or any(d in todo for d in s.needs)):
                todo.append(s.name)
        for name in todo:
            for dep in self.by_name[name].needs:
                if dep not in todo and not self.done(dep):
                    raise ValueError(f"stage {name!r} needs stage {dep!r}, which is {self.status(dep)}: run "
                                     f"`--stages {dep}` first (or include it)")
        if "ship" in todo and not allow_partial:
            missing = [s.name for s in self.stages if s.name != "ship" and s.name not in todo
                       and not self.done(s.name)]
            if missing:
                raise ValueError(f"cannot ship: stage(s) {', '.join(missing)} not done (run them, or ship "
                                 f"what exists with --stages ship --allow-partial)")
        return todo

    # -- run ------------------------------------------------------------------------------
    def run(self, select=None, force=(), allow_partial: bool = False) -> list[str]:
        """Run the planned stages (see :meth:`plan`) in order, recording each; a failing stage is
        recorded as failed and its exception re-raised (the stages after it do not run). Returns
        the names of the stages that ran."""
        todo = self.plan(select, force, allow_partial)
        forced = set(self._names(force, "--force"))
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
        entry = {"status": "started", "run": 0, "started": _now(),
                 "attempts": int(prev.get("attempts", 0)) + 1, "commit": self._commit(), "device": self._device()}
        self._begin(stage.name, entry)
        self.log(f"[release] {stage.name}: {stage.what} (≈ {stage.estimate_s / 60:.1f} min on an H100)")
        t0 = time.time()
        try:
            res = stage.run(self, out) or {}
        except BaseException as e:
            entry.update(status="failed", ended=_now(), wall_s=round(time.time() - t0, 1),
                         error=f"{type(e).__name__}: {e}", traceback=traceback.format_exc(limit=8))
            self.save()
            raise
        missing = [f for f in stage.outputs if not (out / f).exists()]
        if missing:
            entry.update(status="failed", ended=_now(), wall_s=round(time.time() - t0, 1),
                         error=f"outputs missing: {', '.join(missing)}")
            self.save()
            raise RuntimeError(f"stage {stage.name}: finished without writing {', '.join(missing)}")
        entry.update(status="done", ended=_now(), wall_s=round(time.time() - t0, 1),
                     command=res.get("command"), config=res.get("config", {}),
                     outputs=list(stage.outputs), figures=res.get("figures", {}))
        entry.pop("error", None)
        entry.pop("traceback", None)
        self.save()
        self.log(f"[release] {stage.name}: done in {entry['wall_s']:.0f} s")

    # -- listing --------------------------------------------------------------------------
    def table(self) -> str:
        """The stages with their status, recorded times and the H100 estimate (``--list``)."""
        rows = [f"release {self.out} ({self.options.scale}; policy: "
                f"{self.options.from_policy or self.options.policy_config})",
                f"{'stage':17s} {'status':10s} {'wall':>8s} {'H100 est.':>9s}  {'ended':25s} needs"]
        for s in self.stages:
            e = self.entry(s.name)
            wall = f"{e['wall_s']:.0f} s" if e.get("wall_s") is not None else "–"
            rows.append(f"{s.name:17s} {self.status(s.name):10s} {wall:>8s} {s.estimate_s / 60:>7.1f} m  "
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
            _link(src, d / src.name)
        return d

    def progress_on(self) -> bool:
        """Whether the experiments report progress (not ``--quiet``)."""
        from mjxsysid.progress import quiet
        return not quiet()


def _link(src: Path, dst: Path) -> None:
    """dst becomes a hard link of src (a copy where links fail); an existing dst is replaced
    atomically (linked under a temporary name, then renamed: processes running other stages at
    once may link the same file)."""
    if not src.is_file():
        raise FileNotFoundError(f"{src} not found (is its stage done?)")
    dst.parent.mkdir(parents=True, exist_ok=True)
    if dst.is_file() and os.path.samefile(src, dst):   # linked already (rename would leave the temporary)
        return
    tmp = dst.with_name(f"{dst.name}.{os.getpid()}.tmp")
    if tmp.exists() or tmp.is_symlink():
        tmp.unlink()
    try:
        os.link(src, tmp)
    except OSError:
        shutil.copy2(src, tmp)
    os.replace(tmp, dst)


# ----------------------------------------------------------------------------------------
# the stages
# ----------------------------------------------------------------------------------------

def train_config(options: Options) -> dict:
    """The TrainConfig dict the policy stage trains with: the default config with the overrides
    of ``options.policy_config``, and for a tiny release :data:`TINY_TRAIN`'s sizes on top."""
    from mjxsysid.policy.train import TrainConfig, config_with_overrides
    cfg = config_with_overrides(config_path(options.policy_config))
    if options.scale == "tiny":
        from mjxsysid.policy.interface import PRETRAINED_DIR
        cfg.update(TINY_TRAIN, init_from=cfg.get("init_from") or str(PRETRAINED_DIR / "policy.npz"))
    TrainConfig.from_dict(cfg)   # checked here: a bad key fails before anything trains
    return cfg


def stage_policy(rel: Release, out: Path) -> dict:
    """Train the policy (``train-policy --config``; it checkpoints and resumes itself), or adopt
    ``options.from_policy``."""
    from mjxsysid.policy.interface import file_sha256
    from mjxsysid.checkpoint import load_meta
    if rel.options.from_policy:
        src = Path(rel.options.from_policy)
        if not src.is_file():
            raise FileNotFoundError(f"--from-policy: policy weights not found: {src}")
        shutil.copyfile(src, out / "policy.npz")
        if src.with_suffix(".json").is_file():   # how it was trained: kept for the shipped provenance
            shutil.copyfile(src.with_suffix(".json"), out / ADOPTED_PROVENANCE)
        meta = load_meta(out / "policy.npz")
        return {"command": f"adopted {src} (no training)",
                "config": {"adopted_from": str(src), "sha256": file_sha256(out / "policy.npz"),
                           "train_config": meta.get("config")},
                "figures": {"trained_wall_s": meta.get("wall_s"), "trained_on": meta.get("device")}}
    from mjxsysid.policy.train import TrainConfig, train
    cfg_dict = train_config(rel.options)
    cfg = TrainConfig.from_dict(cfg_dict)
    res = train(cfg, out, resume=True, log=rel.log)
    stats = res["stats"]
    return {"command": f"mjxsysid train-policy --config {rel.options.policy_config} --out {out}"
                       + (" (tiny sizes: mjxsysid.release.TINY_TRAIN)" if rel.options.scale == "tiny" else ""),
            "config": cfg_dict,
            "figures": {"train_wall_s": res["wall_s"], "sha256": file_sha256(out / "policy.npz"),
                        **{k: stats[k] for k in ("reward", "rate_err", "thrust_err", "latent_err_rel",
                                                 "latent_min_std") if k in stats}}}


def _previous_policy() -> Path | None:
    from mjxsysid.policy.interface import PRETRAINED_DIR
    p = PRETRAINED_DIR / "policy.npz"
    return p if p.is_file() else None


def stage_policy_eval(rel: Release, out: Path) -> dict:
    """``evaluate-policy`` at the release size (eval.json) and ``evaluate-policy --held-out`` of
    the release's policy against the shipped (previous) one (heldout/results.*)."""
    from mjxsysid.policy.interface import file_sha256
    from mjxsysid.experiments.heldout import SETS, run as heldout_run
    from mjxsysid.policy.evaluate import evaluate_policy
    sz = rel.sizes
    ev = evaluate_policy(rel.policy_path, n=sz["eval_vehicles"], seed=0, log=rel.log)
    (out / "eval.json").write_text(json.dumps(ev, indent=2) + "\n")
    policies = {"release": str(rel.policy_path)}
    prev = _previous_policy()
    if prev is not None and file_sha256(prev) != file_sha256(rel.policy_path):
        policies["previous"] = str(prev)
    sets = sz["heldout_sets"] or SETS
    ho = heldout_run(out / "heldout", policies, sets=sets, vehicles=sz["heldout_vehicles"],
                     period=sz["heldout_period"], seed=0, progress=rel.progress_on())
    lem, lat = ev["lemniscate"], ev["latent"]
    weights = " ".join(f"--weights {k}={v}" for k, v in policies.items())
    return {"command": f"mjxsysid evaluate-policy --weights {rel.policy_path} --vehicles {sz['eval_vehicles']} "
                       f"--out {out} && mjxsysid evaluate-policy --held-out {weights} --vehicles "
                       f"{sz['heldout_vehicles']} --period {sz['heldout_period']:g}"
                       + (f" --sets {','.join(sets)}" if sz["heldout_sets"] else "") + f" --out {out / 'heldout'}",
            "config": {"vehicles": sz["eval_vehicles"], "heldout": {"policies": policies, "sets": list(sets),
                                                                    "vehicles": sz["heldout_vehicles"],
                                                                    "period_s": sz["heldout_period"]}},
            "figures": {"success": lem["policy"]["success_rate"],
                        "rmse_ratio_over_oracle": lem.get("rmse_ratio_policy_over_oracle"),
                        "z_err_rel": lat["z_err_rel"],
                        "probe_r2_thrust_to_weight": lat["probe_r2_identifiable"].get("thrust_to_weight"),
                        "heldout_targets_met": {k: v["all"] for k, v in ho["numbers"]["targets"].items()}}}


def _imu_config(rel: Release):
    """The simulator of the pairs: the policy's training IMU randomisation when its config has
    it (``env.randomize_imu``), else a clean IMU (the shipped decoders' pairs)."""
    from mjxsysid.checkpoint import load_meta
    from mjxsysid.sim import SimConfig
    env = (load_meta(rel.policy_path).get("config") or {}).get("env", {})
    if not env.get("randomize_imu"):
        return SimConfig(), ""
    from mjxsysid.policy.env import IMU_FIELDS
    cfg = SimConfig(**{k: env.get(k, getattr(SimConfig(), k)) for k in IMU_FIELDS})
    flags = (f" --imu-noise {cfg.gyro_noise:g} {cfg.accel_noise:g} --imu-bias {cfg.gyro_bias:g} {cfg.accel_bias:g}"
             f" --imu-vibration {cfg.gyro_vibration:g} {cfg.accel_vibration:g} --randomize-imu"
             + (f" --imu-clean-fraction {cfg.imu_clean_fraction:g}" if cfg.imu_clean_fraction else ""))
    return cfg, flags


def _collect(rel: Release, out: Path, *, seconds, sizes) -> dict:
    from mjxsysid.policy.interface import file_sha256
    from mjxsysid.dataset.collect import collect, imu_settings, load_pairs
    n_train, n_test, batch = sizes
    sim, flags = _imu_config(rel)
    path = collect(out, policy=rel.policy_path, n_train=n_train, n_test=n_test, seed=0, batch=batch,
                   seconds=seconds, sim_config=sim, log=rel.log)
    arrays, meta = load_pairs(path)
    cmd = (f"mjxsysid collect --policy {rel.policy_path} --out {out} --train {n_train} --test {n_test} "
           f"--batch {batch}" + (" --single-latent" if seconds is None else f" --seconds {seconds:g}") + flags)
    return {"command": cmd, "config": {"train": n_train, "test": n_test, "batch": batch, "seconds": seconds,
                                       "prior": meta.get("prior"), "imu": imu_settings(sim)},
            "figures": {"failed_train": int(arrays["failed_train"].sum()), "failed_test": int(arrays["failed_test"].sum()),
                        "pairs_sha256": file_sha256(path)}}


def stage_pairs(rel: Release, out: Path) -> dict:
    """Single-latent (θ, ẑ) pairs, as the shipped cfm.json's (``collect --single-latent``)."""
    return _collect(rel, out, seconds=None, sizes=rel.sizes["pairs"])


def stage_seq_pairs(rel: Release, out: Path) -> dict:
    """Flights of random manoeuvres with ẑ at 10 Hz (tools/archive/seq_decoder_pipeline.sh's collect)."""
    return _collect(rel, out, seconds=rel.sizes["seq_seconds"], sizes=rel.sizes["seq_pairs"])


def _train(rel: Release, pairs: Path, out: Path, kinds, seq_cfg=None) -> dict:
    from mjxsysid.cfm.pipeline import train_decoders
    from mjxsysid.cfm.train import CFMConfig
    cfg = dataclasses.replace(CFMConfig(), **rel.sizes["cfm"])
    res = train_decoders(pairs, out, cfg, kinds=kinds, seq_cfg=seq_cfg, log=rel.log, resume=True)
    over = " ".join(f"--{k} {v}" for k, v in rel.sizes["cfm"].items() if k in ("epochs", "width", "batch"))
    seq = f" --seq-epochs {seq_cfg['epochs']}" if seq_cfg and "epochs" in seq_cfg else ""
    return {"command": f"mjxsysid train-cfm --pairs {pairs} --out {out} --kinds {','.join(kinds)} {over}{seq}".rstrip(),
            "config": {"cfm": dataclasses.asdict(cfg), "seq_cfg": seq_cfg},
            "figures": {k: {kk: v[kk] for kk in ("wall_s", "final_train_loss", "final_val_loss")} for k, v in res.items()}}


def stage_decoders(rel: Release, out: Path) -> dict:
    """CFM and Regression (``train-cfm --kinds cfm,regression``) on the single-latent pairs."""
    return _train(rel, rel.stage_dir("pairs") / "pairs.npz", out, ("cfm", "regression"))


def stage_seq_decoder(rel: Release, out: Path) -> dict:
    """The flight-level decoder (``train-cfm --kinds cfm_seq``) on the latent trajectories."""
    return _train(rel, rel.stage_dir("seq_pairs") / "pairs.npz", out, ("cfm_seq",), seq_cfg=dict(rel.sizes["seq_cfg"]))


def stage_decoder_eval(rel: Release, out: Path) -> dict:
    """``evaluate-decoder`` of CFM + Regression on the single-latent pairs (single/) and of the
    flight-level decoder, with the release's CFM as its single-latent reference, on the
    trajectories (flight/)."""
    from mjxsysid.cfm.pipeline import evaluate_decoders
    from mjxsysid.dataset.collect import paper_vehicle_latents
    sz = rel.sizes
    single, flight = out / "single", out / "flight"
    for f in ("cfm.npz", "regression.npz"):
        _link(rel.stage_dir("decoders") / f, single / f)
    _link(rel.stage_dir("seq_decoder") / "cfm_seq.npz", flight / "cfm_seq.npz")
    _link(rel.stage_dir("decoders") / "cfm.npz", flight / "cfm.npz")
    zhat, traj = paper_vehicle_latents(rel.policy_path, instant=sz["paper_flight"], flight=sz["paper_flight"])
    kw = dict(n_cases=sz["eval_cases"], n_samples=sz["eval_samples"], log=rel.log)
    rep = evaluate_decoders(single, rel.stage_dir("pairs") / "pairs.npz", paper_zhat=zhat, **kw)
    seq = evaluate_decoders(flight, rel.stage_dir("seq_pairs") / "pairs.npz", paper_traj=traj, **kw)["sequence"]
    flag = "" if sz["paper_flight"] else " --no-paper-flight"
    return {"command": f"mjxsysid evaluate-decoder --decoders {single} --pairs {rel.stage_dir('pairs')} --cases "
                       f"{sz['eval_cases']} --samples {sz['eval_samples']}{flag} && mjxsysid evaluate-decoder "
                       f"--decoders {flight} --pairs {rel.stage_dir('seq_pairs')} --cases {sz['eval_cases']} "
                       f"--samples {sz['eval_samples']}{flag}",
            "config": {"cases": sz["eval_cases"], "samples": sz["eval_samples"], "paper_flight": sz["paper_flight"]},
            "figures": {"coverage_mean": rep["coverage_mean"], "calibrated_within_5_points": rep["calibrated_within_5_points"],
                        "energy_score": rep["energy_score"], "sequence_targets": seq["targets"],
                        "energy_ratio_flight_vs_single": seq["energy_ratio_flight_vs_single"]}}


def stage_noise(rel: Release, out: Path) -> dict:
    """The noise-sensitivity experiment's measurement (:func:`mjxsysid.studies.noise.noise_sensitivity`)
    at the docs' levels and at the low ones, with the figure."""
    from mjxsysid.studies.noise import DEFAULT_LEVELS, figure, noise_sensitivity
    sz = dict(rel.sizes["noise"])
    dec = rel.decoder_set()
    runs = {"noise_sensitivity.json": DEFAULT_LEVELS, "noise_sensitivity_low.json": ("clean", "x0.5_white", "x1_white")}
    if rel.options.scale == "tiny":
        runs = {"noise_sensitivity.json": ("clean", "x1"), "noise_sensitivity_low.json": ("clean", "x1_white")}
    figures, cmds = {}, []
    for name, levels in runs.items():
        cmd = (f"mjxsysid.studies.noise.noise_sensitivity(vehicles={sz['vehicles']}, seconds={sz['seconds']}, "
               f"samples={sz['samples']}, seed=4242, levels={list(levels)}, policy='{rel.policy_path}', "
               f"decoders='{dec}') -> {out / name}")
        res = noise_sensitivity(policy=rel.policy_path, decoders=dec, seed=4242, levels=levels, log=rel.log, **sz)
        (out / name).write_text(json.dumps({"command": cmd, **res}, indent=1) + "\n")
        cmds.append(cmd)
        figures[name] = {lv: {"flight_level_identifiable_within_5": v["flight_level"]["identifiable_90_within_5_points"],
                              "flight_level_params_within_5": v["flight_level"]["coverage_90_within_5_points"]}
                         for lv, v in res["levels"].items()}
    figure(json.loads((out / "noise_sensitivity.json").read_text()), out / "noise_sensitivity.png")
    return {"command": " && ".join(cmds), "config": {**sz, "levels": {k: list(v) for k, v in runs.items()}},
            "figures": figures}


def _experiments(rel: Release, out: Path, runs) -> dict:
    """Run the experiments ``runs`` ((folder, experiment name, seed, variant or None, methods or
    None)) with the release's policy and decoders into out/<folder>/, each skipped when its
    results.json exists (a finished run of an interrupted stage)."""
    from mjxsysid.experiments import get_experiment
    dec = rel.decoder_set()
    figures, cmds = {}, []
    for folder, name, seed, variant, methods in runs:
        kw = {"decoders": dec}
        if variant:
            kw["variant"] = variant
        if methods:
            kw["methods"] = tuple(methods.split(","))
        cmd = (f"mjxsysid experiment {name} --policy {rel.policy_path} --decoders {dec} --seed {seed}"
               + (f" --variant {variant}" if variant else "") + (f" --methods {methods}" if methods else "")
               + (" --quick" if rel.sizes["quick"] else "") + f" --out {out / folder}")
        cmds.append(cmd)
        done = out / folder / "results.json"
        if done.is_file():
            rel.log(f"[release] {folder}: done before (results.json), kept")
            res = json.loads(done.read_text())
        else:
            rel.log(f"[release] {cmd}")
            res = get_experiment(name)(out / folder, quick=rel.sizes["quick"], policy=rel.policy_path, seed=seed,
                                       progress=rel.progress_on(), **kw)
        figures[folder] = {"wall_s": res.get("wall_s"), **res["numbers"].get("headline", {})}
    return {"command": " && ".join(cmds), "config": {"runs": [list(r) for r in runs], "quick": rel.sizes["quick"]},
            "figures": figures}


TUNE_RUNS = {
    "tune_nominal": (("tune_nominal", "tune-nominal", 0, None, None),
                     ("tune_nominal_baseline_start", "tune-nominal", 0, "baseline_start", "baseline,cfm,oracle_cem"),
                     ("tune_nominal_protect", "tune-nominal", 0, "protect", "baseline,cfm,oracle_cem")),
    "tune_slow": (("tune_slow", "tune-slow", 0, None, None),
                  ("tune_slow_heading_cost", "tune-slow", 0, "heading_cost", None),
                  ("tune_slow_baseline_start", "tune-slow", 0, "baseline_start", "baseline,cfm,oracle_cem")),
    "tune_slow_more": (("tune_slow_true_rotor_state", "tune-slow", 0, "true_rotor_state", "cfm,oracle_cem"),
                       ("tune_slow_steady_rotor_state", "tune-slow", 0, "steady_rotor_state", "cfm,oracle_cem"),
                       ("tune_slow_seed7", "tune-slow", 7, None, None),
                       ("tune_slow_seed7_baseline_start", "tune-slow", 7, "baseline_start", "baseline,cfm,oracle_cem")),
    "tune_lemniscate": (("tune_lemniscate", "tune-lemniscate", 0, None, None),
                        ("tune_lemniscate_no_lead_in", "tune-lemniscate", 0, "no_lead_in", None),
                        ("tune_lemniscate_no_lead_in_baseline_start", "tune-lemniscate", 0, "no_lead_in,baseline_start",
                         None)),
}
"""Per tune stage: (folder, experiment, seed, variant, methods) of each run: the runs of
docs/fair_comparisons.md §7 (tools/archive/gpu_tune.sh's, issue 26)."""
STUDY_RUNS = (("robustness", "robustness", 0, None, None),
              ("robustness_single_latent", "robustness", 0, "single_latent", None),
              ("replay", "replay", 0, None, None),
              ("payload", "payload", 0, None, None))
"""The studies stage's runs (tools/archive/fair_baselines.sh's robustness and replay, and payload)."""


def _tune_stage(key):
    def run(rel: Release, out: Path) -> dict:
        return _experiments(rel, out, TUNE_RUNS[key])
    run.__doc__ = f"The {key.replace('_', '-')} runs of :data:`TUNE_RUNS`."
    return run


def stage_studies(rel: Release, out: Path) -> dict:
    """robustness (flight-level decoder, and --variant single_latent), replay and payload."""
    return _experiments(rel, out, STUDY_RUNS)


def stage_fidelity(rel: Release, out: Path) -> dict:
    """benchmarks/closed_loop_fidelity.py on a held-out identification flight and on the test
    flight itself (:func:`mjxsysid.studies.fidelity.fidelity_benchmark`)."""
    from mjxsysid.cfm.sequence import SequenceDecoder
    from mjxsysid.studies.fidelity import fidelity_benchmark
    sz = rel.sizes["fidelity"]
    dec = SequenceDecoder.load(rel.decoder_set() / "cfm_seq.npz")
    figures, cmds = {}, []
    for ident, name in (("held_out", "closed_loop_fidelity.json"), ("same", "closed_loop_fidelity_same_flight.json")):
        res = fidelity_benchmark(vehicles=sz["vehicles"], models=sz["models"], duration=sz["duration"],
                                 identification=ident, policy=rel.policy_path, decoder=dec, log=rel.log)
        (out / name).write_text(json.dumps(res, indent=2) + "\n")
        cmds.append(f"python benchmarks/closed_loop_fidelity.py --vehicles {sz['vehicles']} --models {sz['models']} "
                    f"--duration {sz['duration']:g} --identification {ident} --out {out / name} (release policy and "
                    f"flight-level decoder)")
        figures[name] = {"mean_inside_decoded": res["mean"]["inside_decoded"],
                         "median_width_ratio": res["width_ratio_decoded_over_pm20"]["median"]}
    return {"command": " && ".join(cmds), "config": sz, "figures": figures}


# ----------------------------------------------------------------------------------------
# the shipped tree: weights with provenance, the docs' run files, the generated pages
# ----------------------------------------------------------------------------------------

def policy_provenance(weights, evaluation: dict, *, train_log=None, command: str, note: str | None = None,
                      commit: str | None = None) -> dict:
    """policy.json beside shipped policy weights: what, the command, config, seed, commit,
    device, wall time, env steps, mean training speed, normaliser, final training stats and the
    evaluation (``evaluate-policy``'s eval.json), read from the files given."""
    from mjxsysid.checkpoint import load_meta
    meta = load_meta(weights)
    sps = None
    if train_log is not None and Path(train_log).exists():
        rows = [json.loads(x) for x in Path(train_log).read_text().splitlines() if x.strip()]
        sps = sum(r["steps_per_s"] for r in rows[1:]) / max(len(rows) - 1, 1) if rows else None
    prov = {"what": "unified latent-conditioned adaptive policy (μ, φ, π, aux decoder)", "command": command,
            "config": meta.get("config"), "seed": (meta.get("config") or {}).get("seed"),
            "commit": commit if commit is not None else _commit(),
            "device": meta.get("device"), "jax": meta.get("jax"), "wall_s": meta.get("wall_s"),
            "env_steps": meta.get("env_steps"), "mean_train_steps_per_s": sps,
            "normalizer": meta.get("normalizer"), "final_train_stats": meta.get("final_stats"),
            "evaluation": evaluation, "evaluation_command": "mjxsysid evaluate-policy --vehicles 1000 --out OUT"}
    if note:
        prov["note"] = note
    return prov


def decoder_provenance(path, kind: str, evaluation: dict, *, what: str = "of the shipped policy's latent",
                       command: str, evaluation_command: str, note: str | None = None,
                       commit: str | None = None) -> dict:
    """cfm.json / regression.json / cfm_seq.json beside shipped decoders: what, the command,
    config, seed, commit, device, wall time, losses, the data they were trained on and the
    evaluation (``evaluate-decoder``'s decoder_eval.json: all of it for cfm, energy score and
    RMSE for regression, its ``sequence`` part for cfm_seq)."""
    from mjxsysid.cfm.sample import Decoder
    from mjxsysid.cfm.sequence import SequenceDecoder
    dec = SequenceDecoder.load(path) if kind == "cfm_seq" else Decoder.load(path)
    m = dec.meta
    desc = "p(θ | ẑ_1..ẑ_W) (flight-level, W = 1 latent up to a whole flight)" if kind == "cfm_seq" else "p(θ | ẑ)"
    prov = {"what": f"{kind} decoder {desc} {what}", "command": command,
            "config": {k: getattr(dec.cfg, k) for k in dec.cfg.__dataclass_fields__},
            "seed": dec.cfg.seed, "commit": commit if commit is not None else _commit(),
            "device": f"{m.get('device')}, jax {m.get('jax')}",
            "wall_s": m.get("wall_s"), "steps_per_s": m.get("steps_per_s"),
            "final_train_loss": m.get("final_train_loss"), "final_val_loss": m.get("final_val_loss"),
            "data": m.get("data"), **({"early_stopping": m["early_stopping"]} if "early_stopping" in m else {}),
            "stored_dtype": "float16 (evaluated after rounding)",
            "evaluation": evaluation.get("sequence") if kind == "cfm_seq" else evaluation if kind == "cfm" else {
                "energy_score": evaluation.get("energy_score"), "rmse_norm": evaluation.get("rmse_norm")},
            "evaluation_command": evaluation_command}
    if kind == "cfm_seq":
        prov.update(n_params=m.get("n_params"), val_loss_min=m.get("val_loss_min"),
                    val_loss_argmin_epoch=m.get("val_loss_argmin_epoch"))
    if note:
        prov["note"] = note
    return prov


DOCS_RUNS = (
    # (stage, path in the stage folder, path under docs/runs/)
    ("policy_eval", "eval.json", "release/policy/eval.json"),
    ("policy", "train_log.jsonl", "release/policy/train_log.jsonl"),
    ("policy_eval", "heldout", "release/policy/heldout"),
    ("decoder_eval", "single/decoder_eval.json", "release/decoders/decoder_eval.json"),
    ("decoder_eval", "single/sbc_ranks.png", "release/decoders/sbc_ranks.png"),
    ("decoder_eval", "single/paper_vehicle_posterior.png", "release/decoders/paper_vehicle_posterior.png"),
    ("decoders", "train_log.txt", "release/decoders/train_log.txt"),
    ("decoder_eval", "flight/decoder_eval.json", "release/decoders/seq_decoder_eval.json"),
    ("seq_decoder", "train_log.txt", "release/decoders/seq_decoder_log.txt"),
    ("noise", "noise_sensitivity.json", "release/noise/noise_sensitivity.json"),
    ("noise", "noise_sensitivity_low.json", "release/noise/noise_sensitivity_low.json"),
    *((key, folder, f"release/tuning/{folder}") for key, runs in TUNE_RUNS.items() for folder, *_ in runs),
    *(("studies", folder, f"release/studies/{folder}") for folder, *_ in STUDY_RUNS),
    ("fidelity", "closed_loop_fidelity.json", "release/studies/closed_loop_fidelity.json"),
    ("fidelity", "closed_loop_fidelity_same_flight.json", "release/studies/closed_loop_fidelity_same_flight.json"),
)
"""The run outputs the docs quote, and where under docs/runs/release/ a release ships them (one
folder per kind of run); ``ship`` replaces docs/runs/release/ whole."""
OPTIONAL = ("train_log.jsonl", "single/paper_vehicle_posterior.png")
"""Files of DOCS_RUNS a done stage may lack: an adopted policy has no training log; a tiny release
flies no paper vehicle."""
RELEASE_RUNS = "release"
"""The folder under docs/runs/ that holds exactly what the last release shipped (its run files and
its record, release.json)."""
DOCS_FILES = (("noise", "noise_sensitivity.png", "noise_sensitivity.png"),)
"""Figures the docs pages show directly (stage, file, path under docs/)."""
SHIPPED = (("policy", "policy.npz"), ("decoders", "cfm.npz"), ("decoders", "regression.npz"),
           ("seq_decoder", "cfm_seq.npz"))
"""(stage, weights file) shipped into mjxsysid/pretrained/ with a provenance JSON each."""


def shrink_pngs(path: Path) -> None:
    """Rewrite every PNG at or under ``path`` as a 256-colour palette image (a plot looks the same
    at about half the bytes): the figures docs/runs/ keeps in git."""
    from PIL import Image
    for f in ([path] if path.is_file() else sorted(path.rglob("*.png"))):
        if f.suffix == ".png":
            with Image.open(f) as im:
                small = im.convert("RGB").quantize(colors=256)
            small.save(f, "PNG", optimize=True)


def _copy(src: Path, dst: Path, *, link: bool = False) -> None:
    if dst.is_dir() and not dst.is_symlink():
        shutil.rmtree(dst)
    elif dst.exists():
        dst.unlink()
    dst.parent.mkdir(parents=True, exist_ok=True)
    if src.is_dir():
        shutil.copytree(src, dst)
    elif link:
        _link(src, dst)
    else:
        shutil.copy2(src, dst)


_TRAINING_KEYS = ("command", "commit", "device", "jax", "wall_s", "env_steps", "mean_train_steps_per_s")


def _adopted_training(rel: Release) -> dict:
    """For a release that adopted a policy (``--from-policy``): how that policy was trained, from
    the provenance JSON the policy stage kept beside it (its command, commit, device, wall time,
    steps/s: the release did not train it), and where it came from. Empty for a release that
    trained its own."""
    if not rel.options.from_policy:
        return {}
    out = {"adopted_from": rel.options.from_policy}
    prov = rel.stage_dir("policy") / ADOPTED_PROVENANCE
    if prov.is_file():
        prior = json.loads(prov.read_text())
        out.update({k: prior[k] for k in _TRAINING_KEYS if k in prior})
    return out


def build_tree(rel: Release, tree: Path, *, partial: bool = False) -> list[str]:
    """Lay out what a release ships, as a tree rooted at ``tree``: mjxsysid/pretrained/ (the
    weights, hard-linked, and their provenance JSON, each with a ``release`` section: the release
    folder, commit, stage, its wall time and device) and docs/runs/release/<kind>/ (:data:`DOCS_RUNS`),
    docs/ (:data:`DOCS_FILES`). ``partial``: skip what a stage not done did not write (else an
    error). Returns what was left out."""
    left_out = []
    pre = tree / "mjxsysid" / "pretrained"

    def have(stage, rel_path):
        ok = rel.done(stage) and (rel.stage_dir(stage) / rel_path).exists()
        if not ok:
            if not partial and rel_path not in OPTIONAL:
                raise FileNotFoundError(f"{rel.stage_dir(stage) / rel_path}: not written (stage {stage} "
                                        f"is {rel.status(stage)})")
            left_out.append(f"{stage}/{rel_path}")
        return ok

    def release_info(stage):
        e = rel.entry(stage)
        return {"dir": rel.out.name, "path": str(rel.out.resolve()), "commit": e.get("commit"), "stage": stage,
                "stage_wall_s": e.get("wall_s"), "stage_ended": e.get("ended"), "device": e.get("device"),
                "scale": rel.options.scale}

    cmd = f"mjxsysid release --out {rel.out.name}"
    if have("policy", "policy.npz"):
        _copy(rel.policy_path, pre / "policy.npz", link=True)
        ev_path = rel.stage_dir("policy_eval") / "eval.json"
        ev = json.loads(ev_path.read_text()) if ev_path.is_file() else {}
        stage_cmd = rel.entry("policy").get("command")
        prov = policy_provenance(rel.policy_path, ev, train_log=rel.stage_dir("policy") / "train_log.jsonl",
                                 command=f"{cmd}  (stage policy: {stage_cmd})", commit=rel.entry("policy").get("commit"))
        prov["evaluation_command"] = rel.entry("policy_eval").get("command") or prov["evaluation_command"]
        prov.update(_adopted_training(rel))
        prov["release"] = release_info("policy")
        (pre / "policy.json").write_text(json.dumps(prov, indent=2, ensure_ascii=False) + "\n")
    evals = {"single": rel.stage_dir("decoder_eval") / "single" / "decoder_eval.json",
             "flight": rel.stage_dir("decoder_eval") / "flight" / "decoder_eval.json"}
    for stage, f in SHIPPED[1:]:
        if not have(stage, f):
            continue
        kind = f.removesuffix(".npz")
        _copy(rel.stage_dir(stage) / f, pre / f, link=True)
        ev_path = evals["flight" if kind == "cfm_seq" else "single"]
        ev = json.loads(ev_path.read_text()) if ev_path.is_file() else {}
        prov = decoder_provenance(rel.stage_dir(stage) / f, kind, ev,
                                  what="of the release's policy latent",
                                  command=f"{cmd}  (stage {stage}: {rel.entry(stage).get('command')})",
                                  evaluation_command=rel.entry("decoder_eval").get("command") or "",
                                  commit=rel.entry(stage).get("commit"))
        prov["release"] = release_info(stage)
        (pre / f"{kind}.json").write_text(json.dumps(prov, indent=2, ensure_ascii=False) + "\n")
    for stage, src, dst in DOCS_RUNS:
        if have(stage, src):
            _copy(rel.stage_dir(stage) / src, tree / "docs" / "runs" / dst)
            shrink_pngs(tree / "docs" / "runs" / dst)
    for stage, src, dst in DOCS_FILES:
        if have(stage, src):
            _copy(rel.stage_dir(stage) / src, tree / "docs" / dst)
    return left_out


def _tool(name: str):
    """tools/NAME.py of the source checkout, imported as a module."""
    path = ROOT / "tools" / f"{name}.py"
    if not path.is_file():
        raise FileNotFoundError(f"{path} not found: the tables stage needs the source checkout's tools/")
    spec = importlib.util.spec_from_file_location(f"mjxsysid_tools_{name}", path)
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    return mod


def stage_tables(rel: Release, out: Path) -> dict:
    """Lay out the shipped tree in out/tree (:func:`build_tree`) and regenerate the generated
    docs pages from it: docs/fair_comparisons.md (tools/fair_tables.py, reading each run file
    from the tree where the release wrote one, else from the checkout's docs/runs/) and the noise
    tables of docs/noise.md."""
    from mjxsysid.studies.noise import replace_tables
    tree = out / "tree"
    if tree.exists():
        shutil.rmtree(tree)
    build_tree(rel, tree)
    fair = _tool("fair_tables")
    page = fair.page(overlay=tree)
    (tree / "docs" / "fair_comparisons.md").write_text(page)
    runs = {f"docs/runs/{p}": json.loads((tree / "docs" / "runs" / p).read_text())
            for p in ("release/noise/noise_sensitivity.json", "release/noise/noise_sensitivity_low.json")}
    (tree / "docs" / "noise.md").write_text(replace_tables((ROOT / "docs" / "noise.md").read_text(), runs))
    files = sorted(str(p.relative_to(tree)) for p in tree.rglob("*") if p.is_file())
    return {"command": "python tools/fair_tables.py (overlay: the release's run files); docs/noise.md's tables "
                       "(mjxsysid.studies.noise.replace_tables)",
            "config": {"tree": str(tree)}, "figures": {"files": len(files), "pages": ["docs/fair_comparisons.md",
                                                                                     "docs/noise.md"]}}


def stage_ship(rel: Release, out: Path) -> dict:
    """Copy the tree of the tables stage (weights, provenance, docs run files, pages) into
    ``ship_to`` (default: this checkout). With ``allow_partial`` and the tables stage not done,
    a tree of whatever the done stages wrote (no pages regenerated)."""
    tree = rel.stage_dir("tables") / "tree"
    left_out = []
    if not rel.done("tables"):
        if not rel.allow_partial:
            raise ValueError("cannot ship: stage tables not done")
        tree = out / "tree"
        if tree.exists():
            shutil.rmtree(tree)
        left_out = build_tree(rel, tree, partial=True)
    dest = rel.ship_to
    files = []
    if (tree / "docs" / "runs" / RELEASE_RUNS).is_dir() and (dest / "docs" / "runs" / RELEASE_RUNS).is_dir():
        shutil.rmtree(dest / "docs" / "runs" / RELEASE_RUNS)      # replaced whole: no file of an earlier release stays
    for p in sorted(tree.rglob("*")):
        if p.is_file():
            r = p.relative_to(tree)
            _copy(p, dest / r)
            files.append(str(r))
    if not left_out:
        _copy(rel.out / RECORD, dest / "docs" / "runs" / RELEASE_RUNS / RECORD)     # the record as the ship began
        files.append(f"docs/runs/{RELEASE_RUNS}/{RECORD}")
    (out / "shipped.json").write_text(json.dumps({"to": str(dest), "files": files, "left_out": left_out}, indent=2) + "\n")
    if left_out:
        rel.log(f"[release] ship: left out (stages not done): {', '.join(left_out)}")
    rel.log(f"[release] shipped {len(files)} files into {dest}")
    return {"command": f"copy {tree} into {dest}", "config": {"to": str(dest), "partial": bool(left_out)},
            "figures": {"files": len(files), "left_out": left_out}}


STAGES = (
    Stage("policy", stage_policy, (), ("policy.npz",), 130,
          "train the policy (train-policy --config), or adopt --from-policy"),
    Stage("policy_eval", stage_policy_eval, ("policy",), ("eval.json", "heldout/results.json"), 115,
          "evaluate-policy (1,000 vehicles) and --held-out against the shipped policy"),
    Stage("pairs", stage_pairs, ("policy",), ("pairs.npz",), 20, "collect --single-latent (θ, ẑ) pairs"),
    Stage("decoders", stage_decoders, ("pairs",), ("cfm.npz", "regression.npz"), 40,
          "train-cfm --kinds cfm,regression"),
    Stage("seq_pairs", stage_seq_pairs, ("policy",), ("pairs.npz",), 30, "collect 10 s latent trajectories"),
    Stage("seq_decoder", stage_seq_decoder, ("seq_pairs",), ("cfm_seq.npz",), 35,
          "train-cfm --kinds cfm_seq (the flight-level decoder)"),
    Stage("decoder_eval", stage_decoder_eval, ("decoders", "seq_decoder"),
          ("single/decoder_eval.json", "flight/decoder_eval.json"), 55,
          "evaluate-decoder: CFM + Regression, and the flight-level decoder"),
    Stage("noise", stage_noise, ("decoders", "seq_decoder"), ("noise_sensitivity.json", "noise_sensitivity_low.json"),
          85, "decoding under IMU noise (mjxsysid experiment noise-sensitivity)"),
    Stage("tune_nominal", _tune_stage("tune_nominal"), ("decoders", "seq_decoder"),
          tuple(f"{r[0]}/results.json" for r in TUNE_RUNS["tune_nominal"]), 215,
          "experiment tune-nominal, --variant baseline_start, protect"),
    Stage("tune_slow", _tune_stage("tune_slow"), ("decoders", "seq_decoder"),
          tuple(f"{r[0]}/results.json" for r in TUNE_RUNS["tune_slow"]), 290,
          "experiment tune-slow, --variant heading_cost, baseline_start"),
    Stage("tune_slow_more", _tune_stage("tune_slow_more"), ("decoders", "seq_decoder"),
          tuple(f"{r[0]}/results.json" for r in TUNE_RUNS["tune_slow_more"]), 300,
          "experiment tune-slow --variant true_rotor_state, steady_rotor_state; --seed 7 (and baseline_start)"),
    Stage("tune_lemniscate", _tune_stage("tune_lemniscate"), ("decoders", "seq_decoder"),
          tuple(f"{r[0]}/results.json" for r in TUNE_RUNS["tune_lemniscate"]), 420,
          "experiment tune-lemniscate, --variant no_lead_in (and baseline_start)"),
    Stage("studies", stage_studies, ("decoders", "seq_decoder"),
          tuple(f"{r[0]}/results.json" for r in STUDY_RUNS), 260,
          "experiment robustness (and --variant single_latent), replay, payload"),
    Stage("fidelity", stage_fidelity, ("decoders", "seq_decoder"),
          ("closed_loop_fidelity.json", "closed_loop_fidelity_same_flight.json"), 130,
          "closed-loop fidelity, held-out and same-flight identification"),
    Stage("tables", stage_tables, ("policy_eval", "decoder_eval", "noise", "tune_nominal", "tune_slow",
                                   "tune_slow_more", "tune_lemniscate", "studies", "fidelity"),
          ("tree/docs/fair_comparisons.md", "tree/docs/noise.md"), 5,
          "lay out the shipped tree and regenerate docs/fair_comparisons.md and docs/noise.md's tables"),
    Stage("ship", stage_ship, (), ("shipped.json",), 5,
          "copy weights + provenance into mjxsysid/pretrained/, run files into docs/runs/release/<kind>/, the pages",
          after=("tables",)),
)
"""The stages of a release, in order (see the module doc)."""


def run_release(out, *, select=None, force=(), allow_partial: bool = False, options: Options | None = None,
                ship_to=None, stages=None, log=echo, **kw) -> Release:
    """Open (or start) the release in ``out`` and run the planned stages (:meth:`Release.run`);
    returns the :class:`Release`."""
    rel = Release(out, options, ship_to=ship_to, stages=stages, log=log, **kw)
    rel.run(select, force, allow_partial)
    return rel
