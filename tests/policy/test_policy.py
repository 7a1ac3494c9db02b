"""The unified adaptive policy: networks, losses, schedules, a tiny learning run, checkpoints,
deployment = training, and the shipped weights."""
import dataclasses
import json

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from mjxsysid import theta as P
from mjxsysid.runtime.checkpoint import load_tree, save_tree
from mjxsysid.policy.adaptive import networks as N
from mjxsysid.policy.adaptive.config import EnvConfig, TrainConfig
from mjxsysid.policy.adaptive.controller import (
    PRETRAINED,
    PolicyCarry,
    PolicyController,
)
from mjxsysid.policy.adaptive.env import TrainEnv, training_env
from mjxsysid.policy.adaptive.losses import (
    IDENT_TARGET_NAMES,
    alignment_losses,
    gae,
    gaussian_logp,
    identifiable_log,
    identifiable_projection,
    schedules,
    variance_loss,
)
from mjxsysid.policy.adaptive.train import train
from mjxsysid.policy.adaptive.trainer import Trainer
from mjxsysid.policy.interface import resolve_policy

NETS = N.Networks()


@pytest.fixture(scope="module")
def params():
    return NETS.init(jax.random.PRNGKey(0))  # compiled (the Trainers' init shares it)


def test_network_shapes_and_jit(params):
    th = jnp.zeros((5, 19))
    hist = jnp.zeros((5, N.HISTORY, N.STATE))
    s = jnp.zeros((5, N.STATE))
    z = jax.jit(NETS.encode)(params, th)
    zh = jax.jit(NETS.adapt)(params, hist)
    mean, log_std = jax.jit(NETS.act)(params, s, z)
    assert z.shape == zh.shape == (5, 8) and mean.shape == (5, 4) and log_std.shape == (4,)
    assert NETS.value(params, s, th, z).shape == (5,)
    from mjxsysid.policy.adaptive.config import PARAM_MODULES
    assert set(params) == set(PARAM_MODULES)        # lr_constant's modules are the networks' groups
    assert NETS.decode(params, z).shape == (5, 19)
    assert np.all(np.abs(np.asarray(mean)) <= 1) and np.all(np.abs(np.asarray(zh)) <= 1)
    # φ mirrors the XAdap layout: 100 steps -> conv lengths 24, 20, 16 -> 512 features.
    assert params["phi"]["Dense_1"]["kernel"].shape == (512, 8)


def test_gaussian_logp_closed_form():
    x, m, ls = jnp.array([0.3, -0.2, 0.0, 1.0]), jnp.array([0.1, 0.0, 0.5, 1.0]), jnp.log(jnp.array([0.5, 1.0, 2.0, 0.1]))
    sd = np.exp(np.asarray(ls))
    expect = np.sum(-0.5 * ((np.asarray(x) - np.asarray(m)) / sd) ** 2 - np.log(sd) - 0.5 * np.log(2 * np.pi))
    np.testing.assert_allclose(float(gaussian_logp(x, m, ls)), expect, rtol=1e-6)


def test_gae_against_loop():
    rng = np.random.default_rng(0)
    T, n = 7, 3
    r, v = rng.normal(size=(T, n)), rng.normal(size=(T, n))
    d = rng.random((T, n)) < 0.2
    last = rng.normal(size=n)
    adv, ret = gae(jnp.asarray(r), jnp.asarray(v), jnp.asarray(d), jnp.asarray(last), 0.9, 0.8)
    exp = np.zeros((T, n))
    nxt_adv, nxt_v = np.zeros(n), last
    for t in reversed(range(T)):
        nd = 1 - d[t]
        delta = r[t] + 0.9 * nxt_v * nd - v[t]
        nxt_adv = delta + 0.9 * 0.8 * nd * nxt_adv
        exp[t] = nxt_adv
        nxt_v = v[t]
    np.testing.assert_allclose(np.asarray(adv), exp, rtol=1e-5, atol=1e-6)
    np.testing.assert_allclose(np.asarray(ret), exp + v, rtol=1e-5, atol=1e-6)


def test_variance_loss_hand_computed():
    z = jnp.array([[0.0, 1.0], [0.0, -1.0]])  # std 0 and 1
    np.testing.assert_allclose(float(variance_loss(z, 0.5)), 0.5 - np.sqrt(1e-6), rtol=1e-4)


@pytest.mark.parametrize("scale_invariant", [False, True])
def test_alignment_terms_and_stop_gradients(params, scale_invariant):
    key = jax.random.PRNGKey(3)
    th = jax.random.normal(key, (16, 19))
    hist = jax.random.normal(jax.random.fold_in(key, 1), (16, N.HISTORY, N.STATE))
    l1, l2 = alignment_losses(NETS, params, th, hist, scale_invariant)
    z, zh = jax.jit(NETS.encode)(params, th), jax.jit(NETS.adapt)(params, hist)   # compiled: not op by op
    scale = np.asarray(jnp.std(z, 0) + 1e-3) if scale_invariant else 1.0
    expect = np.mean(np.sum(((np.asarray(z) - np.asarray(zh)) / scale) ** 2, -1))
    np.testing.assert_allclose([float(l1), float(l2)], [expect, expect], rtol=1e-5)
    # both gradients from one compiled Jacobian (row 0: ∂λ1-term, row 1: ∂λ2-term)
    jac = jax.jit(jax.jacrev(lambda p: jnp.stack(alignment_losses(NETS, p, th, hist, scale_invariant))))(params)
    g1, g2 = jax.tree.map(lambda x: x[0], jac), jax.tree.map(lambda x: x[1], jac)
    norm = lambda t: float(sum(jnp.sum(x**2) for x in jax.tree.leaves(t)))
    assert norm(g1["mu"]) > 0 and norm(g1["phi"]) == 0   # λ1 moves μ towards sg[ẑ]
    assert norm(g2["phi"]) > 0 and norm(g2["mu"]) == 0   # λ2 moves φ towards sg[z^θ]


def test_schedules():
    cfg = TrainConfig(iterations=100, warmup=0.2, ramp=0.3, p_max=0.5, bc_coef=2.0, bc_final=0.1, bc_decay=0.5)
    p = [float(schedules(cfg, i)[0]) for i in (0, 20, 35, 50, 100)]
    np.testing.assert_allclose(p, [0, 0, 0.25, 0.5, 0.5], atol=1e-6)
    b = [float(schedules(cfg, i)[1]) for i in (0, 25, 50, 100)]
    np.testing.assert_allclose(b, [2.0, 1.05, 0.1, 0.1], atol=1e-6)


def test_config_errors():
    with pytest.raises(ValueError, match="unknown training config key"):
        TrainConfig.from_dict({"learning_rat": 1e-3})
    with pytest.raises(ValueError, match="divisible"):
        TrainConfig.from_dict({"num_envs": 30, "minibatches": 4})


TINY = dict(num_envs=64, unroll=16, epochs=2, minibatches=4, log_every=1, checkpoint_every=4,
            warmup=0.3, ramp=0.3)


@pytest.fixture(scope="module")
def tiny_trainer():
    """The trainer of the tiny learning test, shared with the loss-weight tests: one compile."""
    return Trainer(TrainConfig(iterations=16, **TINY))


# The tiny Trainer's iteration runs 16 times here and in test_loss_weight_options_*: compiled with XLA's
# optimisations (support.jax_setup.xla_optimised) it is faster in all (measured: test_policy.py 72 -> 61 s).
@pytest.mark.usefixtures("xla_optimised_test")
def test_tiny_training_improves_tracking_and_resumes(tmp_path, tiny_trainer):
    """16 iterations × 1024 steps (seconds after compile) cut the body-rate tracking error of the
    untrained policy by 30 % or more (measured: 3.6 -> 2.2 rad/s with the interruption, 1.9
    without); an interrupted run resumes
    from its checkpoint."""
    cfg = TrainConfig(iterations=16, **TINY)

    class Stop(Exception):
        pass

    def interrupt(msg):
        if msg.startswith("it     6/"):
            raise Stop

    with pytest.raises(Stop):
        train(cfg, tmp_path, resume=False, log=interrupt, trainer=tiny_trainer)
    assert (tmp_path / "checkpoint.npz").exists() and not (tmp_path / "policy.npz").exists()
    lines = []
    res = train(cfg, tmp_path, resume=True, log=lines.append, trainer=tiny_trainer)
    assert any("resumed from" in m and "iteration 4" in m for m in lines), lines[:2]
    log = [json.loads(x) for x in (tmp_path / "train_log.jsonl").read_text().splitlines()]
    assert log[-1]["iteration"] == 16
    first, last = log[0]["rate_err"], np.mean([r["rate_err"] for r in log[-3:]])
    assert last < 0.7 * first, (first, last)
    assert res["stats"]["latent_min_std"] > 0.02  # no collapse (hinge at 0.1 holds it up)
    ctrl = PolicyController.load(tmp_path / "policy.npz")
    assert ctrl.phi_every == cfg.env.phi_every
    with pytest.raises(ValueError, match="different config"):
        train(TrainConfig(iterations=17, **TINY), tmp_path, resume=True)


def test_warm_start_loads_the_policy_and_says_what_is_wrong(tmp_path, tiny_trainer):
    """TrainConfig.init_from: μ, φ, π and aux start from a policy.npz (the probe loop's accumulate
    variant fine-tunes this way); a missing or wrong file is an error naming init_from."""
    import copy
    from mjxsysid.policy.adaptive.focus import save_weak
    from mjxsysid.policy.adaptive.weights import load_policy_params
    tr = copy.copy(tiny_trainer)                   # the tiny Trainer's compiled init, another config
    tr.cfg = dataclasses.replace(tiny_trainer.cfg, init_from=str(PRETRAINED))
    ts = tr.init(jax.random.PRNGKey(3))
    want, _ = load_policy_params(PRETRAINED)
    for k in ("mu", "phi", "pi", "aux"):
        for a, b in zip(jax.tree.leaves(ts.params[k]), jax.tree.leaves(want[k])):
            np.testing.assert_array_equal(np.asarray(a), np.asarray(b))
    assert set(ts.params) - {"mu", "phi", "pi", "aux"}       # the critic starts afresh
    tr.cfg = dataclasses.replace(tiny_trainer.cfg, init_from=str(tmp_path / "none.npz"))
    with pytest.raises(FileNotFoundError, match="init_from: policy weights not found"):
        tr.warm_start_params()
    tr.cfg = dataclasses.replace(tiny_trainer.cfg, init_from=str(save_weak(tmp_path / "w.npz", P.PAPER_HARDWARE[None])))
    with pytest.raises(ValueError, match="init_from: .*not mjxsysid policy weights"):
        tr.warm_start_params()


def test_episode_starts_once_per_unroll(params):
    """TrainConfig.reset_per_unroll: an environment whose episode ends restarts from the given
    precomputed start (same vehicle and reference; its own random stream), the others fly on."""
    env = TrainEnv(EnvConfig())

    @jax.jit   # one reset and one step compiled (vmapped over the pair), not two of each
    def run(keys):
        st, fresh = (jax.tree.map(lambda x, i=i: x[i], jax.vmap(lambda k: env.reset(k, 0.0))(keys)) for i in (0, 1))
        last = st.replace(step=jnp.int32(env.config.episode_steps - 1))
        _, _, _, obs = env.policy_input(params, last)
        pair = jax.tree.map(lambda a, b: jnp.stack([a, b]), last, st)
        out = jax.vmap(lambda x: training_env(env).step(params, x, jnp.zeros(4), obs, 0.0, False, fresh))(pair)
        return st, fresh, [jax.tree.map(lambda x, i=i: x[i], out) for i in (0, 1)]

    st, fresh, ((ended, t_end), (going, t_go)) = run(jnp.stack([jax.random.PRNGKey(1), jax.random.PRNGKey(2)]))
    assert bool(t_end.done) and not bool(t_go.done)
    np.testing.assert_array_equal(np.asarray(ended.theta), np.asarray(fresh.theta))
    np.testing.assert_array_equal(np.asarray(ended.sim.pos), np.asarray(fresh.sim.pos))
    assert int(ended.step) == 0 and not np.array_equal(np.asarray(ended.key), np.asarray(fresh.key))
    np.testing.assert_array_equal(np.asarray(going.theta), np.asarray(st.theta))
    assert int(going.step) == 1


def test_checkpoint_round_trip_and_errors(tmp_path, params):
    path = save_tree(tmp_path / "p.npz", params, {"note": "x"})
    back = load_tree(path, params)
    for a, b in zip(jax.tree.leaves(params), jax.tree.leaves(back)):
        np.testing.assert_array_equal(np.asarray(a), np.asarray(b))
    with pytest.raises(ValueError, match="missing array|unexpected arrays"):
        load_tree(path, {"mu": params["mu"]})
    with pytest.raises(FileNotFoundError, match="not found"):
        load_tree(tmp_path / "nope.npz", params)


def test_deployed_controller_equals_training_policy(params):
    """The low-level controller computes exactly the action the training env's policy takes
    on the same history, last action, command and ẑ."""
    env = TrainEnv(EnvConfig())

    @jax.jit  # one compile for both paths (op by op, the env's reset alone compiled ~150 kernels)
    def both(params):
        st = env.reset(jax.random.PRNGKey(5), 1.0)
        st = st.replace(zhat=jnp.linspace(-0.5, 0.5, 8), last_raw=jnp.array([0.1, -0.2, 0.3, 0.0]),
                        history=jax.random.normal(jax.random.PRNGKey(6), (N.HISTORY, N.STATE)))
        s, z, _, obs = env.policy_input(params, st)
        mean, _ = NETS.act(params, s, z)
        ctrl = PolicyController(params=params, z_override=jnp.zeros(8), use_override=jnp.array(False))
        carry = PolicyCarry(st.history, st.last_raw, st.zhat, jnp.int32(3), jnp.array(True))
        carry2, u = ctrl.step(carry, st.sim.imu, st.command)
        return u, N.to_motor(mean), carry2.history, N.push_history(st.history, obs, mean)

    u, u_train, hist, hist_train = both(params)
    np.testing.assert_allclose(np.asarray(u), np.asarray(u_train), atol=1e-6)
    np.testing.assert_allclose(np.asarray(hist), np.asarray(hist_train), atol=1e-6)


@pytest.mark.skipif(not PRETRAINED.exists(), reason="no shipped policy weights")
def test_pretrained_policy_hovers_and_tracks_paper_vehicle():
    from mjxsysid.rollout.flight import fly_vehicles
    # 5 s: the hover of tests/experiments/test_experiments_robustness.py::test_payload_tiny (one compile)
    _, m, _ = fly_vehicles(P.PAPER_HARDWARE, controller="policy", policy=resolve_policy("mjxsysid"),
                           reference="hover", duration=5.0)
    assert not bool(m["failed"][0])
    assert float(m["max_pos_err_m"][0]) < 0.05, float(m["max_pos_err_m"][0])
    meta = json.loads((PRETRAINED.parent / "policy.json").read_text())
    for k in ("config", "seed", "commit", "device", "wall_s", "evaluation"):
        assert k in meta, k


def test_collect_pairs_tiny(collected_pairs, tmp_path):
    """`mjxsysid collect --train 6 --test 2 --batch 4` (conftest.collected_pairs)."""
    from mjxsysid.dataset.collect import load_pairs
    arrays, meta = load_pairs(collected_pairs)
    assert arrays["theta_train"].shape == (6, 19) and arrays["zhat_test"].shape == (2, 8)
    assert np.all(np.abs(arrays["zhat_train"]) <= 1) and not arrays["failed_train"].any()
    assert len(meta["weights_sha256"]) == 64 and meta["prior"] == "wide_actuators"  # the decoders' prior
    with pytest.raises(FileNotFoundError):
        load_pairs(tmp_path / "nope")


def test_collect_reducers_keep_what_collect_returns():
    """collect's flights are reduced inside the compiled flight (only ẑ and the failure flag
    leave the devices): the reducers pick the same numbers as the whole flight would give."""
    from types import SimpleNamespace
    from mjxsysid.dataset.collect import LatentsAt, last_latent_and_failure
    from mjxsysid.rollout.harness import failure_mask
    T = 7
    lat = jnp.arange(T * 8, dtype=jnp.float32).reshape(T, 8)
    pos = jnp.zeros((T, 3)).at[:, 2].set(1.0)

    def flight(bad_step=None):
        p = pos if bad_step is None else pos.at[bad_step, 2].set(-0.1)   # a crash at bad_step
        return SimpleNamespace(latent=lat, ref_pos=jnp.zeros((T, 3)).at[:, 2].set(1.0),
                               frame=SimpleNamespace(pos=p, diverged=jnp.zeros(T, bool)))
    for bad, failed in ((None, False), (2, True), (T - 1, True)):
        z, f = last_latent_and_failure(flight(bad))
        np.testing.assert_array_equal(z, lat[-1])
        assert bool(f) is failed and bool(f) == bool(failure_mask(flight(bad))[-1])
        zt, f2 = LatentsAt((1, 4, 6))(flight(bad))
        np.testing.assert_array_equal(zt, lat[jnp.asarray([1, 4, 6])])
        assert bool(f2) is failed
    assert hash(LatentsAt((1, 4))) == hash(LatentsAt((1, 4)))   # the compiled flight is reused


@pytest.mark.slow
def test_collect_reduced_flight_equals_whole_flight():
    """latents_in_flight / latent_trajectories_in_flight (reduced in the compiled flight) give
    bit for bit what the whole flight gives (fly_batch without reduce, then indexed)."""
    from mjxsysid.dataset import collect as C
    from mjxsysid.sim import Quadrotor
    theta = np.asarray(P.DEFAULT_PRIOR.sample(jax.random.PRNGKey(1), 3))
    key, n = jax.random.PRNGKey(2), 3
    low, high = resolve_policy("mjxsysid").batched(n), C.broadcast(C.Cascade.make("baseline"), n)
    zt, _, f, _ = C.latent_trajectories_in_flight("mjxsysid", theta, key, seconds=0.5)
    _, idx, steps = C.trajectory_times(0.5)
    k_man, k_fly = jax.random.split(key)
    ref, dist, _ = C.random_manoeuvres(k_man, theta, 0.5, C.MANOEUVRES, 0)
    fl = C.fly_batch(Quadrotor(), theta, low, high, ref, dist, k_fly, steps)
    np.testing.assert_array_equal(zt, np.asarray(fl.latent[:, idx]))
    np.testing.assert_array_equal(f, np.asarray(jax.vmap(C.failure_mask)(fl))[:, -1])
    assert float(np.std(zt)) > 1e-3                                   # real latents
    z, f = C.latents_in_flight("mjxsysid", theta, key, steps=120)
    ref, dist, k_fly = C.lemniscate_excitation(key, theta)
    fl = C.fly_batch(Quadrotor(), theta, low, high, ref, dist, k_fly, 120)
    np.testing.assert_array_equal(z, np.asarray(fl.latent[:, -1]))
    np.testing.assert_array_equal(f, np.asarray(jax.vmap(C.failure_mask)(fl))[:, -1])


def test_identifiable_projection_is_exact():
    """(y − y') A equals the standardised difference of log T/W, log κ, log authority, log τ_m."""
    norm = P.prior_normalizer("default", n=4000)
    A = identifiable_projection(norm, P.DEFAULT_PRIOR, n=3000)
    assert A.shape == (19, len(IDENT_TARGET_NAMES))
    std = np.std(np.asarray(identifiable_log(P.DEFAULT_PRIOR.sample(jax.random.PRNGKey(0), 3000))), 0)
    th = P.DEFAULT_PRIOR.sample(jax.random.PRNGKey(9), 65)
    y, g = np.asarray(norm.normalize(th)), np.asarray(identifiable_log(th))
    np.testing.assert_allclose((y[1:] - y[:-1]) @ np.asarray(A), (g[1:] - g[:-1]) / std, atol=2e-4)
    np.testing.assert_allclose(np.exp(g[:, 0]), np.asarray(P.nominal_thrust_to_weight(th)), rtol=1e-5)
    assert float(A[P.MASS, 0]) < 0 < float(A[P.OMEGA_MAX, 0]) and float(A[P.TAU_M, 5]) > 0
    # the yaw-authority variant: column 1 becomes log(k_τ Ω_max² / J_zz), still exact
    Ay = np.asarray(identifiable_projection(norm, P.DEFAULT_PRIOR, n=3000, yaw_authority=True))
    gy = np.asarray(identifiable_log(th, yaw_authority=True))
    th_np = np.asarray(th, np.float64)
    np.testing.assert_allclose(np.exp(gy[:, 1]), th_np[:, P.KTAU] * th_np[:, P.OMEGA_MAX] ** 2 / th_np[:, 6],
                               rtol=1e-4)
    np.testing.assert_array_equal(gy[:, [0, 2, 3, 4, 5]], g[:, [0, 2, 3, 4, 5]])
    stdy = np.std(np.asarray(identifiable_log(P.DEFAULT_PRIOR.sample(jax.random.PRNGKey(0), 3000), True)), 0)
    np.testing.assert_allclose((y[1:] - y[:-1]) @ Ay, (gy[1:] - gy[:-1]) / stdy, atol=2e-4)
    assert float(Ay[P.OMEGA_MAX, 1]) > 0 > float(Ay[6, 1]) and abs(float(Ay[P.KT, 1])) < 1e-6


@pytest.mark.usefixtures("xla_optimised_test")
@pytest.mark.parametrize("over", [{"rec_ident_coef": 0.0}, {"rec_ident_coef": 1.0, "rec_coef": 0.0},
                                  {"lambda1": 0.1}, {"var_target": 0.3}])
def test_loss_weight_options_share_the_compile_and_train(tiny_trainer, over):
    """Every loss-weight trial option runs one tiny training step through the base config's
    compiled iteration: finite losses, shapes kept, and weights that differ from the base step."""
    t0 = tiny_trainer
    # p as train() passes it (a float32 array, not a Python float): the compiled reset is shared
    ts, env = t0.init(jax.random.PRNGKey(0)), t0.reset(jax.random.PRNGKey(1), jnp.float32(0.0))
    base, _, base_stats = t0.iteration(ts, env)
    t = t0.reweighted(dataclasses.replace(t0.cfg, **over))
    assert t._iteration_jit is t0._iteration_jit and t.cfg != t0.cfg
    new, env2, stats = t.iteration(ts, env)
    assert all(np.isfinite(float(v)) for v in stats.values()), stats
    assert float(stats["rec_ident"]) > 0 and float(base_stats["rec_ident"]) > 0
    assert env2.history.shape == env.history.shape
    moved = [k for k in ("mu", "aux", "phi") if any(
        not np.allclose(np.asarray(a), np.asarray(b)) for a, b in
        zip(jax.tree.leaves(new.params[k]), jax.tree.leaves(base.params[k])))]
    assert "mu" in moved, moved   # every option here acts on μ's gradient
    with pytest.raises(ValueError, match="beyond the loss weights.*learning_rate"):
        t0.reweighted(dataclasses.replace(t0.cfg, learning_rate=1e-3))


def test_latent_health_and_trial_summary_on_a_synthetic_latent():
    """A latent that linearly codes log T/W and log τ_m (and nothing about κ) probes as such;
    trial_summary reads the headline numbers from it."""
    from mjxsysid.policy.adaptive.evaluate import latent_health, trial_summary
    th = np.asarray(P.DEFAULT_PRIOR.sample(jax.random.PRNGKey(2), 600))
    g = np.asarray(identifiable_log(th))
    rng = np.random.default_rng(0)
    z_theta = np.concatenate([g[:, [0, 5]], rng.normal(size=(600, 6))], 1) * 0.1
    zhat = z_theta + 0.001 * rng.normal(size=z_theta.shape)
    lat = latent_health(z_theta, zhat, np.asarray(P.prior_normalizer("default", n=2000).normalize(th)), th)
    lem = {"policy": {"success_rate": 1.0}, "oracle": {"success_rate": 1.0}, "rmse_ratio_policy_over_oracle": 1.02}
    s = trial_summary({"latent": lat, "latent_flight": lat, "lemniscate": lem})
    assert s["train_cmds"]["r2_thrust_to_weight"] > 0.99 and s["flight"]["r2_tau_m"] > 0.99
    assert s["train_cmds"]["r2_kappa"] < 0.1
    np.testing.assert_allclose(s["train_cmds"]["z_err_rel"], 0.001 * np.sqrt(8) / np.sqrt(z_theta.var(0).sum()), rtol=0.1)
    assert s["rmse_ratio"] == 1.02 and s["success_policy"] == 1.0
    assert lat["n"] == 600 and "note" not in lat
    # Too few vehicles (a policy whose flights all failed: none are left): no figure, not an R² of 1.
    none = latent_health(z_theta[:0], zhat[:0], th[:0], th[:0])
    assert none["n"] == 0 and "unavailable" in none["note"]
    s0 = trial_summary({"latent": none, "latent_flight": latent_health(z_theta[:3], zhat[:3], th[:3], th[:3]),
                        "lemniscate": lem})
    for k in ("train_cmds", "flight"):
        assert all(np.isnan(v) for v in s0[k].values()), s0[k]
        assert not s0[k]["r2_thrust_to_weight"] >= 0.9                  # the bar is failed, not passed
    from mjxsysid.policy.adaptive.evaluate import linear_probe_r2
    assert np.isnan(linear_probe_r2(zhat[:2], th[:2])).all()          # an empty held-out split


@pytest.mark.slow
@pytest.mark.skipif(not PRETRAINED.exists(), reason="no shipped policy weights")
def test_fast_eval_tiny_on_shipped_policy():
    """fast_eval end to end (tiny sizes; minutes of CPU compiles): all headline numbers present
    and sane for the shipped policy, which flies every vehicle."""
    from mjxsysid.policy.adaptive.evaluate import fast_eval
    ctrl = PolicyController.load()
    ev = fast_eval(ctrl.params, n_probe=48, n_lem=4, steps=250, flight_steps=200, period=10.0, log=lambda m: None)
    s = ev["summary"]
    assert s["success_policy"] == 1.0 and 0.5 < s["rmse_ratio"] < 2.0
    for k in ("train_cmds", "flight"):
        assert 0.0 < s[k]["z_err_rel"] < 1.5 and s[k]["z_min_std"] > 0.02
        assert all(np.isfinite(v) for v in s[k].values())


def test_warm_start_normalizer_check_allows_float32_rounding_only():
    """init_from accepts a policy whose normaliser differs in the last bits (another device's
    reductions), not one of another prior, nor one with other keys."""
    from mjxsysid.policy.adaptive.weights import same_normalizer
    norm = {"shift": [0.1, -2.0, 3.5], "scale": [1.0, 0.5, 2.0]}
    near = {k: (np.asarray(v) * (1 + 1e-7)).tolist() for k, v in norm.items()}
    far = {k: (np.asarray(v) * 1.01 + 0.01).tolist() for k, v in norm.items()}
    assert same_normalizer(norm, near)
    assert not same_normalizer(norm, far)
    assert not same_normalizer(norm, {**norm, "flow_map": [[1.0]]})
    assert not same_normalizer(norm, {k: v[:-1] for k, v in norm.items()})
