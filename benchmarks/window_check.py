"""The window-length check's and the motor-map check's thresholds (:mod:`mjxsysid.identify.windowcheck`,
:mod:`mjxsysid.identify.idlecheck`) from simulated flights.

Flies vehicles of the prior with the lag-aware oracle (MJX) on each flight of ``--references`` at each
IMU noise level of ``--levels``, finds each log's posterior mode (the library's, no decoded proposal),
re-fits it with the rate windows 2× and 4× as long, and keeps the statistic. The threshold is its
``--quantile`` quantile over the logs; ``--held-out SEED`` flies other vehicles (another seed) and counts
how many the threshold flags; ``--logs`` gives the statistic of real logs.

    python benchmarks/window_check.py --vehicles 6 --out docs/runs/measurements/log-grounded/window-check
    python benchmarks/window_check.py --vehicles 6 --out ... --write-threshold    # into the shipped table
    python benchmarks/window_check.py --from DIR/simulated.json.gz --logs ../shared/data/logs/crazyflie/*.bin
    python benchmarks/window_check.py --shipped     # both checks' flags under the shipped thresholds, no flight

Writes OUT/simulated.json.gz (one row per log: vehicle, flight, level, the statistic and its shifts),
OUT/held_out.json.gz, OUT/motor_idle.json.gz, OUT/rotorpy.json and OUT/logs.json, and prints the threshold
and the false-alarm rates.
"""
from __future__ import annotations

import argparse
import json
import time
from pathlib import Path

import numpy as np

LEVELS = "clean,x1,x5_white,x5_vibration,x20"
REFERENCES = "lemniscate:10,lemniscate:20,minsnap:10,hover:8"


LEAN = ("idle_shift", "idle_span", "idle_origin")
"""The motor-map check's features the rows leave out: the threshold reads the statistic, not the shifts."""


def statistics_of(datas, seed: int = 0) -> list[dict]:
    """The window check of each log (:class:`~mjxsysid.identify.logdata.LogData`) from its mode, as the
    posterior computes it (:func:`~mjxsysid.identify.windowcheck.run`)."""
    from mjxsysid.identify.coords import PHYSICAL_PRIOR
    from mjxsysid.identify.batched import _Logs
    from mjxsysid.identify.inference import _starts
    from mjxsysid.identify.mode import find_modes
    from mjxsysid.identify.posterior_config import DEFAULT
    from mjxsysid.identify import idlecheck
    from mjxsysid.identify.windowcheck import run
    out = []
    for i, d in enumerate(datas):
        st = _starts(d, None, np.random.default_rng(seed + i), PHYSICAL_PRIOR, DEFAULT.starts)
        t0 = time.perf_counter()
        modes = find_modes(_Logs([d]), st[None].astype(np.float32), PHYSICAL_PRIOR)
        t1 = time.perf_counter()
        res = run(_Logs, [d], modes, PHYSICAL_PRIOR)[0]
        t2 = time.perf_counter()
        idle = {k: v for k, v in idlecheck.features(idlecheck.run(_Logs, [d], modes)[0]).items() if k not in LEAN}
        out.append(res | idle | {"rates_nsr": _rates_nsr(d, modes[0][0]), "mode_s": round(t1 - t0, 2),
                                 "check_s": round(t2 - t1, 2), "idle_s": round(time.perf_counter() - t2, 2)})
    return out


def _rates_nsr(data, mode) -> float:
    from mjxsysid.identify.calibrate import log_features
    return log_features(data, mode)["rates_nsr"]


def simulate(vehicles: int, seed: int, levels, references, log=print, save=None, motor_idle: float = 0.0) -> list[dict]:
    """Rows of simulated logs: {vehicle, flight, level, shift, coord, factor, shifts, ...}; ``save``: called
    with the rows so far after each flight and level; ``motor_idle``: the simulator's idle offset
    (``SimConfig.motor_idle``: a motor map the likelihood lacks)."""
    import jax
    from mjxsysid import theta as P
    from mjxsysid.experiments.posterior_calibration import parse_reference
    from mjxsysid.identify.logdata import LogTooShort, prepare
    from mjxsysid.rollout.flight import flight_log, fly_vehicles
    from mjxsysid.sim import Quadrotor, SimConfig
    from mjxsysid.uses.imu_noise import LEVELS as NOISE
    th = np.asarray(P.get_prior("wide_actuators").sample(jax.random.PRNGKey(seed), vehicles))
    rows = []
    for ref in references:
        for lv in levels:
            sim = Quadrotor(SimConfig(**NOISE[lv], motor_idle=motor_idle))
            t0 = time.perf_counter()
            fl, m, _ = fly_vehicles(th, controller="oracle", sim=sim, seed=seed + 97 * list(NOISE).index(lv),
                                    **parse_reference(ref))
            fly_s = time.perf_counter() - t0
            datas, idx = [], []
            for i in np.flatnonzero(~np.asarray(m["failed"], bool)):
                try:
                    datas.append(prepare(flight_log(fl.frame, i)))
                    idx.append(int(i))
                except LogTooShort:
                    continue
            for i, r in zip(idx, statistics_of(datas, seed)):
                rows.append({"vehicle": i, "flight": ref, "level": lv} | r)
            shifts = [r["shift"] for r in rows[-len(idx):] if r["shift"] is not None] if idx else []
            mode_s = sum(r["mode_s"] for r in rows[-len(idx):]) if idx else 0.0
            check_s = sum(r["check_s"] for r in rows[-len(idx):]) if idx else 0.0
            log(f"{ref} {lv}: {len(idx)} logs (flown in {fly_s:.0f} s, modes {mode_s:.0f} s, checks {check_s:.0f} s), "
                f"shift max {max(shifts, default=0.0):.2f}", flush=True)
            if save is not None:
                save(rows)
    return rows


def rotorpy_rows(levels, seed: int = 0, log=print) -> list[dict]:
    """The check on RotorPy flights (another simulator, aerodynamics on: :mod:`mjxsysid.experiments.rotorpy_noise`'s
    vehicles and noise, the shipped policy flying a 10 s lemniscate) -> rows."""
    from mjxsysid.experiments import rotorpy_noise as R
    from mjxsysid.identify.logdata import prepare
    R.import_rotorpy()
    ctrl = R.PolicyController.load()
    rng = np.random.default_rng(seed)
    steps = int(round(R.FULL["seconds"] / R.LOG_DT))
    white, bias, vib = rng.standard_normal((steps, 6)), rng.standard_normal(6), rng.standard_normal((steps, 6))
    rows = []
    for vn, make in R.VEHICLES.items():
        for lv in levels:
            rec = R.fly(make(), R.FULL["seconds"], R.NOISE_LEVELS[lv], white, bias, ctrl, vib)
            r = statistics_of([prepare({"imu": rec["imu"], "motor": rec["motor"]})])[0]
            rows.append({"vehicle": vn, "flight": "rotorpy lemniscate:10", "level": lv} | r)
            log(f"rotorpy {vn} {lv}: shift {r['shift']:.2f} ({r['coord']}, {r['factor']}×)", flush=True)
    return rows


def _compact(obj) -> str:
    """``obj`` as compact JSON, floats to 4 significant digits (the rows are provenance, not precision)."""
    def r(x):
        return float(f"{x:.4g}") if isinstance(x, float) else {k: r(v) for k, v in x.items()} if isinstance(x, dict) \
            else [r(v) for v in x] if isinstance(x, list) else x
    return json.dumps(r(obj), separators=(",", ":")) + "\n"


def write_rows(out: Path, name: str, obj) -> Path:
    """``obj`` compact (:func:`_compact`) and gzipped at ``out``/<name>.json.gz (a plain <name>.json there removed)."""
    import gzip
    (out / f"{name}.json").unlink(missing_ok=True)
    path = out / f"{name}.json.gz"
    path.write_bytes(gzip.compress(_compact(obj).encode(), 9, mtime=0))
    return path


def read_rows_file(out: Path, name: str) -> dict | None:
    """``out``/<name>.json.gz (or a plain <name>.json), or None where neither is."""
    from mjxsysid.experiments.posterior_calibration import read_json
    for path in (out / f"{name}.json.gz", out / f"{name}.json"):
        if path.is_file():
            return read_json(path)
    return None


def threshold_of(rows, quantile: float) -> float:
    """The ``quantile`` quantile of the rows' statistic (the rows the check ran on)."""
    from mjxsysid.identify.windowcheck import threshold
    return threshold([r["shift"] for r in rows], quantile)


def flagged(rows, thr: float) -> tuple[int, int]:
    """(logs above the threshold, logs the check ran on)."""
    s = [r["shift"] for r in rows if r["shift"] is not None]
    return sum(x > thr for x in s), len(s)


HELD_OUT_ROWS = Path("docs/runs/measurements/log-grounded/nuts-calibration/rows/held_out")
"""The calibration's held-out rows: those collected with the window check carry its statistic."""


def shipped_flags(out: Path) -> None:
    """Both checks' flags under the shipped table's thresholds, from the files a run wrote into ``out``
    (simulated, held_out, motor_idle, rotorpy, logs) and the calibration's held-out rows: per set, per flight."""
    from mjxsysid.experiments.posterior_calibration import read_rows
    from mjxsysid.identify import idlecheck as I
    from mjxsysid.identify import windowcheck as W
    from mjxsysid.identify.calibrate import load
    table = load()
    t_w, t_i = table[W.KEY]["threshold"], table[I.KEY]["threshold"]
    print(f"shipped thresholds: window check {t_w:g}, motor-map check {t_i:g}")

    def show(name, rows):
        for fl in sorted({r.get("flight", "?") for r in rows}):
            rs = [r for r in rows if r.get("flight", "?") == fl]
            w = [r["shift"] for r in rs if r.get("shift") is not None]
            g = [r["idle_gain"] for r in rs if r.get("idle_gain") is not None]
            print(f"  {name} {fl}: window {sum(x > t_w for x in w)} of {len(w)}; motor map {sum(x > t_i for x in g)} "
                  f"of {len(g)} (largest {max(g, default=0.0):.1f})")
    for name in ("simulated", "held_out", "motor_idle", "rotorpy"):
        if (d := read_rows_file(out, name)) is not None:
            show(name, d["rows"])
    if (out / "logs.json").is_file():
        for p, r in json.loads((out / "logs.json").read_text())["logs"].items():
            print(f"  {Path(p).name}: window {r.get('shift')}, motor map {r.get('idle_gain')}")
    cal = read_rows([HELD_OUT_ROWS])
    w = [(r["features"]["window_shift"], r["level"]) for r in cal if r["features"].get("window_shift") is not None]
    print(f"  calibration's held-out rows: window {sum(x > t_w for x, _ in w)} of {len(w)} "
          f"({sorted({lv for x, lv in w if x > t_w})})")


def main():
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--vehicles", type=int, default=6)
    ap.add_argument("--seed", type=int, default=5)
    ap.add_argument("--levels", default=LEVELS)
    ap.add_argument("--references", default=REFERENCES)
    ap.add_argument("--quantile", type=float, default=None, help="default: windowcheck.QUANTILE")
    ap.add_argument("--held-out", type=int, default=None, metavar="SEED", help="fly --held-out-vehicles more at this seed")
    ap.add_argument("--held-out-vehicles", type=int, default=2)
    ap.add_argument("--from", dest="from_", default=None, help="read the simulated rows from this simulated.json.gz")
    ap.add_argument("--logs", nargs="*", default=[], help="real logs to check against the threshold")
    ap.add_argument("--rotorpy", action="store_true", help="check RotorPy flights too (rotorpy 3.0.0 installed)")
    ap.add_argument("--motor-idle", type=float, default=None, metavar="SHARE",
                    help="check --held-out-vehicles more flown with this idle offset in the motor map (a misfit): "
                         "OUT/motor_idle.json")
    ap.add_argument("--misfit-seed", type=int, default=78, help="--motor-idle's vehicles' seed")
    ap.add_argument("--out", default="docs/runs/measurements/log-grounded/window-check")
    ap.add_argument("--shipped", action="store_true",
                    help="fly nothing: both checks' flags under the shipped thresholds from the files in --out")
    ap.add_argument("--write-threshold", action="store_true",
                    help="write the threshold into the shipped calibration table (mjxsysid/pretrained/posterior_calibration.json)")
    a = ap.parse_args()
    if a.shipped:
        return shipped_flags(Path(a.out))
    from mjxsysid.identify import windowcheck as W
    q = W.QUANTILE if a.quantile is None else a.quantile
    out = Path(a.out)
    out.mkdir(parents=True, exist_ok=True)
    levels, refs = a.levels.split(","), a.references.split(",")
    cmd = ("python benchmarks/window_check.py " + f"--vehicles {a.vehicles} --seed {a.seed} --levels {a.levels} "
           f"--references {a.references}" + (f" --quantile {a.quantile}" if a.quantile is not None else ""))
    if a.from_:
        from mjxsysid.experiments.posterior_calibration import read_json
        sim = read_json(a.from_)
    else:
        t0 = time.perf_counter()
        sim = {"command": cmd, "rows": []}

        def save(rows):
            write_rows(out, "simulated", sim | {"rows": rows})
        sim["rows"] = simulate(a.vehicles, a.seed, levels, refs, save=save)
        sim["wall_s"] = round(time.perf_counter() - t0, 1)
        write_rows(out, "simulated", sim)
    rows = sim["rows"]
    thr = threshold_of(rows, q)
    k, n = n_above, n_sim = flagged(rows, thr)
    print(f"threshold {thr:.3f}: the {q:g} quantile of {n} simulated logs ({k} above it)")
    for lv in levels:
        kl, nl = flagged([r for r in rows if r["level"] == lv], thr)
        print(f"  {lv}: {kl} of {nl} above")
    if a.held_out is not None:
        ho = simulate(a.held_out_vehicles, a.held_out, levels, refs)
        write_rows(out, "held_out", {"seed": a.held_out, "rows": ho})
        k, n = flagged(ho, thr)
        print(f"held out (seed {a.held_out}): {k} of {n} logs above the threshold")
    if a.motor_idle is not None:
        mi = simulate(a.held_out_vehicles, a.misfit_seed, levels, refs, motor_idle=a.motor_idle)
        write_rows(out, "motor_idle", {"motor_idle": a.motor_idle, "seed": a.misfit_seed, "rows": mi})
        k, n = flagged(mi, thr)
        print(f"motor idle {a.motor_idle:g}: {k} of {n} logs above the threshold")
    if a.rotorpy:
        ro = rotorpy_rows(levels)
        (out / "rotorpy.json").write_text(json.dumps({"rows": ro}, indent=1) + "\n")
        k, n = flagged(ro, thr)
        print(f"RotorPy: {k} of {n} logs above the threshold")
    if a.logs:
        from mjxsysid.identify.logdata import prepare
        from mjxsysid.logs.csvlog import read_any_log
        res = {}
        for p in a.logs:
            try:
                r = statistics_of([prepare(read_any_log(p))])[0]
            except Exception as e:      # a real log the posterior refuses: said, not fatal
                r = {"shift": None, "why": f"{type(e).__name__}: {e}"}
            res[p] = r
            s = r["shift"]
            print(f"{p}: " + (r["why"] if s is None else f"shift {s:.2f} ({r['coord']}, {r['factor']}× windows) "
                              + ("FLAGGED" if s > thr else "passes")), flush=True)
        (out / "logs.json").write_text(json.dumps({"threshold": thr, "logs": res}, indent=1) + "\n")
    if a.write_threshold:
        from mjxsysid.identify import idlecheck as I
        from mjxsysid.identify.calibrate import SHIPPED
        table = json.loads(SHIPPED.read_text())
        table[W.KEY] = {"threshold": round(thr, 4), "quantile": q, "logs": n_sim, "above": n_above,
                        "levels": levels, "references": refs, "command": cmd + " --write-threshold",
                        "rows": str(out / "simulated.json.gz"), "date": time.strftime("%Y-%m-%d")}
        idle = I.threshold_entry([{"level": r["level"], "features": {k: r.get(k) for k in ("idle_gain", "idle_maps")}}
                                  for r in rows])
        if idle is not None:
            table[I.KEY] = idle | {"references": refs, "command": cmd + " --write-threshold",
                                   "rows": str(out / "simulated.json.gz"), "date": time.strftime("%Y-%m-%d")}
        SHIPPED.write_text(json.dumps(table, indent=1) + "\n")
        print(f"wrote {W.KEY}" + (f" and {I.KEY}" if idle is not None else "") + f" into {SHIPPED}")


if __name__ == "__main__":
    main()
