"""The decoding a user runs (`mjxsysid decode`, the demo): a flight or a log → decoded and log-grounded posteriors → report.

Fly (or replay) a vehicle with the frozen policy, read its latent ẑ at a given rate and decode
each into a distribution of physical models.

A flight log (``--log``): the CSV of :mod:`mjxsysid.logs.csvlog` or a PX4 ULog
(:mod:`mjxsysid.logs.ulog`), checked (:mod:`mjxsysid.logs.checks`) before it is replayed.

Windows (``--window``): at each decode time t the flight-level posterior p(θ | ẑ over a window)
comes from the sequence decoder (``cfm_seq.npz``) given the latents it was trained on (10 Hz,
from 0.2 s on) with times in the window: ``flight`` (default) everything flown so far
(0.2 s … t), ``SECONDS`` a sliding window (t − SECONDS, t]; ``instant`` is the single-latent
CFM p(θ | ẑ(t)) alone. The instant posterior is always computed too (``decoded.npz`` key
``samples``; the window's are ``samples_window``).

Modules: :mod:`~mjxsysid.decoding.windows` (which latents each decode time reads),
:mod:`~mjxsysid.decoding.posteriors` (the decoded and log-grounded posteriors),
:mod:`~mjxsysid.decoding.checking` (a decoded flight's checks),
:mod:`~mjxsysid.decoding.command` (the command end to end and its outputs),
:mod:`~mjxsysid.decoding.fleet` (several logs at once, one table),
:mod:`~mjxsysid.decoding.demo` (the CPU quick start: the paper vehicle flown, decoded and grounded).
"""
from mjxsysid.decoding.checking import checks_summary, decoders_prior, flight_checks, log_latents
from mjxsysid.decoding.posteriors import decode_latents, decode_posterior, ground_in_log
from mjxsysid.decoding.command import OUT_OF_PRIOR_TITLE, run_decode, write_summary_md
from mjxsysid.decoding.windows import (MAX_DECODES, check_window, every_times, parse_window, window_bounds,
                                       window_masks)

__all__ = ["MAX_DECODES", "OUT_OF_PRIOR_TITLE", "check_window", "checks_summary", "decode_latents", "decode_posterior",
           "decoders_prior", "every_times", "flight_checks", "ground_in_log", "log_latents", "parse_window",
           "run_decode", "window_bounds", "window_masks", "write_summary_md"]
