"""The log-grounded posterior as one object: draws, summary, information gap, calibration, diagnostics.

    post = mjxsysid.identify("flight.ulg")          # any log format, or a log's arrays
    post.summary()["thrust_to_weight"]              # {unit, median, q05, q95, seen, why}
    theta = post.sample(200)                        # (200, 19) physical models
    post.gap(decoded_theta)                         # what the log shows against what the latent knows
    post.calibration, post.diagnostics

In the style of sbi's posterior objects: the draws are the calibrated ones
(:mod:`.calibrate`); a quantity the log does not pin is reported as not seen, as broad as the
prior, with the reason.
"""
from __future__ import annotations

import dataclasses
from pathlib import Path

import numpy as np

from mjxsysid.identify.coords import PHYSICAL_PRIOR, PhysicalPrior, log_quantities
from mjxsysid.identify.gap import Summary, information_gap, seen_by_name
from mjxsysid.identify.logspace import LOG_NAMES, LOG_UNITS
from mjxsysid.identify.inference import log_grounded_posterior

DIAGNOSTIC_KEYS = ("method", "proposal", "decoded_is", "laplace_is", "smc_stages", "smc_acceptance",
                   "smc_acceptance_min", "smc_tempering", "nuts", "features", "weights", "channels_used", "rates", "mode",
                   "drag_per_mass", "rotor_speed", "window_check", "idle_check")


@dataclasses.dataclass(frozen=True)
class LogPosterior:
    """One log's posterior: ``result`` the dict of
    :func:`~mjxsysid.identify.inference.log_grounded_posterior`, ``source`` what the reader said
    of the log (format, rates, segment, conversions), ``prior`` the stated physical prior."""
    result: dict
    source: dict | None = None
    prior: PhysicalPrior = PHYSICAL_PRIOR

    @classmethod
    def fit(cls, rec_or_data, decoded_theta=None, *, prior: PhysicalPrior = PHYSICAL_PRIOR, **kw) -> "LogPosterior":
        """The posterior of a log's arrays (a reader's dict) or a LogData; ``decoded_theta`` (S, 19)
        the decoders' samples as the proposal, or None; ``kw``: those of log_grounded_posterior."""
        res = log_grounded_posterior(rec_or_data, decoded_theta, prior=prior, **kw)
        src = rec_or_data.get("source") if isinstance(rec_or_data, dict) else None
        return cls(res, src, prior)

    @property
    def theta(self) -> np.ndarray:
        """The draws θ (S, 19) (hidden coordinates from the prior)."""
        return self.result["theta"]

    def sample(self, n: int | None = None, seed: int = 0) -> np.ndarray:
        """n draws θ (n, 19), resampled from the posterior's (all of them, in order, for n=None)."""
        if n is None:
            return self.theta
        if n < 1:
            raise ValueError(f"sample(n): n must be ≥ 1, got {n}")
        idx = np.random.default_rng(seed).choice(len(self.theta), n, replace=n > len(self.theta))
        return self.theta[idx]

    def seen(self) -> dict:
        """{LOG_NAMES quantity: (seen, why)} (:func:`~.gap.seen_by_name`); without a calibration,
        seen when the band is narrower than half the prior's range."""
        cal = self.result.get("calibration") or {}
        if cal.get("applied"):
            return seen_by_name(cal)
        gap = information_gap(self.theta, self.theta, prior=self.prior)
        return {k: (v["seen_by_log"], v["seen_why"]) for k, v in gap.items()}

    def summary(self) -> dict:
        """{quantity of LOG_NAMES (:data:`~.logspace.QUANTITIES`): {unit, median, q05, q95, seen, why}}, the
        quantities the log pins first; a quantity it does not pin is not seen, as broad as the prior, with why."""
        q = log_quantities(self.theta)
        lo, med, hi = np.percentile(q, [5, 50, 95], 0)
        seen = self.seen()
        rows = {n: {"unit": u, "median": float(med[j]), "q05": float(lo[j]), "q95": float(hi[j]),
                    "seen": bool(seen[n][0]), "why": seen[n][1]} for j, (n, u) in enumerate(zip(LOG_NAMES, LOG_UNITS))}
        return Summary(sorted(rows.items(), key=lambda kv: not kv[1]["seen"]))

    def gap(self, decoded_theta, truth=None) -> dict:
        """The information gap against the decoders' samples θ (S, 19) (:func:`~.gap.information_gap`)."""
        return information_gap(decoded_theta, self.theta, truth, self.prior, seen=self.seen())

    @property
    def calibration(self) -> dict:
        """What the calibration did: the table, the band's width factor and group per visible coordinate,
        the model check, seen and why (:func:`~.calibrate.calibrate`)."""
        return self.result.get("calibration", {})

    @property
    def diagnostics(self) -> dict:
        """The sampler's and the log's diagnostics: method, importance sampling (ESS, Pareto k̂), SMC
        stages and acceptance, the log's features, the residual discounts, the channels used."""
        return {k: self.result[k] for k in DIAGNOSTIC_KEYS if k in self.result}

    def __repr__(self) -> str:
        lines = [f"LogPosterior({len(self.theta)} draws, {self.result.get('method')}"
                 + (f", {self.source.get('format')} {Path(self.source.get('path', '')).name}" if self.source else "") + ")"]
        for n, r in self.summary().items():
            lines.append(f"  {n:28s} {r['q05']:.4g} – {r['q95']:.4g} {r['unit']}"
                         + ("" if r["seen"] else "  (not seen)"))
        return "\n".join(lines)


def identify(log, decoded_theta=None, *, segment=None, **kw) -> LogPosterior:
    """The log-grounded posterior of a flight log: a path of any known format
    (:func:`mjxsysid.logs.csvlog.read_any_log`, cut at its airborne ``segment``) or a log's arrays ->
    :class:`LogPosterior`. ``decoded_theta``: the decoders' samples of the log (S, 19) as the proposal,
    or None (the prior and the log alone); ``kw``: seed, ``config`` (a :class:`~.posterior_config.PosteriorConfig`)
    and any of its fields (those of :func:`~mjxsysid.identify.inference.log_grounded_posterior`)."""
    if isinstance(log, (str, Path)):
        from mjxsysid.logs.csvlog import read_any_log
        log = read_any_log(log, segment)
    elif not isinstance(log, dict):
        raise TypeError(f"identify takes a flight-log path or a log's arrays (dict), got {type(log).__name__}")
    return LogPosterior.fit(log, decoded_theta, **kw)
