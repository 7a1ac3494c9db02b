"""Regenerate (or check) the generated docs pages of this checkout from its run files:
docs/fair_comparisons.md, docs/noise.md's noise tables, docs/results.md, README's results table and
docs/runs/README.md (:func:`mjxsysid.release.pages.generate`).

    python tools/fair_tables.py            # rewrite the pages
    python tools/fair_tables.py --check    # exit 1 if a page differs from what the runs give
"""
from __future__ import annotations

import argparse
import sys
from pathlib import Path

from mjxsysid.release.pages import check, generate

ROOT = Path(__file__).resolve().parents[1]


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--check", action="store_true", help="exit 1 if a generated page is stale")
    ap.add_argument("--root", type=Path, default=ROOT, help="the checkout (default: this one)")
    a = ap.parse_args(argv)
    try:
        if a.check:
            stale = check(a.root)
            for p in stale:
                print(f"{a.root / p} is stale: run python tools/fair_tables.py", file=sys.stderr)
            return 1 if stale else 0
        for p, text in generate(a.root).items():
            (a.root / p).write_text(text)
            print(f"wrote {a.root / p}")
    except FileNotFoundError as e:
        print(f"fair_tables: {e}", file=sys.stderr)
        return 1
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
