"""Sharding the batch axis over several devices (mjxsysid.runtime.distributed) gives the one-device
results. Two CPU devices are forced with XLA_FLAGS, which must be set before JAX starts: each
check runs in a subprocess that computes both results (``limit_devices(1)``: the one-device path,
no sharding; then both devices) and prints them as JSON.

Tolerances: the partitioned programs reassociate float sums (e.g. the minibatch means of the
training loss, whose gradients the compiler all-reduces over the devices), so results agree to
float32 rounding amplified by the dynamics, not bit for bit. Every comparison is per leaf,
|a − b| / max(1, max |a|) ≤ 1e-5: flights (positions, rotor speeds in rad/s, latents, metrics;
0.2 s of flight), collected latents, one training iteration's parameters, and the loss.
"""
import json
import os
import subprocess
import sys
import textwrap

import numpy as np
import pytest

from support.paths import ROOT

PRELUDE = """
import json, os, sys
import jax, numpy as np
jax.config.update("jax_compilation_cache_dir", os.environ["MJXSYSID_JAX_CACHE"])
jax.config.update("jax_persistent_cache_min_compile_time_secs", 0.5)
from mjxsysid.runtime import distributed as D
assert len(jax.devices()) == 2, jax.devices()
def maxdiff(a, b):
    # largest |a - b| over leaves, relative to max(1, max |a|) of each leaf
    la, lb = jax.tree.leaves(a), jax.tree.leaves(b)
    assert len(la) == len(lb)
    out = 0.0
    for x, y in zip(la, lb):
        x, y = np.asarray(x, np.float64), np.asarray(y, np.float64)
        assert x.shape == y.shape and np.array_equal(np.isnan(x), np.isnan(y))   # NaN only where both
        scale = max(1.0, float(np.max(np.abs(np.nan_to_num(x)), initial=0.0)))
        out = max(out, float(np.max(np.abs(np.nan_to_num(x) - np.nan_to_num(y)), initial=0.0)) / scale)
    return out
"""


def run_two_devices(body: str) -> dict:
    """Run PRELUDE + body on 2 forced CPU devices; the body prints one JSON line last."""
    # the suite's XLA flags (support.jax_setup) and two forced devices
    env = dict(os.environ, XLA_FLAGS=os.environ.get("XLA_FLAGS", "") + " --xla_force_host_platform_device_count=2",
               JAX_PLATFORMS="cpu", PYTHONPATH=str(ROOT))   # the suite's cache: support.jax_setup exports MJXSYSID_JAX_CACHE
    env.pop("MJXSYSID_DEVICES", None)
    code = PRELUDE + textwrap.dedent(body)
    p = subprocess.run([sys.executable, "-c", code], env=env, capture_output=True, text=True, timeout=900)
    assert p.returncode == 0, p.stderr[-3000:]
    r = json.loads(p.stdout.strip().splitlines()[-1])
    print(r)  # the measured differences (pytest -s)
    return r


@pytest.mark.parametrize("sim", ["RigidSim", pytest.param("Quadrotor", marks=pytest.mark.slow)])
def test_fly_batch_two_devices_equals_one_and_drops_padding(sim):
    """K_θ under the cascade (the slow tier flies the shipped policy, whose weights are
    replicated, through the same fly_batch: collect and evaluation tests below). The default tier
    flies the rigid-body twin (the same fly_batch, sharding and padding; its program compiles in
    about 2 s against the MJX simulator's 5, twice: one device, then two); `-m slow` the MJX one."""
    r = run_two_devices(f"""
        from mjxsysid import theta as P
        from mjxsysid.rollout.flight import fly_vehicles
        from mjxsysid.sim.quadrotor import Quadrotor, SimConfig
        from mjxsysid.sim.rigid import RigidSim
        sim = {sim}(SimConfig())
        theta = np.asarray(P.DEFAULT_PRIOR.sample(jax.random.PRNGKey(0), 5))   # odd: one padded row
        with D.limit_devices(1):
            f1, m1, _ = fly_vehicles(theta, controller="oracle", reference="lemniscate", duration=0.2, seed=3, sim=sim)
        f2, m2, _ = fly_vehicles(theta, controller="oracle", reference="lemniscate", duration=0.2, seed=3, sim=sim)
        mesh = D.batch_mesh()
        print(json.dumps({{"mesh": mesh.size, "padded": D.padded_size(5, mesh),
                          "shapes": [list(np.shape(x)[:2]) for x in jax.tree.leaves(f2)],
                          "sharded_over": len(f2.frame.pos.sharding.device_set),
                          "diff": maxdiff(f1, f2), "metric_diff": maxdiff(m1, m2),
                          "moved": float(np.abs(np.asarray(f2.frame.pos[:, -1] - f2.frame.pos[:, 0])).max())}}))
    """)
    assert r["mesh"] == 2 and r["padded"] == 6
    assert all(s == [5, 100] for s in r["shapes"])          # padding dropped from every leaf
    assert r["sharded_over"] == 2
    assert r["moved"] > 1e-4                                 # the flights did something
    assert r["diff"] <= 1e-5 and r["metric_diff"] <= 1e-5


@pytest.mark.slow
def test_collect_pairs_two_devices_equal_one():
    """collect's flights (a few minutes on 2 CPU cores; the fast tier flies the same policy
    through the same fly_batch above)."""
    r = run_two_devices("""
        from mjxsysid import theta as P
        from mjxsysid.dataset.collect import latents_in_flight
        theta = np.asarray(P.DEFAULT_PRIOR.sample(jax.random.PRNGKey(1), 3))
        with D.limit_devices(1):
            z1, f1 = latents_in_flight("mjxsysid", theta, jax.random.PRNGKey(2), steps=120)
        z2, f2 = latents_in_flight("mjxsysid", theta, jax.random.PRNGKey(2), steps=120)
        print(json.dumps({"shape": list(z2.shape), "diff": maxdiff(z1, z2), "failed_equal": bool((f1 == f2).all()),
                          "z_spread": float(np.std(z2, 0).max())}))
    """)
    assert r["shape"] == [3, 8]
    assert r["failed_equal"]
    assert r["z_spread"] > 1e-3                              # real latents, not a constant
    assert r["diff"] <= 1e-5


@pytest.mark.slow
def test_training_iteration_two_devices_equals_one():
    """One full PPO iteration (about 5 minutes on 2 CPU cores, compiles; the fast tier checks
    the data-parallel update on a small loss below). One minibatch: on a mesh each device
    shuffles its own samples (test_local_minibatches_partition_each_device), so with several
    minibatches their composition differs from one device's; with one, every sample is in it
    on both. The compiled iteration moves no samples between the devices (no all-gather)."""
    r = run_two_devices(r"""
        import re
        from mjxsysid.policy.adaptive.config import TrainConfig
        from mjxsysid.policy.adaptive.trainer import Trainer
        from mjxsysid.policy.adaptive.train import training_mesh
        cfg = TrainConfig(num_envs=8, unroll=4, epochs=1, minibatches=1, iterations=10)
        def one_iteration(mesh):
            tr = Trainer(cfg, mesh)
            ts = tr.place(tr.init(jax.random.PRNGKey(0)))
            env = tr.reset(*tr.place((jax.random.PRNGKey(1), np.float32(0.0))))
            ts, env, stats = tr.iteration(ts, env)
            return ts, env, stats
        with D.limit_devices(1):
            ts1, env1, s1 = one_iteration(training_mesh(cfg))
        ts2, env2, s2 = one_iteration(training_mesh(cfg))
        p0 = Trainer(cfg).init(jax.random.PRNGKey(0)).params
        tr2 = Trainer(cfg, training_mesh(cfg))
        hlo = tr2._iteration_jit.lower(*tr2.abstract_state(), tr2.weights).compile().as_text()
        print(json.dumps({"env_sharded_over": len(jax.tree.leaves(env2)[0].sharding.device_set),
                          "all_gathers": len(re.findall(r" all-gather(?:-start)?\(", hlo)),
                          "all_reduces": len(re.findall(r" all-reduce(?:-start)?\(", hlo)),
                          "loss1": float(s1["loss"]), "loss2": float(s2["loss"]),
                          "param_rel_diff": maxdiff(ts1.params, ts2.params),
                          "param_change": maxdiff(ts1.params, p0),
                          "env_diff": maxdiff(env1.theta, env2.theta)}))
    """)
    assert r["env_sharded_over"] == 2
    assert r["all_gathers"] == 0 and r["all_reduces"] >= 1   # gradients summed, samples never moved
    assert np.isfinite(r["loss1"])
    assert abs(r["loss1"] - r["loss2"]) <= 1e-5 * max(1.0, abs(r["loss1"]))
    assert r["param_change"] > 1e-6                          # the update moved the parameters
    assert r["param_rel_diff"] <= 1e-5
    assert r["env_diff"] <= 1e-6


def test_local_minibatches_partition_each_device():
    """Trainer._local_minibatches on 2 devices: every epoch's minibatches hold each sample once,
    rows of one sample stay together across leaves, and each device's slice of every minibatch
    comes from its own environments (so the shuffle moves nothing between the devices)."""
    r = run_two_devices("""
        from mjxsysid.policy.adaptive.config import TrainConfig
        from mjxsysid.policy.adaptive.trainer import Trainer
        from mjxsysid.policy.adaptive.train import training_mesh
        cfg = TrainConfig(num_envs=16, unroll=4, epochs=1, minibatches=4, iterations=10)
        tr = Trainer(cfg, training_mesh(cfg))
        t, n, d = cfg.unroll, cfg.num_envs, 2
        ids = np.arange(t * n, dtype=np.float32).reshape(t, n)          # sample id = t·N + env
        env_of = np.broadcast_to(np.arange(n, dtype=np.float32), (t, n))
        # The layout Trainer._advantages gives on a mesh: (D, T·N/D), device by device.
        flat = tuple(D.shard_batch(x.reshape(t, d, n // d).swapaxes(0, 1).reshape(d, -1), d) for x in (ids, env_of, ids))
        snaps = D.shard_batch((np.arange(n, dtype=np.float32), np.arange(n, dtype=np.float32) * 10), n)
        (a, b, c), (s1, s2) = jax.jit(tr._local_minibatches)(jax.random.PRNGKey(0), flat, snaps)
        a, b, c, s1, s2 = map(np.asarray, (a, b, c, s1, s2))
        half = a.shape[1] // 2
        print(json.dumps({"shape": list(a.shape), "snap_shape": list(s1.shape),
                          "each_once": sorted(a.ravel().tolist()) == list(range(t * n)),
                          "snaps_once": sorted(s1.ravel().tolist()) == list(range(n)),
                          "rows_together": bool(np.array_equal(a, c) and np.array_equal(s2, 10 * s1)
                                                and np.array_equal(b, a % n)),
                          "device0_local": bool(np.all(b[:, :half] < n // 2) and np.all(s1[:, :s1.shape[1] // 2] < n // 2)),
                          "device1_local": bool(np.all(b[:, half:] >= n // 2) and np.all(s1[:, s1.shape[1] // 2:] >= n // 2)),
                          "shuffled": bool(not np.array_equal(np.sort(a, 1), a))}))
    """)
    assert r["shape"] == [4, 16] and r["snap_shape"] == [4, 4]
    assert r["each_once"] and r["snaps_once"] and r["rows_together"]
    assert r["device0_local"] and r["device1_local"] and r["shuffled"]


@pytest.mark.slow
def test_evaluation_rollout_and_cfm_sampling_two_devices_equal_one():
    """evaluate-policy's environment rollout (3 envs: padded, series on axis 1) and the CFM
    sampling over cases of evaluate-decoder / decode (3 cases: padded)."""
    r = run_two_devices("""
        from mjxsysid.cfm.sample import Decoder
        from mjxsysid.policy.adaptive.controller import PolicyController
        from mjxsysid.policy.adaptive.config import EnvConfig
        from mjxsysid.policy.adaptive.env import TrainEnv
        from mjxsysid.policy.adaptive.evaluate import env_rollout
        from mjxsysid.cfm.load import load_decoders
        from mjxsysid.policy.interface import resolve_policy
        ctrl = PolicyController.load(None)
        env = TrainEnv(EnvConfig(episode_steps=31))
        cfm, _ = load_decoders(None, resolve_policy("mjxsysid"))
        z = np.asarray(jax.random.normal(jax.random.PRNGKey(4), (3, 8)) * 0.1, np.float32)
        out = {}
        for d in (1, 2):
            with D.limit_devices(d):
                out[d] = (env_rollout(env, ctrl.params, jax.random.PRNGKey(3), 3, 30, False),
                          cfm.sample_norm(z, jax.random.PRNGKey(5), 4, steps=5))
        print(json.dumps({"shapes": {k: list(np.shape(v)) for k, v in out[2][0].items()},
                          "samples": list(np.shape(out[2][1])), "diff_rollout": maxdiff(out[1][0], out[2][0]),
                          "diff_samples": maxdiff(out[1][1], out[2][1]),
                          "rate_err": float(np.mean(out[2][0]["rate_err"]))}))
    """)
    assert r["shapes"]["rate_err"] == [30, 3] and r["shapes"]["theta"] == [3, 19]
    assert r["samples"] == [3, 4, 19]
    assert r["rate_err"] > 0
    assert r["diff_rollout"] <= 1e-5 and r["diff_samples"] <= 1e-5


def test_data_parallel_gradient_two_devices_equals_one():
    """The training update's mechanism: batch sharded, parameters replicated, minibatch
    constrained with ``constrain_batch``; the compiler all-reduces the gradient."""
    r = run_two_devices("""
        import jax.numpy as jnp, optax
        def loss(w, x, y):
            return jnp.mean((jnp.tanh(x @ w["a"]) @ w["b"] - y) ** 2)
        def step(w, x, y, mesh):
            x, y = D.constrain_batch((x, y), mesh)
            g = jax.grad(loss)(w, x, y)
            return jax.tree.map(lambda p, q: p - 0.1 * q, w, g), g
        k = jax.random.split(jax.random.PRNGKey(0), 4)
        w = {"a": jax.random.normal(k[0], (6, 16)), "b": jax.random.normal(k[1], (16, 3))}
        x, y = jax.random.normal(k[2], (64, 6)), jax.random.normal(k[3], (64, 3))
        res = {}
        for d in (1, 2):
            with D.limit_devices(d):
                mesh = D.batch_mesh(divides=64)
                ws, xs, ys = D.shard_batch((w, x, y), 64, axes=(None, 0, 0), mesh=mesh)  # w replicated
                f = jax.jit(lambda w, x, y: step(w, x, y, mesh))
                res[d] = f(ws, xs, ys)
                hlo = f.lower(ws, xs, ys).compile().as_text()
                res[f"allreduce{d}"] = "all-reduce" in hlo
                res[f"in{d}"] = len(xs.sharding.device_set)
                res[f"w{d}"] = len(ws["a"].sharding.device_set)
        # the helpers inside a caller's jit (padding 5 -> 6 rows over the 2 devices)
        g = jax.jit(lambda v: D.unpad(jnp.sin(D.shard_batch(v, 5)), 5))(jnp.arange(5.0))
        res["jit_ok"] = bool(np.allclose(np.asarray(g), np.sin(np.arange(5.0)), atol=1e-6))
        print(json.dumps({"diff": maxdiff(res[1], res[2]), "grad_norm": float(optax.global_norm(res[1][1])),
                          "jit_ok": res["jit_ok"], "w2": res["w2"],
                          "allreduce1": res["allreduce1"], "allreduce2": res["allreduce2"],
                          "in1": res["in1"], "in2": res["in2"]}))
    """)
    assert r["in1"] == 1 and r["in2"] == 2
    assert r["jit_ok"]
    assert r["w2"] == 2                                      # the shared weights replicated on both
    assert r["allreduce2"] and not r["allreduce1"]          # the compiler inserted the all-reduce
    assert r["grad_norm"] > 1e-3
    assert r["diff"] <= 1e-5


def test_one_device_is_a_no_op():
    """In this process (one CPU device): nothing padded, placed or copied."""
    import jax
    import jax.numpy as jnp
    from mjxsysid.runtime import distributed as D
    if len(jax.devices()) != 1:
        pytest.skip("this process has several devices")
    tree = {"a": jnp.arange(5.0), "w": jnp.ones(3)}
    assert D.shard_batch(tree, 5, axes={"a": 0, "w": None}) is tree
    assert D.unpad(tree["a"], 5) is tree["a"]
    assert D.replicate(tree) is tree
    assert D.padded_size(5, D.batch_mesh()) == 5


def test_padding_and_unpad_helpers_on_a_fake_mesh():
    """Padding repeats the last row (valid inputs, never NaN) and unpad drops it."""
    import jax.numpy as jnp
    from mjxsysid.runtime.distributed import _pad, unpad
    x = jnp.arange(10.0).reshape(5, 2)
    p = _pad(x, 8)
    assert p.shape == (8, 2) and np.array_equal(p[5:], np.repeat(x[-1:], 3, 0))
    assert np.array_equal(unpad({"x": p}, 5)["x"], x)
    assert np.array_equal(unpad(jnp.swapaxes(p, 0, 1), 5, axis=1), x.T)


def test_launcher_detection_and_bad_settings():
    from mjxsysid.runtime.distributed import device_count, launcher_env
    assert launcher_env({}) is None
    assert launcher_env({"JAX_COORDINATOR_ADDRESS": "10.0.0.1:1234"}) == "jax"
    slurm = {"SLURM_JOB_ID": "7", "SLURM_STEP_NODELIST": "n[1-2]", "SLURM_PROCID": "0",
             "SLURM_LOCALID": "0", "SLURM_NTASKS": "2"}
    assert launcher_env(slurm) == "slurm"
    assert launcher_env({**slurm, "SLURM_NTASKS": "1"}) is None           # one task: nothing to join
    assert launcher_env({k: v for k, v in slurm.items() if k != "SLURM_STEP_NODELIST"}) is None  # sbatch, no srun
    assert launcher_env({**slurm, "MJXSYSID_DISTRIBUTED": "0"}) is None
    assert launcher_env({"OMPI_MCA_orte_hnp_uri": "x", "OMPI_COMM_WORLD_SIZE": "4"}) == "ompi"
    with pytest.raises(ValueError, match="SLURM_NTASKS"):
        launcher_env({**slurm, "SLURM_NTASKS": "two"})
    os.environ["MJXSYSID_DEVICES"] = "zero"
    try:
        with pytest.raises(ValueError, match="MJXSYSID_DEVICES"):
            device_count()
    finally:
        del os.environ["MJXSYSID_DEVICES"]


def test_maybe_initialize_names_a_missing_variable():
    from mjxsysid.runtime.distributed import maybe_initialize
    assert maybe_initialize({}) is False                      # no launcher: a plain run
    with pytest.raises(ValueError, match="JAX_NUM_PROCESSES"):
        maybe_initialize({"JAX_COORDINATOR_ADDRESS": "127.0.0.1:1234", "JAX_PROCESS_ID": "0"})


@pytest.mark.slow
def test_two_processes_equal_one(tmp_path):
    """Multi-host path on one machine: 2 processes of 1 CPU device each, joined by
    ``maybe_initialize`` through JAX_COORDINATOR_ADDRESS (gloo collectives), fly 5 vehicles;
    both gather the result of one process alone."""
    import socket
    code = textwrap.dedent("""
        import os, sys, numpy as np
        from mjxsysid.runtime import distributed as D
        joined = D.maybe_initialize()
        import jax
        jax.config.update("jax_compilation_cache_dir", os.environ["MJXSYSID_JAX_CACHE"])
        from mjxsysid import theta as P
        from mjxsysid.rollout.flight import fly_vehicles
        theta = np.asarray(P.DEFAULT_PRIOR.sample(jax.random.PRNGKey(0), 5))
        f, m, _ = fly_vehicles(theta, controller="oracle", reference="lemniscate", duration=0.1, seed=3)
        np.save(sys.argv[1], np.asarray(f.frame.pos))
        print(joined, jax.process_count(), len(jax.devices()), D.batch_mesh().size)
    """)
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        port = s.getsockname()[1]
    base = dict(os.environ, JAX_PLATFORMS="cpu", PYTHONPATH=str(ROOT),
                MJXSYSID_JAX_CACHE=os.environ["MJXSYSID_JAX_CACHE"])
    for k in ("XLA_FLAGS", "MJXSYSID_DEVICES", "JAX_COORDINATOR_ADDRESS"):
        base.pop(k, None)
    single = subprocess.run([sys.executable, "-c", code, str(tmp_path / "single.npy")], env=base,
                            capture_output=True, text=True, timeout=900)   # first: it also warms the cache
    procs = [subprocess.Popen([sys.executable, "-c", code, str(tmp_path / f"pos{i}.npy")], text=True,
                              stdout=subprocess.PIPE, stderr=subprocess.PIPE,
                              env=dict(base, JAX_COORDINATOR_ADDRESS=f"127.0.0.1:{port}",
                                       JAX_NUM_PROCESSES="2", JAX_PROCESS_ID=str(i)))
             for i in range(2)]
    outs = [p.communicate(timeout=900) for p in procs]
    for p, (o, e) in zip(procs, outs):
        assert p.returncode == 0, e[-3000:]
    assert single.returncode == 0, single.stderr[-3000:]
    last = lambda text: text.strip().splitlines()[-1].split()     # Gloo prints to stdout too
    assert [last(o) for o, _ in outs] == [["True", "2", "2", "2"]] * 2   # joined, 2 processes, mesh of 2
    assert last(single.stdout) == ["False", "1", "1", "1"]
    ref = np.load(tmp_path / "single.npy")
    assert ref.shape == (5, 50, 3)
    for i in range(2):
        np.testing.assert_allclose(np.load(tmp_path / f"pos{i}.npy"), ref, rtol=0, atol=1e-5)


def test_helpers_inside_jit():
    """The sharded boundaries may sit inside a caller's jit (e.g. CFM sampling): tracers pass."""
    import jax
    import jax.numpy as jnp
    from mjxsysid.runtime import distributed as D

    @jax.jit
    def f(x):
        y = D.shard_batch(x, 5)
        return D.unpad(y * 2.0, 5)

    np.testing.assert_array_equal(f(jnp.arange(5.0)), 2.0 * np.arange(5.0))
