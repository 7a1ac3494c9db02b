"""Offscreen rendering of recorded quadrotor rollouts (host side, never inside ``jax.jit``).

Rollouts come from :mod:`mjxsysid.sim` as :class:`~mjxsysid.sim.quadrotor.Frame` records (or
any object with ``.pos`` (T, 3) and ``.quat`` (T, 4) wxyz, numpy or jax arrays) sampled every
``dt`` seconds. They are replayed kinematically in a plain MuJoCo model of the vehicle
(:func:`vehicle_model`: arms, rotors and hub sized from θ) and drawn with ``mujoco.Renderer``.

GL backend
----------
MuJoCo picks its GL context class once, at ``import mujoco``, from ``MUJOCO_GL``
(``mujoco/rendering/classic/gl_context.py``; unset on Linux means GLFW, which needs a display).
``mujoco.Renderer`` reads ``mujoco.rendering.classic.gl_context.GLContext`` each time a renderer
is created, so the backend can still be chosen after import. :func:`ensure_gl` (called lazily
by every render function, cached) does that:

* ``MUJOCO_GL`` set by the user: that backend only (a probe context is created to fail early,
  with a clear message).
* ``MUJOCO_GL`` unset (or set by :func:`headless_env`): try, in order, GLFW (only when
  ``DISPLAY``/``WAYLAND_DISPLAY`` is set), EGL, OSMesa; the first that creates a context wins.

Nothing here touches the environment at import time (on a machine without EGL,
``import mujoco`` fails when ``MUJOCO_GL=egl``). Scripts that want the headless default before
``import mujoco`` call :func:`headless_env` first.
"""
from __future__ import annotations

import ctypes
import ctypes.util
import dataclasses
import math
import os
import sys
import warnings
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from mjxsysid import params as P

if TYPE_CHECKING:  # pragma: no cover
    import mujoco

ASSET = Path(__file__).resolve().parent.parent / "assets" / "quadrotor.xml"
PAPER_ARM = 0.184  # m, the arm length the asset's geometry is drawn for

GHOST_TINTS = (
    (0.10, 0.75, 0.35),  # green
    (0.65, 0.30, 0.90),  # purple
    (0.95, 0.55, 0.05),  # orange
    (0.05, 0.70, 0.85),  # cyan
    (0.90, 0.20, 0.55),  # magenta
    (0.55, 0.55, 0.10),  # olive
)
TRAIL_RGBA = (0.85, 0.15, 0.10, 0.9)
REFERENCE_RGBA = (0.10, 0.10, 0.10, 0.45)

_DISABLED = ("disable", "disabled", "off", "false", "0")
_GL_STATE: dict[str, Any] = {"backend": None, "auto_env": False}
_FFMPEG_SET = False


# ----------------------------------------------------------------------------------------
# GL backend selection
# ----------------------------------------------------------------------------------------

def _has_display() -> bool:
    return bool(os.environ.get("DISPLAY") or os.environ.get("WAYLAND_DISPLAY"))


def _lib_loadable(*names: str) -> bool:
    for name in names:
        for cand in (ctypes.util.find_library(name), f"lib{name}.so", f"lib{name}.so.1"):
            if not cand:
                continue
            try:
                ctypes.CDLL(cand)
                return True
            except OSError:
                continue
    return False


def headless_env() -> str | None:
    """Choose a headless GL backend through ``MUJOCO_GL``; call before ``import mujoco``.

    Only acts on Linux when ``MUJOCO_GL`` is unset and there is no ``DISPLAY`` /
    ``WAYLAND_DISPLAY``: sets ``MUJOCO_GL=egl`` if libEGL can be loaded, else ``osmesa`` if
    libOSMesa can, else leaves it unset (so ``import mujoco`` never fails because of it).
    Returns the resulting value of ``MUJOCO_GL`` (None if unset). If mujoco is already imported
    the variable no longer affects it, but :func:`ensure_gl` still honours the choice.
    """
    if (os.environ.get("MUJOCO_GL") is None and not _has_display()
            and sys.platform.startswith("linux")):
        choice = "egl" if _lib_loadable("EGL") else "osmesa" if _lib_loadable("OSMesa") else None
        if choice is not None:
            os.environ["MUJOCO_GL"] = choice
            _GL_STATE["auto_env"] = True
    return os.environ.get("MUJOCO_GL")


def _pyopengl_platform() -> str | None:
    mod = sys.modules.get("OpenGL.platform")
    plat = getattr(mod, "PLATFORM", None) if mod is not None else None
    return None if plat is None else type(plat).__name__


def _purge_pyopengl():
    """Forget a PyOpenGL import made by a failed probe, so another platform can be loaded."""
    for name in list(sys.modules):
        if name == "OpenGL" or name.startswith("OpenGL.") or name in ("mujoco.egl", "mujoco.osmesa",
                                                                      "mujoco.egl.egl_ext"):
            del sys.modules[name]


def _load_context_class(backend: str):
    """Import the GLContext class of one backend ('glfw', 'egl', 'osmesa')."""
    if backend == "glfw":
        from mujoco.glfw import GLContext
        return GLContext
    plat = _pyopengl_platform()
    want = {"egl": "EGLPlatform", "osmesa": "OSMesaPlatform"}[backend]
    if plat is not None and plat != want:
        raise RuntimeError(f"PyOpenGL is already initialised for {plat} in this process; set "
                           f"MUJOCO_GL={backend} before Python starts")
    env = os.environ.get("PYOPENGL_PLATFORM")
    if plat is None and env is not None and env.lower() != backend:
        if not _GL_STATE.get("pyopengl_env_ours"):
            raise RuntimeError(f"PYOPENGL_PLATFORM={env} is set; unset it or set it to {backend}")
        os.environ["PYOPENGL_PLATFORM"] = backend
    if backend == "egl":
        from mujoco.egl import GLContext
    else:
        from mujoco.osmesa import GLContext
    return GLContext


def _probe_context(cls):
    """Create and make current a 16x16 context of class ``cls``; raise if it is unusable.

    GLFW does not raise: it warns (e.g. "X11: The DISPLAY environment variable is missing") and
    returns no window, so a missing window or any GLFW warning counts as failure. No MuJoCo
    render context is made here: a failed ``mjr_makeContext`` can leave MuJoCo's GL loader
    unusable for the rest of the process, which would defeat the fallback.
    """
    error = None
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        ctx = cls(16, 16)
        try:
            if hasattr(ctx, "_context") and not ctx._context:
                error = "no GL context/window was created"
            else:
                ctx.make_current()
        finally:
            ctx.free()
    glfw_errors = [str(w.message) for w in caught if type(w.message).__name__ == "GLFWError"]
    if error or glfw_errors:
        raise RuntimeError("; ".join(([error] if error else []) + glfw_errors[:1]))
    for w in caught:  # re-emit unrelated warnings
        warnings.warn_explicit(w.message, w.category, w.filename, w.lineno)


def _probe(backend: str):
    """Return a working GLContext class for ``backend`` or raise with the reason."""
    had_opengl = "OpenGL" in sys.modules
    env_before = os.environ.get("PYOPENGL_PLATFORM")
    try:
        cls = _load_context_class(backend)
        _probe_context(cls)
        if env_before is None and os.environ.get("PYOPENGL_PLATFORM") is not None:
            _GL_STATE["pyopengl_env_ours"] = True
        return cls
    except BaseException as e:  # noqa: BLE001 - any failure means "this backend is unusable"
        if isinstance(e, KeyboardInterrupt):
            raise
        if not had_opengl and backend in ("egl", "osmesa"):
            # The failed probe was the first user of PyOpenGL: undo it so that the next
            # backend can initialise PyOpenGL for its own platform.
            _purge_pyopengl()
            if env_before is None:
                os.environ.pop("PYOPENGL_PLATFORM", None)
            else:
                os.environ["PYOPENGL_PLATFORM"] = env_before
        msg = str(e).strip().splitlines()[0] if str(e).strip() else ""
        if isinstance(e, AttributeError) and "NoneType" in msg and backend in ("egl", "osmesa"):
            # PyOpenGL's way of saying that it could not load the platform library.
            lib = {"egl": "libEGL", "osmesa": "libOSMesa"}[backend]
            raise RuntimeError(f"{lib} could not be loaded by PyOpenGL ({msg})") from e
        raise RuntimeError(f"{type(e).__name__}: {msg}"[:300]) from e


def ensure_gl() -> str:
    """Make ``mujoco.Renderer`` use a working offscreen GL context; returns the backend name.

    Called lazily by the render functions (cached after the first success). See the module
    docstring for the order tried. Raises ``RuntimeError`` naming every backend tried and why
    it failed, and how to choose one with ``MUJOCO_GL``.
    """
    if _GL_STATE["backend"] is not None:
        return _GL_STATE["backend"]
    try:
        import mujoco
        from mujoco.rendering.classic import gl_context
    except Exception as e:  # import mujoco itself fails for a MUJOCO_GL that cannot load
        raise RuntimeError(
            f"import mujoco failed with MUJOCO_GL={os.environ.get('MUJOCO_GL')!r} ({type(e).__name__}: "
            f"{e}); unset MUJOCO_GL or set it to a backend that exists here: 'egl' (GPU or Mesa "
            "EGL, headless), 'osmesa' (software) or 'glfw' (needs a display)") from e

    requested = os.environ.get("MUJOCO_GL", "").lower().strip()
    if requested in _DISABLED:
        raise RuntimeError(f"MUJOCO_GL={requested!r} disables rendering; unset it or set "
                           "MUJOCO_GL=egl (headless GPU/Mesa), osmesa (software) or glfw (display)")
    linux = sys.platform.startswith("linux")
    auto = requested in ("", "enable", "enabled", "on", "true", "1") or _GL_STATE["auto_env"]
    current = getattr(gl_context, "GLContext", None)
    if not linux:
        # macOS / Windows: mujoco's own choice (CGL / GLFW / WGL) is the only option.
        candidates = ["default"]
    elif auto:
        candidates = (["glfw"] if _has_display() else []) + ["egl", "osmesa"]
        if requested in ("egl", "osmesa"):  # set by headless_env: try that one first
            candidates.remove(requested)
            candidates.insert(0, requested)
    else:
        candidates = ["glfw" if requested == "glx" else requested]

    tried = []
    for backend in candidates:
        try:
            if backend == "default":
                if current is None:
                    raise RuntimeError("mujoco has no GLContext on this platform")
                try:
                    _probe_context(current)
                except Exception as e:  # noqa: BLE001
                    raise RuntimeError(f"{type(e).__name__}: {e}"[:300]) from e
                cls = current
            else:
                cls = _probe(backend)
        except RuntimeError as e:
            tried.append(f"{backend} ({e})")
            continue
        gl_context.GLContext = cls
        if hasattr(mujoco, "GLContext"):
            mujoco.GLContext = cls
        _GL_STATE["backend"] = backend
        return backend
    raise RuntimeError(
        "no offscreen OpenGL backend works in this process; tried: " + "; ".join(tried)
        + ". Set MUJOCO_GL before starting Python: 'egl' (GPU or Mesa EGL, headless), 'osmesa' "
        "(software, needs libOSMesa) or 'glfw' (needs a display), and check the GL libraries "
        "are installed (e.g. apt-get install libegl1 libosmesa6).")


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


# ----------------------------------------------------------------------------------------
# Vehicle model
# ----------------------------------------------------------------------------------------

def _one_theta(theta, what="theta") -> np.ndarray:
    theta = P.validate_theta(_host(theta, what), what=what)
    if theta.shape != (P.N_PARAMS,):
        raise ValueError(f"{what} must be one vehicle of shape ({P.N_PARAMS},); got {theta.shape}")
    return theta.astype(np.float64)


def vehicle_model(theta, *, base_xml=None) -> "mujoco.MjModel":
    """MuJoCo model of vehicle θ (19,) for rendering, from ``assets/quadrotor.xml`` (or
    ``base_xml``, a path or an XML string with the same named elements).

    Geometry scales with the arm length l: rotor i centred at l·ROTOR_DIRECTIONS[i] with disc
    radius 0.35 l, arm capsules through opposite rotors, hub box and nose sphere scaled by
    l / 0.184 m. Mass, inertia, rotor sites and actuator gear are set from θ too (they do not
    affect kinematic replay). Elements missing from ``base_xml`` are skipped; the body
    ``quadrotor`` with a free joint is required.
    """
    import mujoco

    theta = _one_theta(theta)
    if base_xml is None:
        spec = mujoco.MjSpec.from_file(str(ASSET))
    elif isinstance(base_xml, (str, os.PathLike)) and Path(base_xml).suffix == ".xml" \
            and Path(base_xml).is_file():
        spec = mujoco.MjSpec.from_file(str(base_xml))
    elif isinstance(base_xml, str) and base_xml.lstrip().startswith("<"):
        spec = mujoco.MjSpec.from_string(base_xml)
    else:
        raise ValueError(f"base_xml must be an existing .xml file or an MJCF string; got {base_xml!r}")
    body = spec.body("quadrotor")
    if body is None:
        raise ValueError("base_xml has no body named 'quadrotor'")

    arm = float(theta[P.ARM])
    s = arm / PAPER_ARM
    rotors = np.zeros((4, 3))
    rotors[:, :2] = arm * P.ROTOR_DIRECTIONS
    body.mass = float(theta[P.MASS])
    body.inertia = theta[P.INERTIA]
    body.explicitinertial = True

    def geom(name):
        return spec.geom(name)

    if (g := geom("hub")) is not None:
        g.size = np.array([0.04, 0.03, 0.015]) * s
    if (g := geom("nose")) is not None:
        g.size = np.array([0.012, 0.0, 0.0]) * s
        g.pos = np.array([0.045 * s, 0.0, 0.0])
    arm_radius = 0.006 * s
    for name, (a, b) in (("arm13", (0, 2)), ("arm24", (1, 3))):
        if (g := geom(name)) is not None:
            g.fromto = np.concatenate([rotors[a], rotors[b]])
            g.size = np.array([arm_radius, 0.0, 0.0])
    for i in range(4):
        if (g := geom(f"rotor{i + 1}")) is not None:
            g.pos = rotors[i] + np.array([0.0, 0.0, 0.012 * s])
            g.size = np.array([0.35 * arm, 0.004 * s, 0.0])
        if (site := spec.site(f"rotor{i + 1}")) is not None:
            site.pos = rotors[i]
    kappa = float(theta[P.KTAU] / theta[P.KT])
    for i in range(4):
        if (act := spec.actuator(f"thrust{i + 1}")) is not None:
            gear = np.array(act.gear, dtype=np.float64)
            gear[5] = float(P.YAW_SIGNS[i]) * kappa
            act.gear = gear
    _dress_scene(spec, body)
    model = spec.compile()
    _free_qpos_adr(model)  # fail early if there is no free joint
    return model


def _dress_scene(spec, body):
    """Rendering-only touches: a sky gradient instead of black, and the 'chase' camera aimed at
    the vehicle's initial position (it then keeps that offset: mode trackcom)."""
    import mujoco

    if not any(t.type == mujoco.mjtTexture.mjTEXTURE_SKYBOX for t in spec.textures):
        spec.add_texture(name="render_sky", type=mujoco.mjtTexture.mjTEXTURE_SKYBOX,
                         builtin=mujoco.mjtBuiltin.mjBUILTIN_GRADIENT, rgb1=[0.62, 0.76, 0.9],
                         rgb2=[0.97, 0.98, 1.0], width=64, height=384)
    cam = spec.camera("chase")
    if cam is None or cam.parent is None or cam.parent.name not in ("world", ""):
        return
    eye = np.asarray(cam.pos, np.float64)
    target = np.asarray(body.pos, np.float64)
    fwd = target - eye
    if np.linalg.norm(fwd) < 1e-6:
        return
    fwd /= np.linalg.norm(fwd)
    right = np.cross(fwd, [0.0, 0.0, 1.0])
    if np.linalg.norm(right) < 1e-6:
        return
    right /= np.linalg.norm(right)
    up = np.cross(right, fwd)
    cam.alt.type = mujoco.mjtOrientation.mjORIENTATION_XYAXES
    cam.alt.xyaxes = np.concatenate([right, up])


def _free_qpos_adr(model) -> int:
    import mujoco
    bid = mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_BODY, "quadrotor")
    if bid < 0:
        raise ValueError("model has no body named 'quadrotor'")
    for j in range(model.body_jntnum[bid]):
        jid = model.body_jntadr[bid] + j
        if model.jnt_type[jid] == mujoco.mjtJoint.mjJNT_FREE:
            return int(model.jnt_qposadr[jid])
    raise ValueError("body 'quadrotor' has no free joint")


# ----------------------------------------------------------------------------------------
# Input handling
# ----------------------------------------------------------------------------------------

def _host(x, what: str) -> np.ndarray:
    try:
        import jax
        if isinstance(x, jax.core.Tracer):
            raise TypeError(f"{what} is a traced JAX value: render functions run on the host; "
                            "call them outside jax.jit / vmap with concrete arrays")
    except ImportError:  # pragma: no cover
        pass
    return np.asarray(x, dtype=np.float64)


def _states(frames, what: str) -> tuple[np.ndarray, np.ndarray]:
    """(pos (T,3), quat (T,4)) from a Frame-like object or a (pos, quat) pair."""
    if hasattr(frames, "pos") and hasattr(frames, "quat"):
        pos, quat = frames.pos, frames.quat
    elif isinstance(frames, (tuple, list)) and len(frames) == 2:
        pos, quat = frames
    else:
        raise TypeError(f"{what} must be a mjxsysid.sim.Frame (or any object with .pos (T, 3) and "
                        f".quat (T, 4)) or a (pos, quat) pair; got {type(frames).__name__}")
    return _pos_quat(pos, quat, what)


def _pos_quat(pos, quat, what: str) -> tuple[np.ndarray, np.ndarray]:
    pos = _host(pos, f"{what} pos")
    quat = _host(quat, f"{what} quat")
    if pos.ndim == 1:
        pos = pos[None]
    if quat.ndim == 1:
        quat = quat[None]
    if pos.ndim != 2 or pos.shape[-1] != 3 or pos.shape[0] < 1:
        raise ValueError(f"{what}: pos must have shape (T, 3); got {pos.shape}")
    if quat.ndim != 2 or quat.shape[-1] != 4:
        raise ValueError(f"{what}: quat must have shape (T, 4) (wxyz); got {quat.shape}")
    if quat.shape[0] != pos.shape[0]:
        raise ValueError(f"{what}: pos has {pos.shape[0]} samples but quat has {quat.shape[0]} "
                         f"(shapes {pos.shape} and {quat.shape})")
    if not (np.all(np.isfinite(pos)) and np.all(np.isfinite(quat))):
        raise ValueError(f"{what}: pos/quat contain non-finite values")
    norm = np.linalg.norm(quat, axis=-1, keepdims=True)
    if np.any(norm < 1e-6):
        raise ValueError(f"{what}: quat contains a zero quaternion")
    return pos, quat / norm


def _ghost_list(ghosts, n: int | None):
    if ghosts is None:
        return []
    if not isinstance(ghosts, (list, tuple)):
        raise TypeError(f"ghosts must be a list of (theta_k, pos_k (T, 3), quat_k (T, 4)); "
                        f"got {type(ghosts).__name__}")
    out = []
    for k, g in enumerate(ghosts):
        if not isinstance(g, (list, tuple)) or len(g) != 3:
            raise TypeError(f"ghosts[{k}] must be a tuple (theta_k, pos_k (T, 3), quat_k (T, 4))")
        th = _one_theta(g[0], what=f"ghosts[{k}] theta")
        pos, quat = _pos_quat(g[1], g[2], f"ghosts[{k}]")
        if n is not None and pos.shape[0] != n:
            raise ValueError(f"ghosts[{k}]: pos has {pos.shape[0]} samples, the rollout has {n} "
                             f"(ghost pos shape {pos.shape}); sample ghosts on the same clock")
        out.append((th, pos, quat))
    return out


def _reference(reference) -> np.ndarray | None:
    if reference is None:
        return None
    if hasattr(reference, "pos"):
        reference = reference.pos
    ref = _host(reference, "reference")
    if ref.ndim != 2 or ref.shape[-1] != 3 or ref.shape[0] < 1:
        raise ValueError(f"reference must have shape (T, 3); got {ref.shape}")
    return ref


def _check_size(width, height):
    for name, v in (("width", width), ("height", height)):
        if int(v) != v or v < 16:
            raise ValueError(f"{name} must be an integer >= 16; got {v!r}")


# ----------------------------------------------------------------------------------------
# Scene
# ----------------------------------------------------------------------------------------

@dataclasses.dataclass
class _Ghost:
    model: Any
    data: Any
    adr: int
    pos: np.ndarray
    quat: np.ndarray
    rgba: np.ndarray


class _Scene:
    """A renderer for one true vehicle plus ghost vehicles, trail and reference line."""

    def __init__(self, theta, *, camera, width, height, ghosts, ghost_alpha, base_xml):
        import mujoco
        self.mj = mujoco
        self.model = vehicle_model(theta, base_xml=base_xml)
        names = [self.model.cam(i).name for i in range(self.model.ncam)]
        if isinstance(camera, str):
            if camera not in names:
                raise ValueError(f"unknown camera {camera!r}; available cameras: {names}")
            self.camera = names.index(camera)
        elif isinstance(camera, (int, np.integer)) and -1 <= int(camera) < self.model.ncam:
            self.camera = int(camera)
        else:
            raise ValueError(f"camera must be a camera name {names} or an index in "
                             f"[-1, {self.model.ncam}); got {camera!r}")
        if not 0.0 < ghost_alpha <= 1.0:
            raise ValueError(f"ghost_alpha must be in (0, 1]; got {ghost_alpha}")
        vis = self.model.vis.global_
        vis.offwidth = max(int(vis.offwidth), int(width))
        vis.offheight = max(int(vis.offheight), int(height))
        self.data = mujoco.MjData(self.model)
        self.adr = _free_qpos_adr(self.model)
        self.ghosts = []
        for k, (th, pos, quat) in enumerate(ghosts):
            gm = vehicle_model(th, base_xml=base_xml)
            rgba = np.array(GHOST_TINTS[k % len(GHOST_TINTS)] + (ghost_alpha,), np.float32)
            self.ghosts.append(_Ghost(gm, mujoco.MjData(gm), _free_qpos_adr(gm), pos, quat, rgba))
        self.opt = mujoco.MjvOption()
        self.pert = mujoco.MjvPerturb()
        self.renderer = mujoco.Renderer(self.model, height=int(height), width=int(width))

    def close(self):
        self.renderer.close()

    def __enter__(self):
        return self

    def __exit__(self, *exc):
        self.close()

    # ----------------------------------------------------------------------- drawing
    def _add_line(self, p0, p1, rgba, width):
        scn = self.renderer.scene
        if scn.ngeom >= scn.maxgeom:
            return
        g = scn.geoms[scn.ngeom]
        mj = self.mj
        mj.mjv_initGeom(g, mj.mjtGeom.mjGEOM_LINE, np.zeros(3), np.zeros(3), np.eye(3).ravel(),
                        np.asarray(rgba, np.float32))
        mj.mjv_connector(g, mj.mjtGeom.mjGEOM_LINE, width, np.asarray(p0, np.float64),
                         np.asarray(p1, np.float64))
        g.category = mj.mjtCatBit.mjCAT_DECOR
        scn.ngeom += 1

    def _add_polyline(self, pts, rgba, width, fade=False):
        n = len(pts) - 1
        for i in range(n):
            c = np.array(rgba, np.float32)
            if fade:
                c[3] *= 0.15 + 0.85 * (i + 1) / n
            self._add_line(pts[i], pts[i + 1], c, width)

    def draw(self, pos, quat, i, *, trail_pts=None, ref_pts=None, line_scale=1.0):
        mj = self.mj
        self.data.qpos[self.adr:self.adr + 3] = pos
        self.data.qpos[self.adr + 3:self.adr + 7] = quat
        mj.mj_forward(self.model, self.data)
        self.renderer.update_scene(self.data, camera=self.camera)
        scn = self.renderer.scene
        for gh in self.ghosts:
            gh.data.qpos[gh.adr:gh.adr + 3] = gh.pos[i]
            gh.data.qpos[gh.adr + 3:gh.adr + 7] = gh.quat[i]
            mj.mj_kinematics(gh.model, gh.data)
            n0 = scn.ngeom
            mj.mjv_addGeoms(gh.model, gh.data, self.opt, self.pert,
                            int(mj.mjtCatBit.mjCAT_DYNAMIC), scn)
            for j in range(n0, scn.ngeom):
                g = scn.geoms[j]
                rgb = 0.3 * np.asarray(g.rgba[:3]) + 0.7 * gh.rgba[:3]
                g.rgba = np.concatenate([rgb, gh.rgba[3:]]).astype(np.float32)
        if ref_pts is not None and len(ref_pts) > 1:
            self._add_polyline(ref_pts, REFERENCE_RGBA, 1.5 * line_scale)
        if trail_pts is not None and len(trail_pts) > 1:
            self._add_polyline(trail_pts, TRAIL_RGBA, 2.0 * line_scale, fade=True)
        return self.renderer.render()


def _decimate(pts: np.ndarray, max_points: int) -> np.ndarray:
    if len(pts) <= max_points:
        return pts
    idx = np.unique(np.linspace(0, len(pts) - 1, max_points).round().astype(int))
    return pts[idx]


def _trail_seconds(trail) -> float:
    if trail is True:
        return 2.0
    if trail is False or trail is None:
        return 0.0
    if isinstance(trail, (int, float)) and trail >= 0:
        return float(trail)
    raise ValueError(f"trail must be a bool or a duration in seconds >= 0; got {trail!r}")


# ----------------------------------------------------------------------------------------
# Public API
# ----------------------------------------------------------------------------------------

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
