"""Offscreen rendering (mjxsysid.render): videos, frames, ghosts, plots and input checks.

Needs an offscreen GL backend (EGL / OSMesa / GLFW with a display); the GL tests skip with the
reason when none can be created.
"""
import os
import subprocess
import sys

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from mjxsysid import theta as P
from mjxsysid.sim import rollout

pytestmark = pytest.mark.render

T = 250  # 0.5 s at dt = 0.002
W, H = 160, 120


@pytest.fixture(scope="module")
def gl():
    pytest.importorskip("mediapy")
    pytest.importorskip("imageio_ffmpeg")
    from mjxsysid.render import ensure_gl
    try:
        return ensure_gl()
    except RuntimeError as e:
        pytest.skip(f"no offscreen GL backend: {e}")


@pytest.fixture(scope="module")
def flight(sim):
    """Paper vehicle climbing straight up for 0.5 s (cmd 0.5 vs hover ≈ 0.40)."""
    theta = P.paper_hardware()
    s0 = sim.init(theta, jax.random.PRNGKey(0))
    cmds = jnp.full((T, 4), 0.5, jnp.float32)
    _, frames = jax.jit(lambda th, s, u: rollout(sim, th, s, u))(theta, s0, cmds)
    frames = jax.device_get(frames)
    assert frames.pos[-1, 2] - frames.pos[0, 2] > 0.3  # it climbs
    return theta, frames


def _vehicle_rows(video):
    """Mean image row of the moving vehicle in each frame of a fixed-camera video: pixels that
    differ from the per-pixel median over time (the static background)."""
    v = video.astype(int)
    bg = np.median(v, 0)
    rows = []
    for f in v:
        r = np.nonzero(np.abs(f - bg).max(-1) > 30)[0]
        rows.append(r.mean() if r.size >= 3 else np.nan)
    return np.array(rows)


def test_import_is_lazy_and_headless_env():
    code = ("import sys, mjxsysid.render as r; "
            "assert 'mediapy' not in sys.modules and 'mujoco' not in sys.modules; "
            "v = r.headless_env(); assert v in ('egl', 'osmesa', None), v; "
            "assert 'mujoco' not in sys.modules and 'matplotlib' not in sys.modules; print(v)")
    env = {k: v for k, v in os.environ.items() if k not in ("MUJOCO_GL", "DISPLAY", "WAYLAND_DISPLAY")}
    out = subprocess.run([sys.executable, "-c", code], env=env, capture_output=True, text=True,
                         timeout=60)
    assert out.returncode == 0, out.stderr[-2000:]


def test_headless_env_respects_user_settings(monkeypatch):
    from mjxsysid.render import headless_env
    monkeypatch.setenv("MUJOCO_GL", "osmesa")
    assert headless_env() == "osmesa"
    monkeypatch.delenv("MUJOCO_GL")
    monkeypatch.setenv("DISPLAY", ":0")
    assert headless_env() is None and "MUJOCO_GL" not in os.environ


def test_vehicle_model_scales_with_arm_length():
    import mujoco
    from mjxsysid.render import vehicle_model
    sizes = {}
    for arm in (0.05, 0.25):
        th = P.paper_hardware()
        th[P.ARM] = arm
        m = vehicle_model(th)
        d = mujoco.MjData(m)
        mujoco.mj_kinematics(m, d)
        for i in range(4):
            site = m.site(f"rotor{i + 1}").id
            np.testing.assert_allclose(m.site_pos[site], np.asarray(P.rotor_positions(th))[i],
                                       atol=1e-6)
            geom = m.geom(f"rotor{i + 1}").id
            np.testing.assert_allclose(m.geom_pos[geom][:2], arm * P.ROTOR_DIRECTIONS[i], atol=1e-6)
            assert m.geom_size[geom][0] == pytest.approx(0.35 * arm)
        assert m.geom_size[m.geom("arm13").id][1] == pytest.approx(arm, rel=1e-4)  # half-length
        sizes[arm] = m.geom_size[m.geom("hub").id].copy()
        assert m.body_mass[m.body("quadrotor").id] == pytest.approx(th[P.MASS])
    assert np.all(sizes[0.25] > 4 * sizes[0.05])


def test_render_rollout_mp4(gl, flight, tmp_path):
    from mjxsysid.render import read_video, render_rollout
    theta, frames = flight
    path = render_rollout(theta, frames, tmp_path / "flight.mp4", fps=50, camera="side",
                          width=W, height=H, trail=False)
    assert path.is_file() and path.stat().st_size > 1000
    video = read_video(path)
    assert video.shape == (25, H, W, 3)  # 0.5 s at 50 fps
    assert all(f.std() > 10 for f in video), "blank frames"
    rows = _vehicle_rows(video)
    assert np.isfinite(rows[[0, -1]]).all(), "vehicle not found in the image"
    assert rows[-1] < rows[0] - 8, f"vehicle should climb in the image: rows {rows}"

    # speedup halves the frame count; chase camera with a trail and a reference line works too.
    path2 = render_rollout(theta, frames, tmp_path / "fast.mp4", fps=50, speedup=2.0,
                           width=W, height=H, reference=np.asarray(frames.pos) + 0.1)
    assert read_video(path2).shape[0] == 12


def test_ghosts_drawn_with_their_own_size(gl, flight):
    from mjxsysid.render import render_frame
    theta, frames = flight
    pos, quat = np.asarray(frames.pos), np.asarray(frames.quat)
    kw = dict(index=-1, camera="side", width=W, height=H, trail=False)
    plain = render_frame(theta, frames, **kw)
    assert plain.shape == (H, W, 3) and plain.dtype == np.uint8 and plain.std() > 10

    def ghost_pixels(arm):
        th = theta.copy()
        th[P.ARM] = arm
        img = render_frame(theta, frames, ghosts=[(th, pos + np.array([0.8, 0.0, 0.0]), quat)],
                           ghost_alpha=0.6, **kw)
        return (np.abs(img.astype(int) - plain.astype(int)).max(-1) > 25).sum()

    small, large = ghost_pixels(0.1), ghost_pixels(0.3)
    assert small > 5, "ghost not visible"
    assert large > 2 * small, (small, large)


def test_plots_write_pngs(flight, tmp_path):
    from mjxsysid.render import plot_prior_marginals, plot_trajectory
    theta, frames = flight
    p1 = plot_trajectory(frames, tmp_path / "traj.png", reference=np.asarray(frames.pos) * 0.95,
                         title="climb", theta=theta)
    samples = P.DEFAULT_PRIOR.sample(jax.random.PRNGKey(1), 2000)
    p2 = plot_prior_marginals(samples, tmp_path / "prior.png", mark=theta)
    for p in (p1, p2):
        assert p.is_file() and p.stat().st_size > 20_000
        assert p.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"


def test_marginals_tick_labels_are_readable(tmp_path):
    """marginals.png, as `decode --log` draws it: a log-grounded band far narrower than the axis (the regression's
    point far off), small values on linear axes. No two tick labels of a panel overlap, and the log axes' labels
    span the axis (they once crowded the samples' corner)."""
    from support.figures import kept_figure, overlapping_tick_labels

    from mjxsysid.render.posterior import plot_marginals
    rng = np.random.default_rng(0)
    samples = np.array(P.DEFAULT_PRIOR.sample(jax.random.PRNGKey(2), 400))
    samples[:, P.TAU_M] = 0.03 * (1 + 1e-3 * rng.standard_normal(400))          # a narrow band
    samples[:, P.TAU_EXT] = 1e-6 * rng.standard_normal((400, 3))                # small values
    point = P.PAPER_HARDWARE.copy()
    point[P.TAU_M], point[P.TAU_EXT] = 0.036, [9e-4, -3e-3, -6e-4]
    with kept_figure() as shown:
        plot_marginals(samples, P.PAPER_HARDWARE, tmp_path / "m.png", point=point)
        axes = shown["fig"].axes[:P.N_PARAMS]
        for ax in axes:
            assert overlapping_tick_labels(ax) == [], ax.get_title()
        ax = axes[P.TAU_M]
        assert ax.get_xscale() == "log"
        ticks = [t for t in ax.get_xticks() if t > 0]
        assert ticks[-1] > 0.033 and ticks[0] < 0.031, ticks      # over the axis, not the samples' 0.0299–0.0301


def test_marginals_of_a_real_log_mark_no_truth(tmp_path):
    """A real log has no truth (``decode --log`` passes NaN): no black line, and the legend names the regression
    alone; with no point either, no legend."""
    from support.figures import kept_figure

    from mjxsysid.render.posterior import plot_marginals
    samples = np.array(P.DEFAULT_PRIOR.sample(jax.random.PRNGKey(2), 200))
    with kept_figure() as shown:
        plot_marginals(samples, np.full(P.N_PARAMS, np.nan), tmp_path / "m.png", point=P.PAPER_HARDWARE)
        ax = shown["fig"].axes[0]
        assert [t.get_text() for t in ax.get_legend().get_texts()] == ["regression"]
        assert all(line.get_color() != "k" for a in shown["fig"].axes for line in a.lines)
    with kept_figure() as shown:
        plot_marginals(samples, None, tmp_path / "n.png")
        assert shown["fig"].axes[0].get_legend() is None


def test_bad_inputs_raise(gl, flight, tmp_path):
    from mjxsysid.render import plot_prior_marginals, render_frame, render_rollout
    theta, frames = flight
    pos, quat = np.asarray(frames.pos), np.asarray(frames.quat)
    out = tmp_path / "x.mp4"
    kw = dict(width=W, height=H)
    with pytest.raises(ValueError, match=r"pos must have shape \(T, 3\); got \(250, 2\)"):
        render_rollout(theta, (pos[:, :2], quat), out, **kw)
    with pytest.raises(ValueError, match="pos has 250 samples but quat has 100"):
        render_rollout(theta, (pos, quat[:100]), out, **kw)
    with pytest.raises(ValueError, match=r"unknown camera 'top'.*chase.*side"):
        render_rollout(theta, frames, out, camera="top", **kw)
    with pytest.raises(ValueError, match=r"ghosts\[0\]: pos has 10 samples"):
        render_rollout(theta, frames, out, ghosts=[(theta, pos[:10], quat[:10])], **kw)
    with pytest.raises(ValueError, match=r"theta must have shape \(\.\.\., 19\)"):
        render_rollout(theta[:5], frames, out, **kw)
    with pytest.raises(ValueError, match="arm_length must be > 0"):
        bad = theta.copy()
        bad[P.ARM] = -1
        render_rollout(bad, frames, out, **kw)
    with pytest.raises(ValueError, match="even"):
        render_rollout(theta, frames, out, width=161, height=H)
    with pytest.raises(ValueError, match="fps must be"):
        render_rollout(theta, frames, out, fps=0, **kw)
    with pytest.raises(TypeError, match=r"\.pos \(T, 3\)"):
        render_rollout(theta, object(), out, **kw)
    with pytest.raises(IndexError):
        render_frame(theta, frames, index=T, **kw)
    with pytest.raises(ValueError, match=r"shape \(n >= 2, 19\)"):
        plot_prior_marginals(np.ones((10, 18)), tmp_path / "p.png")
    assert not out.exists()


def test_side_by_side_places_videos_next_to_each_other(tmp_path):
    """Two clips of different length -> one clip of the longer length, twice the width, the
    shorter one holding its last frame; captions drawn."""
    from mjxsysid.render.video import _mediapy, read_video, side_by_side
    mediapy = _mediapy()
    a = np.full((6, 32, 48, 3), 200, np.uint8)
    b = np.full((4, 32, 48, 3), 50, np.uint8)
    mediapy.write_video(tmp_path / "a.mp4", a, fps=10)
    mediapy.write_video(tmp_path / "b.mp4", b, fps=10)
    out = side_by_side([tmp_path / "a.mp4", tmp_path / "b.mp4"], tmp_path / "ab.mp4", fps=10, labels=["A", "B"])
    v = read_video(out)
    assert v.shape[0] == 6 and v.shape[1:3] == (32, 96)
    assert abs(float(v[-1, 20:, 60:].mean()) - 50) < 10       # the shorter clip holds its last frame
    with pytest.raises(ValueError, match="labels"):
        side_by_side([tmp_path / "a.mp4"], tmp_path / "x.mp4", labels=["A", "B"])
