"""`mjxsysid decode`: fly (or replay) a vehicle with the frozen policy, read its latent ẑ at a
given rate and decode each into a distribution of physical models.

Flight-log CSV format (``--log``), one row per control step at 500 Hz, header required::

    t, gyro_x, gyro_y, gyro_z, acc_x, acc_y, acc_z, a_cmd, omega_cmd_x, omega_cmd_y, omega_cmd_z,
    motor_1, motor_2, motor_3, motor_4

SI units, body frame x forward / y left / z up: gyro (rad/s), specific force acc (m/s², ≈ +9.81
on z at hover), commanded mass-normalised collective thrust a_cmd (m/s²) and body rates (rad/s),
motor commands Ω_cmd/Ω_max ∈ [0, 1] in mjxsysid's rotor order (1 front-right, 2 front-left,
3 back-left, 4 back-right). The policy's history is rebuilt from the logged IMU, commands and
motor commands (the logged motor commands stand in for the policy's actions).
"""
from __future__ import annotations

import json
from pathlib import Path

import jax
import numpy as np

from mjxsysid import params as P
from mjxsysid.cfm.sample import Decoder
from mjxsysid.policy import networks as N
from mjxsysid.policy.interface import PRETRAINED_DIR, resolve_policy

LOG_COLUMNS = ("t", "gyro_x", "gyro_y", "gyro_z", "acc_x", "acc_y", "acc_z", "a_cmd", "omega_cmd_x",
               "omega_cmd_y", "omega_cmd_z", "motor_1", "motor_2", "motor_3", "motor_4")


LOG_DT = 0.002  # s: the policies run at 500 Hz; a log's rows must be 500 Hz steps


def read_log(path) -> dict:
    """Read a flight-log CSV -> dict of arrays (imu (T, 6), a_cmd (T,), omega_cmd (T, 3),
    motor (T, 4), t (T,)).

    The whole file is checked before anything is returned; ``ValueError`` names the file and
    the line/column of the first problem: not UTF-8 text, empty, a delimiter other than ``,``,
    missing or repeated columns (other extra columns are ignored), a row with the wrong number
    of values, a non-numeric or non-finite cell, fewer than 100 rows (0.2 s), time not strictly
    increasing or not sampled at 500 Hz (median step within 5 % of 2 ms), motor commands
    outside [0, 1]. Line numbers count the header as line 1; blank lines are skipped."""
    path = Path(path)
    if not path.is_file():
        raise FileNotFoundError(f"flight log not found: {path}")
    try:
        text = path.read_bytes().decode("utf-8-sig")
    except UnicodeDecodeError:
        raise ValueError(f"{path}: not a text (UTF-8) CSV file") from None
    lines = [(i + 1, ln) for i, ln in enumerate(text.splitlines()) if ln.strip()]
    if not lines:
        raise ValueError(f"{path}: empty file; expected a header line {','.join(LOG_COLUMNS)} and rows")
    hline, head = lines[0]
    for other, name in ((";", "semicolons"), ("\t", "tabs"), ("|", "'|'")):
        if other in head and head.count(other) >= head.count(","):
            raise ValueError(f"{path}: line {hline}: columns are separated by {name}; expected commas")
    header = [h.strip() for h in head.split(",")]
    if _is_number(header[0]):
        raise ValueError(f"{path}: line {hline}: no header line; expected {','.join(LOG_COLUMNS)}")
    dup = sorted({h for h in header if header.count(h) > 1})
    if dup:
        raise ValueError(f"{path}: line {hline}: column(s) {dup} appear more than once")
    missing = [c for c in LOG_COLUMNS if c not in header]
    if missing:
        raise ValueError(f"{path}: missing column(s) {missing}; expected {list(LOG_COLUMNS)}")
    rows = lines[1:]
    if len(rows) < N.HISTORY:
        raise ValueError(f"{path}: {len(rows)} rows; need at least {N.HISTORY} (0.2 s at 500 Hz)")
    idx = [header.index(c) for c in LOG_COLUMNS]
    data = np.empty((len(rows), len(LOG_COLUMNS)), np.float64)
    for r, (ln, row) in enumerate(rows):
        cells = row.split(",")
        if len(cells) != len(header):
            hint = " (separated by semicolons?)" if ";" in row else " (separated by tabs?)" if "\t" in row else ""
            raise ValueError(f"{path}: line {ln}: {len(cells)} values, header has {len(header)}{hint}")
        for c, k in enumerate(idx):
            cell = cells[k].strip()
            try:
                v = float(cell)
            except ValueError:
                raise ValueError(f"{path}: line {ln}, column {LOG_COLUMNS[c]}: {cell[:40]!r} is not a number") from None
            if not np.isfinite(v):
                raise ValueError(f"{path}: line {ln}, column {LOG_COLUMNS[c]}: {cell!r} is not finite")
            data[r, c] = v
    col = {c: data[:, i] for i, c in enumerate(LOG_COLUMNS)}
    dt = np.diff(col["t"])
    if np.any(dt <= 0):
        r = int(np.argmax(dt <= 0)) + 1
        raise ValueError(f"{path}: line {rows[r][0]}, column t: time {col['t'][r]:.6g} s does not increase "
                         f"(previous row {col['t'][r - 1]:.6g} s)")
    med = float(np.median(dt))
    if abs(med - LOG_DT) > 0.05 * LOG_DT:
        raise ValueError(f"{path}: column t: rows are {med * 1e3:.4g} ms apart (median); the policy runs at "
                         f"500 Hz: resample the log to 2 ms steps")
    motor = np.stack([col[f"motor_{i}"] for i in range(1, 5)], -1)
    bad = np.argwhere((motor < -1e-6) | (motor > 1 + 1e-6))
    if bad.size:
        r, m = bad[0]
        raise ValueError(f"{path}: line {rows[r][0]}, column motor_{m + 1}: {motor[r, m]:.6g} is outside [0, 1] "
                         f"(motor commands are normalised Ω_cmd/Ω_max)")
    f32 = {k: v.astype(np.float32) for k, v in col.items()}
    if not all(np.all(np.isfinite(v)) for v in f32.values()):
        c = next(k for k, v in f32.items() if not np.all(np.isfinite(v)))
        raise ValueError(f"{path}: column {c}: values too large (beyond float32)")
    return {"t": col["t"], "imu": np.stack([col[c] for c in LOG_COLUMNS[1:7]], -1),
            "a_cmd": col["a_cmd"], "omega_cmd": np.stack([col[c] for c in LOG_COLUMNS[8:11]], -1),
            "motor": motor}


def _is_number(text: str) -> bool:
    try:
        float(text)
        return True
    except ValueError:
        return False


def write_log(path, t, imu, a_cmd, omega_cmd, motor) -> Path:
    """Write a flight log in the documented CSV format."""
    arr = np.column_stack([t, imu, a_cmd, omega_cmd, motor])
    np.savetxt(path, arr, delimiter=",", header=",".join(LOG_COLUMNS), comments="", fmt="%.7g")
    return Path(path)


def load_decoders(decoders=None, policy=None, *, warn=None,
                  allow_mismatch: bool = False) -> tuple[Decoder, Decoder]:
    """(CFM, Regression) decoders from the folder ``decoders`` (default: the folder where the
    policy's decoders ship; see :class:`~mjxsysid.policy.interface.PolicyRef`).

    Decoders trained on another policy's latents than ``policy``'s (their provenance records
    the weights' sha256) are an error: another policy's latent means something else, so the
    decoded models would be meaningless. ``allow_mismatch=True`` turns the error into a
    warning (told to ``warn(msg)``). A file of the wrong kind (``cfm.npz`` holding a
    regression decoder, …) is an error too."""
    ref = resolve_policy(policy) if policy is not None else None
    d = Path(decoders) if decoders is not None else (ref.decoders_dir if ref else PRETRAINED_DIR)
    for f in ("cfm.npz", "regression.npz"):
        if not (d / f).is_file():
            hint = "" if decoders is not None else (
                f" (no shipped decoders for {ref.label}: train them with `mjxsysid collect "
                f"--policy ...` and `mjxsysid train-cfm`, then pass --decoders DIR)" if ref else "")
            raise FileNotFoundError(f"decoder not found: {d / f}{hint}")
    cfm, reg = Decoder.load(d / "cfm.npz"), Decoder.load(d / "regression.npz")
    for dec, f, kind in ((cfm, "cfm.npz", "cfm"), (reg, "regression.npz", "regression")):
        if dec.kind != kind:
            raise ValueError(f"{d / f}: holds a {dec.kind} decoder, expected {kind}")
    if ref is not None:
        for dec, f in ((cfm, "cfm.npz"), (reg, "regression.npz")):
            trained_on = dec.meta.get("data", {}).get("pairs_meta", {}).get("weights_sha256")
            if trained_on and trained_on != ref.sha256():
                msg = (f"{d / f}: trained on the latents of another policy (weights sha256 "
                       f"{trained_on[:12]}…), not {ref.label} ({ref.sha256()[:12]}…)")
                if not allow_mismatch:
                    raise ValueError(msg + "; pass the decoders trained for this policy "
                                     "(mjxsysid collect + train-cfm)")
                if warn is not None:
                    warn("warning: " + msg)
                break
    return cfm, reg


def decode_latents(zhat_t, times, *, rate: float, samples: int, seed: int = 0, decoder=None,
                   regression=None, start: float = N.HISTORY * 0.002):
    """Decode ẑ (T, 8) sampled at ``rate`` Hz after ``start`` s. Returns dict with times (K,),
    zhat (K, 8), samples (K, S, 19) physical, regression (K, 19) physical. Decoders default to
    the shipped ones of mjxsysid's policy."""
    if not rate > 0:
        raise ValueError(f"--rate must be > 0 Hz, got {rate}")
    if samples < 2:
        raise ValueError(f"--samples must be >= 2, got {samples}")
    idx = decode_indices(times, rate, start)
    if decoder is None or regression is None:
        cfm0, reg0 = load_decoders()
        decoder, regression = decoder or cfm0, regression or reg0
    z = np.asarray(zhat_t)[idx]
    s = np.asarray(decoder.sample_theta(z, jax.random.PRNGKey(seed), samples))
    return {"times": np.asarray(times)[idx], "zhat": z, "samples": s,
            "regression": np.asarray(regression.point(z))}


def decode_posterior(zhat_t, times, truth=None, *, decoder, regression, rate: float = 10.0,
                     samples: int = 100, seed: int = 0) -> dict:
    """What ``mjxsysid decode`` writes, in memory: ẑ (T, 8) over ``times`` (T,) decoded at
    ``rate`` Hz -> dict with the arrays of ``decoded.npz`` (times (K,), zhat (K, 8), samples
    (K, S, 19), regression (K, 19), theta_true (19,) or NaN) and ``summary`` (the content of
    ``summary.json``: :func:`summarize_posterior` of the last decoded latent's samples, plus
    ``_invalid_fraction``)."""
    dec = decode_latents(zhat_t, times, rate=rate, samples=samples, seed=seed, decoder=decoder,
                         regression=regression)
    final = dec["samples"][-1]
    summary = summarize_posterior(final, truth)
    summary["_invalid_fraction"] = float(P.project_valid(final)[1].mean())  # e.g. J triangle violated
    truth = np.full(P.N_PARAMS, np.nan, np.float32) if truth is None else np.asarray(truth, np.float32)
    return dict(dec, theta_true=truth, summary=summary)


def log_latents(policy, rec: dict):
    """ẑ (T, 8) and times (T,) (s from the log's start, first step at 2 ms) of a flight log read
    by :func:`read_log`, rebuilt by the frozen ``policy`` (a name, path or PolicyRef)."""
    ref = resolve_policy(policy)
    zhat_t = ref.load().replay(rec["imu"], rec["a_cmd"], rec["omega_cmd"], rec["motor"])
    return np.asarray(zhat_t), rec["t"] - rec["t"][0] + LOG_DT


def decode_indices(times, rate: float, start: float = N.HISTORY * 0.002) -> np.ndarray:
    """Indices (K,) of the steps at which a ``rate`` Hz decoder reads ẑ: every 1/rate s from the
    first step at or after ``start`` s (the last step if the flight is shorter)."""
    times = np.asarray(times)
    dt = float(times[1] - times[0]) if len(times) > 1 else 0.002
    every = max(int(round(1.0 / (rate * dt))), 1)
    after = np.flatnonzero(times >= start - 1e-9)
    if len(after) == 0:
        return np.array([len(times) - 1])
    return after[(after - after[0]) % every == 0]


def summarize_posterior(samples, truth=None) -> dict:
    """samples (S, 19) (+ truth (19,)) -> {name: {mean, q05, q95[, true, inside]}} plus the
    identifiable combinations."""
    q05, q95 = np.percentile(samples, [5, 95], 0)
    out = {}
    for j, n in enumerate(P.PARAM_NAMES):
        d = {"mean": float(samples[:, j].mean()), "q05": float(q05[j]), "q95": float(q95[j])}
        if truth is not None:
            d.update(true=float(truth[j]), inside=bool(q05[j] <= truth[j] <= q95[j]))
        out[n] = d
    ident = np.asarray(P.identifiable(samples))
    iq05, iq95 = np.percentile(ident, [5, 95], 0)
    ti = None if truth is None else np.asarray(P.identifiable(truth))
    for j, n in enumerate(P.IDENTIFIABLE_NAMES):
        d = {"mean": float(ident[:, j].mean()), "q05": float(iq05[j]), "q95": float(iq95[j])}
        if ti is not None:
            d.update(true=float(ti[j]), inside=bool(iq05[j] <= ti[j] <= iq95[j]))
        out[n] = d
    return out


def plot_decoded_over_time(dec: dict, truth, path):
    """ẑ and the identifiable combinations (median, 5–95 % band) over time."""
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    t = dec["times"]
    ident = np.asarray(P.identifiable(dec["samples"]))  # (K, S, 5)
    fig, ax = plt.subplots(2, 3, figsize=(14, 6.5))
    ax = ax.flat
    ax[0].plot(t, dec["zhat"])
    ax[0].set_title("latent ẑ (8 dims)")
    for j, n in enumerate(P.IDENTIFIABLE_NAMES):
        a = ax[j + 1]
        lo, med, hi = np.percentile(ident[:, :, j], [5, 50, 95], 1)
        a.fill_between(t, lo, hi, alpha=0.3, label="CFM 5–95 %")
        a.plot(t, med, label="CFM median")
        a.plot(t, np.asarray(P.identifiable(dec["regression"]))[:, j], "--", label="regression")
        if truth is not None:
            a.axhline(float(np.asarray(P.identifiable(truth))[j]), color="k", label="true")
        a.set_title(n)
        if n != "torque_ratio":
            a.set_yscale("log")
    for a in ax:
        a.set_xlabel("time (s)")
        a.grid(alpha=0.3)
    ax[1].legend(fontsize=8)
    fig.tight_layout()
    fig.savefig(path, dpi=100)
    plt.close(fig)
    return path


def run_decode(out, *, theta=None, log=None, reference="lemniscate", period=10.0, duration=None,
               samples=100, rate=10.0, weights=None, seed=0, video=False, ghosts=4, echo=print,
               policy="mjxsysid", decoders=None) -> dict:
    """Fly θ (or replay ``log``) with a frozen latent policy (``policy``, ``weights``: see
    :func:`~mjxsysid.policy.interface.resolve_policy`; default the shipped one), decode at
    ``rate`` Hz with that policy's decoders (or those in ``decoders``), write out/decoded.npz,
    out/summary.json and plots (and out/decoded.mp4 with ``video``)."""
    from mjxsysid.analysis.flight import fly_vehicles, one_flight
    from mjxsysid.cfm.pipeline import plot_marginals
    # Every input is checked before any work starts.
    if not rate > 0:
        raise ValueError(f"--rate must be > 0 Hz, got {rate}")
    if samples < 2:
        raise ValueError(f"--samples must be >= 2, got {samples}")
    if (log is None) == (theta is None):
        raise ValueError("give either a vehicle (theta) or a flight log, not both or neither")
    rec = read_log(log) if log is not None else None
    if theta is not None:
        theta = P.validate_theta(theta, what="vehicle")
        if theta.shape != (P.N_PARAMS,):
            raise ValueError(f"vehicle: one θ of shape ({P.N_PARAMS},) expected, got {theta.shape}")
    ref = resolve_policy(policy, weights)
    cfm, reg = load_decoders(decoders, ref, warn=echo)
    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    from mjxsysid.progress import stages
    st = stages(["flying" if log is None else "replaying the log", "decoding", "plots"]
                + (["video"] if video and log is None else []), desc="decode")
    st.start("flying" if log is None else "replaying the log")
    flight = None
    if log is not None:
        zhat_t, times = log_latents(ref, rec)
        truth = None
    else:
        flight, _, _ = fly_vehicles(theta, controller="policy", policy=ref, reference=reference,
                                    period=period, duration=duration, seed=seed)
        one = one_flight(flight)
        zhat_t, times, truth = one.latent, one.time, np.asarray(theta, np.float32)
    st.start("decoding")
    dec = decode_posterior(zhat_t, times, truth, decoder=cfm, regression=reg, rate=rate, samples=samples,
                           seed=seed)
    summary = dec.pop("summary")
    final = dec["samples"][-1]
    np.savez_compressed(out / "decoded.npz", **dec)
    (out / "summary.json").write_text(json.dumps(summary, indent=2) + "\n")
    st.start("plots")
    plot_marginals(final, truth if truth is not None else np.full(19, np.nan), out / "marginals.png",
                   point=dec["regression"][-1], title=f"decoded p(θ | ẑ) at t = {dec['times'][-1]:.1f} s")
    plot_decoded_over_time(dec, truth, out / "decoded_over_time.png")
    if video and flight is not None:
        st.start("video")
        from mjxsysid.render.video import render_rollout
        gth, _ = P.project_valid(final[:ghosts])
        gfl, _, _ = fly_vehicles(gth, controller="policy", policy=ref, reference=reference,
                                 period=period, duration=duration, seed=seed)
        g = [(gth[i], np.asarray(gfl.frame.pos[i]), np.asarray(gfl.frame.quat[i])) for i in range(len(gth))]
        render_rollout(truth, one.frame, out / "decoded.mp4", ghosts=g, reference=one.ref_pos, fps=25,
                       width=480, height=360)
    st.close()
    if truth is not None:
        n_in = sum(v["inside"] for k, v in summary.items() if k in P.PARAM_NAMES)
        echo(f"true θ inside the decoded 5–95 % interval for {n_in}/{P.N_PARAMS} parameters")
    return summary
