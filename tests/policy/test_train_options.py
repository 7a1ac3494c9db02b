"""Policy-training options of issue 30: the optimiser's variants (flat Adam, the learning-rate
decay) and the start and iteration compiled in background threads (the same results as the jitted
path; a failed compile raises in the caller)."""
import dataclasses
import json

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from mjxsysid.policy.adaptive.trainer import Trainer, optimizer
from mjxsysid.policy.adaptive.config import TrainConfig

MICRO = TrainConfig(num_envs=8, unroll=4, epochs=1, minibatches=2, iterations=2, reset_per_unroll=True)


def _steps(opt, params, grads, n):
    """Updates of ``n`` steps of ``opt`` on constant gradients."""
    state, out = opt.init(params), []
    for _ in range(n):
        upd, state = opt.update(grads, state, params)
        out.append(upd)
    return out


def test_flat_optimizer_is_the_same_update():
    """optax.flatten: Adam and the global-norm clip on one vector give each leaf the update of the
    tree version (float32 rounding apart), also where the clip acts (norm above max_grad_norm)."""
    params = {"a": jnp.ones((3, 2)), "b": {"c": jnp.arange(4.0)}}
    grads = {"a": jnp.full((3, 2), 0.7), "b": {"c": jnp.array([0.1, -2.0, 0.5, 3.0])}}   # norm 3.8 > 1: clipped
    base = TrainConfig(max_grad_norm=1.0)
    tree = _steps(optimizer(base), params, grads, 3)
    flat = _steps(optimizer(dataclasses.replace(base, flat_optimizer=True)), params, grads, 3)
    for u, v in zip(tree, flat):
        for x, y in zip(jax.tree.leaves(u), jax.tree.leaves(v)):
            np.testing.assert_allclose(np.asarray(x), np.asarray(y), rtol=1e-6, atol=1e-9)


def test_learning_rate_decays_linearly_to_lr_final():
    """lr_decay: Adam's step on a constant gradient (≈ the learning rate) falls linearly from
    learning_rate to lr_final × learning_rate over iterations × epochs × minibatches steps."""
    cfg = TrainConfig(iterations=5, epochs=2, minibatches=2, learning_rate=1e-2, lr_decay=True, lr_final=0.1)
    n = cfg.iterations * cfg.epochs * cfg.minibatches
    ups = _steps(optimizer(cfg), {"w": jnp.zeros(1)}, {"w": jnp.full(1, 0.5)}, n + 1)
    size = np.array([-float(u["w"][0]) for u in ups])
    want = 1e-2 * np.concatenate([np.linspace(1.0, 0.1, n + 1)])
    np.testing.assert_allclose(size, want, rtol=1e-3)
    const = _steps(optimizer(dataclasses.replace(cfg, lr_decay=False)), {"w": jnp.zeros(1)}, {"w": jnp.full(1, 0.5)}, n)
    np.testing.assert_allclose([-float(u["w"][0]) for u in const], 1e-2, rtol=1e-3)
    with pytest.raises(ValueError, match="lr_final must be in"):
        TrainConfig.from_dict({"lr_final": 1.5})


@pytest.mark.slow
def test_background_compile_gives_the_jitted_results():
    """Trainer.start_compile: start (state + first episodes) and the iteration compiled in threads
    give the jitted path's values bit for bit (the same program), the start matching init + reset.
    Slow (four compiles, ≈ 30 s cold on 2 cores); in the fast tier every ``train`` call runs the
    background path (tests of learning, resuming, sensor randomisation) and the error path is below."""
    key = jax.random.PRNGKey(5)
    a = Trainer(MICRO)
    ts_a, env_a = a.start(key)
    ts_i = a.init(key)
    env_i = a.reset(jax.random.fold_in(ts_i.key, 123), jnp.float32(0.0))
    b = Trainer(MICRO)
    b.start_compile()
    ts_b, env_b = b.start(key)
    out_a, out_b = a.iteration(ts_a, env_a), b.iteration(ts_b, env_b)
    assert set(b._compiled) == {"start", "iteration"} and set(b.compile_seconds) == {"start", "iteration"}
    for x, y, z in zip(jax.tree.leaves((ts_a, env_a)), jax.tree.leaves((ts_b, env_b)), jax.tree.leaves((ts_i, env_i))):
        np.testing.assert_array_equal(np.asarray(x), np.asarray(y))
        np.testing.assert_array_equal(np.asarray(x), np.asarray(z))
    for x, y in zip(jax.tree.leaves(out_a), jax.tree.leaves(out_b)):
        np.testing.assert_array_equal(np.asarray(x), np.asarray(y))


def test_background_compile_error_raises_in_the_caller():
    """A compile that fails in its thread raises the same error at the first call that needs it."""
    tr = Trainer(MICRO)

    def broken(ts, env, weights):
        raise ValueError("bad iteration for the test")
    tr._iteration_jit = jax.jit(broken)
    tr._start_jit = jax.jit(lambda params, key: key)   # a trivial start: only the iteration's compile matters here
    tr.start_compile()
    with pytest.raises(ValueError, match="bad iteration for the test"):
        tr.iteration(None, None)                  # raises before running anything


def test_lr_constant_modules_keep_the_learning_rate():
    """lr_constant: under lr_decay the named modules' Adam step stays at learning_rate while the
    others' falls to lr_final × it; the config takes a JSON list and rejects unknown modules and
    flat Adam (one vector, one rate)."""
    cfg = TrainConfig.from_dict({"iterations": 4, "epochs": 1, "minibatches": 1, "learning_rate": 1e-2,
                                 "lr_decay": True, "lr_final": 0.1, "lr_constant": ["phi"]})
    assert cfg.lr_constant == ("phi",)
    params = {k: {"w": jnp.zeros(2)} for k in ("mu", "phi", "pi", "v", "aux")}
    grads = {k: {"w": jnp.full(2, 0.3)} for k in params}
    last = _steps(optimizer(cfg), params, grads, 5)[-1]           # step 4 of 4: the decayed rate
    np.testing.assert_allclose(-np.asarray(last["phi"]["w"]), 1e-2, rtol=1e-3)
    for k in ("mu", "pi", "v", "aux"):
        np.testing.assert_allclose(-np.asarray(last[k]["w"]), 1e-3, rtol=1e-3)
    # Without lr_constant the split is not made: the same update as one Adam.
    whole = _steps(optimizer(dataclasses.replace(cfg, lr_constant=())), params, grads, 5)[-1]
    np.testing.assert_allclose(-np.asarray(whole["phi"]["w"]), 1e-3, rtol=1e-3)
    with pytest.raises(ValueError, match="unknown module"):
        TrainConfig.from_dict({"lr_constant": ["psi"]})
    with pytest.raises(ValueError, match="flat_optimizer"):
        TrainConfig.from_dict({"lr_constant": ["phi"], "flat_optimizer": True, "lr_decay": True})
    with pytest.raises(ValueError, match="lr_decay"):
        TrainConfig.from_dict({"lr_constant": ["phi"]})
    assert TrainConfig.from_dict(json.loads(json.dumps(cfg.to_dict()))) == cfg   # survives a checkpoint's JSON
