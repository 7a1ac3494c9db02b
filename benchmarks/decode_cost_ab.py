"""`decode --log` of a 10 s log at two commits, cold and warm, alternated in one run on one machine (issue 54's
cost target: "no slower than today on 2 cores, cold and warm").

    python benchmarks/decode_cost_ab.py --revs db68964,HEAD --repeats 3 --out docs/runs/measurements/benchmarks/decode_cost_ab.json

Each commit is checked out as a git worktree (a temporary folder) and imported from there: a ``sitecustomize``
drops this checkout's editable-install finder, so ``import mjxsysid`` finds the worktree's package. The log is the
shipped policy's 10 s lemniscate on the paper vehicle, written once by this checkout
(``decode_long_log.base_log``). Each repeat runs every commit cold (an empty JAX compilation cache) then warm (the
cache the cold run filled), each as ``mjxsysid profile --json F -- decode --log LOG --out D -q`` in a fresh process;
the commits' order flips from one repeat to the next, so a machine whose load drifts favours neither.
"""
from __future__ import annotations

import argparse
import datetime
import json
import os
import platform
import statistics
import subprocess
import sys
import tempfile
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))
ROOT = Path(__file__).resolve().parents[1]
SHIM = "import sys\nsys.meta_path[:] = [f for f in sys.meta_path if 'editable' not in repr(f)]\n"


def worktree(rev: str, where: Path) -> tuple[str, Path]:
    """``rev`` checked out (detached) at ``where`` -> (its short hash, the folder)."""
    sha = subprocess.run(["git", "-C", str(ROOT), "rev-parse", "--short", rev], capture_output=True, text=True,
                         check=True).stdout.strip()
    subprocess.run(["git", "-C", str(ROOT), "worktree", "add", "--detach", "-f", str(where), sha],
                   capture_output=True, text=True, check=True)
    return sha, where


def decode_once(tree: Path, shim: Path, log: Path, out: Path, cache: Path) -> dict:
    """One `decode --log` in a fresh process importing ``tree``'s package -> its profile (wall_s, compile_s, …)."""
    js = out.with_suffix(".json")
    env = dict(os.environ, PYTHONPATH=f"{tree}{os.pathsep}{shim}", MJXSYSID_JAX_CACHE=str(cache))
    cmd = [sys.executable, "-m", "mjxsysid.cli", "profile", "--top", "4", "--json", str(js), "--",
           "decode", "--log", str(log), "--out", str(out), "-q"]
    r = subprocess.run(cmd, env=env, cwd=tree, capture_output=True, text=True, check=False)
    if r.returncode != 0:
        raise SystemExit(f"decode at {tree}: exit {r.returncode}\n{r.stderr[-3000:]}")
    return json.loads(js.read_text())


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--revs", default="db68964,HEAD", help="two git revisions, comma-separated (default: issue 54's "
                   "base db68964 and HEAD)")
    p.add_argument("--repeats", type=int, default=3, help="cold + warm runs of each commit (default 3)")
    p.add_argument("--out", type=Path, default=None, help="write the results as JSON")
    a = p.parse_args(argv)
    revs = [r for r in a.revs.split(",") if r]
    if len(revs) != 2 or a.repeats < 1:
        p.error("--revs needs two revisions and --repeats ≥ 1")
    import decode_long_log as D
    results: dict = {}
    with tempfile.TemporaryDirectory(prefix="mjxsysid_decode_ab_") as tmp:
        tmp = Path(tmp)
        shim = tmp / "shim"
        shim.mkdir()
        (shim / "sitecustomize.py").write_text(SHIM)
        trees = [worktree(r, tmp / f"tree{i}") for i, r in enumerate(revs)]
        log = tmp / "log10.csv"
        D.tiled_log(D.base_log(), 10.0, log)
        try:
            for k in range(a.repeats):
                for sha, tree in (trees if k % 2 == 0 else trees[::-1]):
                    cache = tmp / f"cache_{sha}_{k}"
                    for run in ("cold", "warm"):
                        res = decode_once(tree, shim, log, tmp / f"dec_{sha}_{k}_{run}", cache)
                        results.setdefault(sha, {}).setdefault(run, []).append(res)
                        print(f"{sha} {run} #{k}: {res['wall_s']:.1f} s (compiling {res['compile_s']:.1f} s)",
                              file=sys.stderr, flush=True)
        finally:
            for _, tree in trees:
                subprocess.run(["git", "-C", str(ROOT), "worktree", "remove", "--force", str(tree)],
                               capture_output=True, check=False)
    (s0, _), (s1, _) = trees
    lines = ["| commit | cold: median (runs) | warm: median (runs) |", "|---|---|---|"]
    med = {}
    for sha in (s0, s1):
        med[sha] = {run: statistics.median(r["wall_s"] for r in results[sha][run]) for run in ("cold", "warm")}
        lines.append(f"| `{sha}` ({revs[[s0, s1].index(sha)]}) | " + " | ".join(
            f"{med[sha][run]:.1f} s (" + ", ".join(f"{r['wall_s']:.1f}" for r in results[sha][run]) + ")"
            for run in ("cold", "warm")) + " |")
    lines.append(f"| ratio {s1} / {s0} | {med[s1]['cold'] / med[s0]['cold']:.2f} | "
                 f"{med[s1]['warm'] / med[s0]['warm']:.2f} |")
    print("\n".join(lines))
    if a.out:
        a.out.parent.mkdir(parents=True, exist_ok=True)
        a.out.write_text(json.dumps({"date": datetime.date.today().isoformat(), "machine": platform.platform(),
                                     "cpus": os.cpu_count(), "revs": dict(zip((s0, s1), revs)),
                                     "results": results, "median_s": med}, indent=1) + "\n")
    return 0


if __name__ == "__main__":
    sys.exit(main())
