"""The log-grounded posterior calibrated by simulation: collect, fit, evaluate (:mod:`mjxsysid.identify.calibrate`).

- ``collect``: fly vehicles of a prior with the lag-aware oracle (MJX, 10 s lemniscate) at IMU noise
  levels (:data:`mjxsysid.uses.imu_noise.LEVELS`), run the *raw* log-grounded posterior on each
  flight's IMU and motor commands (no decoded proposal), and keep one row per log: the truth and
  raw 5/50/95 % bands in the visible coordinates v, the features, the residual discounts. Sharded (``shard``
  'i/k': every k-th vehicle from the i-th); several flights (lemniscates, min-snap, hover: strong to no excitation).
- ``fit``: rows -> the calibration table (:func:`~mjxsysid.identify.calibration_fit.fit`) with provenance.
- ``evaluate``: a table applied to rows it never saw -> coverage and median width per coordinate and level, the
  oracle width (the 90 % quantile of the median's error), the share of logs holding fewer than half of their
  truths, a coverage-against-width figure and SBC-style rank histograms.
"""
from __future__ import annotations

import json
import platform
import time
from pathlib import Path

import numpy as np

from mjxsysid.identify.calibrate import BINS, COORD_FEATURE, FEATURE_NAMES, log_features, raw_bands
from mjxsysid.identify.calibration_fit import fit
from mjxsysid.experiments.common import git_commit
from mjxsysid.identify.coords import V_NAMES, visible_from_theta
from mjxsysid.runtime.progress import progress

TRAIN_LEVELS = ("clean", "x1", "x5_white", "x5_vibration", "x20")
HELDOUT_LEVELS = ("x2", "x10")
SHORT = ("T/W", "ρ1", "ρ2", "ρ3", "τ_m", "A_x", "A_y", "A_z", "yaw", "c_x", "c_y", "c_z")


def _shard(n: int, spec: str | None) -> np.ndarray:
    if spec is None:
        return np.arange(n)
    i, k = (int(x) for x in spec.split("/"))
    if not 0 <= i < k:
        raise ValueError(f"--shard {spec}: expected i/k with 0 <= i < k")
    return np.arange(i, n, k)


REFERENCES = ("lemniscate:10",)
REFERENCES_ALL = ("lemniscate:10", "lemniscate:20", "minsnap:10", "hover:8")
"""The flights of a calibration: 'lemniscate:PERIOD', 'minsnap:SECONDS' or 'hover:SECONDS' (the oracle
flies each; a slower lemniscate and hover excite the rates less)."""

BATCH = 256
"""Logs identified together on an accelerator, the rows written after each batch. A larger batch costs less
a log (:data:`~mjxsysid.identify.inference.LOG_BATCH`), but a run cut by its budget or the device loses more,
and the committed rows were collected in batches of this size."""


def parse_reference(spec: str) -> dict:
    """'lemniscate:10' -> fly_vehicles' reference, period and duration."""
    name, _, arg = spec.partition(":")
    x = float(arg) if arg else 10.0
    if name == "lemniscate":
        return {"reference": "lemniscate", "period": x}
    if name in ("minsnap", "hover"):
        return {"reference": name, "duration": x}
    raise ValueError(f"unknown calibration flight {spec!r}: 'lemniscate:PERIOD', 'minsnap:SECONDS' or 'hover:SECONDS'")


def collect(*, prior: str = "wide_actuators", vehicles: int = 64, levels=TRAIN_LEVELS, seed: int = 5,
            shard: str | None = None, out: Path, time_budget_s: float | None = None,
            references=REFERENCES, controller: str = "oracle", aero: bool = False, velocity: bool = True,
            policy=None, motor_idle: float = 0.0, motor_kappa: float = 1.0, paths: int = 1, resume: bool = False) -> dict:
    """Fly every level, then identify; ``prior``: a prior or held-out family, or a list of them flown alike and
    identified together (each row then names its ``prior``); write ``out`` (JSON: rows) after every log, or every batch of logs
    identified together on an accelerator (the levels interleaved: a stopped run keeps a balanced set of
    what it finished); ``time_budget_s``: start no new batch after this long (the result then says
    ``cut_by_budget``); ``references``: the flights
    (:func:`parse_reference`), each at every level; ``controller``: who flies ('oracle', the lag-aware
    oracle, or 'policy', the shipped adaptive policy: another closed loop's reaction to the noise);
    ``aero``: the simulator's rotor aerodynamics on (``SimConfig.aero``: physics the likelihood lacks);
    ``velocity``: False drops the logs' body velocity (a log without a state estimate); ``policy``: the
    weights controller 'policy' flies (a path; None: the shipped policy); ``motor_idle``, ``motor_kappa``: the
    simulator's static motor map (``SimConfig.motor_idle``, ``motor_kappa``: an idle offset and a curvature the
    likelihood lacks; 0 and 1: the map θ describes); ``paths``: path draws per flight and level (:func:`flights`);
    ``resume``: keep the rows of the file already at ``out`` (a
    run the budget or the machine cut, the same settings: ValueError naming those that differ) and identify only
    the logs it lacks (the flights are seeded, so a resumed file holds the logs one run would). The result's
    ``skipped`` counts the logs the set lacks and why: flights that failed (crashed or diverged), logs too short."""
    from mjxsysid.identify.inference import log_grounded_posteriors
    from mjxsysid.identify.logdata import LogTooShort, prepare
    from mjxsysid.sim import SimConfig
    import jax

    motor = SimConfig(motor_idle=motor_idle, motor_kappa=motor_kappa)    # checks them before any flight
    if int(paths) != paths or paths < 1:
        raise ValueError(f"paths must be a whole number >= 1, got {paths!r}")
    out = Path(out)
    out.parent.mkdir(parents=True, exist_ok=True)
    priors = [prior] if isinstance(prior, str) else list(prior)
    res = {"prior": prior if isinstance(prior, str) else priors, "vehicles": vehicles, "seed": seed, "shard": shard, "levels": list(levels),
           "references": list(references), "controller": controller, "aero": aero, "velocity": velocity,
           "motor_idle": motor_idle, "motor_kappa": motor_kappa, "paths": int(paths), "rows": []}
    if resume and out.is_file():
        res["rows"] = resumed_rows(out, res)
    done = {(r.get("prior", priors[0]), r["vehicle"], r["level"], r["flight"]) for r in res["rows"]}
    tag = {"motor": [motor_idle, motor_kappa]} if motor.motor_map else {}
    t_start = time.perf_counter()
    step = 1 if jax.default_backend() == "cpu" else BATCH          # logs identified together (batched on a GPU)
    logs = []                                                       # (data, vehicle, θ, level, flight name, prior)
    skipped = {"flight failed": 0, "log too short": 0}
    res["skipped"] = skipped                                        # logs the set lacks, and why
    settings = {k: res[k] for k in RESUME_KEYS}
    for p in priors:
        for rec, vehicle, th, lv, flight in progress(flights(settings | {"prior": p}, policy=policy, skipped=skipped),
                                                     desc="flying", unit="log"):
            if (p, vehicle, lv, flight) in done:
                continue
            try:
                logs.append((prepare(rec), vehicle, th, lv, flight, p))
            except LogTooShort:
                skipped["log too short"] += 1
    # every flight's levels interleaved: a batch mixes them, so a run stopped by its budget keeps a balanced set
    order = sorted(range(len(logs)), key=lambda k: (logs[k][1], k))
    for c in progress(range(0, len(order), step), desc="calibration rows"):
        if time_budget_s is not None and time.perf_counter() - t_start > time_budget_s:
            res["cut_by_budget"] = True
            break
        chunk = [logs[k] for k in order[c:c + step]]
        t0 = time.perf_counter()
        posts = log_grounded_posteriors([d for d, *_ in chunk], seeds=[v for _, v, *_ in chunk], calibration=None,
                                        batch=step)
        sec = (time.perf_counter() - t0) / len(chunk)
        for (_, vehicle, th, lv, flight, p), post in zip(chunk, posts):
            res["rows"].append(row(post, th, lv, vehicle, sec) | {"flight": flight, "aero": aero} | tag
                               | ({"prior": p} if len(priors) > 1 else {}))
        out.write_text(json.dumps(res, separators=(",", ":")) + "\n")
    out.write_text(json.dumps(res, separators=(",", ":")) + "\n")
    return res


def flights(settings: dict, *, policy=None, skipped: dict | None = None):
    """The seeded flights of a calibration set's ``settings`` (a row file's :data:`RESUME_KEYS`; ``policy``: the
    weights controller 'policy' flies, None the shipped policy) -> yields (log record, vehicle index, true θ (19,),
    level, flight name) per flight that did not fail, references × levels in order; ``skipped["flight failed"]``
    counts the others. A row file's flights are flown again exactly (the logs its rows came from). ``paths`` (default
    1): the vehicles of each flight and level are flown in this many groups, each with its own seed (a random
    reference such as min-snap draws one path per group: with one, every vehicle of a piece flies the same path at
    a level, and the set samples few drag exposures; docs/identify.md)."""
    from mjxsysid.rollout.flight import flight_log, fly_vehicles
    from mjxsysid.sim import Quadrotor, SimConfig
    from mjxsysid.uses.imu_noise import LEVELS
    import jax

    from mjxsysid import theta as P

    st = {"controller": "oracle", "aero": False, "velocity": True, "motor_idle": 0.0, "motor_kappa": 1.0,
          "paths": 1} | settings
    prior, vehicles, seed, shard = st["prior"], st["vehicles"], st["seed"], st["shard"]
    idle, kappa, controller = st["motor_idle"], st["motor_kappa"], st["controller"]
    motor_map = SimConfig(motor_idle=idle, motor_kappa=kappa).motor_map
    pr = P.get_prior(prior)
    pol = None
    if controller == "policy":
        from mjxsysid.policy.interface import resolve_policy
        pol = resolve_policy("mjxsysid", policy)
    th_all = (pr.vehicles(vehicles) if prior in P.HELDOUT_FAMILIES
              else np.asarray(pr.sample(jax.random.PRNGKey(seed), vehicles)))
    index = _shard(vehicles, shard)
    th = th_all[index]
    for ref, lv in ((r, lv) for r in st["references"] for lv in st["levels"]):
        if lv not in LEVELS:
            raise ValueError(f"unknown noise level {lv!r}; known: {sorted(LEVELS)}")
        s = seed + 1000 * (0 if shard is None else int(shard.split("/")[0])) + 97 * list(LEVELS).index(lv)
        sim = Quadrotor(SimConfig(**LEVELS[lv], aero=st["aero"], motor_idle=idle, motor_kappa=kappa))
        flight = ((ref if controller == "oracle" else f"{ref} ({controller})") + (" aero" if st["aero"] else "")
                  + (f" motor {idle:g}/{kappa:g}" if motor_map else ""))
        for g, part in enumerate(path_groups(len(th), st["paths"])):
            if not len(part):
                continue
            fl, m, _ = fly_vehicles(th[part], controller=controller, sim=sim, seed=s + PATH_SEED_STEP * g, policy=pol,
                                    **parse_reference(ref))
            failed = np.asarray(m["failed"], bool)
            if skipped is not None:
                skipped["flight failed"] = skipped.get("flight failed", 0) + int(failed.sum())
            for i in np.flatnonzero(~failed):
                rec = flight_log(fl.frame, i)
                if not st["velocity"]:
                    rec.pop("velocity_body")
                yield rec, int(index[part[i]]), th[part[i]], lv, flight


PATH_SEED_STEP = 7919
"""The seed step between a flight's path draws (:func:`flights`' ``paths``)."""


def path_groups(n: int, paths: int) -> list[np.ndarray]:
    """A piece's ``n`` vehicles (positions in its shard) in ``paths`` groups, each flying its own path draw."""
    return np.array_split(np.arange(n), paths)


def path_of(settings: dict, vehicle: int) -> int:
    """The path draw (0 … paths − 1) that ``vehicle`` flew in the row file with ``settings`` (its ``vehicles``,
    ``shard``, ``paths``: one where the file predates the setting)."""
    index = _shard(settings["vehicles"], settings.get("shard"))
    pos = int(np.flatnonzero(index == vehicle)[0])
    return next(g for g, part in enumerate(path_groups(len(index), settings.get("paths", 1))) if pos in part)


RESUME_KEYS = ("prior", "vehicles", "seed", "shard", "levels", "references", "controller", "aero", "velocity",
               "motor_idle", "motor_kappa", "paths")
"""The settings a resumed row file must share with the run (:func:`collect`'s ``resume``)."""


def resumed_rows(path: Path, settings: dict) -> list[dict]:
    """The rows of the row file at ``path`` (plain or compressed, :func:`read_json`) collected with ``settings``
    (:data:`RESUME_KEYS`; a key the file lacks is taken as this run's default, written before it existed);
    ValueError naming the file and the settings that differ."""
    prev = {"paths": 1} | read_json(path)            # a file written before ``paths`` flew one path
    bad = [f"{k} {prev[k]!r} (this run {settings[k]!r})" for k in RESUME_KEYS if k in prev and prev[k] != settings[k]]
    if bad:
        raise ValueError(f"cannot resume {path}: it was collected with other settings: {', '.join(bad)}")
    return list(prev["rows"])


def row(post: dict, theta_true, level: str, vehicle: int, seconds: float) -> dict:
    """One calibration row of a raw posterior ``post`` and the true θ (19,); ``rhat_v`` (12,): NUTS's split R̂ per
    visible coordinate where NUTS ran (a coordinate at :data:`~mjxsysid.identify.nuts.RHAT_OK` or above is not
    seen: :func:`calibrated_bands`, as ``decode --log`` reports it)."""
    tv = np.asarray(visible_from_theta(np.asarray(theta_true, np.float32)[None]), np.float64)[0]
    out = {"level": level, "vehicle": vehicle, "seconds": round(seconds, 3), "method": post["method"],
           "truth_v": np.round(tv, 4).tolist(), "bands": np.round(raw_bands(post["v_raw"]), 4).tolist(),
           "features": post["features"], "weights": np.round(np.asarray(post["weights"], np.float64), 5).tolist()}
    if (post.get("nuts") or {}).get("rhat_v") is not None:
        out["rhat_v"] = np.round(np.asarray(post["nuts"]["rhat_v"], np.float64), 4).tolist()
    return out


ROW_SUFFIXES = (".json", ".json.gz", ".json.xz")
"""The row files' forms: plain, gzipped, or xz-compressed (the committed rows: a fifth smaller than gzip's)."""


def read_json(path) -> dict:
    """A JSON file, plain or compressed by its suffix (.gz: gzip, .xz: xz)."""
    import gzip
    import lzma
    path = Path(path)
    raw = path.read_bytes()
    if path.suffix == ".gz":
        raw = gzip.decompress(raw)
    elif path.suffix == ".xz":
        raw = lzma.decompress(raw)
    return json.loads(raw)


def row_files(folder) -> list[Path]:
    """The row files in ``folder`` (:data:`ROW_SUFFIXES`), sorted."""
    return sorted(f for f in Path(folder).iterdir() if f.name.endswith(ROW_SUFFIXES))


VIBRATION_LEVEL = "x5_vibration"
"""The level whose logs carry a rotor vibration: a row collected before the rows carried the detector's
``vibration`` feature takes it from its level (flown again, the detector agrees with the level on 2,046 of 2,048
logs of ten pieces: docs/runs/measurements/log-grounded/vibration-stratum/detector.md)."""


def read_rows(paths) -> list[dict]:
    """Rows of ``collect`` files (folders are searched for :data:`ROW_SUFFIXES`: plain, gzipped or xz)."""
    rows = []
    for p in paths:
        p = Path(p)
        for f in (row_files(p) if p.is_dir() else [p]):
            rows += read_json(f)["rows"]
    for r in rows:
        r["features"].setdefault("vibration", r.get("level") == VIBRATION_LEVEL)
    if not rows:
        raise ValueError(f"no calibration rows in {[str(p) for p in paths]}")
    return rows


def fit_file(paths, out: Path, note: str = "", *, bins: int = BINS, min_group: int = 30, command: str | None = None,
             provenance: dict | None = None, method: str | None = None, base: Path | None = None,
             window_rows: list[dict] | None = None, window_logs: int | None = None) -> dict:
    """Fit the table on the rows of ``paths`` (``bins``, ``min_group``: :func:`~mjxsysid.identify.calibration_fit.fit`'s)
    and write it to ``out`` with its provenance (``command`` that made it, default the CLI's; ``provenance``:
    more entries, e.g. a release stage's). ``method`` ('smc_nuts', 'smc'): fit on that sampler's rows only and
    write the table at ``base`` (default the shipped one) with this one as its table for ``method``
    (:func:`~mjxsysid.identify.calibrate.with_method`), in windows where the method has an entry in
    :data:`~mjxsysid.identify.calibration_fit.WINDOWED` (``window_logs``: its logs a window instead). The window check's and the motor-map check's thresholds
    (:func:`~mjxsysid.identify.windowcheck.threshold_entry`, :func:`~mjxsysid.identify.idlecheck.threshold_entry`)
    are fitted on the rows where enough carry their statistic (with ``window_rows``: more simulated logs'
    statistics, rows of ``{level, features: {window_shift, idle_gain}}``), else kept from ``base``."""
    from mjxsysid.identify import idlecheck, windowcheck
    from mjxsysid.identify.calibrate import VIBRATION_COORDS, load, with_method
    from mjxsysid.identify.calibration_fit import WINDOWED
    rows = read_rows(paths)
    pooled = rows + list(window_rows or [])          # the checks read the mode: every sampler's rows
    checks = {m.KEY: m.threshold_entry(pooled) for m in (windowcheck, idlecheck)}
    if method is not None:
        n = len(rows)
        rows = [r for r in rows if r.get("method") == method]
        if not rows:
            raise ValueError(f"no calibration rows of method {method!r} among the {n} rows of {[str(p) for p in paths]}")
    t0 = time.perf_counter()
    windows = WINDOWED.get(method)
    if windows is not None and window_logs is not None:
        windows = windows | {"logs": window_logs}
    table = fit(rows, bins=bins, min_group=min_group, windows=windows, vibration=VIBRATION_COORDS[method or "smc"])
    levels = sorted({r["level"] for r in rows})
    cmd = "mjxsysid calibrate-posterior --fit " + " ".join(map(str, paths)) + (f" --method {method}" if method else "")
    table["provenance"] = {"command": command or cmd,
                           "rows": len(rows), "levels": levels, "commit": git_commit() or "unknown",
                           "fitted_on": platform.node() or "unknown", "fit_seconds": round(time.perf_counter() - t0, 3),
                           "date": time.strftime("%Y-%m-%d"), "note": note, **(provenance or {})}
    try:
        base_table = load(base, check=method is not None)    # replaced whole: only its checks' thresholds are read
    except FileNotFoundError:
        if method is not None:
            raise
        base_table = {}
    if method is not None:
        table = with_method(base_table, table, method)
    for key, entry in checks.items():                # from these rows where enough carry its statistic, else the base's
        if entry is not None:
            table[key] = entry | {"command": command or cmd, "date": time.strftime("%Y-%m-%d")}
        elif key in base_table:
            table[key] = base_table[key]
    out = Path(out)
    out.parent.mkdir(parents=True, exist_ok=True)
    out.write_text(json.dumps(table, indent=1) + "\n")
    return table


def calibrated_bands(row: dict, table: dict | None) -> tuple[np.ndarray, np.ndarray]:
    """A row's 90 % band (2, 12) after the ``table`` (None: raw) and a (12,) mask of the coordinates
    the model check and the rate logging let through, and NUTS's chains mixed on where the row records their
    R̂ (``rhat_v``; :func:`~mjxsysid.identify.nuts.unmixed_not_seen`) (the table of the row's ``method`` where it
    has one)."""
    from mjxsysid.identify.calibrate import checked_stretch, coord_entry, coord_ok, for_method, model_check
    q = np.asarray(row["bands"], np.float64)
    if table is None:
        return q[[0, 2]], np.ones(len(V_NAMES), bool)
    table = for_method(table, row.get("method"))
    check = model_check(row["features"], row["weights"], table)
    ok = np.array([coord_ok(check, j) for j in range(len(V_NAMES))])
    lo, hi = q[0].copy(), q[2].copy()
    for j in range(len(V_NAMES)):
        c = coord_entry(table, j, row["features"])
        _, k_lo, k_hi, shift, idle_ok = checked_stretch(q[:, j], c, row["features"], check, j)
        ok[j] &= idle_ok
        lo[j] = q[1, j] + shift - k_lo * (q[1, j] - q[0, j])
        hi[j] = q[1, j] + shift + k_hi * (q[2, j] - q[1, j])
    if row.get("rhat_v") is not None:
        from mjxsysid.identify.nuts import mixed_coords
        ok &= mixed_coords(row["rhat_v"])
    return np.stack([lo, hi]), ok


def evaluate(rows: list[dict], table: dict | None, by: str = "level", bands: list | None = None) -> dict:
    """Coverage, widths and clustering per ``by`` ('level', 'flight' or 'velocity': whether the logs carried
    it, and whether they were flown with rotor aerodynamics or another motor map) of ``rows`` under
    ``table`` (None: the raw posterior); ``bands``: the rows' :func:`calibrated_bands` under it, if computed."""
    bands = [calibrated_bands(r, table) for r in rows] if bands is None else bands
    out = {}
    order = ("clean", "x1", "x2", "x5_white", "x5_vibration", "x10", "x20") + REFERENCES_ALL
    if by == "velocity":
        key = lambda r: (("velocity" if r["features"].get("velocity_used") else "no velocity")  # noqa: E731
                         + (", aero" if r.get("aero") else "") + (", motor map" if r.get("motor") else ""))
    else:
        key = lambda r: r.get(by, "lemniscate:10")    # noqa: E731  (rows of one flight name none)
    for lv in sorted({key(r) for r in rows}, key=lambda x: (order.index(x) if x in order else len(order), x)):
        pick = [i for i, r in enumerate(rows) if key(r) == lv]
        rs, (band, ok) = [rows[i] for i in pick], zip(*(bands[i] for i in pick))
        band, ok = np.array(band), np.array(ok)
        tv = np.array([r["truth_v"] for r in rs])
        med, inside = np.array([r["bands"][1] for r in rs]), (band[:, 0] <= tv) & (tv <= band[:, 1])
        width = band[:, 1] - band[:, 0]
        oracle = 2 * np.quantile(np.abs(tv - med), LEVEL_Q, axis=0)
        cov = np.where(ok.any(0), (inside & ok).sum(0) / np.maximum(ok.sum(0), 1), np.nan)
        held = (inside | ~ok).sum(1) / len(V_NAMES)
        out[lv] = {"logs": len(rs), "coverage": dict(zip(V_NAMES, np.round(cov, 3).tolist())),
                   "seen_share": dict(zip(V_NAMES, np.round(ok.mean(0), 3).tolist())),
                   "median_width": dict(zip(V_NAMES, np.round(np.median(width, 0), 4).tolist())),
                   "oracle_width": dict(zip(V_NAMES, np.round(oracle, 4).tolist())),
                   "share_under_half": float(np.mean(held < 0.5)),
                   "tw_width_pct": float(100 * np.median(np.expm1(width[:, 0] / 2)))}
    return out


LEVEL_Q = 0.9


def rank_histograms(rows: list[dict], table: dict | None, path: Path, bands: list | None = None) -> None:
    """Where each truth falls inside its band (0 at q05, 1 at q95; below 0 / above 1 outside), per
    coordinate: a calibrated band spreads them evenly over 0…1 with 5 % beyond each side (``bands``: :func:`evaluate`'s)."""
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    bands = [calibrated_bands(r, table) for r in rows] if bands is None else bands
    pos = []
    for r, (b, _) in zip(rows, bands):
        finite = np.isfinite(b[0]) & np.isfinite(b[1])       # a group too small for its level: an infinite band
        width = np.where(finite, np.maximum(b[1] - b[0], 1e-12), 1.0)
        pos.append(np.where(finite, (np.asarray(r["truth_v"]) - np.where(finite, b[0], 0.0)) / width, np.nan))
    pos = np.clip(np.array(pos), -0.25, 1.25)
    fig, axes = plt.subplots(2, 6, figsize=(14, 4.6), sharey=True)
    edges = np.linspace(-0.25, 1.25, 13)
    for j, ax in enumerate(axes.flat):
        x = pos[np.isfinite(pos[:, j]), j]
        ax.hist(x, edges, color="tab:blue", edgecolor="white")
        ax.axvspan(0, 1, color="0.92", zorder=-1)
        ax.axhline(len(x) * 0.9 / 8, color="k", lw=0.8, ls="--")
        ax.set_title(SHORT[j], fontsize=9)
        ax.tick_params(labelsize=7)
    fig.suptitle("truth's position in its 90 % band (grey: inside; dashed: the calibrated height; the "
                 "outer bins hold what falls outside)", fontsize=9)
    fig.tight_layout()
    fig.savefig(path, dpi=100)
    plt.close(fig)


def coverage_width_figure(before: dict, after: dict, path: Path) -> None:
    """Coverage against median width over the oracle's, each coordinate × level, raw and calibrated."""
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    import matplotlib.ticker
    fig, ax = plt.subplots(figsize=(7, 4.6))
    ax.axhspan(0.85, 0.95, color="0.9", label="0.85–0.95")
    for res, mk, lab in ((before, "o", "raw"), (after, "s", "calibrated")):
        xs, ys = [], []
        for lv in res.values():
            for n in V_NAMES:
                if np.isfinite(lv["coverage"][n]) and lv["oracle_width"][n] > 0:
                    xs.append(lv["median_width"][n] / lv["oracle_width"][n])
                    ys.append(lv["coverage"][n])
        ax.scatter(xs, ys, marker=mk, s=18, alpha=0.7, label=lab)
    ax.axvline(2.0, color="k", lw=0.8, ls="--", label="2× the oracle width")
    ax.set_xscale("log")
    ax.xaxis.set_major_locator(matplotlib.ticker.LogLocator(base=10, subs=(1.0, 2.0, 5.0)))
    ax.xaxis.set_major_formatter(matplotlib.ticker.FormatStrFormatter("%g"))
    ax.xaxis.set_minor_formatter(matplotlib.ticker.NullFormatter())
    ax.set_xlabel("median 90 % band width / oracle width (log scale)")
    ax.set_ylabel("truth inside the 90 % band")
    ax.set_ylim(0, 1.02)
    ax.legend(fontsize=8, loc="lower right")
    ax.set_title("log-grounded posterior: each coordinate at each noise level", fontsize=10)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


def table_markdown(res: dict) -> list[str]:
    """Coverage per coordinate × level as markdown lines ('–': not seen on any log of the level)."""
    lines = ["| group | logs | " + " | ".join(SHORT) + " | under half | T/W width |", "|---" * (len(SHORT) + 4) + "|"]
    for lv, r in res.items():
        cov = [r["coverage"][n] for n in V_NAMES]
        lines.append(f"| {lv} | {r['logs']} | " + " | ".join("–" if not np.isfinite(c) else f"{c:.2f}" for c in cov)
                     + f" | {100 * r['share_under_half']:.1f} % | ±{r['tw_width_pct']:.1f} % |")
    return lines


def mean_coverage(levels: dict) -> dict:
    """:func:`evaluate`'s result {level: {coverage {coord: c}}} -> {level: the coordinates' mean coverage}."""
    return {lv: round(float(np.nanmean(list(r["coverage"].values()))), 3) for lv, r in levels.items()}


def report(paths, table_path: Path, out: Path, record: bool = False, figures: bool = True) -> dict:
    """Evaluate the table at ``table_path`` (default the shipped one) on the rows of ``paths`` (held out)
    against the raw posterior; write ``out``/evaluation.json, evaluation.md and (``figures``) coverage_width.png,
    ranks.png; ``record``: also the mean coverage per level into the table's provenance (``held_out``, keyed by
    ``out``): per sampler, of its own rows, in the provenance of the table that calibrates them
    (:func:`~mjxsysid.identify.calibrate.for_method`)."""
    from mjxsysid.identify.calibrate import SHIPPED, for_method, load
    rows = read_rows(paths)
    table = load(table_path)
    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    bands = [calibrated_bands(r, table) for r in rows]             # each row's, once
    raw, cal = evaluate(rows, None), evaluate(rows, table, bands=bands)
    flights = evaluate(rows, table, by="flight", bands=bands)
    vel = evaluate(rows, table, by="velocity", bands=bands)
    shipped = table_path is not None and Path(table_path).resolve() == SHIPPED.resolve()
    named = str(SHIPPED.relative_to(SHIPPED.parents[2])) if shipped else str(table_path)   # not this machine's path
    res = {"rows": len(rows), "table": named, "raw": raw, "calibrated": cal, "calibrated_by_flight": flights, "calibrated_by_velocity": vel}
    (out / "evaluation.json").write_text(json.dumps(res, indent=1) + "\n")
    md = (["## Calibrated", ""] + table_markdown(cal) + ["", "## Calibrated, by flight", ""] + table_markdown(flights)
          + ["", "## Calibrated, by whether the log carried velocity", ""] + table_markdown(vel)
          + ["", "## Raw", ""] + table_markdown(raw))
    (out / "evaluation.md").write_text("\n".join(md) + "\n")
    if figures:
        coverage_width_figure(raw, cal, out / "coverage_width.png")
        rank_histograms(rows, table, out / "ranks.png", bands)
    if not record:
        return res
    path = Path(table_path) if table_path is not None else SHIPPED
    for method in sorted({r.get("method") for r in rows}, key=str):    # each sampler's rows, in its own table
        own = [k for k, r in enumerate(rows) if r.get("method") == method]
        held = for_method(table, method).setdefault("provenance", {}).setdefault("held_out", {})
        held[str(out)] = {"rows": len(own), "mean_coverage": mean_coverage(
            evaluate([rows[k] for k in own], table, bands=[bands[k] for k in own]))}
    path.write_text(json.dumps(table, indent=1) + "\n")
    return res


__all__ = ["collect", "fit_file", "report", "evaluate", "mean_coverage", "FEATURE_NAMES", "COORD_FEATURE", "log_features"]
