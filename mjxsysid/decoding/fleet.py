"""Several logs at once: ``decode --log A B FOLDER`` decodes each into its own folder and writes one
table of vehicles (fleet.md, fleet.json): per log, each quantity the log saw as its median and 90 %
band, '–' where the log did not see it, and the one-line reason of a log that was refused."""
from __future__ import annotations

from pathlib import Path


SHORT = {"thrust_to_weight": "T/W", "motor_time_constant": "τ_m (ms)", "authority_total[0]": "A_x",
         "authority_total[1]": "A_y", "authority_total[2]": "A_z", "yaw_authority_total": "yaw"}
"""The fleet table's columns (the quantities a user compares across vehicles first)."""


def expand_logs(paths) -> list[Path]:
    """Paths given to ``--log`` -> the logs they name: a folder's files (sorted; hidden files and the
    project's own outputs skipped), except a ROS 2 bag folder (metadata.yaml), which is one log."""
    out = []
    for p in map(Path, paths):
        if p.is_dir() and not (p / "metadata.yaml").is_file():
            files = sorted(f for f in p.iterdir() if f.is_file() and not f.name.startswith(".")
                           and f.suffix.lower() not in (".md", ".json", ".png", ".npz", ".mp4", ".txt"))
            if not files:
                raise ValueError(f"--log {p}: a folder with no log files in it")
            out += files
        elif not p.exists():
            raise FileNotFoundError(f"flight log not found: {p}")
        else:
            out.append(p)
    names = [p.stem for p in out]
    dup = sorted({n for n in names if names.count(n) > 1})
    if dup:
        raise ValueError(f"--log: several logs named {dup}; each is written to OUT/NAME: rename or decode them apart")
    return out


def fleet_row(name: str, summary: dict | None, error: str | None = None) -> dict:
    """One log's row: {log, quantities {name: {median, q05, q95, seen}}, motor_map (the best command→speed map
    where the motor-map check flagged the log, else None), maps ([[ι, κ], ...]: the maps its bands hold their
    values under where flagged, else []), posterior}, or {log, error}."""
    if error is not None:
        return {"log": name, "error": error}
    grounded = (summary or {}).get("_log_grounded", {})
    gap = grounded.get("gap", {})
    cal = grounded.get("calibration") or {}
    flagged = ((cal.get("model_check") or {}).get("idle") or {}).get("ok") is False
    best = (cal.get("features") or {}).get("idle_map")
    maps = (cal.get("features") or {}).get("idle_plausible") or []
    return {"log": name, "quantities": {q: {"median": g["log_median"], "q05": g["log_q05"], "q95": g["log_q95"],
                                            "seen": g["seen_by_log"], "why": g.get("seen_why", "")}
                                        for q, g in gap.items()},
            "motor_map": _describe(best) if flagged and best else None,
            "maps": [list(m) for m in maps] if flagged else [],
            "posterior": (summary or {}).get("_posterior")}


def shared_maps(rows: list[dict]) -> tuple:
    """Flights of one vehicle (``decode --same-vehicle``): the command→speed maps any flagged flight's bands
    hold (their ``maps``), in :data:`~mjxsysid.identify.idlecheck.MAPS`'s order. The map is the vehicle's, so
    a map one flight shows is plausible for every flight: each flagged flight's bands hold their values
    under all of them (:func:`~mjxsysid.identify.idlecheck.run`'s ``shared``)."""
    from mjxsysid.identify.idlecheck import MAPS
    seen = {tuple(float(x) for x in m) for r in rows for m in r.get("maps") or []}
    return tuple(m for m in MAPS if m in seen)


def lacks_shared(row: dict, maps: tuple) -> bool:
    """Does a flagged flight's row lack some of the vehicle's ``maps`` (:func:`shared_maps`): it is decoded
    again with them."""
    own = {tuple(float(x) for x in m) for m in row.get("maps") or []}
    return bool(own) and not set(maps) <= own


def shared_maps_markdown(maps: tuple, again: list[str]) -> str:
    """fleet.md's line on the maps the flights of one vehicle share (:func:`shared_maps`)."""
    if not maps:
        return ""
    names = "; ".join(_describe(m) for m in maps)
    redo = (f" Decoded again with them: {', '.join(again)}." if again else "")
    return (f"\nThe command→speed maps these flights showed (the motor-map check): {names}. The map is the "
            f"vehicle's, so each flagged flight's bands hold their values under every one of them.{redo}\n")


def _cell(q: str, v: dict | None) -> str:
    from mjxsysid.identify.idlecheck import WIDENED
    if not v or not v["seen"]:
        return "–"
    k = 1e3 if q == "motor_time_constant" else 1.0
    mark = "*" if WIDENED in v.get("why", "") else ""
    return f"{k * v['median']:.3g} ({k * v['q05']:.3g}–{k * v['q95']:.3g}){mark}"


def fleet_markdown(rows: list[dict]) -> str:
    """The fleet table: a row per log, the :data:`SHORT` quantities as median (90 % band); a refused log
    gives its reason, a log decoded by the decoders alone says so."""
    blank = " | ".join("" for _ in SHORT)
    lines = ["| log | " + " | ".join(SHORT.values()) + " | not seen |", "|---" * (len(SHORT) + 2) + "|"]
    for r in rows:
        qs = r.get("quantities")
        if "error" in r:
            lines.append(f"| {r['log']} | {blank} | refused: {r['error']} |")
        elif not qs:
            lines.append(f"| {r['log']} | {blank} | {r.get('posterior') or 'decoder-only'} |")
        else:
            unseen = sum(not v["seen"] for v in qs.values())
            cells = " | ".join(_cell(q, qs.get(q)) for q in SHORT)
            lines.append(f"| {r['log']} | {cells} | {unseen} of {len(qs)} |")
    lines += ["", "Median (5–95 %) of the log-grounded posterior, calibrated; '–': not seen by this log "
              "(its summary.json says why); '*': widened to hold its value under every command→speed map "
              "that fits the log about as well as the best (the motor-map check). τ_m in ms, the authorities in rad/s²."]
    return "\n".join(lines) + "\n"


def disagreements(rows: list[dict]) -> list[dict]:
    """Flights of one vehicle: every pair of logs whose 90 % bands of a quantity both logs saw do not overlap
    -> [{quantity, logs (a, b), bands ((q05, q95), (q05, q95))}]. One of the two logs' models does not hold
    (another excitation, a motor model, aerodynamics): the calibration cannot tell which."""
    out = []
    fine = [r for r in rows if r.get("quantities")]
    for q in SHORT:
        for i, a in enumerate(fine):
            for b in fine[i + 1:]:
                va, vb = a["quantities"].get(q), b["quantities"].get(q)
                if va and vb and va["seen"] and vb["seen"] and (va["q95"] < vb["q05"] or vb["q95"] < va["q05"]):
                    out.append({"quantity": q, "logs": (a["log"], b["log"]),
                                "bands": ((va["q05"], va["q95"]), (vb["q05"], vb["q95"])),
                                "motor_maps": (a.get("motor_map"), b.get("motor_map"))})
    return out


def disagreements_markdown(found: list[dict]) -> str:
    """fleet.md's section for ``decode --same-vehicle``: the pairs of :func:`disagreements`, or that none."""
    head = "## One vehicle: do the logs agree?\n\n"
    if not found:
        return head + "Every quantity two logs saw has overlapping 90 % bands.\n"
    lines = [f"- **{SHORT[d['quantity']]}**: {d['logs'][0]} {_band(d['quantity'], d['bands'][0])} against "
             f"{d['logs'][1]} {_band(d['quantity'], d['bands'][1])}" + _maps_part(d) for d in found]
    n = len(found)
    return (head + (f"{n} pairs of bands exclude each other" if n > 1 else "1 pair of bands excludes each other")
            + ": for each, at least one log's model does not "
            "hold (a flight that hardly excites that axis, a motor map, aerodynamics), though each passed its "
            "checks. Where one flight excites that axis far more than the others, its band is the likelier "
            "(docs/logs.md, a Crazyflie's three flights).\n\n" + "\n".join(lines) + "\n")


def _describe(m) -> str:
    from mjxsysid.identify.idlecheck import describe
    return describe(tuple(m))


def _mapped_quantities() -> set[str]:
    """The log quantities made of a coordinate the command→speed map acts on
    (:data:`~mjxsysid.identify.idlecheck.MAPPED`)."""
    from mjxsysid.identify.idlecheck import MAPPED
    from mjxsysid.identify.logspace import LOG_NAMES, V_OF_QUANTITY
    return {n for n, js in zip(LOG_NAMES, V_OF_QUANTITY) if set(js) & set(MAPPED)}


def _maps_part(d: dict) -> str:
    """What a pair's line adds where the motor-map check moved both bands to different maps and the quantity
    rests on the map: the flights show the command→speed map differently."""
    a, b = d.get("motor_maps") or (None, None)
    if not a or not b or a == b or d["quantity"] not in _mapped_quantities():
        return ""
    return (f": their command→speed maps differ ({a} against {b}); the quantity is its value at full command "
            f"under the map, so the flights part on the map, which each shows about the commands it flew")


def _band(q: str, b) -> str:
    k = 1e3 if q == "motor_time_constant" else 1.0
    return f"{k * b[0]:.3g}–{k * b[1]:.3g}"
