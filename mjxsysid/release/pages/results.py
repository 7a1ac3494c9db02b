"""docs/results.md and the results table of README.md: the headline figures, each written from its
run file (no number typed by hand), with the paper's figure or the target beside it.

A row is a function of the run files (:class:`~mjxsysid.release.pages.runs.RunFiles`); the README
shows the first :data:`README_ROWS` rows between two markers, the page every row with the run file
it came from and the page that describes the protocol.
"""
from __future__ import annotations

from collections.abc import Callable
from pathlib import Path
from typing import NamedTuple

from mjxsysid.release.layout import DOCS, run_path
from mjxsysid.release.pages.fair_rows import ratio_over_baseline
from mjxsysid.release.pages.runs import RunFiles

PAGE = f"{DOCS}/results.md"
"""The page (relative to a checkout's root)."""
README = "README.md"
BEGIN = "<!-- BEGIN GENERATED results (mjxsysid.release.pages.results): do not edit by hand -->"
END = "<!-- END GENERATED results -->"
README_ROWS = 6


class Row(NamedTuple):
    result: str
    ours: str
    target: str
    page: str          # the docs page (relative to docs/) that describes the protocol
    runs: tuple        # the run files the figures come from (relative to the checkout's root)


def _g(x: float, digits: int = 3) -> str:
    return f"{x:.{digits}g}"


def _met(ok: bool) -> str:
    return "met" if ok else "**missed**"


def _policy(runs: RunFiles) -> Row:
    rel = run_path("policy", "eval.json")
    lem = runs.load(rel)["lemniscate"]
    p, o, n = lem["policy"], lem["oracle"], lem["nominal"]
    ratio = p["pos_rmse_m"]["mean"] / o["pos_rmse_m"]["mean"]
    return Row(f"adaptive policy, {p['n']:,} prior vehicles, 10 s lemniscate: success; position RMSE",
               f"**{100 * p['success_rate']:.0f} %**; {p['pos_rmse_m']['mean']:.3f} m = {ratio:.2f}× the oracle's "
               f"(nominal K_θ {100 * n['success_rate']:.1f} %, {n['pos_rmse_m']['mean']:.3f} m)",
               f"≥ 99 %; ≤ 1.1× the oracle's ({_met(p['success_rate'] >= 0.99 and ratio <= 1.1)})", "policy.md", (rel,))


def _decoders(runs: RunFiles) -> Row:
    rel = run_path("decoders", "decoder_eval.json")
    d = runs.load(rel)
    c, e = d["calibrated_within_5_points"], d["energy_score"]
    return Row(f"CFM decoder, {d['n_cases']:,} held-out pairs: 90 % intervals within ±5 points; energy score ↓",
               f"**{c['90%']} / {c['of']}**; CFM {e['cfm']:.2f}, Regression {e['regression']:.2f}, "
               f"the prior {e['prior']:.2f}",
               f"every quantity; CFM < Regression ({_met(c['90%'] == c['of'] and e['cfm'] < e['regression'])})",
               "decoding.md", (rel,))


def _paper_vehicle(runs: RunFiles) -> Row:
    rel = run_path("decoders", "seq_decoder_eval.json")
    seq = runs.load(rel)["sequence"]
    if "paper_vehicle" not in seq:       # a tiny release flies no paper vehicle
        return Row("paper vehicle, flight-level decoder: thrust-to-weight 5–95 %",
                   "– (this run flew no paper vehicle)", "width/truth ≤ 0.25", "decoding.md", (rel,))
    pv = seq["paper_vehicle"]
    f = pv["flight"]
    t = f["thrust_to_weight"]
    inside = sum(bool(v["inside"]) for v in f.values())
    width = (t["q95"] - t["q05"]) / t["true"]
    return Row(f"paper vehicle after a {pv['flight_s']:g} s lemniscate, flight-level decoder: thrust-to-weight 5–95 %",
               f"{_g(t['q05'])} – {_g(t['q95'])} (truth {_g(t['true'])}; width/truth **{width:.2f}**); "
               f"truth inside for {inside} / {len(f)} quantities",
               f"width/truth ≤ 0.25 ({_met(width <= 0.25)})", "decoding.md", (rel,))


def _log_grounded(runs: RunFiles) -> Row:
    """The default posterior (the SMC refined by NUTS): each log through its sampler's table."""
    return _coverage_row(runs, run_path("log_grounded", "nuts-calibration", "test", "evaluation.json"),
                         "log-grounded posterior (the default: the SMC refined by NUTS), calibrated by simulation")


def _log_grounded_smc(runs: RunFiles) -> Row:
    """The SMC alone (``--no-refine``) through the SMC's table."""
    return _coverage_row(runs, run_path("log_grounded", "calibrated", "test", "evaluation.json"),
                         "log-grounded posterior, the SMC alone (`--no-refine`), calibrated by simulation")


def _coverage_row(runs: RunFiles, rel: str, what: str) -> Row:
    """A calibration's held-out evaluation (``calibrate-posterior --evaluate``'s evaluation.json) as a row."""
    d = runs.load(rel)
    cal, raw = d["calibrated"], d["raw"]
    every = [v for lv in cal.values() for v in lv["coverage"].values() if v == v]
    means = [sum(c for c in lv["coverage"].values() if c == c) / len(lv["coverage"]) for lv in cal.values()]
    raw_clean = sum(raw["clean"]["coverage"].values()) / len(raw["clean"]["coverage"])
    within = sum(0.85 <= v <= 0.95 for v in every)
    return Row(f"{what}; {d['rows']} held-out simulated logs, {len(cal)} noise levels: 90 % coverage",
               f"mean **{min(means):.2f}–{max(means):.2f}** by level (uncalibrated: {raw_clean:.2f} on clean logs); "
               f"every quantity {min(every):.2f}–{max(every):.2f}",
               f"0.85–0.95 for every quantity at every level ({_met(within == len(every))}: {within} of "
               f"{len(every)} within)", "identify.md", (rel,))


def _tune_slow(runs: RunFiles) -> Row:
    rels = [run_path("tuning", k, "results.json") for k in ("tune_slow", "tune_slow_seed7")]
    a, b = ({m: ratio_over_baseline(d, d, m) for m in ("cfm_tuned", "oracle_cem")} for d in map(runs.load, rels))
    return Row("online tuner, slow motors (τ_m 0.05–0.10 s): position RMSE over fixed Baseline gains",
               f"**{a['cfm_tuned']:.2f}×** (seed 0), {b['cfm_tuned']:.2f}× (seed 7); "
               f"Oracle-CEM {a['oracle_cem']:.2f}× / {b['oracle_cem']:.2f}×",
               f"≤ 0.70× (seed 0 {_met(a['cfm_tuned'] <= 0.70)}, seed 7 {_met(b['cfm_tuned'] <= 0.70)}); "
               "the paper 0.77×", "fair_comparisons.md", tuple(rels))


def _fidelity(runs: RunFiles) -> Row:
    rel = run_path("studies", "closed_loop_fidelity.json")
    lg = {k: run_path("log_grounded", "calibrated", "downstream", "fidelity", f"{k}.json") for k in ("log_grounded", "log_grounded_weighed")}
    d = runs.load(rel)
    inside, ratio = d["mean"]["inside_decoded"], d["width_ratio_decoded_over_pm20"]["median"]
    g, w = (runs.load(r) for r in lg.values())
    gi, gr = g["mean"]["inside_decoded"], g["width_ratio_decoded_over_pm20"]["median"]
    wi, wr = w["mean"]["inside_decoded"], w["width_ratio_decoded_over_pm20"]["median"]
    return Row(f"closed-loop fidelity, {d['protocol']['vehicles']} vehicles identified on a held-out flight: "
               "truth inside the 5–95 % envelope; its width over ±20 %, median",
               f"decoded {100 * inside:.0f} %, {ratio:.1f}×; log-grounded {100 * gi:.0f} %, {gr:.0f}× (the log cannot "
               f"see the mass); log-grounded with the mass weighed **{100 * wi:.0f} %, {wr:.2f}×**",
               f"≥ 90 % at ≤ 1.5× (decoded {_met(inside >= 0.90 and ratio <= 1.5)}, weighed {_met(wi >= 0.90 and wr <= 1.5)})",
               "identify.md", (rel, *lg.values()))


def _xadap_replay(runs: RunFiles) -> Row:
    rel = run_path("xadap", "replay", "replay.json")
    pv = runs.load(rel)["flights"]["lemniscate_10s"]["paper_vehicle"]
    cell = ", ".join(f"{name} {pv[k]['rmse']:.3f} / {pv[k]['pcc']:.2f}"
                     for k, name in (("cfm_mean", "CFM (mean action)"), ("regression", "Regression"), ("random", "Random")))
    return Row("action replay, the released XAdap policy, paper vehicle, 10 s lemniscate (RMSE ↓ / PCC ↑)", cell,
               "the paper (hardware): CFM 0.031–0.034, Regression 0.064", "fair_comparisons.md", (rel,))


ROWS: tuple[Callable[[RunFiles], Row], ...] = (_policy, _decoders, _paper_vehicle, _log_grounded, _log_grounded_smc,
                                               _tune_slow, _fidelity, _xadap_replay)
"""Every row, the README's first."""


def rows(root, overlay=None) -> list[Row]:
    runs = RunFiles(root, overlay)
    return [f(runs) for f in ROWS]


def _table(rs: list[Row], link: Callable[[str], str]) -> list[str]:
    return ["| result | ours | paper / target |", "|---|---|---|",
            *(f"| {r.result} ([more]({link(r.page)})) | {r.ours} | {r.target} |" for r in rs)]


def page(root, overlay=None) -> str:
    """docs/results.md's Markdown."""
    rs = rows(root, overlay)
    lines = ["# Results", "",
             "Back to the [overview](index.md). *Generated by `python tools/fair_tables.py` from the run files",
             "named under the table (`mjxsysid.release.pages.results`); do not edit by hand.* Every figure's",
             "protocol and caveats are on the page each row links to; what works and what does not yet:",
             "[status](status.md).", "",
             *_table(rs, lambda p: p), "", "Run files:", "",
             *(f"- {r.result.split(':')[0]}: " + ", ".join(f"`{p}`" for p in r.runs) for r in rs), ""]
    return "\n".join(lines)


def readme(root, overlay=None) -> str:
    """README.md with its results table (between :data:`BEGIN` and :data:`END`) regenerated."""
    text = (Path(root) / README).read_text()
    if BEGIN not in text or END not in text:
        raise ValueError(f"{README} has no generated results block ({BEGIN!r} … {END!r})")
    head, rest = text.split(BEGIN, 1)
    _, tail = rest.split(END, 1)
    table = _table(rows(root, overlay)[:README_ROWS], lambda p: f"docs/{p}")
    return head + BEGIN + "\n" + "\n".join(table) + "\n" + END + tail
