"""`mjxsysid experiment payload` (paper §VI, the payload figure): a 100 g point mass attached
off-centre at [0.1, 0, 0] m (body frame) while the paper vehicle hovers; the latent is decoded at
10 Hz through the event, and the policy's motor commands are replayed by K_θ̂.

The event is the harness's payload (:class:`~mjxsysid.rollout.harness.Disturbance`): from
``event`` s on the simulator flies θ with mass + m_p, inertia + the point mass's parallel-axis
terms, and the body torque of the offset weight r × (Rᵀ m_p g) recomputed every step (the centre
of mass is not moved: exact in steady hover, see the Disturbance docstring).

Reported, for the decoded median of each quantity (mass, thrust-to-weight, J, angular authority,
τ_ext,y): the level before the event and at the end, the shift against the true one
("moved": 1 = the right amount), the time to move halfway and to settle; and the action-replay
metrics through the event beside the paper's payload row.

Writes results.json, results.md, decoded.npz, payload_decoded.png, payload_replay.png.
"""
from __future__ import annotations

import dataclasses
import sys
import time
from pathlib import Path

import jax
import numpy as np

from mjxsysid import theta as P
from mjxsysid.cfm.load import load_decoders
from mjxsysid.control.high_level import Cascade
from mjxsysid.control.references import Hover
from mjxsysid.dataset.collect import decode_indices
from mjxsysid.experiments.common import markdown_table, write_results
from mjxsysid.policy.interface import resolve_policy
from mjxsysid.render.replay import plot_replay
from mjxsysid.rollout.flight import broadcast, seen_imu
from mjxsysid.rollout.harness import Disturbance, batch_metrics, fly_batch, payload_theta, payload_torque
from mjxsysid.sim import Quadrotor
from mjxsysid.decoding import decode_latents
from mjxsysid.uses.replay import LABELS, action_metrics, replay_flight

PAPER_REPLAY = {"random": (0.156, 0.205), "regression": (0.064, 0.614), "cfm": (0.031, 0.812)}
"""The paper's payload row of the action-prediction table: (RMSE, PCC)."""


@dataclasses.dataclass(frozen=True)
class PayloadConfig:
    """duration: s of hover; event: s, when the payload attaches; payload_mass kg at payload_pos
    (m, body frame); rate: Hz of decoding; samples: CFM samples per decode; replay_samples:
    samples for the CFM mean action; cutoff_hz: PCC low-pass; window: s averaged before the
    event and at the end; settle_band: fraction of the decoded shift that counts as settled;
    post_window: s after the event over which the replay is also scored."""
    duration: float = 8.0
    event: float = 4.0
    payload_mass: float = 0.1
    payload_pos: tuple = (0.1, 0.0, 0.0)
    rate: float = 10.0
    samples: int = 100
    replay_samples: int = 16
    cutoff_hz: float = 5.0
    window: float = 1.0
    settle_band: float = 0.2
    post_window: float = 2.0

    def __post_init__(self):
        if not 0.2 + self.window <= self.event <= self.duration - self.window:
            raise ValueError(f"PayloadConfig.event must leave window={self.window} s before it (after the 0.2 s "
                             f"history) and after it (duration {self.duration} s); got {self.event}")
        if self.samples < 2 or self.replay_samples < 1:
            raise ValueError("PayloadConfig.samples must be >= 2 and replay_samples >= 1")
        if not self.payload_mass > 0:
            raise ValueError(f"PayloadConfig.payload_mass must be > 0 kg, got {self.payload_mass}")


FULL = PayloadConfig()
QUICK = PayloadConfig(duration=3.0, event=1.5, samples=16, replay_samples=4, window=0.5, post_window=1.0)


def quantities(theta) -> dict:
    """The decoded quantities followed through the event. θ (..., 19) -> {name: (...)}."""
    theta = np.asarray(theta, np.float64)
    auth = np.asarray(P.angular_authority(theta))
    return {"mass_kg": theta[..., P.MASS], "thrust_to_weight": np.asarray(P.thrust_to_weight(theta)),
            "J_xx": theta[..., 4], "J_yy": theta[..., 5], "J_zz": theta[..., 6],
            "authority_x": auth[..., 0], "authority_y": auth[..., 1], "authority_z": auth[..., 2],
            "tau_ext_y_Nm": theta[..., 17]}


def true_after(theta, cfg: PayloadConfig) -> np.ndarray:
    """θ with the payload, in level hover: mass, inertia and τ_ext,y = the offset weight's torque."""
    th = np.asarray(payload_theta(theta, cfg.payload_mass, np.asarray(cfg.payload_pos))).copy()
    th[P.TAU_EXT] += np.asarray(payload_torque(np.array([1.0, 0, 0, 0]), np.float32(cfg.payload_mass),
                                               np.asarray(cfg.payload_pos, np.float32)))
    return th


def response(times, series, event: float, window: float, expected: float, band: float = 0.2) -> dict:
    """How a decoded series (K,) at ``times`` (K,) s responds to an event at ``event`` s.

    before / after: means over ``window`` s before the event and at the end; shift = after −
    before; moved = shift / ``expected`` (the true shift; 1 = right amount); t_half: s after the
    event until the series first covers half its own shift; t_settle: s after the event after
    which it stays within ``band`` × |shift| of ``after``; noise: std before the event;
    resolved: |shift| > 3 noise (else t_half and t_settle are None).
    """
    times, series = np.asarray(times, np.float64), np.asarray(series, np.float64)
    pre = (times >= event - window) & (times < event)
    end = times >= times[-1] - window + 1e-9
    before, after = float(series[pre].mean()), float(series[end].mean())
    shift, noise = after - before, float(series[pre].std())
    resolved = abs(shift) > 3 * noise and shift != 0
    post = times >= event
    t_half = t_settle = None
    if resolved:
        moved_half = post & ((series - before) * np.sign(shift) >= 0.5 * abs(shift))
        if moved_half.any():
            t_half = float(times[np.argmax(moved_half)] - event)
        outside = post & (np.abs(series - after) > band * abs(shift))
        last_out = np.flatnonzero(outside)
        t_settle = float(times[last_out[-1] + 1] - event) if last_out.size and last_out[-1] + 1 < len(times) \
            else (0.0 if not last_out.size else None)
    return {"before": before, "after": after, "shift": shift, "expected_shift": float(expected),
            "moved": shift / expected if expected else None,
            "relative_shift": shift / before if before else None,
            "expected_relative_shift": float(expected) / before if before else None,
            "noise": noise, "resolved": bool(resolved), "t_half_s": t_half, "t_settle_s": t_settle}


def run(out, *, quick: bool = False, policy=None, seed: int = 0, progress: bool = True, decoders=None,
        cfg: PayloadConfig | None = None) -> dict:
    """Run the payload experiment into ``out``; returns the results dict."""
    t0 = time.time()
    log = (lambda m: print(m, file=sys.stderr, flush=True)) if progress else (lambda m: None)
    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    cfg = cfg or (QUICK if quick else FULL)
    ref = resolve_policy(policy or "mjxsysid")
    cfm, reg = load_decoders(decoders, ref, warn=log)
    dec_dir = Path(decoders) if decoders is not None else ref.decoders_dir
    theta = P.PAPER_HARDWARE.astype(np.float32)
    theta_p = true_after(theta, cfg)
    sim = Quadrotor()
    steps = int(round(cfg.duration / sim.config.dt))
    log(f"hover {cfg.duration:g} s, {cfg.payload_mass * 1e3:g} g at {list(cfg.payload_pos)} m from {cfg.event:g} s")
    dist = Disturbance.make(payload_mass=cfg.payload_mass, payload_pos=cfg.payload_pos, payload_time=cfg.event)
    fl = fly_batch(sim, theta[None], ref.batched(1), broadcast(Cascade.make("baseline"), 1),
                   broadcast(Hover.make(), 1), broadcast(dist, 1), jax.random.PRNGKey(seed), steps)
    m = {k: np.asarray(v)[0] for k, v in batch_metrics(fl).items()}
    f = jax.tree.map(lambda a: np.asarray(a[0]), fl)
    if f.latent is None:
        raise ValueError(f"policy {ref.label} exposes no latent")
    t = f.time
    err = np.linalg.norm(f.frame.pos - f.ref_pos, axis=-1)
    thrust = np.sum(theta[P.ETA] * theta[P.KT] * f.frame.rotor_speed.astype(np.float64) ** 2, -1)

    log(f"decoding at {cfg.rate:g} Hz, {cfg.samples} samples")
    dec = decode_latents(f.latent, t, rate=cfg.rate, samples=cfg.samples, seed=seed, decoder=cfm, regression=reg)
    dec["samples"] = P.project_valid(dec["samples"])[0]
    q_s, q_r = quantities(dec["samples"]), quantities(dec["regression"])
    q_b, q_a = quantities(theta), quantities(theta_p)
    resp = {}
    for k in q_s:
        med = np.median(q_s[k], 1)
        resp[k] = response(dec["times"], med, cfg.event, cfg.window, float(q_a[k] - q_b[k]), cfg.settle_band)
        resp[k].update(true_before=float(q_b[k]), true_after=float(q_a[k]),
                       q05_end=float(np.percentile(q_s[k][dec["times"] >= dec["times"][-1] - cfg.window + 1e-9], 5)),
                       q95_end=float(np.percentile(q_s[k][dec["times"] >= dec["times"][-1] - cfg.window + 1e-9], 95)),
                       regression=response(dec["times"], q_r[k], cfg.event, cfg.window, float(q_a[k] - q_b[k]),
                                           cfg.settle_band))

    log("action replay through the event")
    rec = {"time": t, "imu": seen_imu(f.frame.imu), "a_cmd": f.a_cmd, "omega_cmd": f.omega_cmd,
           "motor_cmd": f.frame.motor_cmd, "latent": f.latent, "pos": f.frame.pos, "ref_pos": f.ref_pos}
    upd = t[decode_indices(t, cfg.rate)]
    truth_k = np.where((upd > cfg.event)[:, None], theta_p[None], theta[None])
    rp = replay_flight(rec, theta, cfm, reg, jax.random.fold_in(jax.random.PRNGKey(seed), 1), rate=cfg.rate,
                       samples=cfg.replay_samples, cutoff_hz=cfg.cutoff_hz, truth_k=truth_k)
    win = (rp["times"] >= cfg.event) & (rp["times"] < cfg.event + cfg.post_window)
    fs = 1.0 / float(t[1] - t[0])
    post = {k: action_metrics(rp[k][win], rp["policy"][win], fs=fs, cutoff_hz=cfg.cutoff_hz)
            for k in ("random", "regression", "cfm", "cfm_mean", "true")}
    plot_replay(rp, rec, out / "payload_replay.png", labels=LABELS, events=(cfg.event,),
                title=f"{ref.label}: paper vehicle hovering, {cfg.payload_mass * 1e3:g} g at "
                      f"{list(cfg.payload_pos)} m attached at {cfg.event:g} s")
    _plot_decoded(out / "payload_decoded.png", cfg, dec, q_s, q_r, q_b, q_a, t, err, thrust, theta, theta_p)
    np.savez_compressed(out / "decoded.npz", times=dec["times"], zhat=dec["zhat"], samples=dec["samples"],
                        regression=dec["regression"], theta_before=theta, theta_after=theta_p)

    pre = (t >= cfg.event - cfg.window) & (t < cfg.event)
    end = t >= t[-1] - cfg.window + 1e-9
    flight = {"pos_rmse_m": float(m["pos_rmse_m"]), "failed": bool(m["failed"]),
              "max_err_after_event_m": float(err[t >= cfg.event].max()),
              "err_before_event_m": float(err[pre].mean()), "err_end_m": float(err[end].mean()),
              "thrust_before_N": float(thrust[pre].mean()), "thrust_end_N": float(thrust[end].mean()),
              "thrust_expected_rise_N": cfg.payload_mass * P.GRAVITY}
    replay = {"whole_flight": rp["metrics"], "after_event": post,
              "paper": {k: {"rmse": v[0], "pcc": v[1]} for k, v in PAPER_REPLAY.items()}}
    headline = {"decoded_mass_moved": resp["mass_kg"]["moved"], "decoded_mass_t_half_s": resp["mass_kg"]["t_half_s"],
                "decoded_thrust_to_weight_moved": resp["thrust_to_weight"]["moved"],
                "decoded_tau_ext_y_moved": resp["tau_ext_y_Nm"]["moved"],
                "replay_cfm_rmse": rp["metrics"]["cfm"]["rmse"], "replay_cfm_pcc": rp["metrics"]["cfm"]["pcc"],
                "replay_regression_rmse": rp["metrics"]["regression"]["rmse"],
                "thrust_rise_N": flight["thrust_end_N"] - flight["thrust_before_N"]}
    numbers = {"headline": headline, "decoded": resp, "replay": replay, "flight": flight}
    config = {"quick": quick, "vehicle": "paper_hardware", "reference": "hover", "gains": "baseline",
              **dataclasses.asdict(cfg)}
    return write_results(out, "payload", config=config, seeds={"seed": seed}, numbers=numbers,
                         table_md=table_md(cfg, numbers), t0=t0, policy=ref, decoders=dec_dir, notes=NOTES)


NOTES = """
The decoded median of each quantity is averaged over `window` s before the event ("before") and at the
end ("after"); "moved" = (after − before) / (true after − true before), 1 = the right amount, 0 = did not
move; t½ / t_settle: s after the event until the median first covers half its own shift / stays within
20 % of it (– where the shift is within 3× the pre-event noise). The payload is simulated as mass +
parallel-axis inertia + the offset weight's body torque, with the centre of mass left at the body origin
(exact in steady hover). Action replay: K_θ̂ fed the recorded gyro and commands, one CFM sample per
10 Hz update (paper protocol) and the mean action over samples; "true θ" switches to the payload θ at the event.
"""


def _f(x, d=3):
    return "–" if x is None or (isinstance(x, float) and not np.isfinite(x)) else f"{x:.{d}g}"


def table_md(cfg: PayloadConfig, numbers: dict) -> str:
    rows = []
    for k, r in numbers["decoded"].items():
        rows.append([k, _f(r["true_before"]), _f(r["true_after"]), _f(r["before"]), _f(r["after"]),
                     f"[{_f(r['q05_end'])}, {_f(r['q95_end'])}]", _f(r["moved"], 2),
                     _f(r["t_half_s"], 2), _f(r["t_settle_s"], 2), _f(r["regression"]["moved"], 2)])
    t1 = markdown_table(["quantity", "true before", "true after", "decoded before (median)", "decoded after",
                         "decoded 5–95 % at the end", "moved (CFM)", "t½ (s)", "t_settle (s)",
                         "moved (Regression)"], rows)
    rp = numbers["replay"]
    names = {"random": "Random", "regression": "Regression", "cfm": "CFM (1 sample)", "cfm_mean": "CFM (mean action)",
             "true": "true θ (reference)"}
    rows = []
    for k, lab in names.items():
        p = PAPER_REPLAY.get(k)
        w, a = rp["whole_flight"][k], rp["after_event"][k]
        rows.append([lab, f"{p[0]:.3f} / {p[1]:.3f}" if p else "–", f"{w['rmse']:.3f} / {_f(w['pcc'], 3)}",
                     f"{a['rmse']:.3f} / {_f(a['pcc'], 3)}"])
    t2 = markdown_table(["method", "paper RMSE / PCC", f"ours, whole flight ({cfg.duration:g} s)",
                         f"ours, {cfg.post_window:g} s after the event"], rows)
    fl = numbers["flight"]
    return (f"## Decoded quantities through the event ({cfg.payload_mass * 1e3:g} g at {list(cfg.payload_pos)} m, "
            f"{cfg.event:g} s; decoded at {cfg.rate:g} Hz, {cfg.samples} samples)\n\n{t1}\n"
            f"## Action replay through the event (paper Table: payload row)\n\n{t2}\n"
            f"Flight: hover error before {fl['err_before_event_m'] * 100:.1f} cm, peak after the event "
            f"{fl['max_err_after_event_m'] * 100:.1f} cm, at the end {fl['err_end_m'] * 100:.1f} cm; total rotor "
            f"thrust {fl['thrust_before_N']:.3f} → {fl['thrust_end_N']:.3f} N (expected rise "
            f"{fl['thrust_expected_rise_N']:.3f} N).\n")


def _plot_decoded(path, cfg, dec, q_s, q_r, q_b, q_a, t, err, thrust, theta, theta_p):
    from matplotlib.figure import Figure
    keys = list(q_s)
    fig = Figure(figsize=(16, 8.5), layout="constrained")
    axs = fig.subplots(3, 4).ravel()
    td = dec["times"]
    a = axs[0]
    a.plot(td, dec["zhat"], lw=0.9)
    a.set_title("latent ẑ (at the decodes)")
    b = axs[1]
    b.plot(t, err * 100, color="k", lw=0.8, label="position error (cm)")
    b2 = b.twinx()
    b2.plot(t, thrust, color="C3", lw=0.8)
    b2.axhline((theta[P.MASS] + cfg.payload_mass) * P.GRAVITY, color="C3", ls=":", lw=0.8)
    b2.set_ylabel("total thrust (N)", color="C3")
    b.set_title("flight: position error (cm), thrust (N)")
    for i, k in enumerate(keys):
        ax = axs[2 + i]
        lo, med, hi = np.percentile(q_s[k], [5, 50, 95], 1)
        ax.fill_between(td, lo, hi, alpha=0.3, color="C0", lw=0, label="CFM 5–95 %")
        ax.plot(td, med, color="C0", label="CFM median")
        ax.plot(td, q_r[k], color="C1", ls="--", lw=1, label="regression")
        ax.step([td[0], cfg.event, td[-1]], [q_b[k], q_a[k], q_a[k]], where="post", color="k", lw=1.4,
                label="true (before / after)")
        ax.set_title(k)
        if k not in ("tau_ext_y_Nm",) and np.all(lo > 0):
            ax.set_yscale("log")
    for ax in axs[:2 + len(keys)]:
        ax.axvline(cfg.event, color="m", ls="--", lw=1.0)
        ax.set_xlabel("time (s)")
        ax.grid(alpha=0.3)
    for ax in axs[2 + len(keys):]:
        ax.set_visible(False)
    axs[2].legend(fontsize=7)
    fig.suptitle(f"payload {cfg.payload_mass * 1e3:g} g at {list(cfg.payload_pos)} m (body) attached at "
                 f"{cfg.event:g} s; decoded at {cfg.rate:g} Hz")
    fig.savefig(path, dpi=100)
    return path
