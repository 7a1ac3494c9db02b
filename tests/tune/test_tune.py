"""The online predictive tuner (mjxsysid.tune): CEM, cost terms, predictive rollouts, the tuned
flight, and the `tune` / `experiment` command line's input checks."""
import functools
import json

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from mjxsysid import theta as P
from mjxsysid.rollout.flight import broadcast
from mjxsysid.rollout.harness import Disturbance, Flight, fly_batch
from mjxsysid.control.high_level import GAIN_BOUNDS, PRESETS, Cascade
from mjxsysid.control.references import Lemniscate
from mjxsysid.sim.quadrotor import Frame
from mjxsysid.tune import cem as C
from mjxsysid.tune import rotor_state as R
from mjxsysid.tune.tuner import CostWeights, OnlineTuner, TunerConfig, fly_tuned, predict, rollout_cost


# ------------------------------------------------------------------------------------ CEM
def test_search_space_round_trip_and_bounds():
    g = np.array([PRESETS["naive"], PRESETS["baseline"], GAIN_BOUNDS[:, 0], GAIN_BOUNDS[:, 1]])
    np.testing.assert_allclose(C.from_search(C.to_search(g)), g, rtol=1e-5, atol=1e-6)
    far = C.from_search(jnp.full((8,), 50.0)), C.from_search(jnp.full((8,), -50.0))
    np.testing.assert_allclose(far[0], GAIN_BOUNDS[:, 1])
    np.testing.assert_allclose(far[1], GAIN_BOUNDS[:, 0])


def test_cem_candidates_keep_the_mean_and_the_box():
    cfg = C.CEMConfig(candidates=64)
    st = C.cem_init(PRESETS["naive"], cfg)._replace(std=jnp.full(8, 10.0))
    g = C.cem_candidates(st, jax.random.PRNGKey(0), 64)
    np.testing.assert_allclose(g[0], PRESETS["naive"], rtol=1e-5)
    assert np.all(g >= GAIN_BOUNDS[:, 0] - 1e-6) and np.all(g <= GAIN_BOUNDS[:, 1] + 1e-6)


def test_cem_finds_the_minimum_of_a_quadratic():
    target = np.array([7.0, 3.0, 5.0, 1.5, 0.8, 2.0, 11.0, 3.0], np.float32)
    y_star = C.to_search(target)
    w = jnp.linspace(1.0, 3.0, 8)                       # mildly anisotropic

    def cost(gains, _k):
        return jnp.sum(w * (C.to_search(gains) - y_star) ** 2, -1)

    cfg = C.CEMConfig(candidates=128, iterations=40, elite_frac=0.1, min_std=0.001, smoothing=0.2)
    st, hist = C.cem_minimize(cost, C.cem_init(PRESETS["naive"], cfg), jax.random.PRNGKey(1), cfg)
    np.testing.assert_allclose(st.mean, y_star, atol=0.03)     # log space: within 3 %
    assert hist.shape == (40, 128)
    assert float(hist[-1].min()) < 1e-3 * float(hist[0].min())


def test_cem_config_rejects_bad_values():
    with pytest.raises(ValueError, match="candidates"):
        C.CEMConfig(candidates=0)
    with pytest.raises(ValueError, match="iterations"):
        C.CEMConfig(iterations=0)
    with pytest.raises(ValueError, match="models"):
        TunerConfig(models=0)
    with pytest.raises(ValueError, match="horizon"):
        TunerConfig(horizon=-1.0)


# ------------------------------------------------------------------------------------ cost
def _flight(err, motor, *, t=50):
    """A synthetic flight: constant position error vector ``err`` (3,), motor commands (4,)."""
    z3, z4 = np.zeros((t, 3), np.float32), np.zeros((t, 4), np.float32)
    quat = np.tile(np.array([1.0, 0, 0, 0], np.float32), (t, 1))
    ref = np.tile(np.array([0.0, 0.0, 1.0], np.float32), (t, 1))
    fr = Frame(pos=ref + np.asarray(err, np.float32), quat=quat, vel=z3, omega=z3, rotor_speed=z4,
               imu=np.zeros((t, 6), np.float32), motor_cmd=np.tile(np.asarray(motor, np.float32), (t, 1)),
               force=z3, diverged=np.zeros(t, bool))
    return Flight(frame=fr, ref_pos=ref, ref_vel=z3, ref_yaw=np.zeros(t, np.float32), a_cmd=np.zeros(t),
                  omega_cmd=z3, time=0.002 * np.arange(1, t + 1), latent=None)


def test_cost_terms():
    w = CostWeights(heading=0.1, saturation=0.5, failure=5.0, fail_dist=1.0)
    mid = [0.5] * 4
    assert float(rollout_cost(_flight([0.1, 0.0, 0.0], mid), w)) == pytest.approx(0.1, rel=1e-5)
    assert float(rollout_cost(_flight([0.0, 0.3, 0.4], mid), w)) == pytest.approx(0.5, rel=1e-5)
    # saturation: two of four motors at a limit -> half of the commands saturated
    assert float(rollout_cost(_flight([0.1, 0, 0], [1.0, 0.0, 0.5, 0.5]), w)) == pytest.approx(0.1 + 0.25, rel=1e-5)
    # failure: beyond fail_dist from the start -> the failure penalty (no pre-failure steps: RMSE 0)
    assert float(rollout_cost(_flight([1.5, 0, 0], mid), w)) == pytest.approx(5.0, rel=1e-5)


# ----------------------------------------------------------------- tuner on the simulator
@pytest.fixture(scope="module")
def paper_policy():
    from mjxsysid.policy.interface import resolve_policy
    from mjxsysid.sim import Quadrotor
    return Quadrotor(), resolve_policy("mjxsysid")


def test_fixed_gains_through_the_tuned_loop_equal_fly_batch(paper_policy):
    """The suite's 2 s policy lemniscate of the paper vehicle (tests/test_api.py, test_decode.py:
    its fly_batch compile is shared) flown by the tuned loop in 20 segments of 50 steps (the
    segments notebook 02 flies, below) equals one fly_batch of the whole flight."""
    sim, ref = paper_policy
    theta = P.PAPER_HARDWARE[None]
    low = ref.batched(1)
    refs = broadcast(Lemniscate.make(period=10.0), 1)
    dist = broadcast(Disturbance.make(), 1)
    steps = 1000
    tf = fly_tuned(sim, theta, low, refs, dist, "baseline", jax.random.PRNGKey(0), steps)
    fb = fly_batch(sim, theta, low, broadcast(Cascade.make("baseline"), 1), refs, dist, jax.random.PRNGKey(0), steps)
    # float32 round-off of two compiles over 1000 steps: ~1e-6 (a wrong carry, start index or
    # gain between segments is orders of magnitude more)
    np.testing.assert_allclose(tf.flight.frame.pos, np.asarray(fb.frame.pos), atol=1e-5)
    np.testing.assert_allclose(tf.flight.latent, np.asarray(fb.latent), atol=1e-5)
    assert tf.flight.frame.pos.shape == (1, 1000, 3) and np.ptp(tf.flight.frame.pos[0, :, 0]) > 0.1
    assert tf.gains.shape == (1, 20, 8) and np.all(tf.gains == PRESETS["baseline"])
    assert np.all(np.isnan(tf.predicted))
    np.testing.assert_allclose(tf.update_times, 0.1 * np.arange(20), atol=1e-6)


@pytest.fixture(scope="module")
def policy_flights(paper_policy):
    """1000-step (2 s) policy lemniscates under the Baseline gains (the compile of the test above)
    of the paper vehicle (τ_m 0.03 s) and of the same vehicle with slow motors (τ_m 0.09 s)."""
    sim, ref = paper_policy
    slow = P.PAPER_HARDWARE.copy()
    slow[P.TAU_M] = 0.09
    out = {}
    for name, th in (("paper", P.PAPER_HARDWARE), ("slow", slow)):
        fb = fly_batch(sim, th[None], ref.batched(1), broadcast(Cascade.make("baseline"), 1),
                       broadcast(Lemniscate.make(period=10.0), 1), broadcast(Disturbance.make(), 1),
                       jax.random.PRNGKey(0), 1000)
        out[name] = (th, np.asarray(fb.frame.motor_cmd[0]), np.asarray(fb.frame.rotor_speed[0]))
    return out


def test_rotor_estimate_is_the_simulators_rotor_state_for_the_true_model(policy_flights, sim):
    """Each model's rotor estimate runs its own motor lag over the commands sent: with the true θ
    it equals the simulator's rotor speeds to float round-off, while the window covers the
    flight (from the hover start) and once a 0.6 s window has forgotten its start (at e^{-W/τ_m});
    with a wrong τ_m (×0.5, ×2) or the old steady-state start it is measurably off."""
    from mjxsysid.tune.rotor_state import CommandHistory, empty_history, estimate_rotor_speed, push_history, start_rotor_speed
    est = jax.jit(lambda th, h: estimate_rotor_speed(th, h, sim.config))
    for name, (th, cmds, speed) in policy_flights.items():
        tau = float(th[P.TAU_M])
        for n in (10, 400, 1000):
            true = speed[n - 1]
            covered = jax.tree.map(lambda a: a[0], push_history(empty_history(1200, 1), cmds[None, :n]))
            np.testing.assert_allclose(est(jnp.asarray(th), covered), true, rtol=2e-6)
            window = jax.tree.map(lambda a: a[0], push_history(empty_history(300, 1), cmds[None, :n]))
            e = est(jnp.asarray(th), window)
            start_err = (np.abs(cmds[n - 300] * th[P.OMEGA_MAX] - speed[n - 301]).max() if n > 300 else 0.0)
            assert np.abs(e - true).max() <= np.exp(-0.6 / tau) * start_err + 2e-6 * true.max(), (name, n)
            wrong = [np.abs(est(jnp.asarray(th).at[P.TAU_M].set(f * tau), window) - true).max() for f in (0.5, 2.0)]
            steady = start_rotor_speed("steady", jnp.asarray(th), window, None, sim.config)
            if n >= 400:   # manoeuvring: the rotors move, so a wrong lag shows
                assert min(wrong) > max(5 * np.abs(e - true).max(), 1e-3 * true.max()), (name, n, wrong)
                assert np.abs(steady - true).max() > 0.1 * min(wrong), (name, n)
    assert isinstance(window, CommandHistory) and int(window.count) == 300


def test_predictions_reproduce_the_flight_with_the_true_model(paper_policy):
    """With the true θ and each model's own rotor estimate, the tuner's predictive rollout (the
    rigid twin from the loop's state: IMU buffer, integral, policy history, reference time)
    reproduces the next 0.5 s of the simulated flight to well under a millimetre — on slow
    motors too, where starting the rotors at the last command's steady state (the tuner before
    issue 26) is off by centimetres."""
    from mjxsysid.tune.tuner import prediction_error
    sim, ref = paper_policy
    slow = P.PAPER_HARDWARE.copy()
    slow[P.TAU_M] = 0.09
    # one vehicle at a time: the compiled segments of the fixed-gains test above are shared
    outs = [prediction_error(sim, th[None], ref.batched(1), broadcast(Lemniscate.make(period=5.0), 1),
                             start=500, steps=250, rotor_states=("estimate", "steady"))
            for th in (P.PAPER_HARDWARE, slow)]
    est = np.array([o["estimate"]["pos_err"].max() for o in outs])
    steady = np.array([o["steady"]["pos_err"].max() for o in outs])
    assert est.max() < 5e-4, est                               # m, over the whole 0.5 s
    assert steady[1] > 20 * max(est[1], 1e-4), (steady, est)   # slow motors: the old start is far off
    assert outs[0]["estimate"]["rotor_err"][0] < 1e-5 * float(P.PAPER_HARDWARE[P.OMEGA_MAX])


def test_segments_cover_the_flight_once():
    from mjxsysid.tune.tuner import segments
    assert segments(120, 50) == [(0, 50), (50, 50), (100, 20)]     # the last one shorter
    assert segments(100, 50) == [(0, 50), (50, 50)]
    assert segments(3, 50) == [(0, 3)]
    for steps, seg in ((1, 1), (999, 7), (1000, 50)):
        sp = segments(steps, seg)
        assert sp[0][0] == 0 and all(a + n == b for (a, n), (b, _) in zip(sp, sp[1:]))
        assert sum(n for _, n in sp) == steps and all(0 < n <= seg for _, n in sp)
    with pytest.raises(ValueError, match=">= 1"):
        segments(0, 50)


def _paper_vehicle_at_rest(paper_policy):
    """The paper vehicle at rest at the start of a fast (4 s) lemniscate: (sim, θ (1, 19), batched
    and unbatched policy, reference, batched reference, batched loop carry, unbatched carry)."""
    from mjxsysid.tune import tuner as T
    sim, ref = paper_policy
    theta = P.PAPER_HARDWARE[None]
    low, low0 = ref.batched(1), ref.load()
    lem = Lemniscate.make(period=4.0)
    refs = broadcast(lem, 1)
    carry = T._start(sim, *T._axes(low))(jnp.asarray(theta), low, refs,
                                         jnp.stack([jax.random.split(jax.random.PRNGKey(0), 2)]))
    return sim, theta, low, low0, lem, refs, carry, jax.tree.map(lambda a: a[0], carry)


# The two tests below share one compiled tuner update (one config: the protected tuner with the true
# model, K = 1) and one compiled predicted cost of gains.
FAST_LEMNISCATE_TUNER = TunerConfig(models=1, horizon=0.5, protect=1.0, cem=C.CEMConfig(candidates=24, iterations=3))


@functools.partial(jax.jit, static_argnames=("sim", "steps"))
def _predicted_cost(g, *, sim, theta, low0, lem, one, steps):
    """The paper vehicle's predicted cost () of gains ``g`` (8,) over ``steps`` from ``one`` (true model)."""
    from mjxsysid.sim.quadrotor import hover_rotor_speed
    fl = predict(sim, theta, low0, g, jnp.float32(12.0), lem, one, hover_rotor_speed(theta), 0, steps)
    return rollout_cost(fl, FAST_LEMNISCATE_TUNER.weights)


def test_tuner_finds_known_good_gains(paper_policy):
    """From rest at the start of a fast lemniscate (4 s period), the oracle tuner started at the
    naive gains must reach a predicted cost as good as the hand-tuned baseline's (known good)
    and well below the naive one."""
    from mjxsysid.sim.quadrotor import hover_rotor_speed
    sim, theta, low, low0, lem, refs, carry, one = _paper_vehicle_at_rest(paper_policy)
    speed = hover_rotor_speed(jnp.asarray(theta[0]))
    cfg = FAST_LEMNISCATE_TUNER
    hor = cfg.steps(sim.config.dt)[1]
    cost_of = functools.partial(_predicted_cost, sim=sim, theta=jnp.asarray(theta[0]), low0=low0, lem=lem, one=one,
                                steps=hor)

    c_naive, c_base = float(cost_of(jnp.asarray(PRESETS["naive"]))), float(cost_of(jnp.asarray(PRESETS["baseline"])))
    # TunerConfig.unroll (the experiments' unroll 5) flies the same rollout
    unrolled = jax.jit(lambda g: rollout_cost(predict(sim, jnp.asarray(theta[0]), low0, g, jnp.float32(12.0), lem,
                                                      one, speed, 0, hor, 5), cfg.weights))
    assert float(unrolled(jnp.asarray(PRESETS["baseline"]))) == pytest.approx(c_base, rel=1e-4)
    tuner = OnlineTuner(sim, "oracle_cem", cfg)
    state = tuner.init(1)
    for u in range(4):
        state = C.cem_warm(state, cfg.cem) if u else state
        state, gains, info = tuner.update(low, theta, refs, carry, R.empty_history(cfg.window(sim.config.dt), 1),
                                          jnp.asarray(PRESETS["naive"])[None], 0, state, jax.random.PRNGKey(u))
    c_tuned = float(cost_of(gains[0]))
    assert c_base < 0.7 * c_naive, (c_base, c_naive)          # the problem separates the two presets
    assert c_tuned <= 1.05 * c_base, (c_tuned, c_base, c_naive, np.asarray(gains))
    assert info["cost"].shape == (1, 24) and info["models_twr"].shape == (1, 1)


# ------------------------------------------------------------------------------- the CLI
@pytest.mark.parametrize("argv, msg", [
    (["tune", "--models", "0"], "models"),
    (["tune", "--candidates", "0"], "candidates"),
    (["tune", "--duration", "0.2", "--horizon", "0.5"], "longer than the flight"),
    (["tune", "--methods", "naive,bogus"], "unknown method"),
    (["experiment", "tune-everything"], "unknown experiment"),
])
def test_cli_bad_input_exits_2(argv, msg, tmp_path, capsys):
    from mjxsysid.cli import main
    assert main(argv + ["--out", str(tmp_path / "o")]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and msg in err[0], err


def test_cli_tune_rejects_invalid_vehicle(tmp_path, capsys):
    from mjxsysid.cli import main
    v = json.loads(P.vehicle_path("paper_hardware").read_text())
    v["mass"] = -1.0
    f = tmp_path / "bad.json"
    f.write_text(json.dumps(v))
    assert main(["tune", "--vehicle", str(f), "--out", str(tmp_path / "o")]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "mass" in err[0] and "bad.json" in err[0], err


def test_cfm_models_are_the_decoders_samples():
    """The tuner's 'cfm' model source draws exactly what the decoder's public sampler draws for
    the same latent and key (then projected to valid θ): (K, 19), finite, valid."""
    from mjxsysid.cfm.load import load_decoders
    from mjxsysid.tune.tuner import DecoderArgs, draw_models
    dec = load_decoders()[0]
    cfg = TunerConfig(models=3, decoder_steps=4)
    z = jnp.linspace(-0.5, 0.5, 8)
    key = jax.random.PRNGKey(5)
    # the decoder's weights as arguments (as the tuner passes them), not constants folded into the program
    th = jax.jit(lambda zz, k, a: draw_models("cfm", k, None, zz, a, dec.cfg, cfg))(z, key, DecoderArgs(dec.params, dec.normalizer))
    ref = dec.sample_theta(z, key, 3, steps=4)
    np.testing.assert_allclose(np.asarray(th), P.project_valid(np.asarray(ref))[0], rtol=2e-4, atol=1e-9)
    assert th.shape == (3, P.N_PARAMS) and P.validate_theta(np.asarray(th)).shape == (3, P.N_PARAMS)


def test_common_summary_scores_every_method_on_the_same_vehicles():
    from mjxsysid.tune.compare import common_summary

    def res(rmse, failed):
        n = len(rmse)
        return {"metrics": {"pos_rmse_m": rmse, "max_pos_err_m": [2 * r for r in rmse],
                            "heading_rmse_deg": [1.0] * n, "saturation_frac": [0.0] * n, "failed": failed}}
    # method a loses vehicle 2 (its hardest), b loses none: each over its own successes a looks better
    r = {"a": res([0.1, 0.1, 9.0], [False, False, True]), "b": res([0.2, 0.2, 0.5], [False, False, False])}
    c = common_summary(r)
    assert c["n"] == 2 and c["vehicles"] == [0, 1]
    assert c["a"]["pos_rmse_m"]["mean"] == pytest.approx(0.1)
    assert c["b"]["pos_rmse_m"]["mean"] == pytest.approx(0.2)
    assert c["b"]["max_pos_err_m"]["median"] == pytest.approx(0.4)
    c0 = common_summary({"a": res([0.1], [True]), "b": res([0.2], [False])})
    assert c0["n"] == 0 and c0["a"]["pos_rmse_m"]["mean"] is None


@pytest.mark.slow
def test_tune_experiments_tiny(tmp_path):
    """tune-nominal and tune-lemniscate end to end at --quick size (3 vehicles each, one compiled
    tuner update shared): files, the same-vehicle comparison, the lead-in window. Slow (50 s on
    2 cores); the default tier keeps the pieces: common_summary, Delayed and min_height
    (test_references), compare_methods end to end (notebook 02), the CLI's input checks."""
    from mjxsysid.experiments.tuning import run_lemniscate, run_nominal
    res = run_nominal(tmp_path / "nom", quick=True, progress=False, methods=("baseline", "oracle_cem"))
    for f in ("results.json", "results.md", "gains.png", "tracking.png"):
        assert (tmp_path / "nom" / f).is_file()
    nb = res["numbers"]
    common = nb["common_set"]
    ok = [i for i in range(3) if not (nb["baseline"]["per_vehicle"]["failed"][i]
                                      or nb["oracle_cem"]["per_vehicle"]["failed"][i])]
    assert common["vehicles"] == ok and common["n"] == len(ok)
    if ok:
        want = np.mean([nb["baseline"]["per_vehicle"]["pos_rmse_m"][i] for i in ok])
        assert common["baseline"]["pos_rmse_m"]["mean"] == pytest.approx(want, rel=1e-6)
        assert nb["headline"]["baseline_pos_rmse"] == pytest.approx(want, rel=1e-6)
    md = (tmp_path / "nom" / "results.md").read_text()
    assert f"same {common['n']} vehicles" in md and "paper" in md
    assert res["config"]["reference"].startswith("random min-snap (2 segments")

    res = run_lemniscate(tmp_path / "lem", quick=True, progress=False, methods=("baseline", "oracle_cem"))
    per = res["numbers"]["per_period"]
    assert set(per) == {"baseline", "oracle_cem"} and set(per["baseline"]) == {"15.0", "10.0", "7.5"}
    assert res["config"]["lead_in_s"] == 0.5
    for m in per.values():
        for d in m.values():
            assert np.isfinite(d["pos_rmse_m"]) and d["lead_in_pos_rmse_m"] < 0.2   # hovering at the start
    assert (tmp_path / "lem" / "results.md").read_text().count("| 7.5 s |") == 2


@pytest.mark.parametrize("kernel", [pytest.param(False, id="inprocess"),
                                    pytest.param(True, id="kernel", marks=pytest.mark.slow)])
def test_notebook_02_executes(kernel, tmp_path, monkeypatch):
    """Notebook 02 on its fast settings, in this interpreter (default tier: it shares the
    compiled segments of the fixed-gains test above) or in a Jupyter kernel (slow)."""
    from support.paths import ROOT
    from support.notebooks import run_notebook
    if not (ROOT / "mjxsysid" / "pretrained" / "cfm.npz").exists():
        pytest.skip("no shipped decoder")
    outputs, _ = run_notebook("02_tuning.ipynb", tmp_path, monkeypatch, kernel=kernel,
                              env={"MJXSYSID_NOTEBOOK_FAST": "1"})
    assert "cfm_tuned: position RMSE" in outputs and (tmp_path / "tuning_gains.png").exists(), outputs[-2000:]


def test_nominal_models_are_centred_on_each_vehicles_own_nominal_system():
    """Nominal+CEM as the paper defines it: ±20 % perturbations of the vehicle's *own* nominal θ
    (its τ_m at the nominal 0.03 s), not of the paper vehicle: for a light slow-motor vehicle the
    K models bracket its mass, not the paper vehicle's."""
    from mjxsysid.tune.tuner import NOMINAL_TAU_M, draw_models, nominal_theta
    cfg = TunerConfig(models=2000)
    theta = np.array(P.SLOW_ACTUATOR_PRIOR.sample(jax.random.PRNGKey(3), 1))[0]
    theta[P.MASS] = 0.08                                  # far from the paper vehicle's 0.86 kg
    th = np.asarray(draw_models("nominal_cem", jax.random.PRNGKey(0), jnp.asarray(theta), None, None, None, cfg))
    nom = np.asarray(nominal_theta(theta))
    assert NOMINAL_TAU_M == pytest.approx(0.03) and nom[P.TAU_M] == pytest.approx(0.03)
    assert theta[P.TAU_M] >= 0.05                          # the true motors are slow; the nominal ones are not
    np.testing.assert_array_equal(np.delete(nom, P.TAU_M), np.delete(theta, P.TAU_M).astype(np.float32))
    ratio = th / nom
    assert np.all(ratio[:, P.MASS] >= 0.8 - 1e-6) and np.all(ratio[:, P.MASS] <= 1.2 + 1e-6)
    assert np.median(th[:, P.MASS]) == pytest.approx(0.08, rel=0.02)
    assert np.median(th[:, P.TAU_M]) == pytest.approx(0.03, rel=0.02)


def test_the_default_cost_is_the_papers_and_the_heading_variant_is_an_option():
    from mjxsysid.experiments.tuning import FULL_TUNER, _variant
    from mjxsysid.tune.tuner import HEADING_COST
    assert TunerConfig().weights.heading == 0.0 and FULL_TUNER.weights.heading == 0.0
    assert _variant("tune-slow", "heading_cost", FULL_TUNER).weights.heading == HEADING_COST == 0.1
    assert _variant("tune-slow", None, FULL_TUNER) == FULL_TUNER
    with pytest.raises(ValueError, match="no variant 'no_lead_in'"):
        _variant("tune-slow", "no_lead_in", FULL_TUNER)
    assert _variant("tune-lemniscate", "no_lead_in", FULL_TUNER) == FULL_TUNER


def test_tuner_knob_variants_parse_and_reject_bad_values():
    from mjxsysid.experiments.tuning import FULL_TUNER, _variant
    cfg = _variant("tune-slow", "steady_rotor_state,baseline_start,protect,apply_best,cem_3_iterations,horizon_1s",
                   FULL_TUNER)
    assert (cfg.rotor_state, cfg.initial, cfg.protect, cfg.apply, cfg.cem.iterations, cfg.horizon) == \
        ("steady", "baseline", 0.75, "best", 3, 1.0)
    assert _variant("tune-slow", "true_rotor_state", FULL_TUNER).rotor_state == "true"
    assert FULL_TUNER.rotor_state == "estimate" and FULL_TUNER.initial == "naive" and FULL_TUNER.protect == 0.0
    with pytest.raises(ValueError, match="no variant 'bogus'"):
        _variant("tune-nominal", "protect,bogus", FULL_TUNER)
    for kw, msg in ((dict(rotor_state="hidden"), "rotor_state"), (dict(rotor_window=0.0), "rotor_window"),
                    (dict(apply="median"), "apply"), (dict(protect=1.5), "protect")):
        with pytest.raises(ValueError, match=msg):
            TunerConfig(**kw)


def test_a_protected_tuner_never_applies_gains_its_models_predict_worse(paper_policy):
    """protect = 1 with the true model (K = 1): the tuner switches only to gains the model predicts
    better than the incumbent, so the applied gains' predicted cost never exceeds the incumbent's
    (here the naive gains, which the fast lemniscate punishes: it does switch)."""
    sim, theta, low, low0, lem, refs, carry, one = _paper_vehicle_at_rest(paper_policy)
    cfg = FAST_LEMNISCATE_TUNER
    tuner = OnlineTuner(sim, "oracle_cem", cfg)
    hist = R.empty_history(cfg.window(sim.config.dt), 1)
    incumbent = jnp.asarray(PRESETS["naive"])[None]
    cost_of = functools.partial(_predicted_cost, sim=sim, theta=jnp.asarray(theta[0]), low0=low0, lem=lem, one=one,
                                steps=cfg.steps(sim.config.dt)[1])
    state = tuner.init(1)
    switched = []
    for u in range(3):
        state, gains, info = tuner.update(low, theta, refs, carry, hist, incumbent, 0, state, jax.random.PRNGKey(u))
        assert float(cost_of(gains[0])) <= float(cost_of(incumbent[0])) + 1e-6
        switched.append(bool(info["switched"][0]))
        incumbent = gains
    assert switched[0], "naive gains on a fast lemniscate: the model must find better ones"


def test_log_models_come_from_the_ensemble_given_with_the_flight(paper_policy):
    """The tuner given a log (``log_cem``) draws its K models from each vehicle's ensemble: with the
    true θ as the ensemble it applies Oracle-CEM's gains (the same compiled update of the tests above:
    the method is a runtime switch), with another vehicle's θ that vehicle's models; a flight without
    an ensemble is an error naming it."""
    sim, theta, low, low0, lem, refs, carry, one = _paper_vehicle_at_rest(paper_policy)
    cfg = FAST_LEMNISCATE_TUNER
    hist = R.empty_history(cfg.window(sim.config.dt), 1)
    naive = jnp.asarray(PRESETS["naive"])[None]
    other = np.array(theta)
    other[:, P.KT] *= 1.3                                     # a stronger vehicle: thrust-to-weight 1.3×
    out = []
    for method, ens in (("oracle_cem", None), ("log_cem", theta[:, None]), ("log_cem", other[:, None])):
        tuner = OnlineTuner(sim, method, cfg)
        _, gains, info = tuner.update(low, theta, refs, carry, hist, naive, 0, tuner.init(1), jax.random.PRNGKey(0),
                                      ens)
        out.append((np.asarray(gains), np.asarray(info["models_twr"])))
    np.testing.assert_array_equal(out[1][0], out[0][0])
    np.testing.assert_allclose(out[2][1][:, 0], np.asarray(P.thrust_to_weight(other)), rtol=1e-5)
    assert out[2][1][0, 0] == pytest.approx(1.3 * out[0][1][0, 0], rel=1e-5)
    with pytest.raises(ValueError, match="'log_cem' needs an ensemble"):
        fly_tuned(sim, theta, low, refs, broadcast(Disturbance.make(), 1), "log_cem", jax.random.PRNGKey(0), 100,
                  cfg=cfg)
    with pytest.raises(ValueError, match=r"ensemble must be \(B=1, M, 19\)"):
        fly_tuned(sim, theta, low, refs, broadcast(Disturbance.make(), 1), "log_cem", jax.random.PRNGKey(0), 100,
                  cfg=cfg, ensemble=np.repeat(theta, 3, 0))
