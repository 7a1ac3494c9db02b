"""The record of a release: ``DIR/release.json``, shared by the processes that run its stages.

The record holds ``stages`` (per stage: status, run number, times, commit, device, the calls it
made with their config, its figures), ``runs`` (the count of stage runs, the clock that tells a
stale stage), and the header the release writes (``release``, ``options``, ``order``,
``created``). Processes running other stages of one release at once (one per GPU) read, merge
and write it in turn under an advisory lock.
"""
from __future__ import annotations

import contextlib
import datetime
import json
import os
from pathlib import Path

from mjxsysid.runtime import jsonout

RECORD = "release.json"


def now() -> str:
    """The current UTC time, ISO 8601 to the second."""
    return datetime.datetime.now(datetime.UTC).isoformat(timespec="seconds")


def load(out: Path) -> dict:
    """The record in ``out`` (``{"stages": {}}`` where none is); a file that is not a record is a
    ValueError naming it."""
    path = Path(out) / RECORD
    if not path.exists():
        return {"stages": {}}
    try:
        rec = json.loads(path.read_text())
    except (json.JSONDecodeError, UnicodeDecodeError) as e:
        raise ValueError(f"{path}: not valid JSON ({e})") from None
    if not isinstance(rec, dict) or not isinstance(rec.get("stages", {}), dict):
        raise ValueError(f"{path}: not a release record (expected an object with 'stages')")  # noqa: TRY004  (a bad file, not a bad argument)
    rec.setdefault("stages", {})
    return rec


class Record:
    """The record of the release in ``out``: ``data`` (the dict of release.json) and the stage
    entries this process wrote (the only ones its saves put over the file on disk)."""

    def __init__(self, out):
        self.out = Path(out)
        self.data = load(self.out)
        self._mine: set[str] = set()

    @property
    def stages(self) -> dict:
        """Per stage name, its entry."""
        return self.data["stages"]

    def entry(self, name: str) -> dict:
        return self.stages.get(name, {})

    @contextlib.contextmanager
    def _locked(self):
        """The record's lock (``DIR/release.json.lock``, an advisory ``flock``)."""
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
        disk = load(self.out)
        for name in self._mine:
            disk["stages"][name] = self.stages[name]
        disk["runs"] = max(int(disk.get("runs", 0)), int(self.data.get("runs", 0)))
        self.data = disk

    def _write(self, header: dict) -> None:
        self.data.update(header)
        self.data.setdefault("created", now())
        tmp = self.out / f"{RECORD}.{os.getpid()}.tmp"
        tmp.write_text(jsonout.dumps(self.data, indent=2, ensure_ascii=False) + "\n")
        os.replace(tmp, self.out / RECORD)

    def save(self, header: dict) -> None:
        """Write the record with ``header``'s keys: the one on disk with this process's stage
        entries merged in (so several processes can run different stages of one release at once)."""
        with self._locked():
            self._merge()
            self._write(header)

    def begin(self, name: str, entry: dict, header: dict) -> None:
        """Record ``name`` as started with the next run number (atomic across processes);
        ``entry`` is kept and updated in place by the caller, then saved again."""
        with self._locked():
            self._merge()
            self.data["runs"] = int(self.data.get("runs", 0)) + 1
            entry["run"] = self.data["runs"]
            self.stages[name] = entry
            self._mine.add(name)
            self._write(header)
