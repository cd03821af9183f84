"""Shared test set-up: headless offscreen rendering through Mesa's EGL.

MuJoCo picks its OpenGL backend when it is first imported, so this has to run before any test
module imports mujoco (``import safemanip`` sets the same default; a user's own choice wins).
"""

import os

os.environ.setdefault("MUJOCO_GL", "egl")
