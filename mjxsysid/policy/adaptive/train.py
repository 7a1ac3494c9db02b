"""Training of the adaptive policy on the host: :func:`train` runs the jitted iteration of
:class:`~mjxsysid.policy.adaptive.trainer.Trainer` back to back, logs progress, writes
checkpoints that resume exactly, and ships ``policy.npz`` at the end.
"""
from __future__ import annotations

import json
import time
from pathlib import Path

import jax

from mjxsysid.runtime import ahead, jsonout
from mjxsysid.runtime import distributed
from mjxsysid.runtime.checkpoint import load_meta, load_tree, save_tree
from mjxsysid.policy.adaptive.config import TrainConfig
from mjxsysid.policy.adaptive.losses import schedules
from mjxsysid.policy.adaptive.trainer import Trainer
from mjxsysid.policy.adaptive.weights import save_policy_params
from mjxsysid.runtime.progress import progress


def _same_config(saved, cfg: TrainConfig) -> bool:
    """Whether a checkpoint's saved config is ``cfg`` (keys added since it was written read as
    their defaults)."""
    if not isinstance(saved, dict):
        return False
    try:
        return json.loads(json.dumps(TrainConfig.from_dict(saved).to_dict())) == json.loads(json.dumps(cfg.to_dict()))
    except (TypeError, ValueError):
        return False


def training_mesh(cfg: TrainConfig):
    """The data-parallel mesh for ``cfg``: the most devices (of those JAX sees) that divide
    ``num_envs / minibatches``, since each device shuffles its own environments' samples into every
    minibatch (:meth:`~mjxsysid.policy.adaptive.trainer.Trainer._local_minibatches`)."""
    whole = cfg.num_envs % cfg.minibatches == 0
    return distributed.batch_mesh(divides=cfg.num_envs // cfg.minibatches if whole else cfg.num_envs)


def train(cfg: TrainConfig, out_dir, *, resume: bool = True, log=print, trainer: Trainer | None = None,
          background_compile: bool | None = None) -> dict:
    """Train with checkpoints in ``out_dir`` (``checkpoint.npz``: training state and the
    environments' state, so an interrupted run resumed from it continues exactly as an
    uninterrupted one; resumed if present and ``resume``). Writes ``policy.npz`` (shipped
    format) and ``train_log.jsonl``. Returns the last stats and wall time. A progress bar
    (:mod:`mjxsysid.runtime.progress`) advances per iteration with the key metrics. ``trainer``: a
    prebuilt :class:`Trainer` for ``cfg`` (e.g. from :meth:`Trainer.reweighted`, to share its
    compile). ``background_compile`` (default on; ``MJXSYSID_COMPILE_AHEAD=0`` turns it off, for timing the
    difference: :func:`mjxsysid.runtime.ahead.enabled`): the iteration compiles in a background thread while
    the states are made (:meth:`Trainer.start_compile`)."""

    t_enter = time.time()
    if background_compile is None:
        background_compile = ahead.enabled()
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    if trainer is not None and trainer.cfg != cfg:
        raise ValueError("train: the trainer was built for a different config")
    mesh = training_mesh(cfg)
    if trainer is not None and (trainer.mesh.size if trainer.mesh is not None else 1) != mesh.size:
        raise ValueError(f"train: the trainer was built for another device mesh than the {mesh.size} device(s)")
    ckpt = out / "checkpoint.npz"
    meta = load_meta(ckpt) if (resume and ckpt.exists()) else None   # the run to resume
    # A checkpoint of another config is an error before anything compiles (a compile started in the
    # background would run on after the error, holding the CPU).
    if meta is not None and not _same_config(meta.get("config"), cfg):
        raise ValueError(f"{ckpt} was written with a different config; use a new --out or --no-resume")
    t_built = None
    if trainer is None:
        trainer = Trainer(cfg, mesh)
        t_built = time.time()
        if background_compile:
            trainer.start_compile()   # the iteration compiles while the states below are made
    ts, env_state = trainer.start(jax.random.PRNGKey(cfg.seed))   # a fresh run: state and environments
    if meta is not None:
        if meta.get("with_env"):
            ts, env_state = load_tree(ckpt, (ts, env_state))
            # resumed environments: shard their batch axis like a fresh reset's
            env_state = distributed.shard_batch(env_state, cfg.num_envs, mesh=mesh)
        else:  # older checkpoints hold the training state only: environments restart
            ts = load_tree(ckpt, ts)
            p0, _ = schedules(cfg, ts.iteration)
            env_state = trainer.reset(*trainer.place((jax.random.fold_in(ts.key, 123), p0)))
        log(f"resumed from {ckpt} at iteration {int(ts.iteration)}")
    if mesh.size > 1:
        log(f"{cfg.num_envs} environments sharded over {mesh.size} devices ({jax.process_count()} process(es))")
    ts = trainer.place(ts)
    steps_per_it = cfg.num_envs * cfg.unroll
    t_start = time.time()
    # Where this call's wall time goes (BENCHMARKS.md): building the trainer, initialising and
    # resetting (compiles), the first iteration (its compile), the loop, checkpoints, the export.
    timing = {"setup_s": t_start - t_enter, "first_iteration_s": 0.0, "checkpoint_s": 0.0}
    if t_built is not None:
        timing["construct_s"] = t_built - t_enter   # of setup: building the Trainer (before any compile starts)
    wall_prev = meta.get("wall_s", 0.0) if meta is not None else 0.0
    logf = open(out / "train_log.jsonl", "a")
    stats = {}
    t_log, it_log = time.time(), int(ts.iteration)
    bar = progress(total=cfg.iterations, initial=int(ts.iteration), desc="train-policy", unit="it")
    # The iteration count is kept on the host: iterations are dispatched back to back and the
    # host waits on the device only where it logs or checkpoints (docs/runs/measurements/benchmarks/train_profile.json).
    it = int(ts.iteration)
    while it < cfg.iterations:
        ts, env_state, stats = trainer.iteration(ts, env_state)
        it += 1
        if not timing["first_iteration_s"]:
            jax.block_until_ready(stats)
            timing["first_iteration_s"] = time.time() - t_start
        bar.update(1)
        if it % cfg.log_every == 0 or it == cfg.iterations or it == 1:
            stats = {k: float(v) for k, v in stats.items()}
            if not bar.disable:
                bar.set_postfix(reward=f"{stats['reward']:+.3f}", rate_err=f"{stats['rate_err']:.3f}",
                                thrust_err=f"{stats['thrust_err']:.2f}", z_err=f"{stats['latent_err_rel']:.3f}",
                                refresh=False)
            now = time.time()
            sps = (it - it_log) * steps_per_it / max(now - t_log, 1e-9)
            t_log, it_log = now, it
            rec = dict(iteration=it, env_steps=it * steps_per_it, steps_per_s=sps,
                       wall_s=wall_prev + now - t_start, **stats)
            logf.write(jsonout.dumps(rec) + "\n")
            logf.flush()
            log(f"it {it:5d}/{cfg.iterations} | {sps / 1e6:6.2f} M steps/s | reward {stats['reward']:+.3f} "
                f"| rate err {stats['rate_err']:.3f} rad/s | thrust err {stats['thrust_err']:.2f} | "
                f"fail {stats['fail_rate'] * 1e3:.2f}‰ | bc {stats['bc']:.4f} | "
                f"‖z−ẑ‖/spread {stats['latent_err_rel']:.3f} | min std z {stats['latent_min_std']:.2f} "
                f"| p {stats['p_zhat']:.2f}")
        if (it % cfg.checkpoint_every == 0 or it == cfg.iterations) and jax.process_index() == 0:
            t_ck = time.time()
            save_tree(ckpt, (ts, env_state), {"config": cfg.to_dict(), "iteration": it, "with_env": True,
                                              "wall_s": wall_prev + time.time() - t_start})
            timing["checkpoint_s"] += time.time() - t_ck
    bar.close()
    logf.close()
    wall = wall_prev + time.time() - t_start
    timing["loop_s"] = time.time() - t_start
    for name, sec in getattr(trainer, "compile_seconds", {}).items():   # compiled in the background
        timing[f"{name}_compile_s"] = sec
    if jax.process_index() == 0:
        save_policy_params(ts.params, out / "policy.npz", {
            "config": cfg.to_dict(), "normalizer": trainer.env.normalizer.to_dict(),
            "iterations": int(ts.iteration), "env_steps": int(ts.iteration) * steps_per_it,
            "wall_s": wall, "final_stats": {k: float(v) for k, v in stats.items()},
            "device": str(jax.devices()[0]), "device_kind": getattr(jax.devices()[0], "device_kind", ""),
            "devices": mesh.size, "jax": jax.__version__, "timing": timing})
    log("time: " + ", ".join(f"{k[:-2].replace('_', ' ')} {v:.1f} s" for k, v in timing.items()))
    return {"stats": {k: float(v) for k, v in stats.items()}, "wall_s": wall, "timing": timing}
