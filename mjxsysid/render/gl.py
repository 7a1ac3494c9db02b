"""Choosing the OpenGL backend for offscreen rendering (EGL, OSMesa, or GLFW with a display).

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
import os
import sys
import warnings
from typing import Any

_DISABLED = ("disable", "disabled", "off", "false", "0")


_GL_STATE: dict[str, Any] = {"backend": None, "auto_env": False}


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
