"""A disk cache for pose-invariant BEM blocks (the sensor's LU factors, the tank's), shared between processes.

The sensor's own block depends only on its mesh (in the sensor frame) and on
the column coefficients (conductivity, contact impedance, scale); the tank's
(and fixed objects') only on its mesh and coefficients. Their LU
factorisations are the most expensive steps of a tank sweep (O(N^3));
reading them back from disk is O(N^2). Entries are ``.npy`` files in a folder named by
a SHA-256 of every input array (and a format version), written to a
temporary name and renamed, so that a crash or a concurrent writer never
leaves a half-written entry that a reader would trust.

The default folder is the user's cache directory (``platformdirs``), e.g.
``~/.cache/electrosense/bem-blocks`` on Linux; set ``ESENSE_CACHE_DIR`` to
move it. An entry of an ``angels-4`` default mesh is about 0.27 GB, a tank's of 4 000 triangles 0.13 GB
(float64 factors: its solves are not refined); delete the folder to reclaim the space.

Example
-------
>>> import numpy as np, tempfile
>>> from electrosense.bem.block_cache import BlockCache
>>> cache = BlockCache(tempfile.mkdtemp())
>>> key = cache.key(np.arange(6.0))
>>> cache.load(key, ("lu",)) is None
True
>>> cache.save(key, {"lu": np.eye(2)})
>>> cache.load(key, ("lu",))[0].tolist()
[[1.0, 0.0], [0.0, 1.0]]
"""
from __future__ import annotations

import functools
import hashlib
import os
import shutil
import tempfile
import warnings
from pathlib import Path

import numpy as np

__all__ = ["BlockCache", "CACHE_MIN_TRIANGLES", "default_cache_dir", "model_source_files", "source_digest"]

#: sensor meshes with fewer triangles are factorised afresh (under a second on 2 cores: not worth a disk entry;
#: 3 800 triangles take 2.5 s to assemble and factorise, 0.1 s to read back from a 58 MB entry)
CACHE_MIN_TRIANGLES = 3000

_FORMAT = b"bem-sensor-block-v2"  # v2: float32 LU factors


def cache_root() -> Path:
    """Where every electrosense cache lives: ``$ESENSE_CACHE_DIR``, else the platform's user cache directory.

    >>> import os
    >>> from unittest import mock
    >>> with mock.patch.dict(os.environ, {"ESENSE_CACHE_DIR": "/tmp/esense-example"}):
    ...     str(cache_root())
    '/tmp/esense-example'
    """
    root = os.environ.get("ESENSE_CACHE_DIR")
    if not root:
        import platformdirs

        root = platformdirs.user_cache_dir("electrosense")
    return Path(root)


def model_source_files(packages=("meshes", "bem")) -> list[tuple[str, Path]]:
    """``(name, path)`` of every ``.py`` file of the named packages of electrosense, wherever they are installed,
    named from the package down (``"bem/sweep.py"``).

    >>> names = [name for name, _ in model_source_files()]
    >>> "bem/sweep.py" in names and "meshes/tank.py" in names
    True
    """
    import importlib

    out = []
    for package in packages:
        root = Path(importlib.import_module(f"electrosense.{package}").__path__[0])
        out += [(f"{package}/{p.relative_to(root).as_posix()}", p) for p in sorted(root.rglob("*.py"))]
    return out


@functools.lru_cache(maxsize=4)
def source_digest(packages=("meshes", "bem")) -> str:
    """SHA-256 (hex) of the names and bytes of :func:`model_source_files`: what a stored result was made by."""
    digest = hashlib.sha256()
    for name, path in model_source_files(packages):
        digest.update(name.encode())
        digest.update(path.read_bytes())
    return digest.hexdigest()


def default_cache_dir() -> Path:
    """The sensor blocks' folder: ``bem-blocks`` under :func:`cache_root`."""
    return cache_root() / "bem-blocks"


class BlockCache:
    """Named arrays stored under a content hash, in ``folder`` (default: :func:`default_cache_dir`)."""

    def __init__(self, folder=None):
        self.folder = Path(folder) if folder is not None else default_cache_dir()

    @staticmethod
    def key(*arrays: np.ndarray) -> str:
        """SHA-256 of the arrays' dtypes, shapes and bytes (and the cache format)."""
        h = hashlib.sha256(_FORMAT)
        for a in arrays:
            a = np.ascontiguousarray(a)
            h.update(str((a.dtype.str, a.shape)).encode())
            h.update(a.tobytes())
        return h.hexdigest()

    def load(self, key: str, names) -> tuple | None:
        """The arrays ``names`` of entry ``key``, or ``None`` when the entry is missing or unreadable."""
        entry = self.folder / key
        try:
            return tuple(np.load(entry / f"{name}.npy", allow_pickle=False) for name in names)
        except (OSError, ValueError):
            return None

    def save(self, key: str, arrays: dict) -> None:
        """Store ``arrays`` (name -> array) as entry ``key``; a cache that cannot be written only warns."""
        entry = self.folder / key
        need = sum(np.asarray(a).nbytes for a in arrays.values()) + 2**20
        try:
            self.folder.mkdir(parents=True, exist_ok=True)
            if shutil.disk_usage(self.folder).free < 2 * need:
                warnings.warn(f"BEM block cache: not enough free disk space in {self.folder} "
                              f"for {need / 1e9:.2f} GB; not cached", RuntimeWarning, stacklevel=3)
                return
            tmp = Path(tempfile.mkdtemp(prefix=f".{key[:12]}-", dir=self.folder))
            for name, a in arrays.items():
                np.save(tmp / f"{name}.npy", np.asarray(a), allow_pickle=False)
            try:
                os.replace(tmp, entry)
            except OSError:   # another process stored the same entry meanwhile
                shutil.rmtree(tmp, ignore_errors=True)
        except OSError as exc:
            warnings.warn(f"BEM block cache: cannot write {entry} ({exc}); not cached", RuntimeWarning, stacklevel=3)
