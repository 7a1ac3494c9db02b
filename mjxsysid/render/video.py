"""Offscreen rendering of recorded quadrotor rollouts (host side, never inside ``jax.jit``).

Rollouts come from :mod:`mjxsysid.sim` as :class:`~mjxsysid.sim.quadrotor.Frame` records (or
any object with ``.pos`` (T, 3) and ``.quat`` (T, 4) wxyz, numpy or jax arrays) sampled every
``dt`` seconds. They are replayed kinematically in a plain MuJoCo model of the vehicle
(:func:`vehicle_model`: arms, rotors and hub sized from θ) and drawn with ``mujoco.Renderer``.

The GL backend is chosen by :mod:`mjxsysid.render.gl`; the vehicle model and scene are built by
:mod:`mjxsysid.render.scene`; this module writes and reads the videos (mediapy + ffmpeg).
"""

from __future__ import annotations

import math
import warnings
from pathlib import Path

import numpy as np

from mjxsysid.render.gl import ensure_gl
from mjxsysid.render.scene import (
    _check_size,
    _decimate,
    _ghost_list,
    _one_theta,
    _reference,
    _Scene,
    _states,
    _trail_seconds,
)

_FFMPEG_SET = False


def _mediapy():
    global _FFMPEG_SET
    try:
        import mediapy
    except ImportError as e:  # pragma: no cover - mediapy is a dependency, optional on GPU hosts
        raise ImportError("writing videos needs mediapy (pip install mediapy imageio-ffmpeg)") from e
    if not _FFMPEG_SET:
        try:
            import imageio_ffmpeg
            mediapy.set_ffmpeg(imageio_ffmpeg.get_ffmpeg_exe())
        except (ImportError, RuntimeError):
            pass  # fall back to an ffmpeg on PATH
        _FFMPEG_SET = True
    return mediapy


def _quiet_fork_warning():
    # mediapy runs ffmpeg through subprocess (fork + exec at once); JAX's "os.fork() was called"
    # warning does not apply. Call inside warnings.catch_warnings().
    warnings.filterwarnings("ignore", message=r"os\.fork\(\) was called", category=RuntimeWarning)


def read_video(path) -> np.ndarray:
    """Decode a video into uint8 frames (N, H, W, 3).

    Uses ``mediapy.read_video``; mediapy 1.2.7 passes ``-vsync``, which ffmpeg >= 9 (bundled by
    recent imageio-ffmpeg) rejects (google/mediapy#88), so on that error this falls back to
    ``imageio_ffmpeg.read_frames``.
    """
    path = Path(path)
    if not path.is_file():
        raise FileNotFoundError(f"video not found: {path}")
    mediapy = _mediapy()
    with warnings.catch_warnings():
        _quiet_fork_warning()
        try:
            return np.asarray(mediapy.read_video(path))
        except RuntimeError as e:
            if "vsync" not in str(e):
                raise
        import imageio_ffmpeg
        reader = imageio_ffmpeg.read_frames(str(path), pix_fmt="rgb24")
        meta = next(reader)
        w, h = meta["size"]
        frames = [np.frombuffer(f, np.uint8).reshape(h, w, 3) for f in reader]
    return np.stack(frames) if frames else np.zeros((0, h, w, 3), np.uint8)


def render_rollout(theta, frames, path, *, fps: float = 50, camera="chase", width: int = 640,
                   height: int = 480, ghosts=None, ghost_alpha: float = 0.25,
                   speedup: float = 1.0, dt: float = 0.002, trail=True, reference=None,
                   base_xml=None) -> Path:
    """Write an mp4 of a recorded rollout and return its path.

    theta: the vehicle (19,). frames: :class:`mjxsysid.sim.Frame` (or any object with ``.pos``
    (T, 3) and ``.quat`` (T, 4) wxyz, or a (pos, quat) pair), sampled every ``dt`` s. The video
    shows ``speedup`` × real time at ``fps`` frames per second: frame j is sample
    round(j · speedup / (fps · dt)), for floor(T · dt · fps / speedup) frames (at least 1).
    camera: a camera of the model ("chase" tracks the vehicle, "side" is fixed, "onboard") or
    its index (-1: free camera). ghosts: optional list of (theta_k, pos_k (T, 3), quat_k (T, 4))
    drawn as translucent tinted copies (alpha ``ghost_alpha``) sized from their own θ.
    trail: True (last 2 s), False, or a duration in seconds of the recent true path drawn as a
    fading red line. reference: optional positions (T_r, 3) (or an object with ``.pos``) drawn
    as a faint dark line. Width and height must be even (h264). Never call inside ``jax.jit``.
    """
    theta = _one_theta(theta)
    pos, quat = _states(frames, "frames")
    n = pos.shape[0]
    ghost_list = _ghost_list(ghosts, n)
    ref = _reference(reference)
    _check_size(width, height)
    if width % 2 or height % 2:
        raise ValueError(f"width and height must be even for h264 video; got {width}x{height}")
    for name, v in (("fps", fps), ("speedup", speedup), ("dt", dt)):
        if not (isinstance(v, (int, float, np.floating, np.integer)) and math.isfinite(v) and v > 0):
            raise ValueError(f"{name} must be a finite number > 0; got {v!r}")
    trail_s = _trail_seconds(trail)
    path = Path(path)
    if path.suffix.lower() not in (".mp4", ".gif", ".webm", ".mov", ".mkv"):
        raise ValueError(f"path must end in .mp4 (or .gif/.webm/.mov/.mkv); got {path}")

    n_video = max(1, int(math.floor(n * dt * fps / speedup + 1e-9)))
    step = speedup / (fps * dt)  # samples per video frame
    idx = np.minimum(np.round(np.arange(n_video) * step).astype(int), n - 1)
    trail_n = int(round(trail_s / dt))
    trail_stride = max(1, int(round(0.01 / dt)))  # one trail vertex per 10 ms
    ref_pts = None if ref is None else _decimate(ref, 400)
    line_scale = max(1.0, height / 480)

    mediapy = _mediapy()
    backend = ensure_gl()
    path.parent.mkdir(parents=True, exist_ok=True)
    scene = _Scene(theta, camera=camera, width=width, height=height, ghosts=ghost_list,
                   ghost_alpha=ghost_alpha, base_xml=base_xml)
    try:
        with warnings.catch_warnings():
            _quiet_fork_warning()
            with mediapy.VideoWriter(path, shape=(int(height), int(width)),
                                     fps=float(fps)) as writer:
                for i in idx:
                    trail_pts = None
                    if trail_n > 0 and i > 0:
                        lo = max(0, i - trail_n)
                        trail_pts = np.concatenate([pos[lo:i:trail_stride], pos[i:i + 1]])
                    writer.add_image(scene.draw(pos[i], quat[i], i, trail_pts=trail_pts,
                                                ref_pts=ref_pts, line_scale=line_scale))
    except Exception as e:
        path.unlink(missing_ok=True)  # no half-written video left behind
        raise RuntimeError(f"rendering {path} with the {backend} GL backend failed: {e}") from e
    finally:
        scene.close()
    return path


def render_frame(theta, frames=None, *, index: int = -1, camera="chase", width: int = 640,
                 height: int = 480, ghosts=None, ghost_alpha: float = 0.25, dt: float = 0.002,
                 trail=True, reference=None, base_xml=None) -> np.ndarray:
    """Render one image (H, W, 3) uint8 of sample ``index`` of a rollout (for notebooks).

    frames: as in :func:`render_rollout`, or a single state (pos (3,), quat (4,)), or None
    (hovering at (0, 0, 1)). ghosts: list of (theta_k, pos_k, quat_k) with the same number of
    samples as frames. Other arguments as in :func:`render_rollout`.
    """
    theta = _one_theta(theta)
    if frames is None:
        pos, quat = np.array([[0.0, 0.0, 1.0]]), np.array([[1.0, 0.0, 0.0, 0.0]])
    else:
        pos, quat = _states(frames, "frames")
    n = pos.shape[0]
    if not -n <= int(index) < n:
        raise IndexError(f"index {index} out of range for a rollout of {n} samples")
    i = int(index) % n
    ghost_list = _ghost_list(ghosts, n)
    ref = _reference(reference)
    _check_size(width, height)
    if not (math.isfinite(dt) and dt > 0):
        raise ValueError(f"dt must be a finite number > 0; got {dt!r}")
    trail_n = int(round(_trail_seconds(trail) / dt))
    ensure_gl()
    with _Scene(theta, camera=camera, width=width, height=height, ghosts=ghost_list,
                ghost_alpha=ghost_alpha, base_xml=base_xml) as scene:
        trail_pts = None
        if trail_n > 0 and i > 0:
            lo = max(0, i - trail_n)
            trail_pts = np.concatenate([pos[lo:i:max(1, int(round(0.01 / dt)))], pos[i:i + 1]])
        return scene.draw(pos[i], quat[i], i, trail_pts=trail_pts,
                          ref_pts=None if ref is None else _decimate(ref, 400),
                          line_scale=max(1.0, height / 480))


def side_by_side(videos, path, *, fps: float = 50, labels=None) -> Path:
    """Place videos (paths of equal frame size and rate) next to each other in one mp4; the
    shorter ones hold their last frame. ``labels``: optional caption drawn on each panel."""
    mediapy = _mediapy()
    clips = [read_video(v) for v in videos]
    if labels is not None:
        if len(labels) != len(clips):
            raise ValueError(f"got {len(labels)} labels for {len(clips)} videos")
        from PIL import Image, ImageDraw

        def caption(frames, text):
            out = []
            for f in frames:
                im = Image.fromarray(np.ascontiguousarray(f))
                ImageDraw.Draw(im).text((12, 10), text, fill=(20, 20, 20))
                out.append(np.asarray(im))
            return np.stack(out)

        clips = [caption(c, t) for c, t in zip(clips, labels)]
    if not clips:
        raise ValueError("side_by_side needs at least one video")
    h = {c.shape[1] for c in clips}
    if len(h) != 1:
        raise ValueError(f"videos must have the same height, got {sorted(h)}")
    n = max(len(c) for c in clips)
    clips = [np.concatenate([c, np.repeat(c[-1:], n - len(c), 0)]) if len(c) < n else c for c in clips]
    path = Path(path)
    with warnings.catch_warnings():
        _quiet_fork_warning()
        mediapy.write_video(path, np.concatenate(clips, 2), fps=float(fps))
    return path
