"""Where the test tier's compile time goes: JAX's compile events summed per test file and program.

    rm -rf /tmp/census && MJXSYSID_JAX_CACHE=$(mktemp -d) MJXSYSID_CENSUS_DIR=/tmp/census \\
        PYTHONPATH=benchmarks .venv/bin/python -m pytest -q -p tier_compile_census
    python benchmarks/tier_compile_census.py /tmp/census          # the tables

As a pytest plugin (``-p tier_compile_census``, loaded in every xdist worker) it listens to JAX's
trace / lower / backend-compile duration events (:mod:`mjxsysid.runtime.profiling`'s events) and writes,
per worker, [test file, program, kind, seconds] rows to ``$MJXSYSID_CENSUS_DIR`` (``MJXSYSID_CENSUS_BY=test``:
per test). Programs
compiled in subprocesses the tests start (CLI runs, notebook kernels) are not counted. Run as a
script on that folder, it prints the totals per kind, per test file and per program (with the
number of files that built it).
"""
from __future__ import annotations

import collections
import json
import os
import sys
from pathlib import Path

from mjxsysid.runtime.profiling import EVENTS, program_name

_rows: dict = collections.defaultdict(float)
_current = ["(collection)"]


def _on_duration(event, duration, **kw):
    kind = EVENTS.get(event)
    if kind is not None:
        _rows[(_current[0], program_name(kw), kind)] += duration


def pytest_configure(config):
    if os.environ.get("MJXSYSID_CENSUS_DIR"):
        import jax.monitoring
        jax.monitoring.register_event_duration_secs_listener(_on_duration)


def pytest_runtest_logstart(nodeid, location):
    # MJXSYSID_CENSUS_BY=test: per test instead of per file
    _current[0] = nodeid if os.environ.get("MJXSYSID_CENSUS_BY") == "test" else nodeid.split("::")[0]


def _write(config):
    where = os.environ.get("MJXSYSID_CENSUS_DIR")
    if not where:
        return
    Path(where).mkdir(parents=True, exist_ok=True)
    name = f"{os.environ.get('PYTEST_XDIST_WORKER', 'main')}_{os.getpid()}.json"
    (Path(where) / name).write_text(json.dumps([[f, p, k, v] for (f, p, k), v in _rows.items()]))


try:        # tryfirst: before tests/support/worker_exit.py's worker exit
    import pytest
    pytest_unconfigure = pytest.hookimpl(tryfirst=True)(_write)
except ImportError:      # run as a script without pytest
    pass


def report(folder: Path, top: int = 30) -> str:
    rows = [r for f in sorted(folder.glob("*.json")) for r in json.loads(f.read_text())]
    if not rows:
        raise SystemExit(f"no census files in {folder}")
    per_kind, per_file, per_prog = (collections.defaultdict(float) for _ in range(3))
    files = collections.defaultdict(set)
    for f, p, k, v in rows:
        per_kind[k] += v
        per_file[f] += v
        per_prog[p] += v
        files[p].add(f)
    out = [f"compiling, in-process, all workers: {sum(per_kind.values()):.1f} s ("
           + ", ".join(f"{k} {v:.1f} s" for k, v in sorted(per_kind.items())) + ")", "", "per test file:"]
    out += [f"{v:8.1f}  {f}" for f, v in sorted(per_file.items(), key=lambda x: -x[1])[:top]]
    out += ["", "per program (seconds, files that built it):"]
    out += [f"{v:8.1f}  {p[:60]:60s} {len(files[p])}" for p, v in sorted(per_prog.items(), key=lambda x: -x[1])[:top]]
    return "\n".join(out)


if __name__ == "__main__":
    if len(sys.argv) != 2:
        raise SystemExit(__doc__)
    print(report(Path(sys.argv[1])))
