"""Decoder calibration under IMU noise (docs/noise.md): the shipped policy (or ``--policy``) flies
held-out vehicles of the decoders' prior with white noise, a per-flight bias and rotor vibration
on the IMU it reads, and its decoders (or ``--decoders``) decode the latents of each flight.

    python tools/noise_sensitivity.py --vehicles 150 --seconds 4 --samples 200 \\
        --out docs/runs/noise/noise_sensitivity.json --figure docs/noise_sensitivity.png

The measurement is :func:`mjxsysid.studies.noise.noise_sensitivity` (its module doc says what
it measures); this tool runs it, writes the JSON (with the command) and draws the figure. The
`noise` stage of `mjxsysid release` runs it on a release's policy and decoders.
"""
from __future__ import annotations

import argparse
import json
from pathlib import Path

from mjxsysid.studies.noise import DEFAULT_LEVELS, LABELS, LEVELS, figure, level, noise_sensitivity, table  # noqa: F401


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--vehicles", type=int, default=150)
    ap.add_argument("--seconds", type=float, default=4.0)
    ap.add_argument("--samples", type=int, default=200)
    ap.add_argument("--seed", type=int, default=4242, help="held-out vehicles (the pairs used seeds 0 and 1)")
    ap.add_argument("--levels", nargs="+", default=list(DEFAULT_LEVELS), choices=list(LEVELS))
    ap.add_argument("--policy", default="mjxsysid", help="policy name or policy.npz (default: the shipped one)")
    ap.add_argument("--decoders", type=Path, default=None,
                    help="folder with cfm.npz, regression.npz, cfm_seq.npz (default: the policy's shipped ones)")
    ap.add_argument("--out", type=Path, default=Path("docs/runs/noise/noise_sensitivity.json"))
    ap.add_argument("--figure", type=Path, default=None)
    ap.add_argument("--replot", type=Path, default=None,
                    help="only draw --figure and print the table from this result JSON")
    a = ap.parse_args(argv)
    if a.replot is not None:
        if a.figure is None:
            raise SystemExit("--replot needs --figure")
        res = json.loads(a.replot.read_text())
        print(f"wrote {figure(res, a.figure)}")
        print(table(res))
        return 0
    if a.vehicles < 10 or a.samples < 20:
        raise SystemExit("--vehicles must be >= 10 and --samples >= 20 for a coverage to mean anything")
    command = "python tools/noise_sensitivity.py " + " ".join(
        f"--{k} {' '.join(v) if isinstance(v, list) else v}" for k, v in vars(a).items()
        if v is not None and k != "replot")
    res = noise_sensitivity(policy=a.policy, decoders=a.decoders, vehicles=a.vehicles, seconds=a.seconds,
                            samples=a.samples, seed=a.seed, levels=a.levels, log=lambda m: print(m, flush=True))
    res = {"command": command, **res}
    a.out.parent.mkdir(parents=True, exist_ok=True)
    a.out.write_text(json.dumps(res, indent=1) + "\n")
    print(f"wrote {a.out} ({res['wall_s']} s)")
    print(table(res))
    if a.figure is not None:
        print(f"wrote {figure(res, a.figure)}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
