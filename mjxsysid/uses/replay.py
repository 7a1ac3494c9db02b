"""Action replay (paper §IV-C): do decoded models explain the policy's motor commands?

A frozen latent policy flies a vehicle; its flight is recorded (gyro, high-level command,
latent ẑ, motor command, every 2 ms). The recording is then replayed open loop: at 10 Hz a
decoder turns ẑ into a parameter vector θ̂, which instantiates the parametric controller K_θ̂
(:class:`~mjxsysid.control.low_level.KTheta`, the paper's appendix). K_θ̂ sees exactly the
recorded gyro and command at every step (θ̂ held between updates) and its normalised motor
speeds Ω/Ω̂_max are compared with the policy's. The only thing that differs between methods is
how θ̂ comes from the latent:

* ``random``: the flown vehicle's true θ with every entry perturbed by U(−50 %, +50 %), a
  fresh draw at every update (the paper's Random);
* ``regression``: the Regression decoder's point estimate of ẑ;
* ``cfm``: one CFM sample from p(θ | ẑ) at every update (the paper's protocol);
* ``cfm_mean``: the mean of K_θ̂'s commands over ``samples`` CFM samples per update (the
  posterior-mean action; an addition to the paper's table);
* ``true``: K_θ with the vehicle's true θ: not a decoder but the reference point, how close
  the parametric controller of a perfectly identified vehicle comes to the policy.

Metrics over the replayed span (from the first update at 0.2 s, once the history is full):
RMSE of the raw normalised motor commands (all four motors), and the Pearson correlation of
the two histories after a zero-phase 2nd-order Butterworth low-pass (``cutoff_hz``, default
5 Hz), per motor, averaged over the four motors.

Flights (:data:`FLIGHTS`): 3-D lemniscates of 5, 10 and 15 s periods (one period each) and a
5 s hover, under the baseline Cascade.
"""
from __future__ import annotations

import time
from pathlib import Path

import jax
import jax.numpy as jnp
import numpy as np

from mjxsysid.runtime import jsonout
from mjxsysid import theta as P
from mjxsysid.cfm.load import load_decoders
from mjxsysid.cfm.sample import random_baseline
from mjxsysid.control.low_level import Command, KTheta
from mjxsysid.dataset.collect import decode_indices
from mjxsysid.policy.interface import resolve_policy
from mjxsysid.runtime.progress import progress
from mjxsysid.render.replay import plot_replay, plot_summary
from mjxsysid.rollout.flight import fly_vehicles, seen_imu

FLIGHTS = {"lemniscate_5s": ("lemniscate", 5.0), "lemniscate_10s": ("lemniscate", 10.0),
           "lemniscate_15s": ("lemniscate", 15.0), "hover": ("hover", 5.0)}
METHODS = ("random", "regression", "cfm", "cfm_mean", "true")
LABELS = {"random": "Random", "regression": "Regression", "cfm": "CFM (1 sample)",
          "cfm_mean": "CFM (mean action)", "true": "true θ (reference)", "policy": "policy"}


@jax.jit
def replay_commands(theta_k, seg, omega, a_cmd, omega_cmd):
    """K_θ̂ motor commands along a recording.

    theta_k (..., K, 19): θ̂ at each of K updates; seg (T,) int: which update is in force at
    each step; omega (T, 3) measured body rate; a_cmd (T,), omega_cmd (T, 3) the recorded
    command. Returns (..., T, 4) normalised motor speeds."""
    def one(th_k):
        th = th_k[seg]
        return jax.vmap(lambda t, a, w, o: KTheta.make(t).motor_command(Command(a, w), o))(
            th, a_cmd, omega_cmd, omega)

    flat = theta_k.reshape((-1,) + theta_k.shape[-2:])
    out = jax.lax.map(one, flat)
    return out.reshape(theta_k.shape[:-2] + out.shape[-2:])


def lowpass(x, cutoff_hz: float, fs: float):
    """Zero-phase 2nd-order Butterworth low-pass along axis 0 (scipy ``filtfilt``)."""
    from scipy.signal import butter, filtfilt
    if not 0 < cutoff_hz < fs / 2:
        raise ValueError(f"cutoff_hz must be in (0, {fs / 2}) Hz, got {cutoff_hz}")
    b, a = butter(2, cutoff_hz / (fs / 2))
    return filtfilt(b, a, np.asarray(x, np.float64), axis=0)


def pearson(a, b) -> float:
    """Pearson correlation of two 1-D series (nan if either is constant)."""
    a = a - a.mean()
    b = b - b.mean()
    den = np.sqrt((a * a).sum() * (b * b).sum())
    return float((a * b).sum() / den) if den > 1e-12 else float("nan")


def action_metrics(pred, ref, *, fs: float, cutoff_hz: float = 5.0) -> dict:
    """pred, ref (T, 4) normalised motor commands -> {rmse, pcc} (pcc: mean over motors of the
    correlation after :func:`lowpass`)."""
    pred = np.asarray(pred, np.float64)
    ref = np.asarray(ref, np.float64)
    rmse = float(np.sqrt(np.mean((pred - ref) ** 2)))
    fp, fr = lowpass(pred, cutoff_hz, fs), lowpass(ref, cutoff_hz, fs)
    pcc = float(np.nanmean([pearson(fp[:, i], fr[:, i]) for i in range(pred.shape[1])]))
    return {"rmse": rmse, "pcc": pcc}


def decode_for_replay(zhat_k, truth, cfm, reg, key, *, samples: int = 16) -> dict:
    """θ̂ per update for every method. zhat_k (K, 8), truth (19,) -> {method: (K, 19)} plus
    'cfm_samples' (S, K, 19)."""
    k_rand, k_cfm = jax.random.split(key)
    s = np.asarray(cfm.sample_theta(zhat_k, k_cfm, max(samples, 1)))  # (K, S, 19)
    return {"random": np.asarray(random_baseline(k_rand, len(zhat_k), nominal=truth)),
            "true": np.broadcast_to(np.asarray(truth, np.float32), (len(zhat_k), P.N_PARAMS)),
            "regression": np.asarray(reg.point(zhat_k)),
            "cfm": s[:, 0], "cfm_samples": np.swapaxes(s, 0, 1)}


def replay_flight(rec: dict, truth, cfm, reg, key, *, rate: float = 10.0, samples: int = 16,
                  cutoff_hz: float = 5.0, truth_k=None) -> dict:
    """Replay one recording. rec: time (T,), imu (T, 6), a_cmd (T,), omega_cmd (T, 3),
    motor_cmd (T, 4), latent (T, 8). Returns {'metrics': {method: {rmse, pcc}}, 'times' (T',),
    'policy' (T', 4), method: (T', 4) commands, 'update_times' (K,), 'theta_hat': {method: (K, 19)}}.
    ``truth_k`` (K, 19): the true θ in force at each update, for the 'true' method when the
    vehicle changes during the flight (default: ``truth`` throughout)."""
    t = np.asarray(rec["time"])
    idx = decode_indices(t, rate)
    first = idx[0]
    seg = np.searchsorted(idx, np.arange(first, len(t)), side="right") - 1
    th = decode_for_replay(np.asarray(rec["latent"])[idx], truth, cfm, reg, key, samples=samples)
    if truth_k is not None:
        truth_k = np.asarray(truth_k, np.float32)
        if truth_k.shape != (len(idx), P.N_PARAMS):
            raise ValueError(f"truth_k must have shape ({len(idx)}, {P.N_PARAMS}) (one θ per update); "
                             f"got {truth_k.shape}")
        th["true"] = truth_k
    span = slice(first, None)
    args = (jnp.asarray(seg), jnp.asarray(rec["imu"][span, 0:3]), jnp.asarray(rec["a_cmd"][span]),
            jnp.asarray(rec["omega_cmd"][span]))
    out = {m: np.asarray(replay_commands(jnp.asarray(th[m], jnp.float32), *args))
           for m in ("random", "regression", "cfm", "true")}
    out["cfm_mean"] = np.asarray(replay_commands(jnp.asarray(th["cfm_samples"], jnp.float32),
                                                 *args)).mean(0)
    policy = np.asarray(rec["motor_cmd"][span])
    fs = 1.0 / float(t[1] - t[0])
    mets = {m: action_metrics(out[m], policy, fs=fs, cutoff_hz=cutoff_hz) for m in METHODS}
    return {"metrics": mets, "times": t[span], "policy": policy, **out, "update_times": t[idx],
            "theta_hat": {m: th[m] for m in ("random", "regression", "cfm")},
            "latent": np.asarray(rec["latent"])[span]}


def record_flights(policy, theta, flight: str, *, seed: int = 0, sim=None):
    """Fly θ (B, 19) with the policy on one of :data:`FLIGHTS`. Returns (list of B recordings,
    metrics dict of (B,) arrays). A recording's ``imu`` row t is the reading the policy acted on
    at step t (see :func:`~mjxsysid.rollout.flight.seen_imu`)."""
    if flight not in FLIGHTS:
        raise ValueError(f"unknown flight {flight!r}; choose from {list(FLIGHTS)}")
    ref, period = FLIGHTS[flight]
    fl, m, _ = fly_vehicles(theta, controller="policy", policy=policy, reference=ref,
                            period=period, duration=period, seed=seed, sim=sim)
    fl = jax.tree.map(np.asarray, fl)
    imu = seen_imu(fl.frame.imu)
    recs = [{"time": fl.time[i], "imu": imu[i], "a_cmd": fl.a_cmd[i],
             "omega_cmd": fl.omega_cmd[i], "motor_cmd": fl.frame.motor_cmd[i],
             "latent": fl.latent[i], "pos": fl.frame.pos[i], "ref_pos": fl.ref_pos[i]}
            for i in range(len(theta))]
    return recs, {k: np.asarray(v) for k, v in m.items()}


def run_replay(out, *, policy="mjxsysid", weights=None, decoders=None, vehicles: int = 0,
               flights=tuple(FLIGHTS), rate: float = 10.0, samples: int = 16,
               cutoff_hz: float = 5.0, seed: int = 0, log=print) -> dict:
    """Action replay on the paper vehicle plus ``vehicles`` vehicles of the policy's own prior,
    on each of ``flights``. Writes out/replay.json (per-flight tables), out/replay.md,
    out/replay_<flight>.png (the paper vehicle's commands) and out/replay_summary.png."""
    if vehicles < 0:
        raise ValueError(f"--vehicles must be >= 0, got {vehicles}")
    if samples < 1:
        raise ValueError(f"--samples must be >= 1, got {samples}")
    bad = [f for f in flights if f not in FLIGHTS]
    if bad or not flights:
        raise ValueError(f"--flights: unknown {bad or 'none given'}; choose from {','.join(FLIGHTS)}")
    ref = resolve_policy(policy, weights)
    cfm, reg = load_decoders(decoders, ref, warn=log)
    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    theta = P.PAPER_HARDWARE[None].astype(np.float32)
    if vehicles:
        extra = np.asarray(P.get_prior(ref.prior).sample(jax.random.PRNGKey(seed + 7), vehicles))
        theta = np.concatenate([theta, extra])
    t0 = time.time()
    res = {"policy": ref.to_dict(), "decoders": str(decoders or ref.decoders_dir), "rate_hz": rate,
           "samples": samples, "cutoff_hz": cutoff_hz, "seed": seed, "vehicles": len(theta),
           "flights": {}}
    bar = progress(total=len(flights) * len(theta), desc="replay", unit="flight")
    for fi, name in enumerate(flights):
        bar.set_postfix_str(name)
        recs, fm = record_flights(ref, theta, name, seed=seed)
        per = {m: {"rmse": [], "pcc": []} for m in METHODS}
        paper = None
        for i, rec in enumerate(recs):
            bar.update(1)
            if fm["failed"][i]:
                continue
            r = replay_flight(rec, theta[i], cfm, reg, jax.random.fold_in(jax.random.PRNGKey(seed), 1000 * fi + i),
                              rate=rate, samples=samples, cutoff_hz=cutoff_hz)
            for m in METHODS:
                for k in ("rmse", "pcc"):
                    per[m][k].append(r["metrics"][m][k])
            if i == 0:
                paper = r
                plot_replay(r, rec, out / f"replay_{name}.png", labels=LABELS,
                            title=f"{ref.label}: paper vehicle, {name.replace('_', ' ')}, "
                                  f"pos RMSE {fm['pos_rmse_m'][0]:.3f} m")
        entry = {"pos_rmse_m_paper": float(fm["pos_rmse_m"][0]), "failed_paper": bool(fm["failed"][0]),
                 "paper_vehicle": paper["metrics"] if paper else None}
        if vehicles:
            ok = ~fm["failed"][1:]
            arr = {m: {k: np.asarray(per[m][k][1:] if paper else per[m][k]) for k in ("rmse", "pcc")}
                   for m in METHODS}
            entry["prior_vehicles"] = {
                "n_flown": int(ok.sum()), "n": vehicles,
                **{m: {k: {"mean": float(np.nanmean(v)), "std": float(np.nanstd(v))}
                       for k, v in arr[m].items()} for m in METHODS},
                "cfm_best_fraction": {
                    "rmse": float(np.mean(arr["cfm"]["rmse"] < np.minimum(arr["random"]["rmse"],
                                                                         arr["regression"]["rmse"]))),
                    "pcc": float(np.mean(arr["cfm"]["pcc"] > np.maximum(arr["random"]["pcc"],
                                                                       arr["regression"]["pcc"])))}}
        res["flights"][name] = entry
        log(f"  {name}: " + ", ".join(
            f"{LABELS[m]} RMSE {paper['metrics'][m]['rmse']:.3f} PCC {paper['metrics'][m]['pcc']:.2f}"
            for m in METHODS) if paper else f"  {name}: the paper vehicle crashed")
    bar.close()
    res["wall_s"] = time.time() - t0
    (out / "replay.json").write_text(jsonout.dumps(res, indent=2) + "\n")
    (out / "replay.md").write_text(replay_table(res))
    plot_summary(res, out / "replay_summary.png", labels=LABELS, methods=METHODS)
    return res


def replay_table(res: dict) -> str:
    """Markdown table of a :func:`run_replay` result (paper vehicle; prior mean if present)."""
    lines = [f"Action replay, {res['policy']['policy']} policy, decoders {res['decoders']}, "
             f"{res['rate_hz']:g} Hz updates, PCC after a {res['cutoff_hz']:g} Hz low-pass.", "",
             "| flight | method | paper vehicle RMSE ↓ | PCC ↑ | prior vehicles RMSE (mean ± std) | PCC |",
             "|---|---|---|---|---|---|"]
    for name, e in res["flights"].items():
        pv, pr = e.get("paper_vehicle"), e.get("prior_vehicles")
        for m in METHODS:
            a = f"{pv[m]['rmse']:.3f} | {pv[m]['pcc']:.2f}" if pv else "crashed | –"
            b = (f"{pr[m]['rmse']['mean']:.3f} ± {pr[m]['rmse']['std']:.3f} | "
                 f"{pr[m]['pcc']['mean']:.2f} ± {pr[m]['pcc']['std']:.2f}") if pr else "– | –"
            lines.append(f"| {name} | {LABELS[m]} | {a} | {b} |")
    return "\n".join(lines) + "\n"


