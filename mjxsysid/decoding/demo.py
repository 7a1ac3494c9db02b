"""`mjxsysid demo`: the CPU quick start.

Flies the paper's hardware vehicle on the 10 s 3-D lemniscate with the oracle (the lag-aware K_θ
with the true θ), then a handful of vehicles from the prior under the oracle and the
non-adaptive nominal K_θ (the
adaptation problem mjxsysid exists for), and writes plots, a video and a one-page summary.
The paper vehicle's latents are decoded at ``DEMO_DECODES`` times of the flight by the
single-latent CFM (instant) and, every ``FLIGHT_EVERY_S`` s, by the sequence decoder given every
latent so far (flight-level; unavailable, and said so, where the policy ships no ``cfm_seq.npz``).
The same flight's IMU and motor commands are then read as a log: the log-grounded posterior
(:func:`mjxsysid.decoding.ground_in_log`, the decoded samples its proposal) and the
information gap between the two (``--decoder-only`` skips it).
"""
from __future__ import annotations

import time
from pathlib import Path

import jax
import numpy as np

from mjxsysid.runtime import jsonout
from mjxsysid import theta as P
from mjxsysid.cfm.load import load_decoders, load_sequence_decoder
from mjxsysid.cfm.posterior import summarize_posterior
from mjxsysid.identify.gap import gap_markdown
from mjxsysid.policy.interface import resolve_policy
from mjxsysid.runtime.progress import echo, stages
from mjxsysid.render.plots import plot_trajectory
from mjxsysid.render.posterior import plot_decoded_over_time, plot_information_gap, plot_marginals
from mjxsysid.render.video import render_rollout
from mjxsysid.rollout.flight import flight_log, fly_vehicles, one_flight, save_flight
from mjxsysid.rollout.harness import metrics_to_host
from mjxsysid.decoding import decode_latents, ground_in_log


FLIGHT_EVERY_S = 1.0
"""The demo samples the flight-level posterior every this many seconds of the flight (its first
and last decode times included: 11 times of a 10 s flight, one batch)."""

DEMO_DECODES = 11
"""The instant posterior's decode times in the demo (evenly spaced over the 10 Hz latents, the last
included): about one a second. ``decode`` takes up to ``MAX_DECODES`` (30); the demo's figure
needs fewer, and each time is 200 samples of a 2.5 M-parameter flow (BENCHMARKS.md)."""


VIDEO_FPS = 15
"""Frames per second of the demo's video: 150 frames of the 10 s flight. Offscreen rendering on a
CPU (Mesa) costs about 0.13 s a frame with the ghosts, trail and reference: at 25 fps the video would
be a third of the demo's warm time (BENCHMARKS.md)."""


def flight_level_info(dec: dict, seq, ref) -> dict:
    """What the summary says about the flight-level posterior: its decoder, times and number of
    latents, or that it is unavailable (no ``cfm_seq.npz`` beside the policy's decoders)."""
    if seq is None:
        return {"available": False, "decoder": str(ref.decoders_dir / "cfm_seq.npz"),
                "note": f"Flight-level posterior unavailable: no sequence decoder `cfm_seq.npz` in "
                        f"`{ref.decoders_dir}` for policy {ref.label}; the flight-level columns are empty."}
    n = int(dec["n_window"][-1])
    return {"available": True, "decoder": str(ref.decoders_dir / "cfm_seq.npz"),
            "every_s": FLIGHT_EVERY_S, "times_s": [round(float(x), 3) for x in dec["times_window"]],
            "n_latents": n, "max_trained_latents": int(seq.max_len),
            "note": f"Flight-level: {n} latents (10 Hz from 0.2 s to {float(dec['times_window'][-1]):.1f} s; "
                    f"the sequence decoder was trained on 1 to {seq.max_len}; longer flights extrapolate), "
                    f"decoded every {FLIGHT_EVERY_S:g} s."}


def decoded_caption(info: dict, n_decodes: int) -> str:
    """The line above ``decoded_over_time.png``: what its bands are (the instant posterior at
    ``n_decodes`` times)."""
    head = f"paper vehicle, 10 s lemniscate: instant p(θ | ẑ(t)) at {n_decodes} times (shipped CFM)"
    if not info["available"]:
        return head + "; flight-level posterior unavailable (no cfm_seq.npz for this policy)"
    return (head + f"; flight-level p(θ | ẑ(0.2 s … t)) every {info['every_s']:g} s "
            f"(sequence decoder cfm_seq, all latents so far: 1 at 0.2 s to {info['n_latents']} at "
            f"{info['times_s'][-1]:g} s; trained on 1–{info['max_trained_latents']})")


def _held_out_coverage(method: str | None = None) -> str:
    """What the shipped calibration holds on held-out simulated logs, from the provenance of the table of
    posteriors drawn by ``method`` (:func:`~mjxsysid.identify.calibrate.for_method`; its largest held-out
    evaluation): ', holding the
    truth X % of the time on noise-free simulated logs, Y–Z % under IMU noise' ('' where not recorded)."""
    from mjxsysid.identify.calibrate import for_method, load
    held = for_method(load(), method).get("provenance", {}).get("held_out", {})
    cov = max(held.values(), key=lambda v: v.get("rows", 0), default={}).get("mean_coverage")
    if not cov or "clean" not in cov:
        return ""
    noisy = [v for k, v in cov.items() if k != "clean"]
    return (f": on held-out simulated logs they hold the truth {100 * cov['clean']:.0f} % of the time on noise-free "
            f"flights like this one, {100 * min(noisy):.0f}–{100 * max(noisy):.0f} % under IMU noise")


def grounded_md(grounded: dict | None) -> str:
    """summary.md's section on the log-grounded posterior of the paper vehicle's flight ('' without one)."""
    if grounded is None:
        return ""
    lg = grounded["_log_grounded"]
    gap = lg["gap"]
    n_dec = sum(v["decoder_inside"] for v in gap.values())
    seen_q = [k for k, v in gap.items() if v["seen_by_log"]]
    n_seen_in = sum(gap[k]["log_inside"] for k in seen_q)
    seen = [gap[k]["width_ratio"] for k in seen_q]
    how = lg["method"] + (f", {lg['smc_stages']} SMC stages" if "smc_stages" in lg else "")
    cal = lg.get("calibration", {})
    what = (f"Its 90 % bands are calibrated by simulation (docs/identify.md){_held_out_coverage(lg['method'])}" if cal.get("applied")
            else "Its bands are not calibrated (calibration=None): they may hold the truth less often than 90 %")
    misses = [k for k in seen_q if not gap[k]["log_inside"]]
    miss = "" if not misses else (f" Seen and missed: {', '.join(misses)}: on a noise-free log the bands are as narrow "
                                  "as the model's own small biases, the calibration's weakest case.")
    return f"""## What the flight itself shows: the log-grounded posterior

The same flight read as a log — its IMU given its motor commands, through the simulator's rotor lag
and rigid-body model under a broad physical prior, the decoded models its proposal ({how};
`mjxsysid decode --log` does this for any log). {what}. Per log-identifiable quantity, the decoders' band
(what the policy's latent knows, flight-level) against the log's (what the flight shows): the log saw
{len(seen_q)} of {len(gap)} quantities and holds the truth inside {n_seen_in} of those {len(seen_q)} bands; the decoders
hold it inside {n_dec} of {len(gap)}; where the log sees a quantity, the decoded band is a median
{float(np.median(seen)) if seen else float('nan'):.1f}× as wide (`information_gap.png`). Quantities the log does not
see stay as broad as the prior, and the table says why.{miss}

""" + "\n".join(gap_markdown(gap)) + "\n"


def run_demo(out: Path, *, video: bool = True, n_vehicles: int = 16, seed: int = 0,
             policy="mjxsysid", decoder_only: bool = False) -> dict:
    """The quick start. ``policy``: the latent policy flown and decoded (a name, path or
    :class:`~mjxsysid.policy.interface.PolicyRef`; default the shipped one); its shipped
    decoders decode it and the comparison vehicles come from its own prior. ``decoder_only``:
    skip the log-grounded posterior of the paper vehicle's flight (as ``decode --decoder-only``)."""
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt


    ref = resolve_policy(policy)
    cfm, reg = load_decoders(None, ref, warn=print)
    seq = load_sequence_decoder(None, ref)       # the flight-level decoder, None if not shipped
    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    t0 = time.time()
    if n_vehicles < 1:
        raise ValueError(f"--vehicles must be >= 1, got {n_vehicles}")
    stage_names = ["flying", "plotting", "decoding"] + ([] if decoder_only else ["log-grounded posterior"]) + ["video"]
    st = stages(stage_names, desc="demo")
    n_st = len(stage_names)

    def stage(label, msg):
        st.start(label)
        echo(msg)

    theta = np.concatenate([P.PAPER_HARDWARE[None],
                            np.asarray(P.get_prior(ref.prior).sample(jax.random.PRNGKey(seed), n_vehicles))])
    stage("flying", f"[1/{n_st}] flying the paper vehicle and {n_vehicles} prior vehicles on the 10 s lemniscate "
          f"(policy {ref.label}, oracle and nominal K_θ; each first run compiles, ~20 s on CPU)")
    res = {}
    for ctrl in ("policy", "oracle", "nominal"):
        flight, m, _ = fly_vehicles(theta, controller=ctrl, reference="lemniscate", period=10.0,
                                    policy=ref if ctrl == "policy" else None)
        res[ctrl] = (flight, {k: np.asarray(v) for k, v in m.items()})
    flight, m = res["policy"]
    save_flight(flight, theta, out / "flight.npz")
    one = one_flight(flight)
    plot_trajectory(one.frame, out / "tracking.png", reference=one.ref_pos,
                    title=f"paper vehicle, policy {ref.label}, 10 s lemniscate")

    stage("plotting", f"[2/{n_st}] plotting the policy / oracle / nominal comparison")
    fig, ax = plt.subplots(1, 2, figsize=(10, 3.8))
    twr = np.asarray(P.thrust_to_weight(theta))
    labels = {"policy": "adaptive policy (ẑ)", "oracle": "oracle (lag-aware K_θ)", "nominal": "nominal K_θ"}
    for ctrl, mk in (("policy", "s"), ("oracle", "o"), ("nominal", "x")):
        mm = res[ctrl][1]
        rm = np.where(mm["failed"], np.nan, mm["pos_rmse_m"])
        ax[0].scatter(theta[:, P.MASS], rm, marker=mk, label=labels[ctrl], alpha=0.8)
        ax[1].scatter(twr, rm, marker=mk, label=labels[ctrl], alpha=0.8)
        for x, f in zip(theta[:, P.MASS], mm["failed"]):
            if f:
                ax[0].axvline(x, color="r", alpha=0.2)
    for a, xl in zip(ax, ("mass (kg)", "thrust-to-weight")):
        a.set_xscale("log" if xl.startswith("mass") else "linear")
        a.set_yscale("log")
        a.set_xlabel(xl)
        a.set_ylabel("position RMSE (m)")
        a.grid(alpha=0.3)
    ax[0].axvline(P.PAPER_HARDWARE[P.MASS], color="k", ls=":", label="paper vehicle")
    ax[0].legend(fontsize=8)
    fig.suptitle("10 s lemniscate: adaptive policy vs oracle and non-adaptive nominal K_θ (red: nominal failed)")
    fig.tight_layout()
    fig.savefig(out / "oracle_vs_nominal.png", dpi=120)
    plt.close(fig)

    stage("decoding", f"[3/{n_st}] decoding the policy's latent of the paper vehicle at {DEMO_DECODES} times of its "
          "flight with the shipped CFM"
          + (f" and, every {FLIGHT_EVERY_S:g} s, with the flight-level sequence decoder" if seq is not None else
             f" (flight-level posterior unavailable: no cfm_seq.npz in {ref.decoders_dir})"))
    # the 10 Hz decode times of the 10 s flight thinned to DEMO_DECODES (of 99, evenly spaced, the
    # last included); the flight-level posterior still reads every 10 Hz latent
    dec = decode_latents(one.latent, one.time, rate=10.0, samples=200, seed=seed, decoder=cfm,
                         regression=reg, window="flight" if seq is not None else "instant", seq_decoder=seq,
                         window_every=FLIGHT_EVERY_S, max_decodes=DEMO_DECODES)
    post = summarize_posterior(dec["samples"][-1], theta[0])
    flight_info = flight_level_info(dec, seq, ref)
    post_flight = summarize_posterior(dec["samples_window"][-1], theta[0]) if seq is not None else None
    plot_marginals(dec["samples"][-1], theta[0], out / "marginals.png", point=dec["regression"][-1],
                   title="paper vehicle: decoded p(θ | ẑ) at t = 10 s (black: true, orange: regression)")
    plot_decoded_over_time(dec, theta[0], out / "decoded_over_time.png", caption=decoded_caption(flight_info, len(dec["times"])))
    grounded = None
    if not decoder_only:
        stage("log-grounded posterior", f"[4/{n_st}] the log-grounded posterior: the paper vehicle's flight read as a log "
              "(its IMU given its motor commands, the decoded models the proposal)")
        grounded = ground_in_log(dec, {}, flight_log(one.frame), theta[0], seed=seed)
        if "skipped" in grounded["_log_grounded"]:      # a flight too short for the likelihood's windows
            echo(f"log-grounded posterior skipped: {grounded['_log_grounded']['skipped']}")
            grounded = None
    if grounded is not None:
        plot_information_gap(grounded["_log_grounded"]["gap"], out / "information_gap.png",
                             title="paper vehicle: what the policy's latent knows vs what its flight shows")
    np.savez_compressed(out / "decoded.npz", **dec, theta_true=theta[0])
    if video:
        stage("video", f"[{n_st}/{n_st}] flying 4 decoded models and rendering them as ghosts (offscreen)")
        gth, _ = P.project_valid(dec["samples"][-1][:4])
        # flown in a batch of the first flights' size (the comparison vehicles fill it): the policy's
        # flight program is then the one already compiled (a 4-vehicle batch would be one more compile)
        gfl, _, _ = fly_vehicles(np.concatenate([gth, theta[len(gth):]]) if len(theta) > len(gth) else gth,
                                 controller="policy", reference="lemniscate", period=10.0, policy=ref)
        ghosts = [(gth[i], np.asarray(gfl.frame.pos[i]), np.asarray(gfl.frame.quat[i])) for i in range(len(gth))]
        render_rollout(theta[0], one.frame, out / "demo.mp4", reference=one.ref_pos, fps=VIDEO_FPS,
                       width=480, height=360, ghosts=ghosts)
    else:
        stage("video", f"[{n_st}/{n_st}] video skipped (--no-video)")

    summary = {c: {"paper_vehicle": {k: v for k, v in metrics_to_host(
        {k: v[0] for k, v in res[c][1].items()}).items()},
        "prior_vehicles": {"success_rate": float(1 - res[c][1]["failed"][1:].mean()),
                           "pos_rmse_m_median": float(np.nanmedian(
                               np.where(res[c][1]["failed"][1:], np.nan, res[c][1]["pos_rmse_m"][1:])))}}
        for c in res}
    (out / "summary.json").write_text(jsonout.dumps(summary, indent=2) + "\n")
    pp, po, pn = summary["policy"], summary["oracle"], summary["nominal"]
    md = f"""# mjxsysid demo

Paper hardware vehicle (m = 0.925 kg, l = 0.184 m, thrust-to-weight 6.2), 10 s 3-D lemniscate,
baseline high-level gains, 500 Hz, MJX simulator on CPU.

| controller | paper vehicle pos RMSE (m) | heading RMSE (deg) | {n_vehicles} {ref.prior}-prior vehicles: success | median pos RMSE (m) |
|---|---|---|---|---|
| adaptive policy {ref.label} (ẑ from history) | {pp['paper_vehicle']['pos_rmse_m']:.3f} | {pp['paper_vehicle']['heading_rmse_deg']:.2f} | {pp['prior_vehicles']['success_rate']:.0%} | {pp['prior_vehicles']['pos_rmse_m_median']:.3f} |
| oracle K_θ (true θ) | {po['paper_vehicle']['pos_rmse_m']:.3f} | {po['paper_vehicle']['heading_rmse_deg']:.2f} | {po['prior_vehicles']['success_rate']:.0%} | {po['prior_vehicles']['pos_rmse_m_median']:.3f} |
| nominal K_θ (paper θ) | {pn['paper_vehicle']['pos_rmse_m']:.3f} | {pn['paper_vehicle']['heading_rmse_deg']:.2f} | {pn['prior_vehicles']['success_rate']:.0%} | {pn['prior_vehicles']['pos_rmse_m_median']:.3f} |

A controller that knows the vehicle (oracle) flies every vehicle of the prior; one that assumes
the paper vehicle (nominal) degrades or fails as the vehicle departs from it. The adaptive
policy is told nothing about the vehicle: it infers an 8-d latent ẑ from 0.2 s of IMU and
motor history and flies as well as the oracle. That latent is what mjxsysid decodes.

## What the latent says about the paper vehicle

The shipped CFM decoder turns the policy's latent ẑ (read at 10 Hz, decoded at {len(dec['times'])} of those times) into a distribution of
vehicles: *instant*, p(θ | ẑ(t)) from the last latent alone, and *flight-level*, p(θ | ẑ(0.2 s … t))
from every latent flown so far (the sequence decoder `cfm_seq.npz`, the sharpest of the shipped
decoders). At the end of the flight (200 decoded models each):

{{flight_note}}

| quantity | true | instant: mean | 5–95 % | inside | flight-level: mean | 5–95 % | inside |
|---|---|---|---|---|---|---|---|
{{rows}}

The true value lies inside the decoded 5–95 % interval for {{n_in}} of 19 parameters (instant){{n_in_flight}}. Hover and gentle
flight reveal ratios better than scale: see `decoded_over_time.png` for the identifiable
combinations (thrust-to-weight, angular authority, κ) over time, the instant and flight-level
bands against the truth and the regression baseline.

{{grounded}}
Files: `marginals.png`, `decoded_over_time.png`, {'`information_gap.png`, ' if grounded else ''}`decoded.npz`, `tracking.png` (paper vehicle, policy), `oracle_vs_nominal.png`, `flight.npz`, `summary.json`{', `demo.mp4`' if video else ''}.
Wall time {time.time() - t0:.0f} s.
"""
    names = ["mass", "arm_length", "thrust_coeff", "inertia[0]", "inertia[2]", "max_rotor_speed",
             "motor_time_constant", "thrust_to_weight", "torque_ratio", "angular_authority[0]",
             "angular_authority[1]", "angular_authority[2]"]
    cell = lambda p, n: (f"{p[n]['mean']:.4g} | {p[n]['q05']:.4g} – {p[n]['q95']:.4g} | "
                         f"{'yes' if p[n]['inside'] else 'no'}") if p is not None else "– | – | –"
    rows = "\n".join(f"| {n} | {post[n]['true']:.4g} | {cell(post, n)} | {cell(post_flight, n)} |" for n in names)
    n_in = sum(post[n]["inside"] for n in P.PARAM_NAMES)
    n_in_flight = (f" and {sum(post_flight[n]['inside'] for n in P.PARAM_NAMES)} of 19 (flight-level)"
                   if post_flight is not None else "")
    md = (md.replace("{rows}", rows).replace("{n_in}", str(n_in)).replace("{n_in_flight}", n_in_flight)
          .replace("{flight_note}", flight_info["note"]).replace("{grounded}", grounded_md(grounded)))
    st.close()
    summary["paper_vehicle_posterior"] = post
    summary["paper_vehicle_posterior_flight"] = post_flight
    summary["flight_level"] = flight_info
    if grounded is not None:
        summary["paper_vehicle_posterior_log_grounded"] = {k: v for k, v in grounded.items() if not k.startswith("_")}
        summary["log_grounded"] = grounded["_log_grounded"]
    (out / "summary.json").write_text(jsonout.dumps(summary, indent=2) + "\n")
    (out / "summary.md").write_text(md)
    print(md)
    print(f"outputs in {out.resolve()}")
    return summary
