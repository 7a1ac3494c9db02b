"""docs/fair_comparisons.md: every comparison both ways, written from the run files (no number
on the page is typed by hand).

It reads only JSON under docs/runs/ (the folders of [layout][mjxsysid.release.layout]): the runs
of today's protocol in their folders per kind, those of the previous protocol in its archive
and the tune-* runs whose tuner started the rotors at the last command's steady state in theirs
(the page shows each changed comparison both ways),
and the shipped decoders' provenance. A release's tables stage builds it over the release's own
run files (``overlay``).
"""
from __future__ import annotations

from pathlib import Path


from mjxsysid.release.layout import DOCS, pretrained_path, run_path
from mjxsysid.release.pages.fair_rows import (
    decoder_rows,
    fidelity_rows,
    lag_rows,
    lemniscate_rows,
    merged_rows,
    pct,
    policy_rows,
    ratio,
    replay_rows,
    robustness_rows,
    stamp,
    tune_rows,
)
from mjxsysid.release.pages.runs import RunFiles
from mjxsysid.release.runs import TUNE_RUNS

PAGE = f"{DOCS}/fair_comparisons.md"
"""The page (relative to a checkout's root)."""
ISSUE26_RUNS = tuple(r.folder for runs in TUNE_RUNS.values() for r in runs)
"""The tune-* runs of §7: every run of the release's tune stages."""


def issue26_section(t: dict, lag: dict, lag1k: dict, heldout: dict) -> list[str]:
    slow, slow7 = t["tune_slow"], t["tune_slow_seed7"]
    return [
        "## 7. Each model's predictions start from the rotor state it implies",
        "",
        "The tuner started every predictive rollout with each model's rotors at the steady state of the last",
        "motor command; with τ_m 0.05–0.10 s the real rotors are far from it. Now each of the K models runs",
        "*its own* motor lag (τ_m, Ω_max) over the last 0.6 s of commands the controller sent",
        "(`tune.rotor_state.estimate_rotor_speed`; no hidden state read) and the rigid twin carries the IMU latency",
        "buffer. With the true θ a prediction then reproduces the flight to float round-off",
        "([figure](runs/measurements/prediction-error/prediction_error.png), `mjxsysid experiment prediction-error`; tests in",
        "`tests/tune/test_tune.py`). Same vehicles and seeds as the default protocol; Baseline and Nominal+CEM of",
        "a variant run that did not fly them come from the default run of the same seed (their flights do not",
        (f"depend on the tuner's knobs). One {slow['device']['device_kind'].split(' 80GB')[0]}, {slow['date'][:10]}, "
        f"code of commit {str(slow['commit']).split()[0][:10]} (the run files' commit field; the tuner is that of 5144f62)."),
        "",
        "tune-slow (τ_m 0.05–0.10 s, 100 vehicles), the default protocol on two seeds and every knob measured:",
        "",
        *merged_rows([("**seed 0, rotor estimate (default)**", slow, slow),
                      ("**seed 7, rotor estimate (default)**", slow7, slow7),
                      ("seed 0, true rotor speeds (`--variant true_rotor_state`, a diagnostic)", t["tune_slow_true_rotor_state"], slow),
                      ("seed 0, steady state of the last command (`steady_rotor_state`, as before)", t["tune_slow_steady_rotor_state"], slow),
                      ("seed 0, rotor estimate, heading term (`heading_cost`)", t["tune_slow_heading_cost"], slow),
                      ("seed 0, rotor estimate, tuner from Baseline gains (`baseline_start`)", t["tune_slow_baseline_start"], slow),
                      ("seed 7, rotor estimate, tuner from Baseline gains (`baseline_start`)", t["tune_slow_seed7_baseline_start"], slow7)],
                     ["baseline", "nominal_cem", "cfm_tuned", "oracle_cem"]),
        "",
        "tune-nominal (default prior, 100 vehicles):",
        "",
        *merged_rows([("**rotor estimate (default)**", t["tune_nominal"], t["tune_nominal"]),
                      ("tuner from Baseline gains (`baseline_start`)", t["tune_nominal_baseline_start"], t["tune_nominal"]),
                      ("switch only when 75 % of the models agree (`protect`)", t["tune_nominal_protect"], t["tune_nominal"])],
                     ["naive", "baseline", "cfm_tuned", "oracle_cem"]),
        "",
        "tune-lemniscate (paper vehicle, hardware IMU):",
        "",
        *lemniscate_rows([("with the 2 s lead-in (default)", t["tune_lemniscate"]),
                          ("no lead-in (`no_lead_in`)", t["tune_lemniscate_no_lead_in"]),
                          ("no lead-in, tuner from Baseline gains (`no_lead_in,baseline_start`)",
                           t["tune_lemniscate_no_lead_in_baseline_start"])]),
        "",
        "What the tables say:",
        "- **The start of the prediction was the fault.** On tune-slow seed 0 the rotor estimate takes CFM-tuned",
        (f"  from {ratio(t['tune_slow_steady_rotor_state'], slow)} to {ratio(slow, slow)} Baseline's RMSE and Oracle-CEM from "
        f"{ratio(t['tune_slow_steady_rotor_state'], slow, 'oracle_cem')} to {ratio(slow, slow, 'oracle_cem')}; seed 7: "
        f"{ratio(slow7, slow7)} and {ratio(slow7, slow7, 'oracle_cem')} (targets ≤ 0.70× and ≤ 0.6×; the paper 0.77×)."),
        "  Starting every model from the *true* rotor speeds is worse for the decoded ensemble",
        f"  ({ratio(t['tune_slow_true_rotor_state'], slow)}): a model whose τ_m differs from the truth predicts",
        "  better from the rotor state its own lag implies than from a state it could not have reached.",
        "- tune-nominal: CFM-tuned " + ratio(t["tune_nominal"], t["tune_nominal"]) + " Baseline (target ≤ 0.85×: missed), Oracle-CEM "
        + ratio(t["tune_nominal"], t["tune_nominal"], "oracle_cem") + " (≤ 0.8×: met). Started from the Baseline gains",
        "  the tuner reaches " + ratio(t["tune_nominal_baseline_start"], t["tune_nominal"]) + " — a knob chosen after seeing the",
        "  default's result, so the default stays the paper's (the tuner starts from the Naive gains) and both are shown.",
        "- tune-lemniscate: CFM-tuned beats Baseline at every period with the lead-in; launched onto the moving",
        "  reference from the Naive gains it loses about 2× (Oracle-CEM as much: the start, not the models);",
        "  started from the Baseline gains it beats Baseline at every period there too.",
        "- Protecting the incumbent (switch only when 75 % of the models agree) changed nothing measurable on",
        "  tune-nominal. Applying the best candidate instead of the mean (`apply_best`), 3 CEM iterations and a",
        "  1 s horizon are implemented as variants but have not been run.",
        "",
        "The lag-aware oracle (`control.low_level.KThetaLag`) against the paper's K_θ, both with the true θ",
        "and the Baseline cascade, 10 s lemniscate. It runs θ's motor lag over its own commands and asks each",
        "rotor for the speed that moves it as a τ_m = 0.02 s motor would; it cancels the known external torque",
        "τ_ext; where a rotor saturates its mixer gives up yaw torque first, then up to 20 % of the collective",
        "thrust, before roll/pitch torque. The final design and its ablations, 128 vehicles per prior (the",
        f"lag-oracle experiment at 128 vehicles, `lag_oracle_cpu128.json`, {lag['config']['device']}, {lag['config']['date']}):",
        "",
        *lag_rows(lag),
        "",
        "An earlier design (no τ_ext cancel, no thrust cut), 1,000 vehicles per prior on one H100",
        f"(`--vehicles 1000`, {lag1k['config']['date']}; its columns: the paper's K_θ, that design, and the same keeping",
        "yaw with roll/pitch):",
        "",
        *lag_rows({p: {({"k_theta_lag_0.02": "k_theta_lag_0.02_no_thrust_cut_no_torque_cancel"}.get(k, k)): v
                       for k, v in r.items()} for p, r in lag1k.items() if p != "config"}),
        "",
        (f"The final design flies {pct(lag['stress_wide']['k_theta_lag_0.02']['success'])} of `stress_wide` (K_θ "
        f"{pct(lag['stress_wide']['k_theta']['success'])}) on these 128 draws and {heldout['stress_wide']['oracle_success']:.1%} of the "
        f"{heldout['stress_wide']['vehicles']['n']} drawn for the held-out evaluation (`docs/runs/measurements/held-out/probing/`): the target (≥ 90 %) is met on one"),
        "sample and missed by a vehicle on the other — at the edge, not clearly met. The vehicles it loses need",
        "80–98 % of Ω_max on their weakest rotor just to hover. It is no worse than K_θ",
        "on the default prior. It is the `oracle` of flights, policy evaluations and the probe",
        "(`k_theta` names the paper's K_θ, still the action-replay probe); the policy tables elsewhere in the",
        "docs were made with K_θ as the oracle (on the default prior the two differ by about 5 % in RMSE).",
        "",
    ]



def made_by(d: dict, default: str) -> str:
    """Who made a run file: the release whose decoder set it used (``release DIR``, the device,
    date and commit), or ``default`` (the script that made the older runs) with date and commit."""
    dec = str((d.get("decoders") or {}).get("dir", ""))
    dev = (d.get("device") or {}).get("device_kind", "?").split(" 80GB")[0]
    if dec.endswith("decoder_set"):
        return f"`mjxsysid release` (`{Path(dec).parent.name}`), one {dev}, {stamp(d)}"
    return f"{default}, one {dev}, {stamp(d)}"


def page(root, overlay=None) -> str:
    """The page's Markdown, from the run files of the checkout at ``root`` (its docs/runs/ and
    mjxsysid/pretrained/ JSON). ``overlay``: a tree laid out like the checkout whose run files
    replace the checkout's (a release's, before it ships: its tables stage)."""
    runs = RunFiles(root, overlay)
    load = runs.load
    old = {k: load(run_path("previous_protocol", k, "results.json"))
           for k in ("tune_nominal", "tune_slow", "tune_lemniscate", "robustness", "replay")}
    new = {k: load(run_path("studies", k, "results.json")) for k in ("robustness", "robustness_single_latent", "replay")}
    # the archived tune-* runs of sections 1 and 6a (the rotors started at the last command's steady state)
    new.update({k: load(run_path("issue22_tuning", k, "results.json"))
                for k in ("tune_nominal", "tune_slow", "tune_slow_heading_cost", "tune_lemniscate",
                          "tune_lemniscate_no_lead_in")})
    t26 = {k: load(run_path("tuning", k, "results.json")) for k in ISSUE26_RUNS}
    lag = load(run_path("lag_oracle", "lag_oracle_cpu128.json"))
    lag1k = load(run_path("lag_oracle", "lag_oracle.json"))
    nobc_replay = load(run_path("nobc", "replay", "results.json"))
    fid = load(run_path("studies", "closed_loop_fidelity.json"))
    fid_same = load(run_path("studies", "closed_loop_fidelity_same_flight.json"))
    fid_old = load(run_path("previous_protocol", "closed_loop_fidelity.json"))
    dec_old = load(run_path("previous_protocol", "decoder_eval.json"))
    dec_new = load(run_path("decoders", "decoder_eval.json"))
    dec_nobc = load(run_path("nobc", "dec", "decoder_eval.json"))
    pol = load(run_path("policy", "eval.json"))
    pol_nobc = load(run_path("nobc", "eval", "eval.json"))
    shipped_reg = load(pretrained_path("regression.json"))
    xadap_reg = load(pretrained_path("xadap", "regression.json"))
    xadap_dec = load(run_path("xadap", "dec", "decoder_eval.json"))
    xadap_replay = load(run_path("xadap", "replay", "replay.json"))
    s_slow = new["tune_slow"]["numbers"]["ratios"]
    s_old = old["tune_slow"]["numbers"]["ratios"]

    L = ["# Fair comparisons: every comparison both ways",
         "",
         "Back to the [overview](index.md). *Generated by `python tools/fair_tables.py` from the run files in",
         "`docs/runs/archive/previous_protocol/` (the previous protocol) and today's in `docs/runs/release/` and `docs/runs/measurements/`",
         f"({made_by(new['robustness'], '`tools/archive/fair_baselines.sh OUT regression tune heading lemniscate robustness replay fidelity nobc`')};",
         f"the tune-* runs of sections 1 and 6a in `docs/runs/archive/issue22_tuning/`, {stamp(new['tune_slow'])};",
         f"the tune-* runs of section 7 by {made_by(t26['tune_slow'], '`tools/archive/gpu_tune.sh`')}; a release",
         "(`mjxsysid release`) regenerates today's); do not edit by hand.*",
         "",
         "A line-by-line reading of the code against the paper found six places where a comparison favoured",
         "mjxsysid's decoders for reasons unrelated to decoding. Each is fixed (the default is now the paper's",
         "definition) or shown both ways below. **Which comparisons are comparable with the paper:** the tuning",
         "experiments with the default protocol (own-nominal Nominal+CEM, the paper's cost); the decoder",
         "scores with the early-stopped Regression; action replay only for the policy trained without",
         "imitation (the shipped policy imitates K_θ, the replay's probe); closed-loop fidelity only as the",
         "held-out figure. Our vehicles are simulated, the paper's are hardware: absolute numbers differ by",
         "design (our Baseline tracks 5–20× better than the paper's), so compare ratios and orderings.",
         "",
         "## 1. Nominal+CEM on each vehicle's own nominal system; 4. the tuner's cost",
         "",
         "*The tables of sections 1 and 6a are archived runs (`docs/runs/archive/issue22_tuning/`) whose tuner started",
         "its predictions with the rotors at the steady state of the last command. Section 7 has today's.*",
         "",
         "The paper's ablation is \"the same CEM tuner over the nominal system with ±20 % parameter",
         "perturbations\". Before, every randomised vehicle (masses 0.05–2.6 kg) was tuned on copies of the",
         "*paper vehicle*. Now (`tune.tuner.nominal_theta`) each vehicle's own θ with its motor time",
         "constant set to the nominal τ_m = 0.03 s (the default prior's mid-point, fixed, not drawn), each",
         "entry × U(0.8, 1.2). The tuner's cost was position RMSE + saturation + failure + **0.1 × heading",
         "RMSE**; the paper's cost has no heading term, so the default is now `CostWeights(heading=0.0)` and",
         "the heading term is `--variant heading_cost`. Same vehicles, same seeds; \"same n\": vehicles no",
         "method lost.",
         "",
         "tune-slow (τ_m 0.05–0.10 s, 100 vehicles):",
         "",
         *tune_rows([("before: paper-vehicle nominal, heading term (" + stamp(old["tune_slow"]) + ")", old["tune_slow"]),
                     ("own nominal, heading term (`--variant heading_cost`)", new["tune_slow_heading_cost"]),
                     ("**own nominal, the paper's cost (default)**", new["tune_slow"])],
                    ["baseline", "nominal_cem", "cfm_tuned", "oracle_cem"]),
         "",
         "tune-nominal (default prior, 100 vehicles; no Nominal+CEM in this experiment):",
         "",
         *tune_rows([("before: heading term (" + stamp(old["tune_nominal"]) + ")", old["tune_nominal"]),
                     ("**the paper's cost (default)**", new["tune_nominal"])],
                    ["naive", "baseline", "cfm_tuned", "oracle_cem"]),
         "",
         "What changed:",
         "- **A previous claim no longer holds: on slow actuators CFM-tuned does not beat Baseline.** With the",
         f"  paper's cost it is {s_slow['cfm_over_baseline']:.2f}× Baseline's RMSE on the same vehicles (before:",
         f"  {s_old['cfm_over_baseline']:.2f}×), and loses more vehicles ({pct(new['tune_slow']['numbers']['cfm_tuned']['success_rate'])} vs",
         f"  {pct(new['tune_slow']['numbers']['baseline']['success_rate'])}). Even tuning on the true θ (Oracle-CEM) is worse than",
         "  Baseline here: the policy with baseline gains already flies these vehicles well, and a short-horizon",
         "  cost without a heading term picks aggressive gains that fail more often.",
         (f"- CFM-tuned still beats the fair Nominal+CEM ({s_slow['cfm_over_nominal_cem']:.2f}× its RMSE, "
         f"{pct(new['tune_slow']['numbers']['cfm_tuned']['success_rate'])} vs {pct(new['tune_slow']['numbers']['nominal_cem']['success_rate'])}"),
         "  success): planning on the decoded models, not the optimiser alone, is what the margin comes from.",
         "  Own-nominal Nominal+CEM is *worse* than the paper-vehicle one was: its nominal τ_m (0.03 s) is",
         "  2–3× too fast for these vehicles, so its planned gains are too aggressive.",
         "- The heading term was doing real work: without it the tuned controllers' heading RMSE rises",
         ("  (last column), and on tune-slow it is the difference between CFM-tuned "
         f"{new['tune_slow_heading_cost']['numbers']['ratios']['cfm_over_baseline']:.2f}× and {s_slow['cfm_over_baseline']:.2f}× Baseline."),
         (f"- tune-nominal keeps its result: CFM-tuned {new['tune_nominal']['numbers']['ratios']['cfm_over_baseline']:.2f}× Baseline "
         f"(before {old['tune_nominal']['numbers']['ratios']['cfm_over_baseline']:.2f}×), at the price of heading, which the paper's cost ignores."),
         "",
         "## 6a. tune-lemniscate with and without the hover lead-in",
         "",
         "The 2 s hover at the start point was added after a run in which CFM-tuned lost to Baseline about",
         "2×. Both protocols, paper vehicle, three cycles scored (the paper's cost, the default):",
         "",
         *lemniscate_rows([("with the 2 s lead-in (default)", new["tune_lemniscate"]),
                           ("no lead-in (`--variant no_lead_in`)", new["tune_lemniscate_no_lead_in"]),
                           ("before: lead-in, heading term (" + stamp(old["tune_lemniscate"]) + ")", old["tune_lemniscate"])]),
         "",
         "Without the lead-in the CEM methods start from naive gains on a reference already moving and lose",
         "about 2× on the whole flight; Oracle-CEM (true θ) loses exactly as much, so it is the take-off",
         "transient, not the decoded models. The last cycle (results.md) is better than Baseline under both.",
         "",
         *issue26_section(t26, lag, lag1k, load(run_path("held_out", "probing", "results.json"))["numbers"]["evaluation"]),
         "## 6b. Robustness: the flight-level decoder and the paper's single-latent CFM",
         "",
         *robustness_rows([("flight-level (sequence) decoder (default)", new["robustness"]),
                           ("single-latent CFM, the paper's (`--variant single_latent`)", new["robustness_single_latent"])]),
         "",
         "With the paper's single-latent CFM the paper vehicle's true lateral error leaves the decoded",
         "envelope almost at once: the headline (\"true inside\") holds only for the flight-level decoder,",
         "which pools 10 s of latents. Both are reported in `docs/runs/release/studies/robustness*/`.",
         "",
         "## 3. Regression with early stopping",
         "",
         "The paper fixes the Regression baseline's architecture, not its training length. It is now trained",
         "with early stopping: the epoch with the lowest loss on 10 % of the training pairs is kept",
         (f"(`train_regression(early_stopping=True)`; best epoch {shipped_reg['early_stopping']['best_epoch']} of "
         f"{shipped_reg['config']['epochs']} for the shipped one, `mjxsysid/pretrained/regression.json`)."),
         "",
         *decoder_rows([("before: Regression trained to epoch 100", dec_old),
                        ("**early-stopped Regression (shipped)**", dec_new),
                        ("no-imitation policy's decoders (below)", dec_nobc)]),
         "",
         ("CFM keeps a clear lead on the energy score, but the margin shrinks from "
         f"{dec_old['energy_score']['regression'] / dec_old['energy_score']['cfm']:.2f}× to "
         f"{dec_new['energy_score']['regression'] / dec_new['energy_score']['cfm']:.2f}×. (The pairs were re-collected with"),
         "the same protocol, seed and policy on a different GPU; they are not bitwise the shipped CFM's.)",
         "",
         "## 2. Action replay without imitation",
         "",
         "The shipped policy is trained with behaviour cloning from K_θ(true θ) (weight 2 → 0.05), and K_θ is",
         "the replay's probe, so its replay figures partly measure imitation. A policy trained with the",
         "imitation weight 0 for the last half of training (`tools/configs/policy_no_bc.json`: `bc_final 0`,",
         "`bc_decay 0.5`; PPO + latent alignment alone, the paper's eq. 5, after that) was trained and",
         "evaluated like the shipped one:",
         "",
         *policy_rows([("shipped (`mjxsysid/pretrained/policy.npz`)", "2 → 0.05 (never 0)", pol),
                       ("no imitation at the end (`docs/runs/measurements/nobc/`)", "2 → 0 by mid-training", pol_nobc)]),
         "",
         f"It flies every vehicle but at {pol_nobc['lemniscate']['rmse_ratio_policy_over_oracle']:.2f}× the oracle's RMSE (the bar",
         "for shipping it was ≤ 1.1×), and its decoders are less well calibrated; **it is not shipped**.",
         "Action replay, paper vehicle (motor-command RMSE ↓ / PCC ↑; prior vehicles in results.md):",
         "",
         *replay_rows([("shipped policy, Regression to epoch 100 (" + stamp(old["replay"]) + ")",
                        old["replay"]["numbers"]["flights"]),
                       ("shipped policy, early-stopped Regression", new["replay"]["numbers"]["flights"]),
                       ("**no-imitation policy and its decoders (comparable with the paper)**",
                        nobc_replay["numbers"]["flights"])], paper=new["replay"]["numbers"]["paper"]),
         "",
         "- With an early-stopped baseline, Regression matches or beats single-sample CFM on the shipped",
         "  policy's replay RMSE; the earlier \"CFM beats Regression on every flight\" no longer holds.",
         "- Without imitation the policy's actions are no longer close to K_θ: even the true θ gives RMSE",
         "  0.04–0.09 (shipped policy: 0.015–0.04). CFM (mean action) is within 0.01 of the true θ and of",
         "  Regression; single-sample CFM is slightly worse than Regression. The paper's hardware result",
         "  (CFM 0.032–0.034 far below Regression 0.059–0.073) is **not reproduced** in this comparable setting.",
         "",
         "### The released XAdap policy's Regression",
         "",
         "The XAdap decoders (a policy mjxsysid did not train, no imitation of K_θ involved) had the same",
         "over-trained Regression. Retrained with early stopping (`XADAP_WEIGHTS=W tools/archive/fair_baselines.sh",
         (f"OUT xadap`; best epoch {xadap_reg['early_stopping']['best_epoch']} of {xadap_reg['config']['epochs']}; "
         "shipped in `mjxsysid/pretrained/xadap/`), beside its shipped CFM:"),
         "",
         *decoder_rows([("XAdap, Regression to epoch 100", load(run_path("previous_protocol", "xadap_decoder_eval.json"))),
                        ("**XAdap, early-stopped Regression (shipped)**", xadap_dec)]),
         "",
         "Action replay of the released policy, paper vehicle (motor-command RMSE ↓ / PCC ↑):",
         "",
         *replay_rows([("XAdap, Regression to epoch 100", load(run_path("previous_protocol", "xadap_replay.json"))["flights"]),
                       ("**XAdap, early-stopped Regression**", xadap_replay["flights"])]),
         "",
         "- The early-stopped Regression is still worse than the prior itself on the energy score, but in",
         "  action replay it now ties CFM's mean action on RMSE (and beats single-sample CFM on the 10 s, 15 s",
         "  and hover flights); CFM's mean action keeps the best PCC of the three decoders on every flight. Over the 32 prior vehicles",
         "  (`docs/runs/measurements/xadap/replay/replay.md`) Regression has the lowest RMSE on every flight.",
         "",
         "## 5. Closed-loop fidelity on a held-out identification flight",
         "",
         "The benchmark decoded latents from the same disturbed flight it then predicted. It now identifies",
         "on a separate undisturbed flight (a 10 s lemniscate, as the robustness experiment does;",
         "`benchmarks/closed_loop_fidelity.py --identification held_out`, the default):",
         "",
         *fidelity_rows([("before (same flight)", fid_old), ("**held out (default)**", fid),
                         ("same flight, re-run", fid_same)]),
         "",
         "The held-out figure is about the same as the same-flight one (the decoded envelopes are a little",
         "narrower): the \"85 % inside\" claim survives as a held-out figure, still short of the 90 % target.",
         "",
    ]
    return "\n".join(L)
