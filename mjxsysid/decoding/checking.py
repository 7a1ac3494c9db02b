"""A decoded flight's checks: a log replayed by the policy after its plausibility checks, the
out-of-prior check of any flight, and their entry in summary.json (``_checks``)."""
from __future__ import annotations

import numpy as np

from mjxsysid import theta as P
from mjxsysid.logs.checks import LogError, check_log, check_replay, estimate_vehicle, prior_check
from mjxsysid.logs.csvlog import LOG_DT
from mjxsysid.policy.interface import resolve_policy


def log_latents(policy, rec: dict, *, source="flight log", checks: dict | None = None,
                imu_limit: dict | None = None):

    """ẑ (T, 8) and times (T,) (s from the log's start, first step at 2 ms) of a flight log read
    by :func:`~mjxsysid.logs.csvlog.read_log`, rebuilt by the frozen ``policy`` (a name, path or PolicyRef).

    The log's physics is checked first (:func:`~mjxsysid.logs.checks.check_log`): a log
    that cannot be right raises :class:`~mjxsysid.logs.checks.LogError` (naming ``source``)
    before any replay; then the policy's own actions on the logged inputs are compared with the
    logged motor commands. The findings (warnings) are appended to ``checks["findings"]``.
    ``imu_limit``: the IMU noise the decoders are calibrated under
    (:func:`~mjxsysid.logs.checks.imu_noise_limit`; default its shipped decoders' limit)."""
    found = check_log(rec, imu_limit=imu_limit)
    if any(f.level == "error" for f in found):
        raise LogError(source, found)
    ctrl = resolve_policy(policy).load()
    zhat_t = np.asarray(ctrl.replay(rec["imu"], rec["a_cmd"], rec["omega_cmd"], rec["motor"]))
    if hasattr(ctrl, "replay_actions"):
        found += check_replay(rec, ctrl, zhat_t)
    if checks is not None:
        checks.setdefault("findings", []).extend(found)
    return zhat_t, rec["t"] - rec["t"][0] + LOG_DT


def decoders_prior(*decoders) -> str | None:
    """The name of the prior the decoders were trained on (from their provenance), if it is a
    size-factor prior of :mod:`mjxsysid.theta` (what :func:`~mjxsysid.logs.checks.prior.prior_check` compares with)."""
    for d in decoders:
        name = (getattr(d, "meta", None) or {}).get("data", {}).get("pairs_meta", {}).get("prior")
        if name in P.PRIORS:
            return name
    return None


def flight_checks(rec: dict, prior: str | None, checks: dict | None = None) -> dict:
    """Out-of-prior check of a flight (a log's arrays, or a flown flight's): the log-only
    estimates of :func:`~mjxsysid.logs.checks.estimate_vehicle` against the decoders'
    ``prior`` -> ``checks`` with ``estimates``, ``prior``, ``findings`` (appended) and the
    summary's form (:func:`checks_summary`)."""
    checks = {} if checks is None else checks
    est = estimate_vehicle(rec)
    checks["estimates"] = est
    checks["prior"] = prior
    if prior is not None:
        checks.setdefault("findings", []).extend(prior_check(rec, prior, est))
    return checks


def checks_summary(checks: dict) -> dict:
    """The ``_checks`` entry of summary.json: warnings and out-of-prior findings as text, the
    log-only estimates, the prior compared with, ``out_of_prior`` (bool), ``notes`` (what the
    log could not tell: e.g. the motor time constant not estimable, its estimate then no
    measurement) and, for a log read from another format (a ULog), ``source`` (topics, rates,
    segment, conversions) and ``resampled`` (how each column group reached 2 ms)."""
    from mjxsysid.logs.checks import motor_time_constant
    found = checks.get("findings", [])
    oop = [str(f) for f in found if f.level == "out_of_prior"]
    est = checks.get("estimates", {})
    tau, why = motor_time_constant(est) if est else (None, None)
    out = {"warnings": [str(f) for f in found if f.level == "warning"], "out_of_prior": oop,
           "is_out_of_prior": bool(oop), "prior": checks.get("prior"),
           "estimates": {k: float(v) for k, v in est.items()}, "notes": [why] if est and tau is None else [],
           "motor_time_constant_estimable": tau is not None}
    for k in ("source", "resampled"):
        if checks.get(k) is not None:
            out[k] = checks[k]
    return out
