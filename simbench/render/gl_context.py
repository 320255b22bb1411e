"""Off-screen OpenGL context on a CPU (EGL on Mesa llvmpipe, or OSMesa).

The platform classes come from pyrender (``pyrender.platforms``): they own the
EGL/OSMesa handshake, which is the part of pyrender we reuse. ``PYOPENGL_PLATFORM``
must be set before PyOpenGL is first imported, so :func:`configure_gl_environment`
runs at import time of :mod:`simbench.render` (and only sets variables the user has
not set).
"""

from __future__ import annotations

import ctypes.util
import os

from simbench.errors import GLUnavailableError

_FIX = (
    "Off-screen rendering needs EGL (Mesa's libEGL with llvmpipe: Debian/Ubuntu packages "
    "libegl1 libgl1-mesa-dri) or OSMesa (package libosmesa6). Try: "
    "`export MUJOCO_GL=egl PYOPENGL_PLATFORM=egl`, or install OSMesa with "
    "`sudo apt-get install -y libosmesa6` and `export MUJOCO_GL=osmesa PYOPENGL_PLATFORM=osmesa`."
)


def configure_gl_environment() -> str:
    """Choose the GL platform for PyOpenGL and MuJoCo; return it (``egl`` or ``osmesa``).

    Respects ``PYOPENGL_PLATFORM`` / ``MUJOCO_GL`` if the user set them; otherwise EGL.
    The two must agree, because both libraries end up in one process.
    """
    platform = os.environ.get("PYOPENGL_PLATFORM") or os.environ.get("MUJOCO_GL") or "egl"
    if platform not in ("egl", "osmesa"):
        raise GLUnavailableError(
            f"PYOPENGL_PLATFORM/MUJOCO_GL is {platform!r}; simbench renders off-screen and supports "
            f"'egl' or 'osmesa'. {_FIX}"
        )
    os.environ.setdefault("PYOPENGL_PLATFORM", platform)
    os.environ.setdefault("MUJOCO_GL", platform)
    return platform


#: The native library each platform loads (PyOpenGL and MuJoCo find it by this name).
_LIBRARIES = {"egl": "EGL", "osmesa": "OSMesa"}


def check_requested_platform() -> None:
    """If ``PYOPENGL_PLATFORM`` or ``MUJOCO_GL`` names a platform, its native library must be
    installed: a :class:`GLUnavailableError` now, instead of PyOpenGL's ``AttributeError``
    when MuJoCo is first imported (every ``simbench`` command imports it)."""
    for variable in ("MUJOCO_GL", "PYOPENGL_PLATFORM"):  # MuJoCo and PyOpenGL each load the one they are told
        platform = os.environ.get(variable)
        if platform in _LIBRARIES and ctypes.util.find_library(_LIBRARIES[platform]) is None:
            raise GLUnavailableError(f"{variable}={platform} but lib{_LIBRARIES[platform]}.so is not installed. {_FIX}")


class GLContext:
    """An off-screen GL 4.1 core context of a given default framebuffer size."""

    def __init__(self, width: int = 640, height: int = 480) -> None:
        platform = configure_gl_environment()
        try:
            # only the platform in use is imported: the other's native library may be missing
            if platform == "egl":
                from pyrender.platforms.egl import EGLPlatform, get_default_device

                self._platform = EGLPlatform(width, height, device=get_default_device())
            else:
                from pyrender.platforms.osmesa import OSMesaPlatform

                self._platform = OSMesaPlatform(width, height)
            self._platform.init_context()
            self._platform.make_current()
        except Exception as exc:  # any failure of the native GL stack
            raise GLUnavailableError(
                f"could not create an off-screen OpenGL context with PYOPENGL_PLATFORM={platform!r} "
                f"({type(exc).__name__}: {exc}). {_FIX}"
            ) from exc
        self.platform_name = platform

    def make_current(self) -> None:
        self._platform.make_current()

    def close(self) -> None:
        try:
            self._platform.delete_context()
        except Exception:
            pass
