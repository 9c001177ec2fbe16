"""Shared test set-up: offscreen rendering (EGL or OSMesa, chosen once), no progress bars."""
import os

import pytest

os.environ.setdefault("PYVISTA_OFF_SCREEN", "true")
os.environ.setdefault("TQDM_DISABLE", "1")

from meshes.render import can_render_3d  # noqa: E402  (after the environment above)

#: for tests that draw 3D pictures: skipped, saying why, where VTK has no offscreen OpenGL
needs_3d = pytest.mark.skipif(not can_render_3d(), reason="no offscreen OpenGL (EGL or OSMesa) for VTK here")
