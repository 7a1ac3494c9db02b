"""What a new user meets first, cold and warm: each path's wall time, its compile share and the
programs that cost most (issue 41 §1).

    python benchmarks/first_contact.py --out docs/runs/measurements/benchmarks/first_contact.json
    python benchmarks/first_contact.py --paths decode-10s --runs cold       # one path, cold only

Each path runs as `mjxsysid profile --json F -- COMMAND ...` in a fresh process (JAX's in-memory
caches empty). Cold: JAX's persistent compilation cache points to a new empty folder; warm: the
same command again with the folder the cold run filled (what a user's second run finds). The logs
decoded are the shipped policy flying the paper vehicle on a 10 s lemniscate (MJX), written as a
CSV and tiled to 10 minutes (benchmarks/decode_long_log.py). Prints a markdown table for
BENCHMARKS.md.
"""
from __future__ import annotations

import argparse
import datetime
import json
import platform
import subprocess
import sys
import tempfile
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))

PATHS = {
    "demo": ["demo", "--out", "{tmp}/demo"],
    "decode-10s": ["decode", "--log", "{tmp}/log10.csv", "--out", "{tmp}/dec10"],
    "decode-10s-decoder-only": ["decode", "--log", "{tmp}/log10.csv", "--out", "{tmp}/dec10d", "--decoder-only"],
    "decode-10min": ["decode", "--log", "{tmp}/log600.csv", "--out", "{tmp}/dec600"],
    "fly": ["fly", "--controller", "policy", "--reference", "lemniscate", "--out", "{tmp}/fly"],
    "tune-quick": ["tune", "--quick", "--out", "{tmp}/tune"],
}
TARGETS = {"demo": (45, 20), "decode-10s": (15, 5), "decode-10min": (30, None)}
"""Issue 41's targets, seconds (cold, warm)."""


def run_path(name: str, tmp: Path, cache: Path) -> dict:
    import os
    import shutil
    args = [a.format(tmp=tmp) for a in PATHS[name]]
    out = Path(args[args.index("--out") + 1])
    shutil.rmtree(out, ignore_errors=True)
    js = tmp / f"{name}.json"
    env = dict(os.environ, MJXSYSID_JAX_CACHE=str(cache))
    cmd = [sys.executable, "-m", "mjxsysid.cli", "profile", "--top", "8", "--json", str(js), "--", *args, "-q"]
    r = subprocess.run(cmd, env=env, capture_output=True, text=True, check=False)
    if r.returncode != 0:
        raise SystemExit(f"{name}: exit {r.returncode}\n{r.stderr[-3000:]}")
    return json.loads(js.read_text())


def _measure(names: list, runs: list, tmp: Path) -> dict:
    """Each path's runs in fresh processes, its own persistent cache in ``tmp`` -> {path: {run: profile}}."""
    if any(n.startswith("decode") for n in names):
        import decode_long_log as D
        base = D.base_log()
        D.tiled_log(base, 10.0, tmp / "log10.csv")
        D.tiled_log(base, 600.0, tmp / "log600.csv")
    rows = {}
    for n in names:
        cache = tmp / f"cache_{n}"
        for run in runs:
            res = run_path(n, tmp, cache)
            rows.setdefault(n, {})[run] = res
            print(f"{n} {run}: {res['wall_s']:.1f} s (compiling {res['compile_s']:.1f} s, {res['programs']} programs)",
                  file=sys.stderr)
    return rows


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--paths", default=",".join(PATHS), help=f"comma-separated, of {', '.join(PATHS)}")
    p.add_argument("--runs", default="cold,warm", help="cold, warm or both (default)")
    p.add_argument("--out", type=Path, default=None, help="write the results as JSON")
    a = p.parse_args(argv)
    names = [n for n in a.paths.split(",") if n]
    unknown = [n for n in names if n not in PATHS]
    if unknown:
        p.error(f"unknown paths {unknown}; choose from {list(PATHS)}")
    runs = a.runs.split(",")
    if runs not in (["cold"], ["cold", "warm"]):
        p.error("--runs: cold or cold,warm (a warm run needs the cache its cold run fills first)")
    with tempfile.TemporaryDirectory(prefix="mjxsysid_first_contact_") as tmp:
        rows = _measure(names, runs, Path(tmp))
    lines = ["| path | cold wall (compiling, programs) | warm wall (compiling) | target cold / warm |", "|---|---|---|---|"]
    for n, r in rows.items():
        c, w = r.get("cold"), r.get("warm")
        tc, tw = TARGETS.get(n, (None, None))
        lines.append(f"| `{n}` | " + (f"{c['wall_s']:.1f} s ({c['compile_s']:.1f} s, {c['programs']})" if c else "–")
                     + " | " + (f"{w['wall_s']:.1f} s ({w['compile_s']:.1f} s)" if w else "–") + " | "
                     + (f"≤ {tc} s" if tc else "–") + " / " + (f"≤ {tw} s" if tw else "–") + " |")
    print("\n".join(lines))
    if a.out:
        a.out.parent.mkdir(parents=True, exist_ok=True)
        a.out.write_text(json.dumps({"date": datetime.date.today().isoformat(), "machine": platform.platform(),
                                     "cpus": __import__("os").cpu_count(), "paths": {n: PATHS[n] for n in names},
                                     "results": rows}, indent=1))
    return 0


if __name__ == "__main__":
    sys.exit(main())
