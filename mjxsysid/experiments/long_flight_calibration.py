"""Calibration of flight-level decoding on flights longer than the decoder's training flights:
is "a sliding window of trained length" calibrated on 60 s flights?

    mjxsysid collect --seconds 60 --train 16 --test 1000 --out OUT/long     # latent trajectories, GPU
    mjxsysid experiment long-flight-calibration --inputs OUT/long --out docs/runs/measurements/long-flight-calibration

For each held-out flight, the shipped sequence decoder (trained on 10 s flights: max_len latents)
is scored on three windows: the last max_len latents (what `decode` uses past the trained length),
the first max_len latents (the trained regime), and every latent with the count feature saturated
(the extrapolation `decode` avoids). Each: 90 % coverage per parameter and per identifiable
combination, energy score (mjxsysid.cfm.pipeline.posterior_scores). Target: 90 % coverage within
±5 points on 60 s flights.
"""
from __future__ import annotations

import time
from pathlib import Path

import jax
import numpy as np

from mjxsysid import theta as P
from mjxsysid.cfm.load import load_sequence_decoder
from mjxsysid.cfm.pipeline import _public, _usable_traj, posterior_scores
from mjxsysid.dataset.collect import load_pairs
from mjxsysid.experiments.common import leaf_table, write_results


def run(out, *, quick=False, policy=None, seed=0, progress=True, decoders=None, inputs=None) -> dict:
    """The three windows scored (see the module doc) into OUT/results.json. ``inputs``: pairs with
    latent trajectories (`mjxsysid collect --seconds S`; required); ``decoders``: a folder with
    cfm_seq.npz (default: the shipped one); 1,000 flights and 200 samples (``quick``: 20 and 20),
    sampled from PRNGKey(seed). ``policy`` is not used (the pairs name theirs)."""
    if inputs is None:
        raise ValueError("long-flight-calibration needs --inputs PAIRS (collect --seconds S: latent trajectories)")
    from types import SimpleNamespace
    t_start = time.time()
    a = SimpleNamespace(pairs=Path(inputs), decoders=decoders, cases=20 if quick else 1000, samples=20 if quick else 200)
    seq = load_sequence_decoder(a.decoders)
    if seq is None:
        raise ValueError("no sequence decoder (cfm_seq.npz) found")
    arrays, meta = load_pairs(a.pairs)
    if "zhat_traj_test" not in arrays:
        raise ValueError(f"{a.pairs}: no latent trajectories: collect with --seconds S")
    tv, zt = _usable_traj(arrays, "test")
    m = min(a.cases, len(tv))
    tv, zt = tv[:m], zt[:m]
    L, w = zt.shape[1], seq.max_len
    if L <= w:
        raise ValueError(f"flights of {L} latents are not longer than the decoder's training flights ({w})")
    idx = np.arange(L)
    windows = {"last_trained_length": idx >= L - w, "first_trained_length": idx < w,
               "whole_flight_saturated": np.ones(L, bool)}
    t_norm = np.asarray(seq.normalizer.normalize(tv))
    key = jax.random.PRNGKey(seed)
    res = {"flights": m, "latents_per_flight": int(L), "flight_s": float(np.asarray(arrays["traj_times"])[-1]),
           "trained_length": int(w), "samples": a.samples, "device": str(jax.devices()[0]), "windows": {}}
    t0 = time.time()
    for j, (name, msk) in enumerate(windows.items()):
        s = np.concatenate([np.asarray(seq.sample_norm(zt[i:i + 250], jax.random.fold_in(key, 1000 * j + i),
                                                       a.samples, mask=np.broadcast_to(msk, (len(zt[i:i + 250]), L))))
                            for i in range(0, m, 250)])
        sc = _public(posterior_scores(s, t_norm, seq.normalizer))
        res["windows"][name] = sc
        if progress:
            print(f"{name:24s} energy {sc['energy_score']:.3f}  90 % within ±5 points: {sc['coverage_90_within_5_points']}/19, "
                  f"identifiable {sc['identifiable_90_within_5_points']}/{len(P.IDENTIFIABLE_NAMES)}", flush=True)
    res["wall_s"] = time.time() - t0
    last = res["windows"]["last_trained_length"]
    res["target_identifiable_cov90_within_5_points"] = last["identifiable_90_within_5_points"] == len(P.IDENTIFIABLE_NAMES)
    res["pairs_meta"] = {k: meta.get(k) for k in ("policy", "prior", "seed", "n_test", "device") if k in meta}
    numbers = {**res, "headline": {"identifiable_within_5_last_window": last["identifiable_90_within_5_points"]}}
    return write_results(out, "long-flight-calibration", config={"quick": quick, **vars(a)}, seeds={"seed": seed},
                         numbers=numbers, table_md=leaf_table(res["windows"]), t0=t_start)
