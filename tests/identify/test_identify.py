"""The log-grounded posterior (mjxsysid.identify): coordinates, prior, likelihood, inference.

The logs here come from a forward model written for the tests (numpy, step by step: the rotor
lag, Euler's equation, the specific force), independent of the likelihood's windowed sums, so
that the inference is checked where the model is exact."""
import jax
import numpy as np
import pytest

from mjxsysid import theta as P
from mjxsysid.identify import coords as C
from mjxsysid.identify import likelihood as L
from mjxsysid.identify import logdata as LD
from mjxsysid.identify.inference import log_grounded_posterior, log_target
from support.exact_model_log import likelihood_peaks, synthetic_log
from support.paths import PX4_SAMPLE, require_shared

DT = 0.002


def test_coordinates_round_trip_and_prior_covers_the_training_priors():
    th = np.asarray(P.get_prior("wide_actuators").sample(jax.random.PRNGKey(0), 2000))
    v, h = C.visible_from_theta(th), C.hidden_from_theta(th)
    back = np.asarray(C.theta_from(v, h))
    np.testing.assert_allclose(back, th, rtol=2e-4, atol=1e-9)
    for name in ("wide_actuators", "stress", "default"):
        draws = np.asarray(P.get_prior(name).sample(jax.random.PRNGKey(1), 2000))
        assert C.PHYSICAL_PRIOR.contains_theta(draws).mean() == 1.0, name
    # jMAVSim's Iris (a vehicle outside the decoders' prior: τ_m 5 ms) is inside too
    iris = np.array([0.8, 0.165, 4.0 / 1000**2, 0.05 / 1000**2, 0.005, 0.005, 0.009, 0.01, 0.01, 0.01, 1000.0,
                     1, 1, 1, 1, 0.005, 0, 0, 0], np.float32)
    assert C.PHYSICAL_PRIOR.contains_theta(iris)
    q = C.log_quantities(iris)
    assert abs(q[0] - 16 / (0.8 * P.GRAVITY)) < 1e-3   # thrust-to-weight of all four rotors


def test_likelihood_peaks_at_the_truth_and_estimates_the_noise():
    theta = P.paper_hardware().copy()
    theta[P.ETA] = [1.1, 0.9, 1.0, 1.0]
    rec = synthetic_log(theta, seconds=4.0, gyro_noise=0.02, acc_noise=0.3)
    data = LD.prepare(rec)
    sig = L.noise_estimate(data)
    np.testing.assert_allclose(sig, [0.02, 0.02, 0.02, 0.3], rtol=0.15)
    v = np.asarray(C.visible_from_theta(theta))
    y = np.concatenate([v, np.log(sig), [0.0]])[None].repeat(5, 0)
    y[1, 0] += 0.05      # thrust-to-weight 5 % high
    y[2, 5] += 0.05      # roll authority 5 % high
    y[3, 4] += 0.3       # τ_m 35 % slow
    y[4, 12:16] -= 3.0   # the noise 20× smaller than the log's: its evidence must object
    lt = np.asarray(log_target(y.astype(np.float32), data))
    assert np.argmax(lt) == 0 and np.all(lt[1:] < lt[0] - 5), lt


def test_the_noise_below_the_readings_rounding_is_flat_not_a_wall():
    """Second differences at the readings' rounding (a noise-free log) leave log σ without evidence
    below √(q²/12): its Fisher information fades there and the estimate sits at the prior's floor,
    while a noisy channel keeps its 2n."""
    import dataclasses
    data = LD.prepare(synthetic_log(P.paper_hardware(), seconds=4.0, gyro_noise=0.02, acc_noise=0.3))
    s2 = np.asarray(data.s2).copy()
    s2[:3] = 6 * np.asarray(data.n2)[:3] * 1e-14                  # the gyro's second differences at 1e-7 rad/s
    data = dataclasses.replace(data, s2=np.asarray(s2, np.float32))
    sig = L.noise_estimate(data)
    assert np.all(sig[:3] <= 1.001e-6) and abs(sig[3] / 0.3 - 1) < 0.15
    info = L.noise_information(np.log(np.maximum(sig, 1e-6)), data)
    assert np.all(info[:3] < 1e-3 * info[3]) and abs(info[3] / (2 * float(data.n2[3])) - 1) < 1e-3
    x = np.asarray(L.linear_start(data), np.float32)
    lls = []
    for s in (1e-6, 1e-5, 1e-3):
        x[12:15] = np.log(s)
        lls.append(float(L.log_likelihood(x, data)))
    assert abs(lls[1] - lls[0]) < 0.05 * abs(lls[2] - lls[0]), lls     # flat below the rounding, steep above


def test_linear_start_near_the_truth():
    theta = P.paper_hardware()
    data = LD.prepare(synthetic_log(theta, seconds=4.0, gyro_noise=0.01, acc_noise=0.1))
    x0 = L.linear_start(data)
    v = np.asarray(C.visible_from_theta(theta))
    assert abs(x0[0] - v[0]) < 0.05 and abs(x0[4] - v[4]) < 0.3
    np.testing.assert_allclose(x0[5:7], v[5:7], atol=0.1)


def test_a_long_log_reads_at_most_max_windows_windows_and_blocks_spread_over_it():
    """A 10-minute log's 1,198 accelerometer blocks would be padded to 2,048 and every SMC move
    would read them all (its SMC was 4× a 10 s log's): both terms keep MAX_WINDOWS, evenly spaced."""
    T = 80_000                                        # 160 s: 317 blocks of 0.5 s, 1,589 windows
    rng = np.random.default_rng(0)
    imu = np.zeros((T, 6))
    imu[:, 5] = 9.81 + np.linspace(0.0, 1.0, T) + 0.01 * rng.normal(size=T)   # acc_z drifts over the log
    imu[:, :3] = 0.01 * rng.normal(size=(T, 3))
    data = LD.prepare({"imu": imu, "motor": np.full((T, 4), 0.5)})
    assert int(np.asarray(data.wmask).sum()) == LD.MAX_WINDOWS == int(np.asarray(data.bmask).sum())
    acc = np.asarray(data.acc)[np.asarray(data.bmask) > 0]
    assert acc[0] < 9.85 and acc[-1] > 10.75          # the blocks span the log, not its first 128 s


def test_prepare_rejects_a_short_log():
    rec = {"imu": np.zeros((40, 6)), "motor": np.zeros((40, 4))}
    with pytest.raises(ValueError, match="windows"):
        LD.prepare(rec)


def test_body_drag_from_the_logs_velocity_and_the_drag_free_model_biased():
    """A log whose specific force carries the body drag −D_z v_z: with the log's velocity the drag's term
    is profiled (D_z recovered) and thrust-to-weight comes out unbiased, the posterior's band holding it;
    the drag-free model (the same log without its velocity) reads the drag as less thrust."""
    theta = P.paper_hardware()
    rec = synthetic_log(theta, seconds=4.0, gyro_noise=0.01, acc_noise=0.05, seed=2, drag=0.6)
    tt = DT * np.arange(len(rec["imu"]))
    lateral = np.stack([1.5 * np.sin(0.7 * tt), 1.0 * np.cos(0.5 * tt)], -1)   # body x, y velocity
    rec["velocity_body"][:, :2] = lateral
    rec["imu"][:, 3:5] -= np.array([0.3, 0.45]) * lateral                    # the accelerometer reads −D v
    blind = {k: v for k, v in rec.items() if k != "velocity_body"}
    with_v, without = LD.prepare(rec), LD.prepare(blind)
    v = np.asarray(C.visible_from_theta(theta))
    err = [abs(float(L.linear_start(d)[0] - v[0])) for d in (with_v, without)]
    assert err[0] < 0.005 and err[1] > 0.03, err           # 0.6 · 0.8 / g ≈ 5 % low without velocity
    x = np.concatenate([v, np.log([0.01] * 3 + [0.05]), np.log([1e-3] * 4), [0.0]]).astype(np.float32)
    _, acc = L.predict(x[:C.N_V], with_v)
    r0 = (with_v.acc - acc) * with_v.bmask
    assert float(L.drag_per_mass(r0, with_v)) == pytest.approx(0.6, rel=0.05)
    assert float(L.drag_per_mass(r0, without)) == 0.0      # no velocity: no term
    post = log_grounded_posterior(rec, None, samples=400, particles=512, seed=1, calibration=None)   # the room test's SMC program
    tw = C.log_quantities(post["theta"])[:, 0]
    lo, med, hi = np.percentile(tw, [5, 50, 95])
    true = C.log_quantities(theta)[0]
    assert lo <= true <= hi and abs(med / true - 1) < 0.01, (lo, med, hi, true)
    assert post["features"]["velocity_used"]
    assert post["drag_per_mass"] == pytest.approx([0.3, 0.45, 0.6], rel=0.1)        # body x, y, z


def test_posterior_covers_the_truth_hidden_directions_broad_and_the_proposal_only_proposes():
    """On an exact-model log: thrust-to-weight and the roll/pitch authorities inside narrow bands,
    mass as broad as the prior; and two decoded ensembles, one 25 % off in thrust-to-weight, give
    the same posterior (the proposal only proposes: had it been multiplied into the target, the
    second would be dragged off)."""
    theta = P.paper_hardware().copy()
    rec = synthetic_log(theta, seconds=4.0, gyro_noise=0.05, acc_noise=0.5, seed=3)
    rng = np.random.default_rng(0)
    near = np.repeat(theta[None], 64, 0) * rng.uniform(0.9, 1.1, (64, 19)).astype(np.float32)
    off = near.copy()
    off[:, P.KT] *= 1.25                       # thrust-to-weight 25 % high, authorities with it
    posts = [log_grounded_posterior(rec, dec, samples=600, particles=512, seed=1) for dec in (near, off)]
    q = [C.log_quantities(p["theta"]) for p in posts]
    true = C.log_quantities(theta)
    lo, hi = np.percentile(q[0], [1, 99], 0)
    for j in (0, 2, 3):        # thrust-to-weight, roll and pitch authority
        assert lo[j] <= true[j] <= hi[j], (C.LOG_NAMES[j], lo[j], true[j], hi[j])
        assert np.log(hi[j] / lo[j]) < 0.3, C.LOG_NAMES[j]
    tw = [np.median(x[:, 0]) for x in q]
    assert abs(np.log(tw[1] / tw[0])) < 0.03, tw
    # mass and arm length: the log cannot see them; they keep the prior's breadth
    m05, m95 = np.percentile(posts[0]["theta"][:, P.MASS], [5, 95])
    pm = C.PHYSICAL_PRIOR.mass_kg
    assert np.log(m95 / m05) > 0.7 * np.log(pm[1] / pm[0])
    assert "khat" in posts[0]["decoded_is"]


def test_px4_sample_thrust_to_weight_inside_and_what_10_hz_motors_cannot_show():
    """jMAVSim's Iris (PX4's sample log, motors logged at 10 Hz): thrust-to-weight 2.04 inside a band
    within ±20 % (with the defaults, 1.80–2.26: its accelerometer residual takes NUTS's table without
    velocity, whose top bins hold the × 20 logs' bias; ±6.5 % under the SMC's); τ_m 5 ms inside; the rates are not used (10 Hz commands cannot explain them), so
    the roll authority stays as broad as the prior — and the gap says it was not seen."""
    pytest.importorskip("pyulog")
    from mjxsysid.identify.gap import information_gap
    from mjxsysid.logs.ulog import read_ulog
    rec = read_ulog(require_shared(PX4_SAMPLE))
    post = log_grounded_posterior(rec, None, samples=600, particles=512, seed=0, refine=True)
    assert list(post["channels_used"]) == [0, 0, 0, 1]
    q = C.log_quantities(post["theta"])
    lo, hi = np.percentile(q, [5, 95], 0)
    assert lo[0] <= 16 / (0.8 * P.GRAVITY) <= hi[0] and hi[0] / lo[0] < 1.45, (lo[0], hi[0])
    assert lo[1] <= 0.005 <= hi[1]
    gap = information_gap(post["theta"], post["theta"])
    assert not gap["authority_total[0]"]["seen_by_log"] and gap["thrust_to_weight"]["seen_by_log"]
    # the SMC's random-walk moves are accepted (their scale adapts stage by stage; scaled by the
    # particles' covariance alone, 0-0.6 % were once the likelihood entered), then NUTS refines its draws
    assert post["method"] == "smc_nuts" and post["smc_acceptance"] > 0.1, post["smc_acceptance"]
    assert post["nuts"]["converged"] and post["nuts"]["rhat_max"] < 1.1, post["nuts"]   # mixed, if after a longer run


def test_random_walk_scale_moves_toward_its_target_acceptance():
    from mjxsysid.identify.inference import RW_TARGET_ACCEPTANCE, rw_scale_update
    r = {a: float(rw_scale_update(a)) for a in (0.0, 0.005, 0.1, RW_TARGET_ACCEPTANCE - 0.005, 0.6, 1.0)}
    assert r[0.0] == r[0.005] == pytest.approx(np.log(0.2))          # stuck: steps five times shorter
    assert r[0.1] < 0 and abs(r[RW_TARGET_ACCEPTANCE - 0.005]) < 1e-6 and 0 < r[0.6] < r[1.0] <= np.log(2.0) + 1e-6


def test_with_mass_keeps_what_the_log_sees():
    """A weighed vehicle: every draw's mass set, its visible coordinates (what the log sees) unchanged,
    the thrust coefficient and inertia scaled with the mass."""
    from mjxsysid.identify.coords import visible_from_theta, with_mass
    th = np.stack([P.paper_hardware(), P.paper_hardware() * np.float32(1.1)])
    w = with_mass(th, 2.0)
    np.testing.assert_allclose(w[:, P.MASS], 2.0)
    np.testing.assert_allclose(visible_from_theta(w), visible_from_theta(th), atol=1e-5)
    np.testing.assert_allclose(w[:, P.KT] / th[:, P.KT], 2.0 / th[:, P.MASS], rtol=1e-5)
    np.testing.assert_allclose(w[:, P.ARM], th[:, P.ARM], rtol=1e-6)


def test_posterior_runs_at_full_matmul_precision():
    """The posterior's programs are traced with float32 matmuls at full precision whatever the
    caller's default (a GPU's TF32 narrowed and shifted the bands: docs/identify.md): the module's
    public entry points all carry ``full_precision``."""
    import mjxsysid.identify.inference as I
    with jax.default_matmul_precision("tensorfloat32"):
        assert I.full_precision(lambda: jax.config.jax_default_matmul_precision)() == "highest"
        assert jax.config.jax_default_matmul_precision == "tensorfloat32"       # restored after the call
    code = I.full_precision(lambda: None).__code__
    for f in (I.log_grounded_posterior, I.log_grounded_posteriors, I.find_mode, I.log_target):
        assert f.__code__ is code and f.__wrapped__.__module__.startswith("mjxsysid.identify."), f.__name__


def test_innovations_unbiased_in_closed_loop_where_windows_are_not():
    """A controller that reacts to the gyro's noise: the windowed equation error's least squares puts
    τ_m 20 %+ slow (the noise of each window's start correlates with the commands that follow), the
    Kalman innovations' (each prediction from the past only) within 5 %, and their likelihood peaks at
    the true τ_m and authority."""
    theta = P.paper_hardware().copy()
    rec = synthetic_log(theta, seconds=10.0, gyro_noise=0.2, seed=1, closed_loop=True)
    v = np.asarray(C.visible_from_theta(theta))
    windows = L.linear_start(LD.prepare(rec, rates="windows"))
    assert np.exp(windows[4] - v[4]) > 1.2, np.exp(windows[4] - v[4])
    data = LD.prepare(rec, rates="innovations")
    x0 = L.linear_start(data)
    assert abs(np.exp(x0[4] - v[4]) - 1) < 0.1, np.exp(x0[4] - v[4])      # the τ grid's spacing: 9 %
    np.testing.assert_allclose(x0[5:7], v[5:7], atol=0.05)
    # the likelihood along τ_m (2 % steps) and the roll authority peaks at the truth
    d_tau, d_roll = likelihood_peaks(data, v, x0)
    assert abs(d_tau) <= 0.04 and abs(d_roll) <= 0.01, (d_tau, d_roll)


def test_the_identify_room_is_callable_and_gives_a_posterior_object():
    """mjxsysid.identify(log) -> LogPosterior: calibrated draws, a summary that leads with what the
    log saw (thrust-to-weight inside), the hidden mass not in it, diagnostics and the calibration said."""
    import mjxsysid
    from mjxsysid.identify import LogPosterior
    theta = P.paper_hardware().copy()
    rec = synthetic_log(theta, seconds=4.0, gyro_noise=0.05, acc_noise=0.5, seed=3)
    post = mjxsysid.identify(rec, samples=600, particles=512, seed=1)
    assert isinstance(post, LogPosterior) and post.calibration["applied"]
    s = post.summary()
    first = next(iter(s))
    assert s[first]["seen"] and s["thrust_to_weight"]["seen"]
    tw = C.log_quantities(theta)[0]
    assert s["thrust_to_weight"]["q05"] <= tw <= s["thrust_to_weight"]["q95"]
    assert post.sample(50).shape == (50, P.N_PARAMS) and post.sample().shape == (600, P.N_PARAMS)
    assert post.diagnostics["method"] in ("decoded_is", "laplace_is", "smc", "smc_nuts") and "features" in post.diagnostics
    assert "thrust_to_weight" in repr(post)
    gap = post.gap(post.theta)
    assert gap["thrust_to_weight"]["seen_by_log"] == s["thrust_to_weight"]["seen"]
    with pytest.raises(ValueError, match="n must be"):
        post.sample(0)
    with pytest.raises(TypeError, match="flight-log path"):
        mjxsysid.identify(3.0)


def _batched_against_alone(refine: bool, monkeypatch) -> None:
    """Three logs vmapped together (padded to four) against each alone: the same method, bands within a fifth
    of their width (NUTS's trajectories part under float rounding: the same chains, not the same draws).
    Also the residuals computed for the logs together (``_Logs.residuals``: the motor-map check's, the mode's)
    against each log's own, and the mode's discrepancies."""
    from mjxsysid.identify.batched import _Logs
    from mjxsysid.identify.inference import log_grounded_posteriors
    from mjxsysid.identify.likelihood import residuals_jit
    seen = []
    together_residuals = _Logs.residuals

    def spy(self, x):
        out = together_residuals(self, x)
        if len(self) > 1:
            seen.append((list(self.datas), np.array(x), out))
        return out
    monkeypatch.setattr(_Logs, "residuals", spy)
    from support.ahead import record_waits
    waits = record_waits(monkeypatch)     # the programs compiled ahead, alone and together, are the ones run
    base = P.paper_hardware().copy()
    slow = base * np.where(np.arange(19) == P.TAU_M, 1.5, 1.0).astype(np.float32)
    recs = [synthetic_log(t, seconds=3.0, gyro_noise=0.05, acc_noise=0.5, seed=k)
            for k, t in enumerate((base, slow, base))]
    kw = dict(samples=400, particles=256, draws=512, calibration=None, force_smc=True, refine=refine)
    alone = [log_grounded_posterior(r, seed=7 + k, **kw) for k, r in enumerate(recs)]
    together = log_grounded_posteriors(recs, seeds=[7, 8, 9], batch=4, **kw)   # three logs padded to four
    for a, b in zip(alone, together):
        assert a["method"] == b["method"] == ("smc_nuts" if refine else "smc")
        qa, qb = (np.percentile(x["v"], [5, 50, 95], 0) for x in (a, b))
        assert np.all(np.abs(qa - qb) <= 0.2 * (qa[2] - qa[0]) + 1e-5), np.abs(qa - qb) / (qa[2] - qa[0])
    smc = [found for kind, found in waits if kind == "smc"]
    assert len(smc) == 4 and all(smc), waits                        # three logs alone, then together
    if refine:                                                      # each call's first NUTS run; a retry reuses it
        assert sum(found for kind, found in waits if kind == "nuts") == 4, waits
    with pytest.raises(ValueError, match="one of each per log"):
        log_grounded_posteriors(recs, seeds=[1, 2])
    assert len(seen) >= 2                           # dozens of calls for the logs together: the first and the last
    for datas, x, out in (seen[0], seen[-1]):
        assert len(datas) == 3 and all(len(o) == 3 for o in out)
        for i, d in enumerate(datas):
            for got, want in zip(out, residuals_jit(jax.numpy.asarray(x[i]), d)):
                np.testing.assert_allclose(got[i], np.asarray(want), rtol=1e-5, atol=1e-6)
    # the mode's discrepancies, the logs together (two calls) against each alone
    from mjxsysid.identify import logspace as LS
    from mjxsysid.identify.mode import _discrepancies
    datas, x, _ = seen[0]
    ys = LS.y_from_x(x).astype(np.float32)
    together = _discrepancies(_Logs(datas), ys)
    alone = np.concatenate([_discrepancies(_Logs([d]), ys[i:i + 1]) for i, d in enumerate(datas)])
    assert together.shape == (3, 4) and np.all(np.isfinite(together))
    np.testing.assert_allclose(together, alone, atol=1e-5)


@pytest.mark.usefixtures("xla_optimised_test")   # run time, not compiles: cold 30-38 -> 21-26 s
def test_logs_batched_give_each_logs_posterior(monkeypatch):
    """Several logs at once (vmapped over logs, three padded to four) give each log the SMC's posterior it
    gets alone (NUTS's refinement batched too: the slow test below), and the motor-map check's residuals of
    the logs together are each log's own."""
    _batched_against_alone(refine=False, monkeypatch=monkeypatch)


@pytest.mark.slow
def test_logs_batched_give_each_logs_posterior_refined_by_nuts(monkeypatch):
    """The same with NUTS's chains batched over the logs."""
    _batched_against_alone(refine=True, monkeypatch=monkeypatch)


def test_logs_are_evaluated_together_only_with_logs_of_their_shape_and_proposal():
    """The batches: logs of another length, rate or kind of proposal go to their own chunks, each at most
    ``batch`` long, every log once and in order within its group."""
    from mjxsysid.identify.inference import log_chunks
    base = P.paper_hardware().copy()
    d = [LD.prepare(synthetic_log(base, seconds=s, seed=k)) for k, s in enumerate((3.0, 3.0, 5.0, 3.0, 3.0, 3.0))]
    assert log_chunks(d, [True] * 6, 4) == [[0, 1, 3, 4], [5], [2]]
    assert log_chunks(d, [True, False, True, True, False, True], 2) == [[0, 3], [5], [1, 4], [2]]
    assert log_chunks(d, [True] * 6, 1) == [[0], [1], [3], [4], [5], [2]]


def test_the_default_batch_is_what_the_accelerators_memory_holds_of_logs_that_long(monkeypatch):
    """default_batch: one log at a time on a CPU; on an accelerator the largest power of two up to LOG_BATCH
    whose peak fits its share of the device's memory: 10 s logs (172 kB) 1,024 on an H200, 512 on an 80 GB
    card, 256 on a 24 GB one; logs six times as long, a quarter as many; 256 where the device does not say."""
    import jax

    import mjxsysid.identify.inference as I
    from mjxsysid.identify.inference import batch_for, default_batch, log_chunks
    gib, kb10 = 2 ** 30, 172_308
    assert batch_for(kb10, 0.75 * 141 * gib) == I.LOG_BATCH == 1024
    assert batch_for(kb10, 0.75 * 80 * gib) == 512
    assert batch_for(kb10, 0.75 * 24 * gib) == 256
    assert batch_for(6 * kb10, 0.75 * 141 * gib) == 256
    assert batch_for(kb10, None) == 256 and batch_for(10 ** 9, 10 ** 6) == 1
    d = [LD.prepare(synthetic_log(P.paper_hardware().copy(), seconds=3.0, seed=k)) for k in range(3)]
    assert default_batch(d[0]) == 1 and log_chunks(d, [True] * 3, None) == [[0], [1], [2]]     # a CPU

    class Device:
        def memory_stats(self):
            return {"bytes_limit": 3 * 250 * sum(np.asarray(a).nbytes for a in jax.tree.leaves(d[0])) / I.MEMORY_SHARE}
    monkeypatch.setattr(jax, "default_backend", lambda: "gpu")
    monkeypatch.setattr(jax, "devices", lambda: [Device()])
    assert default_batch(d[0]) == 2 and log_chunks(d, [True] * 3, None) == [[0, 1], [2]]
