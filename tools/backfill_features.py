"""Add features the committed calibration rows predate, by flying their logs again: each row file's flights are
seeded (:func:`mjxsysid.experiments.posterior_calibration.flights`), so the logs are the ones its rows came from.
Each log is reduced as ``decode --log`` reduces it and the named features are written into its row (4 decimals,
xz, as ``tools/calibration_pieces.py --land`` writes them). A row whose log is not flown again (a failed flight)
keeps what it had.

    python tools/backfill_features.py acc_noise ROWS.json.xz [...]

Features: ``acc_noise`` (:func:`mjxsysid.identify.calibrate.acc_noise`), ``drag_signal``
(:func:`mjxsysid.identify.calibrate.drag_signal`), ``vibration``
(:func:`mjxsysid.identify.logdata.vibrating`). About 8 logs a second per process, two processes on 2 CPU cores.
"""
from __future__ import annotations

import json
import lzma
import sys
import time
from pathlib import Path


def features_of(rec: dict, names: list[str]) -> dict:
    """The named features of one log record."""
    from mjxsysid.identify.calibrate import acc_noise, drag_signal
    from mjxsysid.identify.logdata import prepare, vibrating
    data = prepare(rec)
    known = {"acc_noise": lambda: round(acc_noise(data), 4), "vibration": lambda: vibrating(data),
             "drag_signal": lambda: None if (d := drag_signal(data)) is None else round(d, 4)}
    bad = [n for n in names if n not in known]
    if bad:
        raise ValueError(f"unknown features {bad}; known: {sorted(known)}")
    return {n: known[n]() for n in names}


def backfill(path: Path, names: list[str]) -> int:
    """Write the named features into the rows of ``path`` (an xz row file) -> how many rows got them."""
    from mjxsysid.experiments.posterior_calibration import RESUME_KEYS, flights, read_json
    d = read_json(path)
    missing = [k for k in ("prior", "vehicles", "seed", "references", "levels") if k not in d]
    if missing:
        raise ValueError(f"{path}: no collection settings ({', '.join(missing)}): its logs cannot be flown again")
    by_key = {(r["vehicle"], r["level"], r["flight"]): r for r in d["rows"]}
    done = 0
    for rec, vehicle, _, lv, flight in flights({k: d[k] for k in RESUME_KEYS if k in d}):
        r = by_key.get((vehicle, lv, flight))
        if r is not None:
            r["features"].update(features_of(rec, names))
            done += 1
    path.write_bytes(lzma.compress((json.dumps(d, separators=(",", ":")) + "\n").encode(), preset=9 | lzma.PRESET_EXTREME))
    return done


def main(argv: list[str]) -> None:
    names, files = argv[0].split(","), [Path(p) for p in argv[1:]]
    t0 = time.perf_counter()
    for f in files:
        n = backfill(f, names)
        print(f"{f}: {n} rows ({time.perf_counter() - t0:.0f} s)", flush=True)


if __name__ == "__main__":
    main(sys.argv[1:])
