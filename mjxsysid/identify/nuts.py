"""NUTS on the log-grounded target (step 3 of :mod:`.inference`): short chains from the SMC's draws
that make its draws the target's, and the long runs that check them.

The SMC's particles come from few ancestors on a clean log: its 90 % bands are about half as wide
as a long NUTS run's on the same target and shifted by up to one of its band widths
(``mjxsysid experiment sampler-reference``). Its draws still give a good scale: NUTS, preconditioned
by their covariance, mixes within a few hundred steps (preconditioned by the Laplace proposal's draws
instead, 3 of 9 logs mixed, against 9 of 9: docs/identify.md). So every SMC posterior ends with
:data:`CHAINS` chains of NUTS (blackjax: Stan's window adaptation with a dense mass matrix for
:data:`WARMUP` steps, then the draws), and its split R̂, bulk ESS and divergences are the fit's
check (:func:`converged`).

Coordinates. NUTS runs in unconstrained coordinates z (:func:`to_constrained`): the prior's box
through a logistic map, with J's triangle inequality built into the yaw-axis authority's lower
bound; only ρ_4's range stays a wall of −inf. There, an affine map u -> m + L u (m the mode, L L^T
the SMC draws' covariance, :func:`preconditioner`) makes the posterior's scales of order one: a
clean log's posterior is 10⁻⁴ wide in some directions and 1 in others, below the floor blackjax's
mass-matrix estimate regularises towards (10⁻³). The map only conditions the sampler: the target is
the same, and R̂ across chains started apart checks it.
"""
from __future__ import annotations

import functools

import jax
import jax.numpy as jnp
import numpy as np

from mjxsysid.identify import logspace as L
from mjxsysid.identify.coords import PHYSICAL_PRIOR, PhysicalPrior
from mjxsysid.identify.target import N_Y, _log_target_y, _y_lo_hi
from mjxsysid.runtime import exported
from mjxsysid.theta import xp_of

CHAINS = 8
"""NUTS chains after an SMC (their draws pooled: ``samples`` / CHAINS each)."""
WARMUP = 200
"""Their warm-up steps (window adaptation). On five clean logs, 8 chains × (200 + 125) gave bands
0.95–1.02 as wide as 4 × (1000 + 2000) and quantiles within 0.02 of its band widths (median; 0.15
at most), against the SMC's 0.46–0.66 and 0.22 (1.0)."""
TARGET_ACCEPTANCE = 0.95
"""The warm-up's target acceptance rate (blackjax's default is 0.8). On an × 1 log, 0.8 left 32
divergent transitions of 8,000; 0.95 left 4, for 3× the leapfrog steps."""
INIT_JITTER = 1.0
"""Each chain starts at the mode plus N(0, this²) in the preconditioned coordinates u (one SMC
posterior standard deviation per direction)."""
RHAT_OK = 1.1
"""A fit whose largest split R̂ (over the 17 coordinates) reaches this has not mixed
(:func:`converged`; Vehtari et al. 2021 ask 1.01 of a final analysis: these chains are short)."""
ESS_OK = 100
"""…or whose smallest bulk ESS is below this. Divergent draws are reported, not judged: ρ_4's range
is a wall of −inf that trajectories hit where the log leaves ρ broad (PX4's sample: 64 % of draws),
and a trajectory that hits it is rejected, which leaves the chain correct."""
MAX_DOUBLINGS = 7
"""The refinement's trees stop at 2^7 − 1 = 127 leapfrog steps (blackjax's default: 10). Clean
logs take 20–80 a draw; vmapped over logs and chains, every step waits for the deepest tree.
The long reference runs keep 10."""
LONGER = (2, 4)
"""A fit that did not mix runs once more with these times the warm-up and the draws (the draws
thinned back to as many), in the same compiled program (:func:`window_nuts`)."""

_A = L.Y_INDEX["log_authority"]
AX, AY, AZ = range(_A.start, _A.stop)
"""The body axes' authorities in y; AZ's lower bound carries J's triangle inequality."""


# ---- the unconstrained coordinates -------------------------------------------------------------

def _log_sigmoid(xp, z):
    return -xp.logaddexp(0.0, -z)


def _sigmoid(xp, z):
    return xp.exp(_log_sigmoid(xp, z))


def lower_bounds(y, lo):
    """The support's lower bound per coordinate (..., 17) at y (..., 17): the box's ``lo`` (17,), with
    log Aᵉ_z's raised to J's triangle inequality, −log(1/Aᵉ_x + 1/Aᵉ_y)."""
    xp = xp_of(y)
    tri = -xp.logaddexp(-y[..., AX], -y[..., AY])
    low = xp.broadcast_to(xp.asarray(lo, y.dtype), y.shape)
    return xp.concatenate([low[..., :AZ], xp.maximum(low[..., AZ], tri)[..., None], low[..., AZ + 1:]], -1)


def to_constrained(z, lo, hi):
    """z (..., 17) in R^17 -> y (..., 17) inside the support: y_j = l_j + (hi_j − l_j) sigmoid(z_j),
    l the box's ``lo`` except log Aᵉ_z's, which the triangle inequality raises (:func:`lower_bounds`;
    it depends on the x and y authorities alone, so the map is triangular)."""
    xp = xp_of(z)
    z = xp.asarray(z)
    lo, hi = xp.asarray(lo, z.dtype), xp.asarray(hi, z.dtype)
    y = lo + (hi - lo) * _sigmoid(xp, z)
    low = lower_bounds(y, lo)
    return xp.concatenate([y[..., :AZ], (low + (hi - low) * _sigmoid(xp, z))[..., AZ:AZ + 1], y[..., AZ + 1:]], -1)


def to_unconstrained(y, lo, hi, eps: float = 1e-6):
    """The inverse of :func:`to_constrained`: y (..., 17) -> z (..., 17) (a point on the support's
    edge is moved ``eps`` of its range inside)."""
    xp = xp_of(y)
    y = xp.asarray(y)
    low = lower_bounds(y, lo)
    p = xp.clip((y - low) / (xp.asarray(hi, y.dtype) - low), eps, 1.0 - eps)
    return xp.log(p) - xp.log1p(-p)


def log_jacobian(z, lo, hi):
    """log |det ∂y/∂z| (...) of :func:`to_constrained` at z (..., 17): the Jacobian is triangular, so
    the sum of log((hi_j − l_j) sigmoid(z_j) sigmoid(−z_j))."""
    xp = xp_of(z)
    z = xp.asarray(z)
    low = lower_bounds(to_constrained(z, lo, hi), lo)
    return xp.sum(xp.log(xp.asarray(hi, z.dtype) - low) + _log_sigmoid(xp, z) + _log_sigmoid(xp, -z), -1)


def unconstrained_log_density(z, data, log_delta, weights, lo, hi, prior: PhysicalPrior = PHYSICAL_PRIOR):
    """The SMC's target at y = :func:`to_constrained` (z) (17,) plus the log-Jacobian: the density
    of z that NUTS samples."""
    y = to_constrained(z, lo, hi)
    return _log_target_y(y, data, log_delta, weights, prior) + log_jacobian(z, lo, hi)


def preconditioner(draws_y, centre_y, lo, hi, ridge: float = 1e-3):
    """The affine map of the module doc from draws y (S, 17) and the centre y (17,): (m (17,), L (17, 17))
    with m the centre's unconstrained coordinates and L the Cholesky factor of the draws' covariance in
    them (its diagonal raised by ``ridge`` of itself, and by 1e-12: draws with fewer distinct rows
    than coordinates still give a map)."""
    z = to_unconstrained(np.asarray(draws_y, np.float64), lo, hi)
    cov = np.atleast_2d(np.cov(z.T))
    cov = cov + np.diag(ridge * np.diag(cov) + 1e-12)
    return to_unconstrained(np.asarray(centre_y, np.float64), lo, hi), np.linalg.cholesky(cov)


# ---- NUTS ---------------------------------------------------------------------------------------

@functools.lru_cache(maxsize=4)
def _window_engine(target_acceptance: float):
    """Stan's window adaptation as ``blackjax.window_adaptation`` runs it, dense mass matrix: its (init,
    update, final) and its schedule of ``num_steps`` -> (num_steps, 2) (blackjax's staged engine; the
    test ``test_one_loop_draws_are_blackjax_window_adaptation_s`` holds it to the public API's draws)."""
    from blackjax.adaptation import staged_adaptation as staged
    from blackjax.adaptation.metric_recipes import lookup_recipe
    from blackjax.adaptation.window_adaptation import _pick_recipe_name
    core = lookup_recipe(_pick_recipe_name(is_mass_matrix_diagonal=False)).build_core(
        imm_shrinkage_to_previous=0.0, initial_inverse_mass_matrix=None)
    core, schedule = staged._resolve_metric_and_schedule(core, None, None)
    return (*staged._make_engine(core, target_acceptance_rate=target_acceptance), schedule)


def plan(key, warmup: int, draws: int, total: int, target_acceptance: float = TARGET_ACCEPTANCE):
    """The steps of a chain that warms up for ``warmup`` steps and then draws ``draws``, padded to ``total``:
    key (2,) -> (each step's key (total, 2): the key's first half split into ``warmup`` keys, then its second
    half into ``draws``, as blackjax's ``window_adaptation(...).run`` and a scan of ``nuts(...).step`` split
    them; the warm-up's schedule (total, 2) int32: Stan's windows, then zeros). Traceable."""
    if warmup + draws > total:
        raise ValueError(f"NUTS's {warmup} warm-up steps and {draws} draws exceed the {total} steps planned")
    k_warm, k_draw = jax.random.split(key)
    keys = jnp.concatenate([jax.random.split(k_warm, warmup), jax.random.split(k_draw, draws),
                            jnp.zeros((total - warmup - draws, 2), key.dtype)])
    stages = np.zeros((total, 2), np.int32)
    with jax.ensure_compile_time_eval():                 # blackjax builds it with jnp: a constant, not a tracer
        stages[:warmup] = np.asarray(_window_engine(target_acceptance)[3](warmup), np.int32)
    return keys, stages


def window_nuts(logdensity, keys, stages, u, warmup, n_steps, thin, *, kept: int, target_acceptance: float,
                max_doublings: int, emit=lambda u: u):
    """One chain from u (D,) over the steps of :func:`plan` (keys (T, 2), stages (T, 2)): Stan's window
    adaptation for ``warmup`` steps, then NUTS draws (trees of at most 2^``max_doublings`` leapfrog steps)
    up to step ``n_steps``, every ``thin``-th kept (``warmup``, ``n_steps`` and ``thin`` may be traced:
    one program serves any lengths up to T) -> (``emit`` of the kept draws' positions (kept, ...),
    divergent transitions (), leapfrog steps (), both summed over every draw, the final step size ()).

    One loop holds the one NUTS kernel: during the warm-up it runs with the adaptation's step size and
    mass matrix and updates them, after it with their final values. The draws are those of blackjax's
    ``window_adaptation(...).run`` followed by ``nuts(...).step``, to the bit (the test
    ``test_one_loop_draws_are_blackjax_window_adaptation_s``); a program that held the two stages apart
    compiled the kernel twice, and another program for each length (on 2 cores, a 10 s log: 3 s to trace
    and compile each)."""
    import blackjax
    a_init, a_update, a_final, _ = _window_engine(target_acceptance)
    kernel = blackjax.nuts.build_kernel()

    def step(i, carry):
        s, ad, out, div, leap = carry
        warm = i < warmup
        final_step, final_imm = a_final(ad)
        s, info = kernel(keys[i], s, logdensity, jnp.where(warm, ad.step_size, final_step),
                         jnp.where(warm, ad.inverse_mass_matrix, final_imm), max_num_doublings=max_doublings)
        new = a_update(ad, (stages[i, 0], stages[i, 1]), s.position, s.logdensity_grad, info.acceptance_rate, i)
        ad = jax.tree.map(lambda x, y: jnp.where(warm, x, y), new, ad)
        j = i - warmup
        slot = jnp.clip(j // thin, 0, kept - 1)
        keep = (j >= 0) & (j % thin == 0)
        out = jax.tree.map(lambda o, e: o.at[slot].set(jnp.where(keep, e, o[slot])), out, emit(s.position))
        return s, ad, out, div + (~warm & info.is_divergent), leap + jnp.where(warm, 0, info.num_integration_steps)

    out = jax.tree.map(lambda e: jnp.zeros((kept,) + e.shape, e.dtype), jax.eval_shape(emit, u))
    start = (blackjax.nuts.init(u, logdensity), a_init(u, 1.0), out, jnp.int32(0), jnp.int32(0))
    _, ad, out, div, leap = jax.lax.fori_loop(0, n_steps, step, start)
    return out, div, leap, a_final(ad)[0]


def _chains(keys, u0, data, log_delta, weights, lo, hi, m, chol, attempt, prior, plans, target_acceptance,
            max_doublings):
    """:func:`window_nuts` per chain (keys (C, 2), u0 (C, 17)) on the log-grounded target in u, with the
    lengths ``plans[attempt]`` ((warm-up, draws, thinning) each; ``attempt`` traced: one program for every
    plan), z = m + chol u -> y (C, kept, 17), divergent transitions (C,), leapfrog steps (C,), step size (C,)."""
    total = max(w + d for w, d, _ in plans)
    kept = plans[0][1] // plans[0][2]

    def logdensity(u):
        return unconstrained_log_density(m + chol @ u, data, log_delta, weights, lo, hi, prior)

    def pick(values):
        return jnp.asarray(values)[attempt]

    def chain(key, u):
        ks, stages = zip(*(plan(key, w, d, total, target_acceptance) for w, d, _ in plans))
        return window_nuts(logdensity, pick(jnp.stack(ks)), pick(np.stack(stages)), u,
                           pick([w for w, _, _ in plans]), pick([w + d for w, d, _ in plans]),
                           pick([t for _, _, t in plans]), kept=kept, target_acceptance=target_acceptance,
                           max_doublings=max_doublings, emit=lambda u: to_constrained(m + chol @ u, lo, hi))

    return jax.vmap(chain)(keys, u0)


def _chains_logs(keys, u0, data, log_delta, weights, lo, hi, m, chol, attempt, prior, plans, target_acceptance,
                 max_doublings):
    """:func:`_chains` vmapped over logs (keys, u0, data, log δ, weights, m and chol with a leading log axis)."""
    def one(k, u, d, a, b, mm, c):
        return _chains(k, u, d, a, b, lo, hi, mm, c, attempt, prior, plans, target_acceptance, max_doublings)
    return jax.vmap(one)(keys, u0, data, log_delta, weights, m, chol)


def _program(keys, u0, data, log_delta, weights, lo, hi, m, chol, *, prior, plans: tuple, attempt: int,
             target_acceptance: float, max_doublings: int, logs: bool) -> tuple:
    """:func:`run_chains`'s checked plans and the (name, function, static arguments, arguments) of
    :func:`mjxsysid.runtime.exported.call` that runs them."""
    plans = tuple(tuple(int(x) for x in p) for p in plans)
    if not plans or any(len(p) != 3 for p in plans):
        raise ValueError(f"NUTS's plans must be (warm-up, draws, thinning) triples; got {plans}")
    if not 0 <= attempt < len(plans):
        raise ValueError(f"NUTS's attempt {attempt} is not among its {len(plans)} plans {plans}")
    if any(d % t or d // t != plans[0][1] // plans[0][2] for _, d, t in plans):
        raise ValueError(f"NUTS's plans {plans} must keep as many draws each, their draws a multiple of the thinning")
    static = {"prior": prior, "plans": plans, "target_acceptance": float(target_acceptance),
              "max_doublings": int(max_doublings)}
    fn, name = (_chains_logs, "nuts_logs") if logs else (_chains, "nuts")
    return plans, (name, fn, static, keys, u0, data, log_delta, weights, lo, hi, m, chol, np.int32(attempt))


def run_chains(keys, u0, data, log_delta, weights, lo, hi, m, chol, *, prior, plans: tuple, attempt: int = 0,
               target_acceptance: float = TARGET_ACCEPTANCE, max_doublings: int = MAX_DOUBLINGS, logs: bool = False):
    """NUTS chains keys (C, 2), u0 (C, 17) (``logs``: a leading log axis on keys, u0, data, log δ, weights, m
    and chol) run with the lengths ``plans[attempt]`` -> y (..., C, kept, 17), divergent transitions (..., C),
    leapfrog steps per draw (..., C), step size (..., C). ``plans``: every (warm-up, draws, thinning) the
    program serves, each keeping as many draws. :func:`_chains` (``logs``: :func:`_chains_logs`) is compiled
    once for them all, through :func:`mjxsysid.runtime.exported.call`: its trace (blackjax's window adaptation
    and NUTS) is kept on disk beside the compilation cache."""
    plans, call = _program(keys, u0, data, log_delta, weights, lo, hi, m, chol, prior=prior, plans=plans,
                           attempt=attempt, target_acceptance=target_acceptance, max_doublings=max_doublings, logs=logs)
    y, div, leap, step = exported.call(*call)
    return y, div, np.asarray(leap) / plans[attempt][1], step


def compile_chains(keys, u0, data, log_delta, weights, lo, hi, m, chol, *, prior, plans: tuple,
                   target_acceptance: float = TARGET_ACCEPTANCE, max_doublings: int = MAX_DOUBLINGS,
                   logs: bool = False) -> None:
    """Compile the program :func:`run_chains` runs with these arguments' shapes (every attempt), and run nothing;
    then R̂ and ESS of its draws (:func:`diagnostics`)."""
    plans, call = _program(keys, u0, data, log_delta, weights, lo, hi, m, chol, prior=prior, plans=plans,
                           attempt=0, target_acceptance=target_acceptance, max_doublings=max_doublings, logs=logs)
    exported.compile_only(*call)
    exported.compile_only("rhat_ess", _rhat_ess_impl, {},
                          jnp.zeros((np.shape(keys)[-2], plans[0][1] // plans[0][2], N_Y), jnp.float32))


def _f32(a):
    return jnp.asarray(a, jnp.float32)


def start(draws_y, centre_y, chains: int, seed: int, prior: PhysicalPrior = PHYSICAL_PRIOR):
    """One log's NUTS start: (keys (chains, 2), u0 (chains, 17), m (17,), chol (17, 17)) from the SMC's
    draws y (S, 17) and the mode y (17,) (:func:`preconditioner`), the chains at the mode jittered by
    :data:`INIT_JITTER`."""
    lo, hi = _y_lo_hi(prior)
    m, chol = preconditioner(draws_y, centre_y, lo, hi)
    u0 = INIT_JITTER * np.random.default_rng(seed).standard_normal((chains, N_Y))
    keys = np.asarray(jax.random.split(jax.random.PRNGKey(seed), chains))
    return keys, u0, m, chol


def _rhat_ess_impl(y):
    """blackjax's split R̂ and bulk ESS of draws y (C, D, 17) -> ((17,), (17,))."""
    from blackjax.diagnostics import ess_bulk, rhat
    return rhat(y), ess_bulk(y)


def _rhat_ess(y):
    """:func:`_rhat_ess_impl` compiled once per shape and exported (:func:`mjxsysid.runtime.exported.call`): called
    eagerly, its ESS's scans and conds were rebuilt for every log (on a GPU, 116 s of XLA compiles in 320 logs)."""
    return exported.call("rhat_ess", _rhat_ess_impl, {}, jnp.asarray(y, jnp.float32))


def diagnostics(y, divergent, leapfrog, step_size) -> dict:
    """Chains' draws y (C, D, 17), divergent transitions (C,), leapfrog steps per draw (C,), step sizes (C,) ->
    rank-normalised split R̂ (17,) (the larger of bulk and tail), bulk ESS (17,), divergences,
    leapfrog steps per draw, step sizes (blackjax.diagnostics)."""
    r, e = _rhat_ess(y)
    return {"rhat": np.asarray(r, np.float64), "ess_bulk": np.asarray(e, np.float64),
            "divergences": int(np.sum(divergent)), "leapfrog_mean": float(np.mean(leapfrog)),
            "step_size": np.asarray(step_size, np.float64)}


def converged(diag: dict) -> tuple[bool, str]:
    """Whether a fit's chains mixed (:data:`RHAT_OK`, :data:`ESS_OK`), and why not."""
    r, e = float(np.max(diag["rhat"])), float(np.min(diag["ess_bulk"]))
    what = f"split R̂ ≤ {r:.3f}, bulk ESS ≥ {e:.0f}, {diag['divergences']} divergent"
    if not np.isfinite(r) or r >= RHAT_OK:
        name = L.Y_NAMES[int(np.argmax(np.where(np.isfinite(diag["rhat"]), diag["rhat"], np.inf)))]
        return False, f"NUTS's chains disagree (split R̂ {r:.2f} ≥ {RHAT_OK} on {name})"
    if not e >= ESS_OK:
        return False, f"too few effective draws ({what}; at least {ESS_OK} needed)"
    return True, what


def refine_plans(samples: int) -> tuple:
    """The refinement's two runs, (warm-up, draws, thinning) per chain for ``samples`` draws over :data:`CHAINS`
    chains: the first, and the retry :data:`LONGER` times as long (thinned back to as many draws)."""
    per = -(-samples // CHAINS)
    return (WARMUP, per, 1), (LONGER[0] * WARMUP, per * LONGER[1], LONGER[1])


def refine(logs, need, draws_y, modes_y, ld, w, prior, seeds, samples, outs) -> None:
    """Step 3 of :mod:`.inference`: the SMC's draws of the logs ``need`` replaced by NUTS's (:data:`CHAINS`
    chains from the mode, preconditioned by the SMC's draws), in place; logs whose chains did not mix
    run once more with :data:`LONGER` times the warm-up and draws (thinned; ``attempts`` 2, ``first``: the first's
    ``why``, largest R̂ and smallest ESS), and keep the SMC's draws (``method`` 'smc') if they still do not: chains that did not meet would set the
    bands by where they started (× 5 vibration, 7 of 12 such logs: the SMC's draws held 78 of 84 truths, the
    pooled chains 74). Each log's
    ``nuts`` entry: its chains' diagnostics, whether they mixed and which draws were kept. ``logs``:
    :class:`~.batched._Logs` (its ``nuts``)."""
    plans = refine_plans(samples)                 # one program for both attempts
    smc_draws = {i: draws_y[i] for i in need}
    starts = [start(draws_y[i], my, CHAINS, sd, prior) for i, my, sd in zip(need, modes_y, seeds)]
    todo = list(range(len(need)))
    for attempt, (warmup, draws, thin) in enumerate(plans):
        keys, u0, m, chol = (np.stack([starts[j][k] for j in todo]) for k in range(4))
        if attempt:
            keys = keys ^ np.uint32(0x9E3779B9)          # fresh chains
        y, div, leap, step = logs.nuts([need[j] for j in todo], keys, u0, ld[todo], w[todo], m, chol, prior,
                                       plans, attempt)
        again = []
        for t, j in enumerate(todo):
            yj = np.asarray(y[t])
            diag = diagnostics(yj, div[t], leap[t], step[t])
            ok, why = converged(diag)
            i = need[j]
            draws_y[i] = yj.transpose(1, 0, 2).reshape(-1, N_Y)[:samples]   # every chain's draws in turn
            outs[i]["method"] = "smc_nuts"
            first = {"first": {k: outs[i]["nuts"][k] for k in ("why", "rhat_max", "ess_bulk_min")}} if attempt else {}
            outs[i]["nuts"] = {**first, "attempts": attempt + 1, "chains": CHAINS, "warmup": warmup, "draws": draws, "thin": thin, "converged": ok,
                               "why": why, "kept": "NUTS's draws", "rhat_max": float(np.max(diag["rhat"])),
                               "ess_bulk_min": float(np.min(diag["ess_bulk"])), "divergences": diag["divergences"],
                               "rhat_v": np.round(diag["rhat"][L.Y_V], 4).tolist(),
                               "chain_spread_v": np.round(np.ptp(yj[:, :, L.Y_V].mean(1), 0), 5).tolist(),
                               "leapfrog_mean": diag["leapfrog_mean"]}
            if not ok:
                again.append(j)
        if not again:
            return
        if attempt:
            for j in again:
                i = need[j]
                draws_y[i] = smc_draws[i]
                outs[i]["method"] = "smc"
                outs[i]["nuts"]["kept"] = "the SMC's draws: NUTS's chains did not mix"
        todo = again


def mixed_coords(rhat_v) -> np.ndarray:
    """Whether NUTS's chains mixed on each visible coordinate, from its split R̂ (12,) -> (12,) bool: R̂ below
    :data:`RHAT_OK` (NaN: not mixed)."""
    return np.asarray(rhat_v, np.float64) < RHAT_OK


def unmixed_not_seen(report: dict, nuts: dict, v=None, prior_draws=None):
    """A visible coordinate on which NUTS's chains disagree (split R̂ ≥ :data:`RHAT_OK`) is not
    seen by the log, whatever its band's width: the fit did not converge there (where no chain mixed,
    the posterior keeps the SMC's draws: :func:`refine`, and on a flat ridge, a hover's authorities, the SMC's
    band is narrow and wrong). With draws ``v`` (S, 12) and ``prior_draws`` (n -> prior draws (n, 12), called
    only where a coordinate did not mix), those coordinates are drawn from the prior, as a failed model
    check's (a band only where the chains' means, ``chain_spread_v``, lie further apart than it is wide held
    4 of 6 hovers' roll authorities, not 6: docs/identify.md). Returns the draws (``v`` itself where none is
    replaced)."""
    bad = [int(j) for j in np.flatnonzero(~mixed_coords(nuts["rhat_v"]))]
    spread = nuts.get("chain_spread_v")
    for j in bad:
        report["seen"][j] = False
        report["why"][j] = (f"NUTS's chains disagree on it (split R̂ {nuts['rhat_v'][j]:.2f} ≥ {RHAT_OK}"
                            + (f", their means {spread[j]:.2g} apart" if spread is not None else "")
                            + "): the fit did not mix" + ("; as broad as the prior" if prior_draws is not None else ""))
    if v is None or prior_draws is None or not bad:
        return v
    v = np.array(v, copy=True)
    v[:, bad] = np.asarray(prior_draws(len(v)), v.dtype)[:, bad]
    if "factor" in report:
        report["factor"] = np.asarray(report["factor"], np.float64).copy()
        report["factor"][bad] = np.nan
    return v


def nuts_reference(data, log_delta, weights, start_y, scale_draws, *, chains: int, warmup: int, draws: int,
                   seed: int = 0, target_acceptance: float = TARGET_ACCEPTANCE, max_doublings: int = 10,
                   prior: PhysicalPrior = PHYSICAL_PRIOR, plans: tuple | None = None) -> dict:
    """NUTS on the log-grounded target of ``data`` (a LogData) at fixed log δ (4,) and weights (4,),
    in the coordinates :func:`preconditioner` makes of ``start_y`` (17,) (the mode) and
    ``scale_draws`` (S, 17) (the SMC's draws); ``chains`` chains started at the mode jittered by
    :data:`INIT_JITTER`; ``target_acceptance``: the warm-up's; ``plans``: those of the compiled program it runs in
    (:func:`run_chains`), the first (``warmup``, ``draws``, 1) (default: that alone; the refinement's own plans, with
    its chains and ``max_doublings``, run in the refinement's program). -> dict: ``y`` (chains, draws, 17) and
    :func:`diagnostics`."""
    if chains < 2 or warmup < 10 or draws < 4:
        raise ValueError(f"NUTS needs chains >= 2, warmup >= 10 and draws >= 4; got {chains}, {warmup}, {draws}")
    plans = ((warmup, draws, 1),) if plans is None else tuple(tuple(int(x) for x in p) for p in plans)
    if plans[0] != (warmup, draws, 1):
        raise ValueError(f"NUTS's reference runs the first of its plans {plans}, which must be ({warmup}, {draws}, 1)")
    lo, hi = (np.asarray(a, np.float32) for a in _y_lo_hi(prior))
    keys, u0, m, chol = start(scale_draws, start_y, chains, seed, prior)
    with jax.default_matmul_precision("highest"):       # as the SMC's target (target.full_precision)
        y, div, n_leap, step = run_chains(jnp.asarray(keys), _f32(u0), data, _f32(log_delta), _f32(weights), _f32(lo),
                                          _f32(hi), _f32(m), _f32(chol), prior=prior, plans=plans,
                                          target_acceptance=target_acceptance, max_doublings=max_doublings)
    return {"y": np.asarray(y, np.float64), **diagnostics(y, div, n_leap, step)}
