"""Shared test set-up: offscreen rendering (EGL or OSMesa, chosen once), no progress bars, the checkout off sys.path."""
import os
import sys
from pathlib import Path

# `python -m pytest` puts the working directory on sys.path, plain `pytest` does not: with the checkout's root
# there, `import bem` would find the source folder beside the installed `electrosense.bem`. Taken off, both
# invocations see only the installed package, as a user's code does (tests/test_readme_commands.py).
CHECKOUT = Path(__file__).resolve().parents[1]
sys.path[:] = [p for p in sys.path if Path(p or ".").resolve() != CHECKOUT]

os.environ.setdefault("PYVISTA_OFF_SCREEN", "true")
os.environ.setdefault("TQDM_DISABLE", "1")

from electrosense.meshes.render import offscreen_backend  # noqa: E402  (after the environment above)

offscreen_backend()  # probed once here; worker processes inherit the choice
