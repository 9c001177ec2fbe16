"""Shared test set-up: offscreen rendering (EGL or OSMesa, chosen once), no progress bars."""
import os

os.environ.setdefault("PYVISTA_OFF_SCREEN", "true")
os.environ.setdefault("TQDM_DISABLE", "1")

from electrosense.meshes.render import offscreen_backend  # noqa: E402  (after the environment above)

offscreen_backend()  # probed once here; worker processes inherit the choice
