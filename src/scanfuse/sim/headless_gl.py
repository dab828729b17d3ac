"""Pick a headless OpenGL for MuJoCo's renderer, before MuJoCo is imported.

MuJoCo reads `MUJOCO_GL` once, when it is imported, and a backend whose system
library is missing fails at that import. So the choice is probed in a child
process: where EGL or OSMesa works, depth images come from `mujoco.Renderer`
(several times faster); elsewhere the simulator casts one ray per pixel with
`mj_multiRay`, which needs no system library.
"""

from __future__ import annotations

import logging
import os
import subprocess
import sys

logger = logging.getLogger(__name__)

HEADLESS_BACKENDS = ('egl', 'osmesa')
_PROBE = (
    'import mujoco\n'
    'model = mujoco.MjModel.from_xml_string(\'<mujoco><worldbody><geom size="1"/>'
    "</worldbody></mujoco>')\n"
    'renderer = mujoco.Renderer(model, 8, 8)\n'
    'renderer.enable_depth_rendering()\n'
    'renderer.render()\n'
)


def probe(backend: str, timeout: float = 60.0) -> bool:
    """Whether MuJoCo can render depth with `backend` on this machine (in a child process)."""
    return probe_output(backend, timeout)[0]


def probe_output(backend: str, timeout: float = 60.0) -> tuple[bool, str]:
    """(works, what the child printed on stderr) of the depth-rendering probe."""
    env = {**os.environ, 'MUJOCO_GL': backend, 'PYOPENGL_PLATFORM': backend}
    try:
        result = subprocess.run(  # noqa: S603 - our own interpreter and a fixed script
            [sys.executable, '-c', _PROBE],
            env=env,
            capture_output=True,
            text=True,
            timeout=timeout,
            check=False,
        )
    except (OSError, subprocess.TimeoutExpired) as err:
        return False, str(err)
    return result.returncode == 0, result.stderr


def choose_headless_gl() -> str | None:
    """Set MUJOCO_GL to a working headless backend if none is set; return the one in use.

    Leaves an explicit MUJOCO_GL alone, and changes nothing once MuJoCo is imported.
    """
    current = os.environ.get('MUJOCO_GL')
    if current or 'mujoco' in sys.modules:
        return current or None
    for backend in HEADLESS_BACKENDS:
        if probe(backend):
            os.environ['MUJOCO_GL'] = backend
            os.environ.setdefault('PYOPENGL_PLATFORM', backend)
            logger.info('depth images through mujoco.Renderer (MUJOCO_GL=%s)', backend)
            return backend
    logger.info('no headless OpenGL: depth images by ray casting (mj_multiRay)')
    return None
