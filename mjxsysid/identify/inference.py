"""The log-grounded posterior: the stated physical prior × the log's likelihood, with the decoded
ensemble as the proposal and a tempered SMC where it misses.

Target: p(v) p(σ, bias) p(log | v, σ, bias; δ, w) (:mod:`.coords`, :mod:`.likelihood`), 17-d: the
visible coordinates v (12), the IMU noise σ per channel (4) and the accelerometer bias. The
discrepancy δ per channel and the weights w that discount correlated residuals
(:func:`~.likelihood.residual_weights`) are set at the joint mode (empirical Bayes: both are
properties of the log and the model, not of the vehicle, and δ's flat direction below the log's
resolution would otherwise spoil every proposal). The hidden coordinates h are independent of the
log, so θ = θ(v, h) with h drawn from the prior.

0. **The mode.** Levenberg–Marquardt (optimistix) on the standardised residuals from a linear
   least-squares start (at fixed τ_m the rate changes are linear in authority × ρ), from the
   decoded samples and from prior draws, δ re-set from the best fit's residuals between rounds;
   then the correlation discounts w, and a Gauss–Newton precision of the tempered Student-t
   residuals there (the Laplace proposal, a Student-t). From the mode, the fit with longer rate
   windows: the model check's window-length test (:mod:`.windowcheck`); under other command→speed maps
   (idle offsets, curved): its motor-map test (:mod:`.idlecheck`).
1. **Importance sampling from the decoders.** The decoded samples θ (S, 19) mapped to v are
   fitted by a Gaussian (widened by :data:`~.proposals.PROPOSAL_WIDEN`), the nuisances' proposal centred on
   the log's own noise estimate; N draws are weighted by target / proposal. Reported: the
   effective sample size and Pareto k̂ of the weights' upper tail (Vehtari et al., PSIS; the
   generalised-Pareto fit is scipy's). The decoded density is the proposal only, never a factor
   of the target: the latent came from the same log. Then from the Laplace proposal, likewise.
2. **Tempered SMC** (blackjax's adaptive tempered SMC, random-walk Metropolis moves whose
   covariance is the particles', re-estimated each stage) when the weights are unreliable
   (ESS < :data:`MIN_ESS_FRACTION` N or k̂ > :data:`MAX_KHAT`): from a mixture of the prior
   (:data:`PRIOR_SHARE`), the decoded and the Laplace proposals, tempered to the target (the path
   q^{1−λ} target^{λ}).
3. **NUTS from the SMC's draws** (:mod:`.nuts`): on a clean log the SMC's particles descend from few
   ancestors and its bands are about half the target's width. :data:`~.nuts.CHAINS` short NUTS
   chains, preconditioned by the SMC draws' covariance, replace its draws; their split R̂,
   bulk ESS and divergences are the fit's check.

The target is :mod:`.target`'s, the mode :mod:`.mode`'s, the SMC :mod:`.smc`'s, NUTS :mod:`.nuts`'s; this module
orchestrates them for one log (:func:`log_grounded_posterior`) or many (:func:`log_grounded_posteriors`).
"""
from __future__ import annotations

import os

import jax
import numpy as np

from mjxsysid.identify import idlecheck
from mjxsysid.identify import logspace as L
from mjxsysid.identify.batched import _Logs
from mjxsysid.identify.calibrate import SHIPPED, calibrate, for_method, load, log_features, window_features
from mjxsysid.identify.coords import PHYSICAL_PRIOR, PhysicalPrior, theta_from, visible_from_theta
from mjxsysid.identify.likelihood import N_NUIS, drag_at, linear_start
from mjxsysid.identify.posterior_config import PosteriorConfig, resolve
from mjxsysid.identify.logdata import LogData, LogTooShort, prepare
from mjxsysid.identify.mode import LAPLACE_WIDEN, find_modes
from mjxsysid.identify.nuts import unmixed_not_seen
from mjxsysid.identify.nuts import refine as nuts_refine
from mjxsysid.identify.nuts import refine_plans
from mjxsysid.identify.proposals import decoded_proposal, ess, nuisance_proposal, pareto_khat
from mjxsysid.identify.smc import PRIOR_SHARE, RW_TARGET_ACCEPTANCE, _smc_start, rw_scale_update
from mjxsysid.identify.windowcheck import run as window_check
from mjxsysid.identify.target import (ACC_BIAS_SD, N_Y, NUIS_BOUNDS, TARGET_CHUNK, full_precision, full_x,
                                      log_prior, log_target)
from mjxsysid.runtime.ahead import Ahead
from mjxsysid.runtime.hostpool import HostPool

__all__ = ["ACC_BIAS_SD", "LAPLACE_WIDEN", "LOG_BATCH", "MAX_KHAT", "MIN_ESS_FRACTION", "N_Y", "NUIS_BOUNDS",
           "PRIOR_SHARE", "RW_TARGET_ACCEPTANCE", "TARGET_CHUNK", "default_method", "find_mode", "find_modes",
           "full_precision", "full_x", "log_grounded_posterior", "log_grounded_posteriors", "log_prior",
           "log_target", "refine_posterior", "rw_scale_update"]

MIN_ESS_FRACTION = 0.05


MAX_KHAT = 0.7
"""Importance sampling is trusted when ESS ≥ 5 % of the draws and k̂ ≤ 0.7 (PSIS's threshold)."""


@full_precision
def find_mode(data: LogData, starts, prior: PhysicalPrior = PHYSICAL_PRIOR, rounds: int = 3):
    """The mode from ``starts`` (K, 21) -> (x* (21,), log δ* (4,), weights (4,), y* (17,), the
    Laplace Student-t at y*). δ and σ are fixed while v and the bias are fitted (Levenberg–Marquardt
    from every start, in later rounds from its previous fit), δ then set from the best fit's
    residuals, ``rounds`` times (δ free in the
    same fit lets a poor start explain the rates as discrepancy and stay there; a Student-t BFGS
    from a good start wandered off in float32); then the correlation discounts w are set."""
    return find_modes(_Logs([data]), np.asarray(starts, np.float32)[None], prior, rounds)[0]


def _ess_diag(lw) -> dict:
    """Importance weights' diagnostics: ESS, and Pareto k̂ where the ESS passes (a generalised
    Pareto fit, tens of ms; below :data:`MIN_ESS_FRACTION` the weights are unreliable whatever
    k̂ says: ``khat`` None)."""
    e = ess(lw)
    frac = e / len(lw)
    return {"ess": e, "draws": len(lw), "ess_fraction": frac,
            "khat": pareto_khat(lw) if frac >= MIN_ESS_FRACTION else None}


def _reliable(diag) -> bool:
    return diag["ess_fraction"] >= MIN_ESS_FRACTION and diag["khat"] is not None and diag["khat"] <= MAX_KHAT


def default_method(out: dict) -> str:
    """The method a posterior's importance diagnostics choose without ``force_smc``: the decoded
    proposal's, else the Laplace's, where their weights are reliable; else 'smc'."""
    for name in ("decoded_is", "laplace_is"):
        if name in out and _reliable(out[name]):
            return name
    return "smc"


@full_precision
def log_grounded_posterior(rec_or_data, decoded_theta=None, *, prior: PhysicalPrior = PHYSICAL_PRIOR,
                           seed: int = 0, config: PosteriorConfig | None = None, **settings) -> dict:
    """The posterior of a flight log (``rec_or_data``: the arrays of ``read_log`` or a
    :class:`LogData`) under the physical ``prior``, with ``decoded_theta`` (S, 19) — the decoders'
    samples of this log, or None — as the proposal (module doc). ``config``: a
    :class:`~.posterior_config.PosteriorConfig` (None: :data:`~.posterior_config.DEFAULT`); ``settings``: fields of it
    that override it (samples, draws, particles, n_mcmc, max_stages, starts, force_smc, refine, rates,
    calibration; a :class:`LogData` carries its own rates). It is :func:`log_grounded_posteriors` of one log.

    -> dict: ``theta`` (samples, 19) (hidden coordinates drawn from the prior), ``v`` (samples, 12),
    ``nuisance`` (samples, 9: log σ (4), log δ (4, fixed), bias), ``method`` ('decoded_is',
    'laplace_is', 'smc_nuts', or 'smc' with ``refine=False`` or where NUTS did not mix), ``decoded_is`` / ``laplace_is`` ({ess, ess_fraction, khat}),
    ``weights`` (4,) the channels' correlation discounts, ``mode`` (21,), ``channels_used`` (4,),
    and for SMC ``smc_stages``, ``smc_acceptance`` (the moves' acceptance rate, mean over the stages),
    ``smc_acceptance_min`` (the lowest stage's), ``smc_tempering`` (1 when it reached the target),
    and after NUTS ``nuts`` (``attempts``, chains, warm-up, draws per chain, ``converged``, ``why`` and ``kept``, the largest
    split R̂, the smallest bulk ESS, divergences, leapfrog steps per draw; after a second attempt ``first``: the first's
    ``why``, largest R̂ and smallest ESS). ``refine=False`` keeps the
    SMC's draws (step 3 of the module doc skipped).

    ``calibration``: "shipped" (default: the table fitted on simulated logs,
    :mod:`.calibrate`), a table (dict) or a path to one, or None for the raw posterior. The draws
    ``v`` / ``theta`` are the calibrated ones; ``v_raw`` the raw ones; ``features`` what the log
    shows; ``calibration`` the report (scale factor and group per coordinate, the model check,
    ``seen`` (12,) and ``why`` (12,) per visible coordinate, ``table`` the file it came from)."""
    dec = None if decoded_theta is None else [decoded_theta]
    return log_grounded_posteriors([rec_or_data], dec, seeds=[seed], prior=prior, config=config, batch=1, workers=1,
                                   **settings)[0]


LOG_BATCH = 1024
"""The most logs evaluated together on an accelerator (:func:`default_batch`; on a CPU one at a time: its
cores are busy with one log's particles already). Batches of 10 s logs at × 1 on one H200, each cold from an
empty cache: 256 logs 1.43 logs/s, 512 1.81–1.97, 1,024 2.32 (``benchmarks/batched_posterior.py --vehicles N
--batch N``, 2026-11-30): each NUTS step of a batch waits for its deepest tree, so fuller batches cost less."""

PEAK_BYTES_PER_DATA_BYTE = 250
"""The accelerator memory a log holds at the batch's peak, per byte of its reduced arrays (:class:`LogData`):
1,024 logs of 10 s (172 kB each) peaked at 37,753 MiB on an H200 (nvidia-smi; 224 bytes a byte, rounded up)."""

MEMORY_SHARE = 0.6
"""The share of the accelerator's memory (its allocator's limit) a batch may fill."""


def batch_for(data_bytes: int, device_bytes: int | None) -> int:
    """Logs of ``data_bytes`` each (their :class:`LogData`) evaluated together on an accelerator whose
    allocator may hold ``device_bytes`` (None: it does not say): the largest power of two up to
    :data:`LOG_BATCH` whose peak (:data:`PEAK_BYTES_PER_DATA_BYTE`) fills at most :data:`MEMORY_SHARE` of it;
    256 where the device does not say."""
    if not device_bytes:
        return 256
    n = int(MEMORY_SHARE * device_bytes // (PEAK_BYTES_PER_DATA_BYTE * max(int(data_bytes), 1)))
    return max(1, min(LOG_BATCH, 1 << (n.bit_length() - 1) if n else 1))


def default_batch(data: LogData) -> int:
    """Logs of ``data``'s shape evaluated together by default: one on a CPU, else :func:`batch_for` of its
    size and the first device's memory (longer logs, smaller batches)."""
    if jax.default_backend() == "cpu":
        return 1
    stats = jax.devices()[0].memory_stats() or {}
    return batch_for(sum(np.asarray(a).nbytes for a in jax.tree.leaves(data)), stats.get("bytes_limit"))


@full_precision
def log_grounded_posteriors(logs, decoded_thetas=None, *, prior: PhysicalPrior = PHYSICAL_PRIOR, seeds=0,
                            config: PosteriorConfig | None = None, batch: int | None = None,
                            workers: int | None = None, desc: str | None = None, **settings) -> list[dict]:
    """The posteriors of many logs (paths of any format, or what :func:`log_grounded_posterior`
    takes), batched:
    logs of one shape (their windows and blocks bucketed, :func:`~.logdata.bucket`) and of one kind
    of proposal are evaluated ``batch`` at a time (default :func:`default_batch`: up to :data:`LOG_BATCH` on an
    accelerator, as its memory holds; 1 on a CPU) by programs vmapped over the logs. ``decoded_thetas``: None, or one (S, 19) or None per
    log; ``seeds``: one per log, or an int (log i gets seeds + i); ``workers``: processes that reduce
    the logs (:func:`~.logdata.prepare`, and again under the longer rate windows and each motor map,
    :func:`~.windowcheck.run`, :func:`~.idlecheck.run`: one :class:`~mjxsysid.runtime.hostpool.HostPool` for
    the call; default 1 on a CPU, up to 16 beside an accelerator);
    ``desc``: a progress bar's label; ``config`` and ``settings`` as :func:`log_grounded_posterior`'s. The SMC's
    and NUTS's programs compile on a thread of the call's own (:class:`~mjxsysid.runtime.ahead.Ahead`) while the
    mode is found.
    A log too short for the posterior raises
    :class:`~.logdata.LogTooShort` naming its index.
    -> one dict per log, in order, as :func:`log_grounded_posterior` returns it (the same draws up
    to float rounding, whatever the batch)."""
    from mjxsysid.runtime.progress import progress
    logs = list(logs)
    n = len(logs)
    dec = [None] * n if decoded_thetas is None else list(decoded_thetas)
    seeds = [int(seeds) + i for i in range(n)] if np.ndim(seeds) == 0 else [int(s) for s in seeds]
    if len(dec) != n or len(seeds) != n:
        raise ValueError(f"log_grounded_posteriors: {n} logs, {len(dec)} decoded ensembles and {len(seeds)} seeds; "
                         "give one of each per log")
    c = resolve(config, **settings)
    cfg = dict(prior=prior, samples=c.samples, draws=c.draws, particles=c.particles, n_mcmc=c.n_mcmc,
               max_stages=c.max_stages, starts=c.starts, force_smc=c.force_smc, refine=bool(c.refine),
               calibration=c.calibration, shared_maps=c.shared_maps)
    rates = c.rates
    if workers is None:
        workers = 1 if jax.default_backend() == "cpu" else min(16, os.cpu_count() or 1)
    if batch is not None and int(batch) < 1:
        raise ValueError(f"log_grounded_posteriors: batch must be ≥ 1, got {batch}")
    if int(workers) < 1:
        raise ValueError(f"log_grounded_posteriors: workers must be ≥ 1, got {workers}")
    out = [None] * n
    with HostPool(int(workers)) as pool, Ahead() as ahead:  # one pool of processes for every reduction of the call
        datas = _prepare_all(logs, rates, pool)
        qvs = [None if d is None else decoded_proposal(d, prior) for d in dec]
        chunks = log_chunks(datas, [q is None for q in qvs], batch)
        for chunk in progress(chunks, desc=desc or "log-grounded posteriors", enabled=False if len(chunks) < 2 else None):
            res = _posterior_batch([datas[i] for i in chunk], [dec[i] for i in chunk], [qvs[i] for i in chunk],
                                   [seeds[i] for i in chunk], pool=pool, ahead=ahead, **cfg)
            for i, r in zip(chunk, res):
                out[i] = r
    return out


def log_chunks(datas: list[LogData], plain: list[bool], batch: int | None) -> list[list[int]]:
    """The logs' indices evaluated together: logs of one shape (rates and every array's shape) and one
    kind of proposal (``plain``: no decoded ensemble), ``batch`` at a time (None: :func:`default_batch` of
    the group's shape), in order within a group. -> chunks of indices covering 0…len(datas)-1 once."""
    groups: dict = {}
    for i, (d, q) in enumerate(zip(datas, plain)):
        key = (d.rates, bool(q), tuple(np.shape(a) for a in jax.tree.leaves(d)))
        groups.setdefault(key, []).append(i)
    out = []
    for idx in groups.values():
        b = default_batch(datas[idx[0]]) if batch is None else int(batch)
        out += [idx[c:c + b] for c in range(0, len(idx), b)]
    return out


def _prepare_one(x, rates: str, i: int):
    """Log i (a path of any format, a log's arrays or a :class:`LogData`) -> its :class:`LogData`."""
    if isinstance(x, LogData):
        return x
    if isinstance(x, (str, os.PathLike)):
        from mjxsysid.logs.csvlog import read_any_log
        x = read_any_log(x)
    try:
        return prepare(x, rates=rates)
    except LogTooShort as e:
        raise LogTooShort(f"log {i}: {e}") from None


def _prepare_all(logs, rates: str, pool: HostPool) -> list:
    """Each log's :class:`LogData` (those given as one kept), on the processes of ``pool`` where it has
    enough logs for them (a reduction is many small NumPy calls: threads wait on each other's interpreter lock)."""
    if all(isinstance(x, LogData) for x in logs):
        return list(logs)
    return pool.map(_prepare_one, logs, [rates] * len(logs), range(len(logs)))


def _starts(data, decoded_theta, rng, prior, starts: int) -> np.ndarray:
    """The mode's ``starts`` starting points (starts, 21), always as many (one compiled fit): a
    linear start, the decoded samples, prior draws."""
    x_lin = linear_start(data)
    sv = [prior.sample_v(rng, max(starts // 3, 1))]
    if decoded_theta is not None:
        dv = np.asarray(visible_from_theta(np.asarray(decoded_theta, np.float32)), np.float32)
        dv = dv[np.all(np.isfinite(dv), 1) & np.asarray(prior.v_valid(dv))][: starts - len(sv[0]) - 1]
        sv.append(dv)
    n_fill = max(starts - 1 - sum(len(a) for a in sv), 0)
    if n_fill:
        sv.append(prior.sample_v(rng, n_fill))
    sv = np.concatenate(sv)
    return np.concatenate([x_lin[None], np.concatenate([sv, np.broadcast_to(x_lin[L.X_NUIS], (len(sv), N_NUIS))], 1)])


_STREAMS = ("is", "nuisance", "mixture", "hidden", "resample", "starts", "laplace", "nuts")
"""A log's host random streams, one generator per use."""


def _streams(seed: int) -> dict:
    """{use: generator} of :data:`_STREAMS` from a log's seed."""
    return dict(zip(_STREAMS, (np.random.default_rng(s) for s in np.random.SeedSequence(seed).spawn(len(_STREAMS)))))


def _nuts_seed(r) -> int:
    """The NUTS chains' seed from a log's "nuts" stream."""
    return int(r.integers(2 ** 31))


@full_precision
def refine_posterior(rec_or_data, post: dict, *, seed: int = 0, prior: PhysicalPrior = PHYSICAL_PRIOR,
                     calibration="shipped") -> dict:
    """An SMC posterior of the log ``rec_or_data`` (:func:`log_grounded_posterior` with ``refine=False``)
    refined by NUTS (step 3 of the module doc): the same as ``refine=True`` with that ``seed`` gives,
    from the SMC's draws, mode, δ and weights in ``post`` (nothing sampled again). -> a new dict."""
    if post.get("method") != "smc" or "nuts" in post:
        raise ValueError(f"refine_posterior: needs an SMC posterior without NUTS, not {post.get('method')!r}")
    data = rec_or_data if isinstance(rec_or_data, LogData) else prepare(rec_or_data, rates=post["rates"])
    ys = L.y_from_x(np.concatenate([post["v_raw"], post["nuisance"]], 1)).astype(np.float32)
    mode = np.asarray(post["mode"], np.float32)
    ld, w, r = mode[L.X_LOG_DISCREPANCY], np.asarray(post["weights"], np.float32), _streams(seed)
    out, draws = dict(post), [ys]           # refined in place: NUTS's draws, or the SMC's kept
    nuts_refine(_Logs([data]), [0], draws, [L.y_from_x(mode)], ld[None], w[None], prior, [_nuts_seed(r["nuts"])],
                len(ys), [out])
    return _finish(out, draws.pop(), data, ld, prior, calibration, seed, r["hidden"], len(ys))


def _posterior_batch(datas, decs, qvs, seeds, *, prior, samples, draws, particles, n_mcmc, max_stages, starts,
                     force_smc, refine, calibration, pool: HostPool, ahead: Ahead, shared_maps=()) -> list[dict]:
    """:func:`log_grounded_posteriors` of logs of one shape and one kind of proposal (module doc); the SMC's and
    NUTS's programs compile on ``ahead``'s thread while the mode is found."""
    nl = len(datas)
    logs = _Logs(datas)
    # host draws from NumPy generators (they compile nothing); the SMC's key is PRNGKey(seed)'s bits
    rng = [_streams(seed) for seed in seeds]
    r_is, r_n, r_mix, r_h, r_res, r_st, r_lp, r_nuts = ([g[k] for g in rng] for k in _STREAMS)
    qns = [nuisance_proposal(d, ACC_BIAS_SD) for d in datas]
    logs.compile_ahead(ahead, qvs, qns, prior, particles=particles, n_mcmc=n_mcmc, max_stages=max_stages,
                       plans=refine_plans(samples) if refine else None)
    # 0. the mode
    st = np.stack([_starts(d, dc, r_st[i], prior, starts) for i, (d, dc) in enumerate(zip(datas, decs))])
    modes = find_modes(logs, st.astype(np.float32), prior)
    ld = np.stack([m[1] for m in modes]).astype(np.float32)
    w = np.stack([m[2] for m in modes]).astype(np.float32)
    laps = [m[4] for m in modes]
    checks = window_check(_Logs, datas, modes, prior, starts, pool)        # the fit at longer rate windows (.windowcheck)
    idles = idlecheck.run(_Logs, datas, modes, starts, shared_maps, pool)   # the fit under other motor maps (.idlecheck)
    outs = [{"proposal": "decoded" if qvs[i] is not None else "prior", "mode": modes[i][0], "weights": modes[i][2],
             "channels_used": np.asarray(d.use), "rates": d.rates, "window_check": checks[i], "idle_check": idles[i]}
            for i, d in enumerate(datas)]
    chosen = [None] * nl
    # 1. the decoded ensemble as the proposal, then the Laplace proposal
    if qvs[0] is not None:
        ys = np.stack([np.concatenate([q.sample(r_is[i], draws), qns[i].sample(r_n[i], draws)], 1) for i, q in enumerate(qvs)])
        lt = logs.targets(ys, ld, w, prior)
        for i, q in enumerate(qvs):
            lw = lt[i].astype(np.float64) - np.asarray(q.log_prob(ys[i, :, L.Y_V]) + qns[i].log_prob(ys[i, :, L.Y_NUIS]), np.float64)
            outs[i]["decoded_is"] = _ess_diag(lw)
            if default_method(outs[i]) == "decoded_is" and not force_smc:
                chosen[i] = ("decoded_is", ys[i], lw)
    need = [i for i in range(nl) if chosen[i] is None]
    if need:
        ys = np.stack([laps[i].sample(r_lp[i], draws) for i in need])
        lt = logs.targets(ys, ld[need], w[need], prior, idx=need)
        for j, i in enumerate(need):
            lw = lt[j].astype(np.float64) - np.asarray(laps[i].log_prob(ys[j]), np.float64)
            outs[i]["laplace_is"] = _ess_diag(lw)
            if default_method(outs[i]) == "laplace_is" and not force_smc:
                chosen[i] = ("laplace_is", ys[j], lw)
    draws_y = [None] * nl
    for i, c in enumerate(chosen):
        if c is not None:
            name, y, lw = c
            p = np.exp(lw - lw.max())
            draws_y[i] = y[r_res[i].choice(len(y), samples, p=p / p.sum())]
            outs[i]["method"] = name
    # 2. tempered SMC from a mixture of the proposals and the prior
    need = [i for i in range(nl) if chosen[i] is None]
    if need:
        y0 = np.stack([_smc_start(prior, qvs[i], qns[i], laps[i], particles, r_mix[i], r_n[i], r_lp[i], r_is[i])
                       for i in need])
        keys = np.stack([np.array([0, seeds[i] & 0xFFFFFFFF], np.uint32) for i in need])
        pts, wts, lam, stages, acc, acc_min = logs.smc(need, keys, y0, ld[need], w[need], [qvs[i] for i in need],
                                                       [qns[i] for i in need], [laps[i] for i in need], prior,
                                                       n_mcmc, max_stages)
        for j, i in enumerate(need):
            wt = np.asarray(wts[j], np.float64)
            draws_y[i] = np.asarray(pts[j])[r_res[i].choice(particles, samples, p=wt / wt.sum())]
            outs[i].update(method="smc", smc_stages=int(stages[j]), smc_acceptance=float(acc[j]),
                           smc_acceptance_min=float(acc_min[j]), smc_tempering=float(lam[j]))
        if refine:
            nuts_refine(logs, need, draws_y, [modes[i][3] for i in need], ld[need], w[need], prior,
                        [_nuts_seed(r_nuts[i]) for i in need], samples, outs)
    return [_finish(outs[i], draws_y[i], datas[i], ld[i], prior, calibration, seeds[i], r_h[i], samples)
            for i in range(nl)]


def _finish(out: dict, ys, data, ld, prior, calibration, seed, r_h, samples) -> dict:
    """One log's draws y (samples, 17) -> its posterior dict: θ, v, the features, the drag, the measured rotor
    speeds' use (:func:`~.speeds.report`, where the log was prepared in this process), the calibration."""
    mode = out["mode"]
    out["rotor_speed"] = getattr(data, "_rows", {}).get("speed")
    xs = np.asarray(full_x(ys, ld))
    v_raw = xs[:, L.X_V]
    out["features"] = (log_features(data, mode) | window_features(out.get("window_check"))
                       | idlecheck.features(out.get("idle_check")))
    if out["features"]["velocity_used"]:     # (3,) 1/s: x and y from the accelerometer's x and y, z from its term
        xy = getattr(data, "_rows", {}).get("drag_xy")
        out["drag_per_mass"] = [*(xy.tolist() if xy is not None else [None, None]), drag_at(mode, data)]
    else:
        out["drag_per_mass"] = None
    v, out["calibration"] = _calibrated(v_raw, out["features"], out["weights"], calibration, prior, seed,
                                        out.get("method"))
    if "nuts" in out and out["calibration"].get("applied"):
        v = unmixed_not_seen(out["calibration"], out["nuts"], v,
                             lambda n: prior.sample_v(np.random.default_rng(seed), n))
    h = prior.sample_h(r_h, samples)
    out.update(v=v, v_raw=v_raw, nuisance=xs[:, L.X_NUIS], theta=np.asarray(theta_from(v, h), np.float32))
    return out


def _calibrated(v_raw, features, weights, calibration, prior, seed, method=None):
    """The raw draws through the calibration table (``calibration``: "shipped", a dict, a path or
    None; its table for ``method`` where it has one, :func:`~.calibrate.for_method`) -> (draws (S, 12), report)."""
    if calibration is None:
        return v_raw, {"applied": False, "why": "calibration=None: the raw posterior"}
    table = load() if calibration == "shipped" else calibration if isinstance(calibration, dict) else load(calibration)
    own = for_method(table, method)
    v, rep = calibrate(v_raw, features, weights, own, prior, rng=seed)
    rep.update(applied=True, method_table=method if own is not table else "pooled", table=str(SHIPPED) if calibration == "shipped" else
               (str(calibration) if not isinstance(calibration, dict) else "a table given in Python"))
    return v, rep
