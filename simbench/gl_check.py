"""``python -m simbench.gl_check``: can this machine render off-screen? Exit 0 if yes.

Creates a GL context with the configured platform (EGL unless MUJOCO_GL /
PYOPENGL_PLATFORM say otherwise), renders one triangle and checks the pixels; also
checks MuJoCo's renderer on the same platform (both live in one simbench process).
"""

from __future__ import annotations

import sys

import numpy as np

from simbench.errors import GLUnavailableError


def check() -> str:
    # PyOpenGL and MuJoCo read their platform when first imported: configure it before loading them
    from simbench.render.gl_context import configure_gl_environment

    platform = configure_gl_environment()
    from simbench.render.rasterizer import GeometryBuffers, Rasterizer

    tri = GeometryBuffers(
        positions=np.array([[-1, -1, 0], [1, -1, 0], [0, 1, 0]], np.float32),
        normals=np.array([[0, 0, -1]] * 3, np.float32), albedo=np.ones((3, 3), np.float32),
        ids=np.full(3, 7, np.int32), retro=np.zeros(3, np.float32), faces=np.array([[0, 1, 2]], np.uint32))
    K = np.array([[32.0, 0, 31.5], [0, 32.0, 31.5], [0, 0, 1]])
    with Rasterizer() as r:
        r.set_static(tri)
        out = r.render(64, 64, K, np.eye(3), np.array([0, 0, 3.0]), [], np.ones(3))
    if out["ids"][32, 32] != 7 or not out["radiance"][32, 32].sum() > 0:
        raise RuntimeError("GL context made, but the test triangle did not render")
    import mujoco

    m = mujoco.MjModel.from_xml_string("<mujoco><worldbody><geom type='sphere' size='.1'/></worldbody></mujoco>")
    with mujoco.Renderer(m, 16, 16) as mr:
        mr.update_scene(mujoco.MjData(m))
        mr.render()
    return platform


def main() -> int:
    try:
        platform = check()
    except GLUnavailableError as exc:
        print(f"gl_check: {exc}", file=sys.stderr)
        return 2
    except Exception as exc:  # a driver that half-works
        print(f"gl_check: rendering failed ({type(exc).__name__}: {exc}). Try MUJOCO_GL=osmesa PYOPENGL_PLATFORM=osmesa "
              "after `sudo apt-get install -y libosmesa6`.", file=sys.stderr)
        return 2
    print(f"off-screen GL works ({platform})")
    return 0


if __name__ == "__main__":
    sys.exit(main())
