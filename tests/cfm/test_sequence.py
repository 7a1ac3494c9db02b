"""Flight-level decoding (issue 11 §1): the sequence CFM p(θ | ẑ_1..ẑ_W), collect's latent
trajectories, decode's window option."""
import json
from pathlib import Path

import jax
import numpy as np
import pytest

from support.jax_setup import xla_optimised

import mjxsysid
from mjxsysid import theta as P
from mjxsysid.cfm import calibration as C
from mjxsysid.cfm.sequence import (SeqCFMConfig, SequenceDecoder, init_params, random_windows,
                                   save_seq_decoder, train_seq_cfm, window_mask)

PRETRAINED = str(Path(mjxsysid.__file__).parent / "pretrained")


@pytest.fixture(scope="module")
def gaussian_problem():
    """θ ~ N(0, I₂); every latent of a flight is θ + N(0, I₂): the posterior given W latents is
    N(Σz / (1 + W), I / (1 + W)), so its width shrinks as 1/√(1 + W)."""
    rng = np.random.default_rng(0)
    n, L, d = 4000, 16, 2
    th = rng.normal(size=(n, d)).astype(np.float32)
    zs = (th[:, None] + rng.normal(size=(n, L, d))).astype(np.float32)
    cfg = SeqCFMConfig(theta_dim=d, z_dim=d, width=64, blocks=2, time_dim=16, set_width=32, heads=2,
                       cond_dim=16, max_len=L, epochs=70, batch=128, lr=2e-3)
    with xla_optimised():                      # a 70-epoch training loop: run time, not compiles
        params, hist = train_seq_cfm(th, zs, cfg, log=None, val=(th[:256], zs[:256]))
    tt = rng.normal(size=(300, d)).astype(np.float32)
    zt = (tt[:, None] + rng.normal(size=(300, L, d))).astype(np.float32)
    return SequenceDecoder(params, cfg), hist, tt, zt


@pytest.mark.usefixtures("xla_optimised_test")
def test_sequence_decoder_accumulates_information_and_stays_calibrated(gaussian_problem):
    dec, hist, tt, zt = gaussian_problem
    assert hist["val_loss"][-1] < hist["val_loss"][0]
    m, L = zt.shape[:2]
    stds = {}
    for w in (1, 4, 16):
        mask = np.zeros((m, L), bool)
        mask[:, L - w:] = True                      # any window: the latents are exchangeable
        s = np.asarray(dec.sample_norm(zt, jax.random.PRNGKey(w), 200, mask=mask))
        assert s.shape == (m, 200, 2)
        stds[w] = float(s.std(1).mean())
        exact = np.sqrt(1.0 / (1 + w))
        assert abs(stds[w] - exact) < 0.2 * exact, (w, stds[w], exact)
        post_mean = zt[:, L - w:].sum(1) / (1 + w)
        assert np.abs(s.mean(1) - post_mean).mean() < 0.12, w
        cov = C.coverage(s, tt, (0.5, 0.9)).mean(1)
        # about 4 and 3.5 standard errors of a mean over 300 tests: √(0.9 · 0.1 / 300) = 0.017, √(0.5 · 0.5 / 300) = 0.029
        assert abs(cov[1] - 0.9) < 0.07 and abs(cov[0] - 0.5) < 0.10, (w, cov)
    # ~ 1/√(1 + W): 16 latents are 2.9× sharper than one.
    assert 2.3 < stds[1] / stds[16] < 3.6, stds
    # One window (W, z_dim) -> (n, d); the order of the latents does not matter.
    a = np.asarray(dec.sample_norm(zt[0, :5], jax.random.PRNGKey(0), 50))
    b = np.asarray(dec.sample_norm(zt[0, :5][::-1], jax.random.PRNGKey(0), 50))
    assert a.shape == (50, 2)
    np.testing.assert_allclose(a, b, atol=1e-4)


def test_random_windows_and_masks():
    start, w = random_windows(jax.random.PRNGKey(0), 20_000, 99)
    start, w = np.asarray(start), np.asarray(w)
    assert w.min() == 1 and w.max() == 99 and np.all(start >= 0) and np.all(start + w <= 99)
    assert 0.1 < np.mean(w == 1) < 0.2            # log-uniform: P(W = 1) = log 2 / log 100 = 0.15
    mask = np.asarray(window_mask(start[:5], w[:5], 99))
    assert mask.shape == (5, 99) and (mask.sum(1) == w[:5]).all()
    assert all(mask[i, start[i]] for i in range(5))


def test_save_load_roundtrip_and_errors(tmp_path):
    cfg = SeqCFMConfig(width=32, blocks=1, time_dim=8, set_width=16, heads=2, cond_dim=8, max_len=7,
                       z_shift=tuple([0.1] * 8), z_scale=tuple([2.0] * 8))
    params = init_params(cfg)
    norm = P.prior_normalizer("default", n=2000)
    path = save_seq_decoder(tmp_path / "cfm_seq.npz", params, cfg, norm, {"traj_rate_hz": 10.0})
    dec = SequenceDecoder.load(path)
    assert dec.cfg == cfg and dec.max_len == 7 and dec.meta["traj_rate_hz"] == 10.0
    z = np.random.default_rng(0).normal(size=(3, 7, 8)).astype(np.float32) * 0.1
    mask = np.ones((3, 7), bool)
    mask[1, 3:] = False
    th = np.asarray(dec.sample_theta(z, jax.random.PRNGKey(0), 4, mask=mask))
    assert th.shape == (3, 4, 19) and np.isfinite(th).all()
    # Masked-out latents do not matter, whatever they hold.
    z2 = z.copy()
    z2[1, 3:] = 1e6
    np.testing.assert_allclose(np.asarray(dec.sample_norm(z2, jax.random.PRNGKey(0), 4, mask=mask)),
                               np.asarray(dec.sample_norm(z, jax.random.PRNGKey(0), 4, mask=mask)), atol=1e-5)
    with pytest.raises(ValueError, match="at least one latent"):
        dec.sample_norm(z, jax.random.PRNGKey(0), 4, mask=np.zeros((3, 7), bool))
    with pytest.raises(ValueError, match=r"\(m, L, 8\)"):
        dec.sample_norm(z[..., :5], jax.random.PRNGKey(0), 4)
    with pytest.raises(ValueError, match="mask must have shape"):
        dec.sample_norm(z, jax.random.PRNGKey(0), 4, mask=mask[:, :3])
    with pytest.raises(ValueError, match="multiple of heads"):
        SeqCFMConfig(set_width=30, heads=4)
    # The single-latent loader names the right class; the sequence loader refuses other kinds.
    from mjxsysid.cfm.train import load_decoder
    with pytest.raises(ValueError, match="SequenceDecoder.load"):
        load_decoder(path)
    import pathlib
    shipped = pathlib.Path(PRETRAINED) / "cfm.npz"
    if shipped.exists():
        with pytest.raises(ValueError, match="not a sequence decoder"):
            SequenceDecoder.load(shipped)


def test_window_parsing_and_masks():
    from mjxsysid.decoding import check_window, parse_window, window_masks
    assert parse_window("flight") == "flight" and parse_window("Instant") == "instant"
    assert parse_window("2.5") == 2.5
    for bad in ("0", "-1", "nan", "abc", "inf"):
        with pytest.raises(ValueError, match="--window"):
            parse_window(bad)
    with pytest.raises(ValueError, match="longer than the flight"):
        check_window("12", 10.0)
    assert check_window("10", 10.0) == 10.0
    lt = 0.2 + 0.1 * np.arange(10)                   # latents at 0.2 … 1.1 s
    rt = np.array([0.2, 0.6, 1.1])
    fl = window_masks(lt, rt, "flight")
    assert fl.sum(1).tolist() == [1, 5, 10]
    sl = window_masks(lt, rt, 0.3)                   # (t − 0.3, t]: 3 latents once available
    assert sl.sum(1).tolist() == [1, 3, 3] and sl[2, -3:].all()
    # The index ranges used for long logs are the rows of the masks.
    from mjxsysid.decoding import window_bounds
    for w, m in (("flight", fl), (0.3, sl), (0.3, window_masks(lt, np.array([0.15, 0.35]), 0.3))):
        rt_ = rt if m.shape[0] == 3 else np.array([0.15, 0.35])
        st, en = window_bounds(lt, rt_, w)
        want = (np.arange(len(lt))[None] >= st[:, None]) & (np.arange(len(lt))[None] <= en[:, None])
        np.testing.assert_array_equal(want, m)


def _tiny_seq_decoders(tmp_path):
    """A decoders folder: the shipped single-latent decoders plus an (untrained) sequence decoder."""
    import pathlib
    import shutil
    src = pathlib.Path(PRETRAINED)
    if not (src / "cfm.npz").exists():
        pytest.skip("no shipped decoders")
    d = tmp_path / "dec"
    d.mkdir()
    for f in ("cfm.npz", "regression.npz"):
        shutil.copy(src / f, d / f)
    cfg = SeqCFMConfig(width=32, blocks=1, time_dim=8, set_width=16, heads=2, cond_dim=8, max_len=20)
    from mjxsysid.cfm.sample import Decoder
    save_seq_decoder(d / "cfm_seq.npz", init_params(cfg), cfg, Decoder.load(d / "cfm.npz").normalizer,
                     {"traj_rate_hz": 10.0})
    return d


def test_decode_latents_with_a_window(tmp_path):
    from mjxsysid.decoding import decode_latents
    from mjxsysid.cfm.load import load_decoders, load_sequence_decoder
    d = _tiny_seq_decoders(tmp_path)
    cfm, reg = load_decoders(d)
    seq = load_sequence_decoder(d)
    times = 0.002 * (np.arange(1000) + 1)            # 2 s at 500 Hz
    z = np.random.default_rng(0).normal(size=(1000, 8)).astype(np.float32) * 0.1
    dec = decode_latents(z, times, rate=5, samples=6, decoder=cfm, regression=reg, window="flight",
                         seq_decoder=seq)
    k = len(dec["times"])
    assert dec["samples"].shape == dec["samples_window"].shape == (k, 6, 19)
    # Latents at 10 Hz from 0.2 s: at the last decode time (2.0 s) the flight holds 19 of them.
    assert dec["n_window"][0] == 1 and dec["n_window"][-1] == 19
    dec1 = decode_latents(z, times, rate=5, samples=6, decoder=cfm, regression=reg, window=0.5, seq_decoder=seq)
    assert dec1["n_window"][-1] == 5
    # Incremental (every prefix / window encoded in one pass) equals decoding each window by itself.
    from mjxsysid.dataset.collect import decode_indices
    from mjxsysid.decoding import window_masks
    lidx = decode_indices(times, 10.0)
    for w, got in (("flight", dec), (0.5, dec1)):
        mask = window_masks(times[lidx], got["times"], w)
        zl = np.broadcast_to(z[lidx], (len(got["times"]), len(lidx), 8))
        direct = np.asarray(seq.sample_theta(zl, jax.random.PRNGKey(1), 6, mask=mask))
        np.testing.assert_allclose(got["samples_window"], direct, rtol=1e-4)
    # A flight with more decode times than max_decodes is decoded at a lower rate, the end included.
    dec2 = decode_latents(z, times, rate=10, samples=6, decoder=cfm, regression=reg, window="flight",
                          seq_decoder=seq, max_decodes=4)
    assert len(dec2["times"]) == 4 and dec2["times"][-1] == dec["times"][-1] and dec2["decode_rate_hz"] < 5
    assert dec2["n_window"][-1] == dec["n_window"][-1] == 19      # the end still conditions on every latent
    # Longer than the decoder's training flights (max_len 20 latents here): every latent enters
    # (the count feature saturates), flagged, and still the one-pass encoding of each prefix.
    t4 = 0.002 * (np.arange(2000) + 1)
    z4 = np.random.default_rng(1).normal(size=(2000, 8)).astype(np.float32) * 0.1
    d4 = decode_latents(z4, t4, rate=2, samples=6, decoder=cfm, regression=reg, window="flight", seq_decoder=seq)
    assert d4["n_window"][-1] > 20 and d4["beyond_trained_length"][-1] and not d4["beyond_trained_length"][0]
    lidx4 = decode_indices(t4, 10.0)
    m4 = window_masks(t4[lidx4], d4["times"], "flight")
    direct4 = np.asarray(seq.sample_theta(np.broadcast_to(z4[lidx4], (len(d4["times"]), len(lidx4), 8)),
                                          jax.random.PRNGKey(1), 6, mask=m4))
    np.testing.assert_allclose(d4["samples_window"], direct4, rtol=1e-4)
    with pytest.raises(ValueError, match="max_decodes"):
        decode_latents(z, times, rate=10, samples=6, decoder=cfm, regression=reg, max_decodes=0)
    msgs = []
    assert load_sequence_decoder(tmp_path, echo=msgs.append) is None and "falling back" in msgs[0]



def test_sequence_decoder_of_another_policy_is_an_error(tmp_path):
    """As for the single-latent decoders: another policy's sequence decoder is refused unless
    allow_mismatch (then a warning)."""
    from mjxsysid.cfm.load import load_sequence_decoder
    from mjxsysid.cfm.sample import Decoder
    d = _tiny_seq_decoders(tmp_path)
    cfg = SeqCFMConfig(width=32, blocks=1, time_dim=8, set_width=16, heads=2, cond_dim=8, max_len=20)
    save_seq_decoder(d / "cfm_seq.npz", init_params(cfg), cfg, Decoder.load(d / "cfm.npz").normalizer,
                     {"traj_rate_hz": 10.0, "data": {"pairs_meta": {"weights_sha256": "0" * 64}}})
    with pytest.raises(ValueError, match="cfm_seq.npz: trained on the latents of another policy"):
        load_sequence_decoder(d, "mjxsysid")
    told = []
    assert load_sequence_decoder(d, "mjxsysid", echo=told.append, allow_mismatch=True) is not None
    assert told and told[0].startswith("warning:")


def test_decode_cli_windows(tmp_path, capsys):
    """Bad windows are one-line errors (exit 2) before anything flies; a log replay decodes with a
    window and falls back to instant without a sequence decoder."""
    from mjxsysid.logs.csvlog import write_log
    from mjxsysid.cli import main
    for w, msg in (("0", "must be > 0"), ("-2", "must be > 0"), ("soon", "'flight', 'instant'"),
                   ("30", "longer than the flight")):
        assert main(["decode", "--duration", "1", "--window", w, "--out", str(tmp_path / "x")]) == 2
        last = capsys.readouterr().err.strip().splitlines()[-1]     # (mujoco may print import notes first)
        assert last.startswith("mjxsysid decode: error: --window") and msg in last, last
    d = _tiny_seq_decoders(tmp_path)
    # A 2 s "log" of a vehicle at rest-ish hover (the policy's history is rebuilt from it): the
    # length of the 2 s flight logs of tests/decoding/test_decode.py (one compiled replay).
    n = 1000
    t = 0.002 * np.arange(n)
    imu = np.zeros((n, 6))
    imu[:, 5] = P.GRAVITY
    log = write_log(tmp_path / "f.csv", t, imu, np.full(n, P.GRAVITY), np.zeros((n, 3)), np.full((n, 4), 0.5))
    assert main(["decode", "--log", str(log), "--window", "5", "--decoders", str(d), "--out", str(tmp_path / "a")]) == 2
    assert "longer than the flight" in capsys.readouterr().err
    assert main(["decode", "--log", str(log), "--window", "0.3", "--samples", "8", "--decoders", str(d),
                 "--decoder-only", "--out", str(tmp_path / "b")]) == 0
    s = json.loads((tmp_path / "b" / "summary.json").read_text())
    assert s["_window"]["window"] == 0.3 and s["_window"]["n_latents"] == 3 and "_instant" in s
    assert set(P.PARAM_NAMES) <= set(s) and set(P.PARAM_NAMES) <= set(s["_instant"])
    dec = np.load(tmp_path / "b" / "decoded.npz")
    assert dec["samples_window"].shape == dec["samples"].shape
    np.testing.assert_allclose(s["mass"]["mean"], dec["samples_window"][-1, :, 0].mean(), rtol=1e-5)
    (d / "cfm_seq.npz").unlink()
    assert main(["decode", "--log", str(log), "--samples", "8", "--decoders", str(d), "--decoder-only",
                 "--out", str(tmp_path / "c")]) == 0
    assert "falling back to --window instant" in capsys.readouterr().err
    s = json.loads((tmp_path / "c" / "summary.json").read_text())
    assert s["_window"]["window"] == "instant" and "_instant" not in s


def test_collect_latent_trajectories(collected_pairs, tmp_path):
    """collect records ẑ at 10 Hz over the flight of random manoeuvres, 4 s here (the collect run
    of tests/policy/test_policy.py::test_collect_pairs_tiny: conftest.collected_pairs)."""
    from mjxsysid.cli import main
    from mjxsysid.dataset.collect import MANOEUVRES, load_pairs
    arrays, meta = load_pairs(collected_pairs)
    times = arrays["traj_times"]
    assert times.shape == (39,)
    np.testing.assert_allclose(times, 0.2 + 0.1 * np.arange(39), atol=1e-5)   # 10 Hz from 0.2 s to 4 s
    assert arrays["zhat_traj_train"].shape == (6, 39, 8) and arrays["zhat_traj_test"].shape == (2, 39, 8)
    np.testing.assert_array_equal(arrays["zhat_train"], arrays["zhat_traj_train"][:, -1])
    assert np.isfinite(arrays["zhat_traj_train"]).all()
    assert np.abs(np.diff(arrays["zhat_traj_train"], axis=1)).max() > 0        # the latent moves in flight
    assert set(arrays["manoeuvre_train"].tolist()) <= set(range(len(MANOEUVRES)))
    assert len(meta["weights_sha256"]) == 64 and meta["seconds"] == 4.0 and meta["traj_rate_hz"] == 10.0
    assert meta["manoeuvres"] == list(MANOEUVRES)
    with pytest.raises(ValueError, match="seconds must be >= 0.2"):
        from mjxsysid.dataset.collect import collect
        collect(tmp_path / "x", n_train=2, n_test=1, seconds=0.1)
    assert main(["collect", "--out", str(tmp_path / "y"), "--manoeuvres", "loop"]) == 2


def test_switch_reference_mixes_types_in_one_batch():
    from mjxsysid.control.references import Lemniscate, MinSnap, Switch, stack
    lem = stack([Lemniscate.make(period=5.0), Lemniscate.make(period=7.0)])
    ms = stack([MinSnap.random(seed=1, duration=4.0, start=(0.0, 0.0, 1.0))] * 2)
    ref = Switch(lem, ms, jax.numpy.array([False, True]))
    pts = jax.vmap(lambda r: r.at(1.3))(ref)
    np.testing.assert_allclose(pts.pos[0], Lemniscate.make(period=5.0).at(1.3).pos, atol=1e-6)
    np.testing.assert_allclose(pts.pos[1], MinSnap.random(seed=1, duration=4.0, start=(0.0, 0.0, 1.0)).at(1.3).pos,
                               atol=1e-6)
    assert np.asarray(jax.vmap(lambda r: r.duration)(ref)).tolist() == [np.inf, 4.0]
