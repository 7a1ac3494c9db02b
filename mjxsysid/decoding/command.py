"""`mjxsysid decode` end to end (:func:`run_decode`): fly or read, check, decode, ground in the
log, and write decoded.npz, summary.json, summary.md and the figures."""
from __future__ import annotations

from pathlib import Path

import numpy as np

from mjxsysid.runtime import jsonout
from mjxsysid import theta as P
from mjxsysid.cfm.load import load_decoders, load_sequence_decoder
from mjxsysid.logs.checks import imu_noise_limit, warn
from mjxsysid.logs.csvlog import LOG_DT, read_any_log
from mjxsysid.policy.interface import resolve_policy
from mjxsysid.runtime.progress import stages
from mjxsysid.render.posterior import plot_decoded_over_time, plot_information_gap, plot_marginals
from mjxsysid.render.video import render_rollout
from mjxsysid.rollout.flight import flight_log, fly_vehicles, make_reference, one_flight
from mjxsysid.decoding.checking import checks_summary, decoders_prior, flight_checks, log_latents
from mjxsysid.decoding.posteriors import decode_posterior, ground_in_log
from mjxsysid.decoding.windows import check_window, parse_window

OUT_OF_PRIOR_TITLE = "OUT OF THE DECODERS' PRIOR — bands not calibrated: "


def _posterior_table(summary: dict) -> list[str]:
    """summary.md's table rows of a posterior's summary entries (mean, 5–95 %; the truth and whether the band
    holds it where a simulated flight knows it; for a log-grounded posterior, whether the log saw the quantity)."""
    entries = {k: v for k, v in summary.items() if isinstance(v, dict) and "mean" in v and "q05" in v}
    seen = any("seen_by_log" in v for v in entries.values())
    known = any("true" in v for v in entries.values())
    rows = ["| quantity | mean | 5 % | 95 % |" + (" true | inside |" if known else "") + (" seen by the log |" if seen else ""),
            "|---|---|---|---|" + ("---|---|" if known else "") + ("---|" if seen else "")]
    for k, v in entries.items():
        true = f"{v['true']:.4g}" if "true" in v else ""
        inside = ("yes" if v["inside"] else "no") if "inside" in v else ""
        rows.append(f"| {k} | {v['mean']:.4g} | {v['q05']:.4g} | {v['q95']:.4g} |" + (f" {true} | {inside} |" if known else "")
                    + ((" yes |" if v.get("seen_by_log") else " no: as broad as the prior |") if seen else ""))
    return rows


def printed_summary(summary: dict) -> dict:
    """What ``mjxsysid decode`` prints (one JSON line): for a log-grounded posterior the quantities
    the log pins first (those of :data:`~mjxsysid.identify.logspace.LOG_NAMES` the information gap
    says the log sees, in that order), then the derived quantities (:data:`~mjxsysid.theta.DERIVED_NAMES`,
    whose widths the training prior sets where the log cannot see them), and ``not_seen_by_log``;
    else the derived quantities alone."""
    from mjxsysid.identify.logspace import LOG_NAMES
    gap = (summary.get("_log_grounded") or {}).get("gap")
    out = {}
    if gap:
        out.update({k: summary[k] for k in LOG_NAMES if k in summary and gap.get(k, {}).get("seen_by_log")})
    out.update({k: v for k, v in summary.items() if k in P.DERIVED_NAMES and k not in out})
    if gap:
        out["not_seen_by_log"] = [k for k in LOG_NAMES if k in gap and not gap[k].get("seen_by_log")]
    return out



def _model_check_lines(g: dict) -> list[str]:
    """summary.md's model check: the window-length and motor-map tests' verdicts, NUTS's chains, the strata a
    vibrating log or a log without velocity was calibrated on, and every reason a coordinate failed."""
    chk = (g.get("calibration") or {}).get("model_check")
    if not chk:
        return []
    win, idle = chk.get("window") or {}, chk.get("idle") or {}
    lines = ["", "## The model check", "", f"- window length: {win.get('why', 'not run')}",
             f"- motor map: {idle.get('why', 'not run')}"] + _nuts_line(g)
    from mjxsysid.identify.calibrate import NO_VELOCITY, NO_VELOCITY_WHY, VIBRATING
    features, strata = g["calibration"].get("features") or {}, g["calibration"].get("calibrated_on") or {}
    if features.get("vibration"):
        on = [k for k, v in strata.items() if v == VIBRATING]
        lines.append("- rotor vibration: a narrow-band peak in the gyro; calibrated on vibrating simulated logs: "
                     + (", ".join(on) if on else "none of the bands (each failed a check or was left raw)"))
    on = [k for k, v in strata.items() if v == NO_VELOCITY]
    if features.get("velocity_used") is False and on:
        lines.append(f"- velocity: {NO_VELOCITY_WHY} ({', '.join(on)})")
    return lines + [f"- failed: {r}" for r in chk.get("reasons", []) if r not in (win.get("why"), idle.get("why"))]


def _nuts_line(g: dict) -> list[str]:
    """summary.md's line on NUTS's chains (``g['nuts']``): whether they mixed, at which attempt, and why the
    first did not."""
    n = g.get("nuts")
    if not n:
        return []
    first = (n.get("first") or {}).get("why")
    if not n.get("converged"):
        return [f"- NUTS: the chains did not mix in {n.get('attempts', 1)} attempt(s) ({n['why']}); the SMC's draws "
                "are kept, and a coordinate whose chains disagree is not seen"]
    again = (f" on a second, longer run ({n['warmup']} warm-up steps, {n['draws']} draws thinned by {n['thin']}); "
             f"the first did not: {first}") if first else ""
    return [f"- NUTS: {n['chains']} chains mixed{again} ({n['why']})"]


def _khat(isd: dict) -> str:
    """The Pareto k̂ of the decoded proposal's weights as the report prints it."""
    k = isd.get("khat")
    return "not fitted (ESS below 5 %)" if k is None and "ess" in isd else "?" if k is None else f"{k:.3g}"

def write_summary_md(summary: dict, path) -> Path:
    """summary.md: the checks' warnings first (out of prior, suspicious log), then the decoded
    derived quantities and parameters (mean, 5–95 %, and the truth if known)."""
    c = summary.get("_checks", {})
    lines = ["# Decoded vehicle", ""]
    if c.get("is_out_of_prior"):
        lines += ["**Out of the decoders' training prior: the bands below are not calibrated.**", ""]
        lines += [f"- {m}" for m in c["out_of_prior"]] + [""]
    if c.get("warnings"):
        lines += ["**Warnings about the log:**", ""] + [f"- {m}" for m in c["warnings"]] + [""]
    w = summary.get("_window", {})
    which = ("log-grounded (the log's IMU given its motor commands under a physical prior; the decoded "
             "samples its proposal)" if summary.get("_posterior") == "log-grounded" else
             f"{w.get('label', '')} at t = {w.get('t_end_s', float('nan')):.2f} s")
    lines += [f"Posterior: {which}.", ""] + _posterior_table(summary)
    if c.get("source") or c.get("resampled") or c.get("notes"):
        lines += ["", "## What was done to the log", ""]
        src = c.get("source") or {}
        lines += [f"- {k}: {v}" for k, v in src.items() if k != "conversions"]
        lines += [f"- conversion: {m}" for m in src.get("conversions", [])]
        lines += [f"- {k}: {v}" for k, v in (c.get("resampled") or {}).items()]
        lines += [f"- note: {m}" for m in c.get("notes", [])]
    g = summary.get("_log_grounded")
    if g and "skipped" in g:
        lines += ["", f"**No log-grounded posterior:** {g['skipped']}. The bands above are the decoders' alone."]
    elif g:
        from mjxsysid.identify.gap import gap_markdown
        d = summary.get("_decoder_only", {})
        lines += ["", "## Decoder-only posterior (what the policy's latent knows)", ""] + _posterior_table(d)
        isd = g.get("decoded_is") or {}
        lines += ["", "## The information gap: decoder-only against log-grounded", "",
                  f"Method: {g['method']} (rate term: {g.get('rates', 'windows')}); the decoded ensemble as importance "
                  f"proposal: ESS {isd.get('ess', float('nan')):.3g} "

                  f"of {isd.get('draws', '?')}, Pareto k̂ {_khat(isd)} (reliable: ESS ≥ 5 %, k̂ ≤ 0.7). Channels "
                  f"used: {', '.join(g.get('channels_used', []))}. A width ratio above 1: the log pins the quantity "
                  f"down more than the policy's latent does; a log-grounded band as wide as the prior: the log cannot "
                  f"see it (docs/identify.md).", ""]
        lines += gap_markdown(g["gap"]) + _model_check_lines(g)
    Path(path).write_text("\n".join(lines) + "\n")
    return Path(path)


def run_decode(out, *, theta=None, log=None, reference="lemniscate", period=10.0, duration=None,
               samples=100, rate=10.0, weights=None, seed=0, video=False, ghosts=4, echo=print,
               policy="mjxsysid", decoders=None, window="flight", truth=None, warn=warn, segment=None,
               decoder_only=False, rates=None, refine=None, shared_maps=None) -> dict:
    """Fly θ (or replay ``log``) with a frozen latent policy (``policy``, ``weights``: see
    :func:`~mjxsysid.policy.interface.resolve_policy`; default the shipped one), decode at
    ``rate`` Hz with that policy's decoders (or those in ``decoders``), write out/decoded.npz,
    out/summary.json and plots (and out/decoded.mp4 with ``video``).

    ``window`` ('flight', 'instant' or seconds, see :func:`parse_window`): the top-level
    entries of summary.json are the posterior at the end of the flight given the latents in
    that window (the sequence decoder; 'instant': the single-latent CFM), ``_instant`` the
    single-latent one, ``_window`` what was used. Without a sequence decoder, falls back to
    'instant' and says so. ``truth`` (θ (19,), with ``log`` only): the logged vehicle's known
    parameters; the summary then reports ``true`` and ``inside`` as for a flown vehicle.
    ``log``: a CSV or a PX4 ULog (``.ulg``, :func:`~mjxsysid.logs.csvlog.read_any_log`); ``segment`` 't0:t1': the part
    of it to decode (a ULog's default: its armed, airborne segment).

    A log's posterior of record is grounded in its own physics unless ``decoder_only``
    (:func:`ground_in_log`: summary.json's top-level entries the log-grounded posterior's, the
    decoders' under ``_decoder_only``, the information gap under ``_log_grounded``; also
    marginals_decoder_only.png and information_gap.png); ``rates`` and ``refine``: its likelihood's rate
    term and whether an SMC's draws are refined by NUTS (default both the library's); ``shared_maps``: the
    command→speed maps other flights of this vehicle showed (:class:`~mjxsysid.identify.PosteriorConfig`'s).

    A log is checked for physical plausibility before any decoding
    (:mod:`mjxsysid.logs.checks`): a log that cannot be right raises ``LogError`` (a
    ``ValueError``); suspicious findings, and a flight outside the decoders' training prior, go
    to ``warn`` (never silenced by ``--quiet``), ``summary["_checks"]``, summary.md and the
    plots' titles."""
    # Every input is checked before any work starts.
    if not rate > 0:
        raise ValueError(f"--rate must be > 0 Hz, got {rate}")
    if samples < 2:
        raise ValueError(f"--samples must be >= 2, got {samples}")
    if (log is None) == (theta is None):
        raise ValueError("give either a vehicle (theta) or a flight log, not both or neither")
    if truth is not None:
        if log is None:
            raise ValueError("truth is for a flight log (a flown vehicle is its own truth)")
        truth = P.validate_theta(truth, what="truth")
        if truth.shape != (P.N_PARAMS,):
            raise ValueError(f"truth: one θ of shape ({P.N_PARAMS},) expected, got {truth.shape}")
    window = parse_window(window)
    rec = read_any_log(log, segment) if log is not None else None
    if theta is not None:
        theta = P.validate_theta(theta, what="vehicle")
        if theta.shape != (P.N_PARAMS,):
            raise ValueError(f"vehicle: one θ of shape ({P.N_PARAMS},) expected, got {theta.shape}")
        # the window must fit in the flight: checked before flying
        d0 = make_reference(reference, period=period, duration=duration, seed=seed)[1]
        check_window(window, d0 if duration is None else duration)
    else:
        check_window(window, float(rec["t"][-1] - rec["t"][0] + LOG_DT))
    ref = resolve_policy(policy, weights)
    cfm, reg = load_decoders(decoders, ref, warn=echo)
    seq = None if window == "instant" else load_sequence_decoder(decoders, ref, echo=echo)
    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    st = stages(["flying" if log is None else "replaying the log", "decoding"]
                + (["log-grounded posterior"] if log is not None and not decoder_only else []) + ["plots"]
                + (["video"] if video and log is None else []), desc="decode")
    st.start("flying" if log is None else "replaying the log")
    flight = None
    checks = {k: rec[k] for k in ("source", "resampled") if rec is not None and k in rec}   # a ULog's reading
    if log is not None:
        zhat_t, times = log_latents(ref, rec, source=log, checks=checks, imu_limit=imu_noise_limit(cfm, reg, seq))
        truth = None if truth is None else np.asarray(truth, np.float32)
    else:
        flight, _, _ = fly_vehicles(theta, controller="policy", policy=ref, reference=reference,
                                    period=period, duration=duration, seed=seed)
        one = one_flight(flight)
        zhat_t, times, truth = one.latent, one.time, np.asarray(theta, np.float32)
        rec = flight_log(one.frame)
    flight_checks(rec, decoders_prior(seq, cfm), checks)
    for f in checks["findings"]:
        warn(f)
    st.start("decoding")
    dec = decode_posterior(zhat_t, times, truth, decoder=cfm, regression=reg, rate=rate, samples=samples,
                           seed=seed, window=window, seq_decoder=seq)
    summary = dec.pop("summary")
    summary["_checks"] = checks_summary(checks)
    label = summary["_window"]["label"]
    flag = OUT_OF_PRIOR_TITLE if summary["_checks"]["is_out_of_prior"] else ""
    if summary["_window"]["decode_rate_hz"] < rate - 1e-6:
        echo(f"note: {summary['_window']['n_decodes']} decode times at most (MAX_DECODES): this "
             f"{summary['_window']['t_end_s']:.0f} s flight is decoded at {summary['_window']['decode_rate_hz']:.3g} Hz; "
             f"every latent (10 Hz) still enters the flight-level posterior")
    if summary["_window"]["beyond_trained_length"]:
        echo(f"note: {summary['_window']['n_latents']} latents, more than the sequence decoder's training flights "
             f"({seq.max_len}): the count feature saturates there; calibration checked to 60 s flights "
             f"(docs/decoding.md)")
    final = dec["samples_window"][-1] if "samples_window" in dec else dec["samples"][-1]
    if log is not None and not decoder_only:
        st.start("log-grounded posterior")
        ground_in_log(dec, summary, rec, truth, seed=seed, rates=rates, refine=refine, shared_maps=shared_maps)
    np.savez_compressed(out / "decoded.npz", **dec)
    jsonout.write_json(out / "summary.json", summary)
    write_summary_md(summary, out / "summary.md")
    st.start("plots")
    t_true = truth if truth is not None else np.full(19, np.nan)
    if "samples_log_grounded" in dec:
        plot_marginals(dec["samples_log_grounded"], t_true, out / "marginals.png", point=dec["regression"][-1],
                       title=f"{flag}log-grounded posterior p(θ | log) (the decoded samples its proposal)")
        plot_marginals(final, t_true, out / "marginals_decoder_only.png", point=dec["regression"][-1],
                       title=f"{flag}decoder-only p(θ | ẑ, {label}) at t = {dec['times'][-1]:.1f} s")
        plot_information_gap(summary["_log_grounded"]["gap"], out / "information_gap.png")
    else:
        plot_marginals(final, t_true, out / "marginals.png", point=dec["regression"][-1],
                       title=f"{flag}decoded p(θ | ẑ, {label}) at t = {dec['times'][-1]:.1f} s")
    plot_decoded_over_time(dec, truth, out / "decoded_over_time.png", window_label=label, title=flag or None)
    if video and flight is not None:
        st.start("video")
        gth, _ = P.project_valid(final[:ghosts])
        gfl, _, _ = fly_vehicles(gth, controller="policy", policy=ref, reference=reference,
                                 period=period, duration=duration, seed=seed)
        g = [(gth[i], np.asarray(gfl.frame.pos[i]), np.asarray(gfl.frame.quat[i])) for i in range(len(gth))]
        render_rollout(truth, one.frame, out / "decoded.mp4", ghosts=g, reference=one.ref_pos, fps=25,
                       width=480, height=360)
    st.close()
    if truth is not None:
        echo(truth_headline(summary, label))
    return summary


def truth_headline(summary: dict, label: str) -> str:
    """The line ``decode --truth`` ends with: with a log-grounded posterior, the truths inside its 90 % bands
    of the quantities the log saw only (the unseen ones are as broad as the prior: counting them would
    flatter it); else the true θ inside the decoded intervals."""
    gap = summary.get("_log_grounded", {}).get("gap")
    if gap:
        seen = [k for k, v in gap.items() if v.get("seen_by_log")]
        n_in = sum(bool(gap[k].get("log_inside")) for k in seen)
        return (f"truth inside the log-grounded 90 % band for {n_in}/{len(seen)} quantities the log saw "
                f"({len(gap) - len(seen)} not seen: as broad as the prior)")
    n_in = sum(v["inside"] for k, v in summary.items() if k in P.PARAM_NAMES)
    return f"true θ inside the decoded ({label}) 5–95 % interval for {n_in}/{P.N_PARAMS} parameters"
