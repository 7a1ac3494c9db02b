"""The vehicle drawn for rendering: a MuJoCo model of θ (arms, rotors and hub sized from θ), and
the scene that replays a rollout kinematically with ghosts, a trail and the reference."""
from __future__ import annotations

import dataclasses
import os
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from mjxsysid import theta as P

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
        # no multisampling and no floor reflection (a second pass of the whole scene): on a CPU's
        # software OpenGL (Mesa) the two cost ~40 % of each frame's time, for a look that is the
        # same at video size but for slightly harder line edges (shadows kept); BENCHMARKS.md
        self.model.vis.quality.offsamples = 0
        self.model.mat_reflectance[:] = 0.0
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
