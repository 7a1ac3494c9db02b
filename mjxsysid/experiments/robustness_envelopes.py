"""`mjxsysid experiment robustness` (paper §V-B, DESIGN §7): decoded-model envelopes under force
disturbances, on the paper vehicle and on vehicles of the policy's prior.

The protocol is :func:`mjxsysid.uses.robustness.robustness_study` with
:class:`~mjxsysid.uses.robustness.RobustnessConfig`: :data:`FULL` (one GPU: paper vehicle +
20 prior vehicles, 100 decoded / 100 ±20 % models per step, 100 noise seeds × 20 models per σ)
or :data:`QUICK` (CPU, minutes). The decoders are a parameter (``decoders=DIR``, default the
policy's shipped ones), so the experiment can be re-run when better decoders exist.

Writes results.json, results.md, envelopes.npz (the paper vehicle's step-test traces (axis, model,
time), and per σ the 5/50/95 % population envelopes (axis, quantile, time) and final errors) and
robustness_step_<force>.png, robustness_mc_envelopes.png, robustness_mc_final_hist.png,
robustness_prior_vehicles.png.
"""
from __future__ import annotations

import dataclasses
import sys
import time
from pathlib import Path

import jax
import numpy as np

from mjxsysid import theta as P
from mjxsysid.cfm.load import load_decoders, load_sequence_decoder
from mjxsysid.experiments.common import markdown_table, mean_std, write_results
from mjxsysid.policy.interface import resolve_policy
from mjxsysid.render.plots import plot_error_envelopes, plot_final_histograms
from mjxsysid.uses.fidelity import POSTERIORS
from mjxsysid.uses.robustness import AXES, RobustnessConfig, mc_stats, robustness_study, step_stats

FULL = RobustnessConfig()
QUICK = RobustnessConfig(duration=2.0, n_decoded=16, n_perturbed=16, mc_rollouts=8, mc_models=4, chunk=512)
N_PRIOR = {"full": 20, "quick": 2}

PAPER = {  # what the paper's figures show (it gives no numbers)
    ("step", "lateral"): "true inside the decoded envelope throughout; envelope far tighter than ±20 %",
    ("step", "vertical"): "less well captured: decoded spread wider, offset from the true trace",
    ("mc", "lateral"): "decoded envelopes track the true growth with σ; final histograms closely match",
    ("mc", "vertical"): "decoded broader and shifted, especially at large σ",
}
TARGET_INSIDE = 0.90


def force_label(f) -> str:
    return "[" + ", ".join(f"{x:g}" for x in f) + "] N"


def force_tag(f) -> str:
    return "f" + "_".join(f"{x:g}".replace("-", "m").replace(".", "p") for x in f)


VARIANTS = {"single_latent": "the paper's single-latent CFM p(θ | ẑ) on the identification flight's last "
                             "latent, not the flight-level decoder (window 'instant')",
            "log_grounded": "draws of the log-grounded posterior of the identification flight's IMU and motor "
                            "commands (the flight-level decoded models its proposal) in place of the decoded models; "
                            "their mass, which no IMU log sees, as broad as its physical prior",
            "log_grounded_weighed": "the log_grounded variant's draws with the true mass (a vehicle put on a scale)"}
"""Protocol variants (``mjxsysid experiment robustness --variant V``): the headline uses the
flight-level decoder, chosen after the paper's single-latent CFM missed the paper vehicle's
truth; the variant reports the paper's decoder beside it."""


def run(out, *, quick: bool = False, policy=None, seed: int = 0, progress: bool = True, decoders=None,
        cfg: RobustnessConfig | None = None, n_prior: int | None = None, variant: str | None = None) -> dict:
    """Run the robustness experiment into ``out``; returns the results dict (see
    :func:`~mjxsysid.experiments.common.write_results`). ``cfg`` / ``n_prior`` override the
    quick / full presets; ``decoders``: folder with cfm.npz (default: the policy's);
    ``variant``: one of :data:`VARIANTS` (None: the default protocol)."""
    if variant is not None and variant not in VARIANTS:
        raise ValueError(f"robustness has no variant {variant!r}; choose from {', '.join(VARIANTS)}")
    t0 = time.time()
    log = (lambda m: print(m, file=sys.stderr, flush=True)) if progress else (lambda m: None)
    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    ref = resolve_policy(policy or "mjxsysid")
    cfg = cfg or (QUICK if quick else FULL)
    if variant == "single_latent":
        cfg = dataclasses.replace(cfg, window="instant")
    elif variant in POSTERIORS:
        cfg = dataclasses.replace(cfg, posterior=variant)
    decoder = load_sequence_decoder(decoders, ref, echo=log) if cfg.window == "flight" else None
    if decoder is None:    # window 'instant', or no sequence decoder shipped (then said so)
        decoder, _ = load_decoders(decoders, ref, warn=log)
        cfg = dataclasses.replace(cfg, window="instant")
    dec_dir = Path(decoders) if decoders is not None else ref.decoders_dir
    n_prior = N_PRIOR["quick" if quick else "full"] if n_prior is None else int(n_prior)
    if n_prior < 0:
        raise ValueError(f"n_prior must be >= 0, got {n_prior}")
    key = jax.random.PRNGKey(seed)
    theta = P.PAPER_HARDWARE[None].astype(np.float32)
    if n_prior:
        theta = np.concatenate([theta, np.asarray(P.get_prior(ref.prior).sample(jax.random.fold_in(key, 11), n_prior))])
    res = robustness_study(theta, decoder, ref, cfg, jax.random.fold_in(key, 12), log=log)
    times, onset = res["times"], res["onset"]
    steps = [[step_stats(g, times, onset) for g in per_v] for per_v in res["step"]]
    mcs = [[mc_stats(g, times, onset) for g in per_v] for per_v in res["mc"]]
    numbers = summarize(cfg, res, steps, mcs)

    _plots(out, cfg, res, steps, mcs, ref.label)
    pv_step, pv_mc = res["step"][0], res["mc"][0]
    np.savez_compressed(out / "envelopes.npz", times=times, onset=onset, zhat=res["zhat"][0],
                        **{f"step_{force_tag(f)}_{k}": pv_step[i][k] for i, f in enumerate(cfg.forces)
                           for k in ("true", "decoded", "pm20")},
                        **{f"mc_sigma{s:g}_{k}_q": np.percentile(
                            pv_mc[i][k].reshape(2, -1, len(times)), [5, 50, 95], 1).swapaxes(0, 1)
                           for i, s in enumerate(cfg.sigmas) for k in ("true", "decoded", "pm20")},
                        **{f"mc_sigma{s:g}_{k}_final": pv_mc[i][k][..., -1].reshape(2, -1)
                           for i, s in enumerate(cfg.sigmas) for k in ("true", "decoded", "pm20")})
    config = {"quick": quick, "variant": variant, "n_prior_vehicles": n_prior, "prior": ref.prior, "gains": "baseline",
              "record_every_steps": 5, **dataclasses.asdict(cfg)}
    return write_results(out, "robustness", config=config,
                         seeds={"seed": seed, "prior_key": f"fold_in(PRNGKey({seed}), 11)",
                                "study_key": f"fold_in(PRNGKey({seed}), 12)"},
                         numbers=numbers, table_md=table_md(cfg, numbers), t0=t0, policy=ref,
                         decoders=dec_dir, notes=NOTES + (f"\n\nVariant {variant}: {VARIANTS[variant]}." if variant else ""))


NOTES = """
Protocol: the true vehicle flies an identification flight (a 10 s-period lemniscate, 1 × 1 × 0.3 m, like
the decoder's training flights; as long as the test rollouts); its latents at 10 Hz are decoded into models
by the sequence decoder (the flight-level posterior; config window 'instant': the single-latent CFM on ẑ at
its end), projected to valid θ. Test rollouts start at rest in hover at (0, 0, 1) m under the baseline cascade
and the frozen policy, all with the same key per step test / per noise seed (identical initial condition
and disturbance realisation); errors are scored from the onset (0.5 s) on, at 100 Hz. Prior vehicles get
forces and σ scaled by m / m_paper (the same accelerations). "inside": fraction of time the true error lies
inside the 5–95 % envelope; width ratio: mean decoded envelope width / mean ±20 % envelope width (< 1:
decoded tighter). Monte Carlo: "coverage" = fraction of the true (seed, time) points inside the decoded
population envelope (0.90 if the distributions agree); ED = 1-D energy distance of the final-error
distributions to the true one (m; lower is closer).
"""


def _agg(vals):
    return mean_std(np.asarray([np.nan if v is None else v for v in vals], np.float64))


def summarize(cfg: RobustnessConfig, res: dict, steps, mcs) -> dict:
    """Per-vehicle statistics -> the numbers of results.json (paper vehicle, prior mean ± std)."""
    ok = ~np.asarray(res["id_failed"], bool)
    prior = [i for i in range(1, len(steps)) if ok[i]]
    pv = {"step": {force_label(f): steps[0][i] for i, f in enumerate(cfg.forces)},
          "mc": {f"sigma={s:g} N": mcs[0][i] for i, s in enumerate(cfg.sigmas)},
          "zhat": res["zhat"][0], "id_failed": bool(res["id_failed"][0])}
    pr = {"n": len(steps) - 1, "n_used": len(prior), "id_failed": int((~ok[1:]).sum()), "step": {}, "mc": {},
          "per_vehicle": [{"theta": res["theta_true"][i], "force_scale": float(res["scale"][i]),
                           "id_failed": bool(res["id_failed"][i]),
                           "step": {force_label(f): steps[i][j] for j, f in enumerate(cfg.forces)},
                           "mc": {f"sigma={s:g} N": mcs[i][j] for j, s in enumerate(cfg.sigmas)}}
                          for i in range(1, len(steps))]}
    for j, f in enumerate(cfg.forces):
        pr["step"][force_label(f)] = {a: {k: _agg([steps[i][j][a][k] for i in prior]) for k in steps[0][j][a]}
                                      for a in AXES}
        pr["step"][force_label(f)]["failed_decoded"] = _agg([steps[i][j]["failed"]["decoded"] for i in prior])
    for j, s in enumerate(cfg.sigmas):
        pr["mc"][f"sigma={s:g} N"] = {a: {k: _agg([mcs[i][j][a][k] for i in prior]) for k in mcs[0][j][a]}
                                      for a in AXES}
        pr["mc"][f"sigma={s:g} N"]["failed_decoded"] = _agg([mcs[i][j]["failed"]["decoded"] for i in prior])
    f0 = force_label(cfg.forces[0])
    lat0 = steps[0][0]["lateral"]
    targets = {"paper_vehicle_lateral_inside_ge_0.90": lat0["inside_decoded"] >= TARGET_INSIDE,
               "paper_vehicle_envelope_narrower_than_pm20": lat0["width_ratio"] < 1.0}
    if prior:
        pl = pr["step"][f0]["lateral"]
        targets["prior_mean_lateral_inside_ge_0.90"] = pl["inside_decoded"]["mean"] >= TARGET_INSIDE
        targets["prior_median_width_ratio_lt_1"] = float(np.nanmedian(
            [steps[i][0]["lateral"]["width_ratio"] for i in prior])) < 1.0
    headline = {"step_lateral_inside_decoded": lat0["inside_decoded"], "step_lateral_width_ratio": lat0["width_ratio"],
                "step_lateral_inside_pm20": lat0["inside_pm20"]}
    if prior:
        headline["prior_step_lateral_inside_decoded_mean"] = pr["step"][f0]["lateral"]["inside_decoded"]["mean"]
        headline["prior_step_lateral_width_ratio_median"] = float(np.nanmedian(
            [steps[i][0]["lateral"]["width_ratio"] for i in prior]))
    mid = len(cfg.sigmas) // 2
    headline[f"mc_sigma{cfg.sigmas[mid]:g}_lateral_energy_distance_decoded_m"] = \
        mcs[0][mid]["lateral"]["energy_distance_decoded_m"]
    headline[f"mc_sigma{cfg.sigmas[mid]:g}_lateral_energy_distance_pm20_m"] = \
        mcs[0][mid]["lateral"]["energy_distance_pm20_m"]
    return {"headline": headline, "targets": targets, "paper_vehicle": pv, "prior_vehicles": pr}


def _f(x, d=2):
    return "–" if x is None or (isinstance(x, float) and not np.isfinite(x)) else f"{x:.{d}f}"


def _ms(d, digits=2):
    return "–" if not d or d.get("mean") is None else f"{d['mean']:.{digits}f} ± {d['std']:.{digits}f}"


def table_md(cfg: RobustnessConfig, numbers: dict) -> str:
    pv, pr = numbers["paper_vehicle"], numbers["prior_vehicles"]
    have_prior = pr["n_used"] > 0
    rows = []
    for f in cfg.forces:
        fl = force_label(f)
        for a in AXES:
            s = pv["step"][fl][a]
            p = pr["step"][fl][a] if have_prior else {}
            rows.append([fl, a, PAPER[("step", a)], _f(s["inside_decoded"]), _f(s["inside_pm20"]),
                         f"{s['width_decoded_m'] * 100:.1f} / {s['width_pm20_m'] * 100:.1f}",
                         _f(s["width_ratio"]), _ms(p.get("inside_decoded")), _ms(p.get("width_ratio"))])
    t1 = markdown_table(["step", "error", "paper (figure)", "inside decoded (paper vehicle)", "inside ±20 %",
                         "width decoded / ±20 % (cm)", "width ratio", f"prior vehicles: inside decoded (n={pr['n_used']})",
                         "prior: width ratio"], rows)
    rows = []
    for s in cfg.sigmas:
        sl = f"sigma={s:g} N"
        for a in AXES:
            m = pv["mc"][sl][a]
            p = pr["mc"][sl][a] if have_prior else {}
            rows.append([f"{s:g} N", a, PAPER[("mc", a)], _f(m["coverage_decoded"]), _f(m["inside_decoded_per_seed"]),
                         _f(m["width_ratio_decoded"]), _f(m["width_ratio_pm20"]),
                         f"{m['energy_distance_decoded_m'] * 100:.2f} / {m['energy_distance_pm20_m'] * 100:.2f}",
                         _ms(p.get("coverage_decoded")),
                         _ms({k: None if v is None else v * 100 for k, v in p["energy_distance_decoded_m"].items()})
                         if p else "–",
                         _ms({k: None if v is None else v * 100 for k, v in p["energy_distance_pm20_m"].items()})
                         if p else "–"])
    t2 = markdown_table(["σ", "error", "paper (figure)", "coverage decoded (paper vehicle)", "inside per seed",
                         "width decoded / true", "width ±20 % / true", "ED final: decoded / ±20 % (cm)",
                         "prior: coverage decoded", "prior: ED decoded (cm)", "prior: ED ±20 % (cm)"], rows)
    tg = "\n".join(f"- {k}: **{'met' if v else 'missed'}**" for k, v in numbers["targets"].items())
    return (f"## Step disturbances ({cfg.n_decoded} decoded, {cfg.n_perturbed} ±{cfg.perturbation:.0%} models)\n\n"
            f"{t1}\n## Monte Carlo, Gaussian forces ({cfg.mc_rollouts} seeds × {cfg.mc_models} models)\n\n{t2}\n"
            f"## Targets (lateral inside ≥ 0.90, envelope narrower than ±20 %)\n\n{tg}\n")


def _plots(out: Path, cfg, res, steps, mcs, label: str):
    t = res["times"]
    pv = res["step"][0]
    for i, f in enumerate(cfg.forces):
        g = pv[i]
        notes = [[f"inside decoded {steps[0][i][a]['inside_decoded']:.2f}, ±20 % "
                  f"{steps[0][i][a]['inside_pm20']:.2f}\nwidth ratio {steps[0][i][a]['width_ratio']:.2f}"]
                 for a in AXES]
        plot_error_envelopes(t, g["true"][:, None], {"decoded": g["decoded"][:, None], "±20 %": g["pm20"][:, None]},
                             out / f"robustness_step_{force_tag(f)}.png", onset=cfg.onset, notes=notes,
                             title=f"step {force_label(f)} from {cfg.onset:g} s, paper vehicle, {label}")
    mc = res["mc"][0]
    cols = [f"σ = {s:g} N" for s in cfg.sigmas]
    n_s = len(cfg.sigmas)
    ens = {k: np.stack([np.stack([mc[j][k][a].reshape(-1, len(t)) for j in range(n_s)]) for a in range(2)])
           for k in ("decoded", "pm20")}
    true = np.stack([np.stack([mc[j]["true"][a] for j in range(n_s)]) for a in range(2)])
    notes = [[f"coverage {mcs[0][j][a]['coverage_decoded']:.2f}\nwidth ratio "
              f"{mcs[0][j][a]['width_ratio_decoded']:.2f}" for j in range(n_s)] for a in AXES]
    plot_error_envelopes(t, true, {"decoded": ens["decoded"], "±20 %": ens["pm20"]},
                         out / "robustness_mc_envelopes.png", cols=cols, onset=cfg.onset, notes=notes,
                         title=f"Gaussian force disturbances, paper vehicle: {cfg.mc_rollouts} true rollouts vs "
                               f"{cfg.mc_models} models per seed")
    finals = {"decoded": ens["decoded"][..., -1], "±20 %": ens["pm20"][..., -1], "true": true[..., -1]}
    notes = [[f"ED decoded {mcs[0][j][a]['energy_distance_decoded_m'] * 100:.2f} cm\nED ±20 % "
              f"{mcs[0][j][a]['energy_distance_pm20_m'] * 100:.2f} cm" for j in range(n_s)] for a in AXES]
    plot_final_histograms(finals, out / "robustness_mc_final_hist.png", cols=cols, notes=notes,
                          title=f"final errors at {cfg.duration:g} s, paper vehicle")
    _plot_prior(out / "robustness_prior_vehicles.png", cfg, steps, mcs)


def _plot_prior(path, cfg, steps, mcs):
    """Per vehicle: step inside-fraction vs width ratio; MC energy distances decoded vs ±20 %."""
    from matplotlib.figure import Figure
    fig = Figure(figsize=(11, 4.2), layout="constrained")
    a, b = fig.subplots(1, 2)
    for j, f in enumerate(cfg.forces):
        x = [s[j]["lateral"]["width_ratio"] for s in steps]
        y = [s[j]["lateral"]["inside_decoded"] for s in steps]
        a.scatter(x[1:], y[1:], s=18, color=f"C{j}", label=f"{force_label(f)}, prior vehicles")
        a.scatter(x[:1], y[:1], s=90, marker="*", color=f"C{j}", edgecolor="k", label=f"{force_label(f)}, paper vehicle")
    a.axhline(TARGET_INSIDE, color="0.5", ls=":")
    a.axvline(1.0, color="0.5", ls=":")
    a.set_xscale("log")
    a.set_xlabel("lateral envelope width, decoded / ±20 %")
    a.set_ylabel("time fraction true lateral error inside decoded 5–95 %")
    a.set_title("step disturbances, ★ paper vehicle (target: upper left)", fontsize=10)
    a.legend(fontsize=7)
    for j, s in enumerate(cfg.sigmas):
        x = [m[j]["lateral"]["energy_distance_pm20_m"] for m in mcs]
        y = [m[j]["lateral"]["energy_distance_decoded_m"] for m in mcs]
        b.scatter(x[1:], y[1:], s=18, color=f"C{j}", label=f"σ = {s:g} N")
        b.scatter(x[:1], y[:1], s=90, marker="*", color=f"C{j}", edgecolor="k")
    lim = [v for m in mcs for j in range(len(cfg.sigmas)) for v in
           (m[j]["lateral"]["energy_distance_pm20_m"], m[j]["lateral"]["energy_distance_decoded_m"]) if v and v > 0]
    if lim:
        b.plot([min(lim), max(lim)], [min(lim), max(lim)], color="0.5", ls=":")
        b.set_xscale("log")
        b.set_yscale("log")
    b.set_xlabel("energy distance of final lateral error, ±20 % vs true (m)")
    b.set_ylabel("decoded vs true (m)")
    b.set_title("Monte Carlo, ★ paper vehicle (below the diagonal: decoded closer)", fontsize=10)
    b.legend(fontsize=7)
    path = Path(path)
    fig.savefig(path, dpi=110)
    return path
