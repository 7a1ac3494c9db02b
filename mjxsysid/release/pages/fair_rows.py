"""The tables of docs/fair_comparisons.md: Markdown rows of run files (each a run's JSON dict)."""
from __future__ import annotations

import numpy as np


def f3(x) -> str:
    return "–" if x is None else f"{x:.3f}"


def pct(x) -> str:
    return f"{100 * x:.0f} %"


def stamp(d: dict) -> str:
    return f"{d['date'][:10]}, commit {str(d['commit']).split()[0]}"


def tune_rows(runs: list[tuple[str, dict]], methods: list[str]) -> list[str]:
    names = {"naive": "Naive", "baseline": "Baseline", "nominal_cem": "Nominal+CEM",
             "cfm_tuned": "CFM-tuned", "oracle_cem": "Oracle-CEM"}
    head = "| protocol | same n | " + " | ".join(f"{names[m]}: RMSE m (success)" for m in methods)
    head += " | CFM-tuned / Baseline | heading °: Baseline / CFM-tuned |"
    out = [head, "|" + "---|" * (len(methods) + 4)]
    for label, d in runs:
        n = d["numbers"]
        cs = n["common_set"]
        cells = [f"{cs[m]['pos_rmse_m']['mean']:.4f} ({pct(n[m]['success_rate'])})" for m in methods]
        r = n["ratios"]
        head_b = cs["baseline"]["heading_rmse_deg"]["mean"]
        head_c = cs["cfm_tuned"]["heading_rmse_deg"]["mean"]
        out.append(f"| {label} | {cs['n']} | " + " | ".join(cells)
                   + f" | **{r['cfm_over_baseline']:.2f}×** | {head_b:.1f} / {head_c:.1f} |")
    return out


def lemniscate_rows(runs: list[tuple[str, dict]]) -> list[str]:
    out = ["| protocol | period | Baseline RMSE m | CFM-tuned | Oracle-CEM | CFM-tuned / Baseline |",
           "|---|---|---|---|---|---|"]
    for label, d in runs:
        h = d["numbers"]["headline"]
        for p in ("15s", "10s", "7.5s"):
            b, c, o = h[f"baseline_{p}"], h[f"cfm_tuned_{p}"], h[f"oracle_cem_{p}"]
            out.append(f"| {label} | {p} | {b:.4f} | {c:.4f} | {o:.4f} | **{c / b:.2f}×** |")
    return out


REPLAY_METHODS = [("random", "Random"), ("regression", "Regression"), ("cfm", "CFM (1 sample)"),
                  ("cfm_mean", "CFM (mean action)"), ("true", "true θ")]
FLIGHTS = [("lemniscate_5s", "lem. 5 s"), ("lemniscate_10s", "lem. 10 s"),
           ("lemniscate_15s", "lem. 15 s"), ("hover", "hover")]


def replay_rows(runs: list[tuple[str, dict]], paper: dict | None = None) -> list[str]:
    """runs: (label, flights) with flights = results.json's numbers.flights or replay.json's flights."""
    out = ["| policy / decoders | flight | " + " | ".join(m for _, m in REPLAY_METHODS) + " |",
           "|" + "---|" * (len(REPLAY_METHODS) + 2)]
    for label, fl in runs:
        for key, name in FLIGHTS:
            if key not in fl:    # a quick run (a tiny release) flies fewer flights
                continue
            pv = fl[key]["paper_vehicle"]
            cells = [f"{pv[m]['rmse']:.3f} / {pv[m]['pcc']:.2f}" for m, _ in REPLAY_METHODS]
            out.append(f"| {label} | {name} | " + " | ".join(cells) + " |")
    for key, name in FLIGHTS[:3] if paper else ():
        p = paper[key]
        cells = [f"{p[m]['rmse']:.3f} / {p[m]['pcc']:.2f}" if m in p else "–" for m, _ in REPLAY_METHODS]
        out.append(f"| the paper (hardware, its own policy) | {name} | " + " | ".join(cells) + " |")
    return out


def robustness_rows(runs: list[tuple[str, dict]]) -> list[str]:
    out = [("| decoder | paper vehicle: lateral inside | width decoded / ±20 % | 20 prior vehicles: inside (mean) "
           "| prior: width ratio (median) | MC σ 3 N, lateral energy distance: decoded / ±20 % (cm) |"),
           "|---|---|---|---|---|---|"]
    for label, d in runs:
        h = d["numbers"]["headline"]
        out.append(f"| {label} | {h['step_lateral_inside_decoded']:.2f} | {h['step_lateral_width_ratio']:.1f}× "
                   f"| {h['prior_step_lateral_inside_decoded_mean']:.2f} | {h['prior_step_lateral_width_ratio_median']:.1f}× "
                   f"| {100 * h['mc_sigma3_lateral_energy_distance_decoded_m']:.1f} / "
                   f"{100 * h['mc_sigma3_lateral_energy_distance_pm20_m']:.1f} |")
    return out


def fidelity_rows(runs: list[tuple[str, dict]]) -> list[str]:
    out = ["| identification | inside decoded 5–95 %: mean (median) | inside ±20 % (mean) | width ratio decoded / ±20 %: median (mean) | run |",
           "|---|---|---|---|---|"]
    for label, d in runs:
        m, md, w = d["mean"], d["median"], d["width_ratio_decoded_over_pm20"]
        out.append(f"| {label} | {m['inside_decoded']:.3f} ({md['inside_decoded']:.3f}) | {m['inside_pm20']:.3f} "
                   f"| {w['median']:.1f}× ({w['mean']:.1f}×) | {d['date']}, {d['device']}, jax {d['jax']} |")
    return out


def decoder_rows(runs: list[tuple[str, dict]]) -> list[str]:
    out = ["| decoders | energy score: CFM / Regression / Random / prior | Regression / CFM | CFM 90 % calibrated (±5 points) |",
           "|---|---|---|---|"]
    for label, d in runs:
        e = d["energy_score"]
        cal = d.get("calibrated_within_5_points")
        prior = f"{e['prior']:.2f}" if "prior" in e else "–"
        calibrated = f"{cal['90%']} of {cal['of']}" if cal else "–"
        out.append(f"| {label} | {e['cfm']:.2f} / {e['regression']:.2f} / {e['random']:.2f} / {prior} "
                   f"| {e['regression'] / e['cfm']:.2f}× | {calibrated} |")
    return out


def policy_rows(runs: list[tuple[str, dict]]) -> list[str]:
    out = [("| policy | imitation of K_θ | 1,000 vehicles, 10 s lemniscate: success; RMSE m | RMSE / oracle K_θ "
           "| slow actuators: success; RMSE m | mean rate error rad/s |"),
           "|---|---|---|---|---|---|"]
    for label, bc, d in runs:
        lem, slow = d["lemniscate"], d["slow_actuators"]
        out.append(f"| {label} | {bc} | {pct(lem['policy']['success_rate'])}; {lem['policy']['pos_rmse_m']['mean']:.4f} "
                   f"| **{lem['rmse_ratio_policy_over_oracle']:.2f}×** "
                   f"| {pct(slow['policy']['success_rate'])}; {slow['policy']['pos_rmse_m']['mean']:.4f} "
                   f"| {d['tracking_policy']['rate_err_mean_rad_s']:.3f} |")
    return out


def merged_rows(runs: list[tuple[str, dict, dict]], methods: list[str]) -> list[str]:
    """Rows of tune-* runs on the same vehicles: (label, run, base run). A method a run did not fly
    (a knob of the tuner changes no fixed-gain flight, nor another model source's) comes from the
    base run of the same seed: per-vehicle results, so "same n" is over the methods shown."""
    names = {"naive": "Naive", "baseline": "Baseline", "nominal_cem": "Nominal+CEM",
             "cfm_tuned": "CFM-tuned", "oracle_cem": "Oracle-CEM"}
    out = ["| protocol | same n | " + " | ".join(f"{names[m]}: RMSE m (success)" for m in methods)
           + " | CFM-tuned / Baseline | Oracle-CEM / Baseline |", "|" + "---|" * (len(methods) + 4)]
    for label, d, base in runs:
        pv = {m: (d if m in d["numbers"] else base)["numbers"][m]["per_vehicle"] for m in methods}
        failed = {m: np.asarray(pv[m]["failed"], bool) for m in methods}
        ok = ~np.any(list(failed.values()), 0)
        mean = {m: float(np.asarray(pv[m]["pos_rmse_m"], np.float64)[ok].mean()) for m in methods}
        cells = [f"{mean[m]:.4f} ({pct(1 - failed[m].mean())})" for m in methods]
        out.append(f"| {label} | {int(ok.sum())} | " + " | ".join(cells)
                   + f" | **{mean['cfm_tuned'] / mean['baseline']:.2f}×** | {mean['oracle_cem'] / mean['baseline']:.2f}× |")
    return out


LAG_COLUMNS = {"k_theta": "K_θ (paper)", "k_theta_lag_0.02": "lag-aware (default)",
               "k_theta_lag_0.02_no_thrust_cut": "… without the thrust cut",
               "k_theta_lag_0.02_no_thrust_cut_no_torque_cancel": "… nor the τ_ext cancel",
               "k_theta_lag_0.02_yaw_with_roll_pitch": "… and yaw kept with roll/pitch"}


def lag_rows(lag: dict) -> list[str]:
    cols = [k for k in LAG_COLUMNS if k in lag["default"]]
    out = ["| prior | " + " | ".join(f"{LAG_COLUMNS[k]}: success; RMSE m" for k in cols) + " | same n |",
           "|" + "---|" * (len(cols) + 2)]
    for prior in ("default", "stress", "stress_wide", "slow_actuators"):
        r = lag[prior]
        cells = [f"{pct(r[k]['success'])}; {r[k]['pos_rmse_m_common']:.4f}" for k in cols]
        out.append(f"| {prior} | " + " | ".join(cells) + f" | {r['common_n']} |")
    return out


SLOW = ["baseline", "nominal_cem", "cfm_tuned", "oracle_cem"]
NOMINAL = ["naive", "baseline", "cfm_tuned", "oracle_cem"]


def ratio_over_baseline(d: dict, base: dict, m: str = "cfm_tuned") -> float:
    """m's mean position RMSE over Baseline's on the same vehicles as :func:`merged_rows` (those no
    method of the experiment lost; a method the tune-* run ``d`` lacks comes from ``base``)."""
    methods = SLOW if "nominal_cem" in base["numbers"] else NOMINAL
    pv = {k: (d if k in d["numbers"] else base)["numbers"][k]["per_vehicle"] for k in methods}
    ok = ~np.any([np.asarray(pv[k]["failed"], bool) for k in methods], 0)
    return float(np.asarray(pv[m]["pos_rmse_m"])[ok].mean() / np.asarray(pv["baseline"]["pos_rmse_m"])[ok].mean())


def ratio(d: dict, base: dict, m: str = "cfm_tuned") -> str:
    """:func:`ratio_over_baseline` as the pages print it ("0.71×")."""
    return f"{ratio_over_baseline(d, base, m):.2f}×"
