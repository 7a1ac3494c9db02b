"""The decoded posterior: ẑ over a flight -> samples of θ at each decode time (instant and over
a window), its summary, and for a log the log-grounded posterior of record (:mod:`mjxsysid.identify`)."""
from __future__ import annotations

import jax
import numpy as np

from mjxsysid import theta as P
from mjxsysid.runtime.jsonout import plain
from mjxsysid.cfm.load import load_decoders
from mjxsysid.cfm.posterior import summarize_posterior
from mjxsysid.dataset.collect import decode_indices
from mjxsysid.policy.adaptive import networks as N
from mjxsysid.decoding.windows import MAX_DECODES, every_times, parse_window, window_bounds


def decode_latents(zhat_t, times, *, rate: float, samples: int, seed: int = 0, decoder=None,
                   regression=None, start: float = N.HISTORY * 0.002, window="instant", seq_decoder=None,

                   max_decodes: int | None = MAX_DECODES, window_every: float | None = None):
    """Decode ẑ (T, 8) sampled at ``rate`` Hz after ``start`` s — at most ``max_decodes`` times
    (evenly spaced, the last included; None: no limit). Returns dict with times (K,), zhat (K, 8),
    samples (K, S, 19) physical (single latent), regression (K, 19) physical, decode_rate_hz ().
    Decoders default to the shipped ones of mjxsysid's policy. With a ``window`` other than
    'instant' and a ``seq_decoder``: also samples_window (K, S, 19), the flight-level posterior
    given the latents at the sequence decoder's rate (10 Hz) in the window, and n_window (K,),
    the number of latents in it, at the decode times times_window (K,) — all of them, or with
    ``window_every`` (s) only those nearest each multiple of it, the first and last included
    (the window's posterior sampled in one batch at fewer times: what the demo does). The
    windows are encoded incrementally
    (:meth:`~mjxsysid.cfm.sequence.SequenceDecoder.encode_flight`): time and memory grow
    linearly with the flight."""
    if not rate > 0:
        raise ValueError(f"--rate must be > 0 Hz, got {rate}")
    if samples < 2:
        raise ValueError(f"--samples must be >= 2, got {samples}")
    if max_decodes is not None and max_decodes < 1:
        raise ValueError(f"max_decodes must be >= 1, got {max_decodes}")
    if window_every is not None and not window_every > 0:
        raise ValueError(f"window_every must be > 0 s, got {window_every}")
    window = parse_window(window)
    times = np.asarray(times)
    idx = decode_indices(times, rate, start)
    rate_used = float(rate)
    if max_decodes is not None and len(idx) > max_decodes:
        idx = idx[np.unique(np.round(np.linspace(0, len(idx) - 1, max_decodes)).astype(int))]
        rate_used = (len(idx) - 1) / max(float(times[idx[-1]] - times[idx[0]]), 1e-9)
    if decoder is None or regression is None:
        cfm0, reg0 = load_decoders()
        decoder, regression = decoder or cfm0, regression or reg0
    z = np.asarray(zhat_t)[idx]
    s = np.asarray(decoder.sample_theta(z, jax.random.PRNGKey(seed), samples))
    out = {"times": times[idx], "zhat": z, "samples": s, "regression": np.asarray(regression.point(z)),
           "decode_rate_hz": np.float64(rate_used)}
    if window != "instant" and seq_decoder is not None:
        lidx = decode_indices(times, float(seq_decoder.meta.get("traj_rate_hz", 10.0)), start)
        wt = out["times"] if window_every is None else every_times(out["times"], window_every)
        out["times_window"] = wt
        starts, ends = window_bounds(times[lidx], wt, window)
        # Past the longest window the decoder was trained on (max_len latents) every latent still
        # enters the pooled features and the count feature saturates: calibrated on 60 s flights
        # (docs/runs/measurements/long-flight-calibration/long_flight_calibration.json; a sliding window of trained length is the
        # other candidate, measured there too).
        out["beyond_trained_length"] = ends - starts + 1 > seq_decoder.max_len
        c = seq_decoder.encode_flight(np.asarray(zhat_t, np.float32)[lidx], ends,
                                      starts=None if window == "flight" else starts)
        out["samples_window"] = np.asarray(seq_decoder.sample_cond_theta(c, jax.random.PRNGKey(seed + 1), samples))
        out["n_window"] = ends - starts + 1
    return out


def decode_posterior(zhat_t, times, truth=None, *, decoder, regression, rate: float = 10.0,
                     samples: int = 100, seed: int = 0, window="instant", seq_decoder=None) -> dict:
    """What ``mjxsysid decode`` writes, in memory: ẑ (T, 8) over ``times`` (T,) decoded at
    ``rate`` Hz -> dict with the arrays of ``decoded.npz`` (times (K,), zhat (K, 8), samples
    (K, S, 19) instant, regression (K, 19), theta_true (19,) or NaN; with a window and a
    ``seq_decoder`` also samples_window (K, S, 19) and n_window (K,), see
    :func:`decode_latents`) and ``summary`` (the content of ``summary.json``:
    :func:`summarize_posterior` of the last decode time's samples — the window's if decoded,
    else the instant ones —, plus ``_invalid_fraction``, ``_window`` (window used, requested,
    label, t_end_s, n_latents) and, for a window, ``_instant``). ``window`` other than
    'instant' without a ``seq_decoder`` falls back to 'instant' (``_window`` says so)."""
    window = parse_window(window)
    used = window if seq_decoder is not None else "instant"
    dec = decode_latents(zhat_t, times, rate=rate, samples=samples, seed=seed, decoder=decoder,
                         regression=regression, window=used, seq_decoder=seq_decoder)
    instant = dec["samples"][-1]
    final = dec["samples_window"][-1] if "samples_window" in dec else instant
    summary = summarize_posterior(final, truth)
    summary["_invalid_fraction"] = float(P.project_valid(final)[1].mean())  # e.g. J triangle violated
    label = {"flight": "flight-level", "instant": "instant"}[used] if isinstance(used, str) else f"last {used:g} s"
    summary["_window"] = {"window": used, "requested": window, "label": label, "t_end_s": float(dec["times"][-1]),
                          "n_latents": int(dec["n_window"][-1]) if "n_window" in dec else 1,
                          "decode_rate_hz": float(dec["decode_rate_hz"]), "n_decodes": int(len(dec["times"])),
                          "beyond_trained_length": bool(dec["beyond_trained_length"][-1])
                          if "beyond_trained_length" in dec else False}
    if used != "instant":
        summary["_instant"] = summarize_posterior(instant, truth)
    truth = np.full(P.N_PARAMS, np.nan, np.float32) if truth is None else np.asarray(truth, np.float32)
    return dict(dec, theta_true=truth, summary=summary)


def ground_in_log(dec: dict, summary: dict, rec: dict, truth=None, *, seed: int = 0, rates: str | None = None,
                  refine: bool | None = None, shared_maps=None) -> dict:
    """Make the log-grounded posterior (:mod:`mjxsysid.identify`) of a log's arrays ``rec`` the
    posterior of record, the decoded samples (the window's at the end of the flight, else the
    instant ones) as its proposal. In place: ``dec["samples_log_grounded"]`` (S, 19); ``summary``'s
    top-level entries (19 parameters, the derived quantities, and the log-identifiable
    quantities of :data:`~mjxsysid.identify.logspace.QUANTITIES`, each once:
    :func:`~mjxsysid.identify.gap.joint_summary`) become the log-grounded posterior's,
    the decoder-only entries move under ``_decoder_only``, and ``_log_grounded`` holds the method,
    its diagnostics (ESS, Pareto k̂, SMC stages), the IMU noise, discrepancy and bias it estimated,
    the measured rotor speeds' use (``rotor_speed``: rotor_speed_used, why, the command→speed fit)
    and the information gap. ``rates``: the likelihood's rate term (default
    :data:`~mjxsysid.identify.logdata.RATES`); ``refine``: whether an SMC's draws are refined by NUTS
    (default: the posterior config's, :data:`~mjxsysid.identify.posterior_config.DEFAULT`); ``shared_maps``: the
    command→speed maps other flights of the vehicle showed (:class:`~mjxsysid.identify.PosteriorConfig`'s).
    Returns ``summary``."""
    from mjxsysid.identify import logspace as L
    from mjxsysid.identify.gap import information_gap, joint_summary, log_summary, seen_by_name
    from mjxsysid.identify.inference import log_grounded_posterior
    from mjxsysid.identify.logdata import LogTooShort
    final = dec["samples_window"][-1] if "samples_window" in dec else dec["samples"][-1]
    try:
        post = log_grounded_posterior(rec, final, seed=seed, rates=rates, refine=refine, shared_maps=shared_maps)
    except LogTooShort as e:       # a log too short for the likelihood's windows: the decoders alone, said so
        summary["_log_grounded"] = {"skipped": str(e)}
        summary["_posterior"] = "decoder-only"
        return summary
    decoder_only = joint_summary({k: summary.pop(k) for k in list(summary) if not k.startswith("_")},
                                 log_summary(final, truth))
    cal = post["calibration"]
    seen = seen_by_name(cal) if cal.get("applied") else None
    gap = information_gap(final, post["theta"], truth, seen=seen)
    summary.update(joint_summary(summarize_posterior(post["theta"], truth), log_summary(post["theta"], truth),
                                 seen={k: (g["seen_by_log"], g["seen_why"]) for k, g in gap.items()}))
    summary["_decoder_only"] = decoder_only
    diag = {k: post[k] for k in ("method", "proposal", "decoded_is", "laplace_is", "smc_stages", "smc_acceptance",
                                 "smc_tempering", "nuts") if k in post}
    nz = np.median(post["nuisance"], 0)
    diag["imu_noise"] = {c: float(x) for c, x in zip(L.CHANNELS, np.exp(nz[L.LOG_NOISE]))}
    diag["discrepancy"] = {c: float(x) for c, x in zip(L.CHANNELS, np.exp(nz[L.LOG_DISCREPANCY]))}
    diag["acc_z_bias"] = float(nz[L.BIAS])
    diag["residual_weights"] = {c: float(x) for c, x in zip(L.CHANNELS, post["weights"])}
    diag["channels_used"] = [c for c, u in zip(L.CHANNELS, post["channels_used"]) if u > 0]
    diag["rates"] = post["rates"]
    diag["drag_per_mass"] = ({"value": post["drag_per_mass"], "unit": "1/s", "axes": "body x, y, z",
                              "what": "the body drag over the mass the accelerometer fits through the log's velocity "
                                      "(x, y: least squares of its x and y; z: its term at the posterior's mode; "
                                      "not calibrated)"}
                             if post.get("drag_per_mass") is not None else
                             {"value": None, "why": "the log carries no velocity: the drag's share of the specific "
                                                    "force is left to the calibration"})
    diag["calibration"] = ({"applied": True, "table": cal["table"], "features": post["features"],
                            "model_check": cal["check"], "width_factor": dict(zip(L.V_NAMES, cal["factor"].tolist())),
                            "calibrated_on": dict(zip(L.V_NAMES, cal["stratum"]))}
                           if cal.get("applied") else {"applied": False, "why": cal["why"]})
    diag["gap"] = gap
    # the measured rotor speeds: used (τ_m from command to speed, the thrust and torque from the speeds) or why not
    diag["rotor_speed"] = post["rotor_speed"]
    summary["_log_grounded"] = plain(diag)
    summary["_posterior"] = "log-grounded"
    dec["samples_log_grounded"] = post["theta"]
    return summary
