"""The MuJoCo digital twin of the LRM room.

The twin is headless: unless the environment says otherwise, MuJoCo and PyOpenGL
render through EGL. Set here, before any module of this package imports dm_control
or mujoco (which choose their backend once, at import), so every command and worker
that builds a twin renders off-screen without ``MUJOCO_GL=egl`` in its environment.
"""

import os

os.environ.setdefault("MUJOCO_GL", "egl")
if os.environ["MUJOCO_GL"] in ("egl", "osmesa"):
    os.environ.setdefault("PYOPENGL_PLATFORM", os.environ["MUJOCO_GL"])
