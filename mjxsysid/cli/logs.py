"""`mjxsysid check-log`: a flight log's checks alone.

Each command's parser (``add_*``) stands beside its handler (``cmd_*``); a handler imports what it
runs when it runs, so `mjxsysid --help` stays instant.
"""
from __future__ import annotations

from pathlib import Path

from mjxsysid.runtime import jsonout


def add_check_log(sub) -> None:
    ck = sub.add_parser("check-log", help="the physical plausibility checks of a flight log alone (any format decode reads)")
    ck.add_argument("log", type=Path, metavar="FILE",
                    help="a flight log of any format decode reads (docs/logs.md)")
    ck.add_argument("--segment", default=None, metavar="T0:T1",
                    help="check only this part, in seconds (a ULog: since its start; default its armed, airborne "
                         "segment; a CSV: its t column)")
    ck.add_argument("--prior", default="wide_actuators",
                    help="the decoders' training prior the log-only vehicle estimates are compared with "
                         "(default wide_actuators, the shipped decoders'; 'none': not compared)")
    ck.add_argument("--json", action="store_true", help="print the findings and estimates as JSON instead of a table")
    ck.set_defaults(handler=cmd_check_log)


def cmd_check_log(args) -> int:
    """Exit 2 on an error finding, 1 on a warning or out-of-prior finding, 0 on none."""
    from mjxsysid.logs import checks as L
    from mjxsysid.logs.csvlog import read_any_log
    from mjxsysid.logs.speedmap import check_fit
    rec = read_any_log(args.log, args.segment)
    fit = check_fit(rec)                 # once: the check and the report read it
    found = L.check_log(rec, speed_fit=fit)
    est = None
    if not any(f.level == "error" for f in found):
        est = L.estimate_vehicle(rec)
        if args.prior.lower() != "none":
            found += L.prior_check(rec, args.prior, est)
    src = rec.get("source")
    speed = _rotor_speed(fit)
    if args.json:
        tau = L.motor_time_constant(est) if est else (None, None)
        print(jsonout.dumps({"findings": [f.as_dict() for f in found], "estimates": est,
                          "notes": [tau[1]] if est and tau[0] is None else [], "source": src,
                          "resampled": rec.get("resampled"), "rotor_speed": speed}, indent=2))
    else:
        t = rec["t"]
        print(f"{args.log}: {len(t)} rows, {t[-1] - t[0] + 0.002:.2f} s"
              + (f" ({src['format']}, segment {src['segment']['t0']:.3f}–{src['segment']['t1']:.3f} s: "
                 f"{src['segment']['why']})" if src else ""))
        for k, how in (rec.get("resampled") or {}).items():
            print(f"  {k}: {how}")
        if est:
            tau, why = L.motor_time_constant(est)
            print(f"estimates: thrust-to-weight {est['thrust_to_weight']:.3g}, motor time constant "
                  + (f"{tau * 1e3:.3g} ms" if tau is not None else "not estimable")
                  + f", weakest motor {est['min_motor_effectiveness']:.2g}, IMU noise {est['gyro_noise']:.2g} rad/s "
                    f"/ {est['accel_noise']:.2g} m/s²")
            if tau is None:
                print(f"note: {why}")
        if speed is not None:
            print("rotor speeds: " + (f"used by the likelihood: τ_m {1e3 * speed['tau_m_s']:.1f} ms from command to speed "
                                      f"(delay {1e3 * speed['delay_s']:.0f} ms, R² {speed['r2']:.3f}: "
                                      f"{'a map per rotor' if speed['per_rotor'] else 'one map'}; one map "
                                      f"{speed['r2_shared']:.3f}, per rotor {speed['r2_per_rotor']:.3f}; n_eff "
                                      f"{speed['n_eff']:.0f}), Ω_ref {speed['omega_ref_rad_s']:.0f} rad/s, idle offsets "
                                      + " ".join(f"{c:.0f}" for c in speed["offset_rad_s"]) + " rad/s"
                                      if speed["rotor_speed_used"]
                                      else f"not used: {speed['why']}"))
        if not found:
            print("no findings")
        else:
            rows = [(f.level.replace("_", " "), f.column, f.message) for f in found]
            w0, w1 = max(len(r[0]) for r in rows), max(len(r[1]) for r in rows)
            print(f"{'level':<{w0}}  {'columns':<{w1}}  message")
            for lv, col, msg in rows:
                print(f"{lv:<{w0}}  {col:<{w1}}  {msg}")
    levels = {f.level for f in found}
    return 2 if "error" in levels else 1 if levels & {"warning", "out_of_prior"} else 0


def _rotor_speed(fit: dict | None) -> dict | None:
    """What the likelihood makes of the log's measured rotor speeds (:func:`~mjxsysid.identify.speeds.report`
    of its :func:`~mjxsysid.logs.speedmap.check_fit`), None for a log without them."""
    if fit is None:
        return None
    from mjxsysid.identify.speeds import report
    return report(fit)
