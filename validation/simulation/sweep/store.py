"""The sweep store: conductance matrices of many poses in a chunked zarr store, written chunk by chunk.

Why zarr (and not netCDF)
-------------------------
A sweep is long, embarrassingly parallel, and may be killed. Zarr keeps every
chunk in its own object (a file in a folder), so a finished chunk is durable
the moment it is written, chunks can be written in any order and by several
writers without touching the others, and nothing has to be rewritten or
closed at the end: a killed sweep leaves a valid store that says which chunks
are done. A netCDF/HDF5 file is one file with one writer and a global index;
a crash during a write can spoil the whole file, and the netCDF library
installed here (netCDF3 through scipy) has no chunking at all. Zarr stores open
with ``xarray.open_zarr`` like any netCDF file; :func:`export_netcdf` writes
a finished sweep as netCDF for tools that want one file.

Layout (``xarray.open_zarr(path)``)
-----------------------------------
dimensions ``pose``, ``electrode`` (1..n, the current's electrode),
``driven`` (1..n, the electrode at 1 V), ``receiver`` (receiver numbers):

* coordinates ``x_m``, ``y_m``, ``z_m``, ``yaw_rad`` (pose): the poses, tank frame;
* ``K_S`` (pose, electrode, driven): nodal conductance matrices (S);
* ``I_A`` (pose, receiver): receiver currents at U = 1 V (A, into the receiver);
* ``R_ohm`` (pose, receiver): U / I (ohm);
* ``computed`` (pose): 1 where the pose's chunk has been computed.

A sweep run with ``--skip-blocked`` holds NaN in ``K_S``, ``I_A`` and ``R_ohm`` at the poses its model
does not reach (the sensor beyond a wall or into an object...), computed all the same; the attribute
``blocked_poses`` counts them (:attr:`SweepStore.reached`).

Attributes: ``format`` (``"esense-sweep 1"``), ``model``, ``sensor``,
``tank_m``, ``water_depth_m``, ``objects``, ``sigma_S_per_m``, ``emitter``,
``model_options`` (mesh parameters, PSM images...), ``mesh`` (what the model
reported: triangles...), ``code_version``, ``grid`` (when the poses are a
grid), ``fingerprint`` (what makes two sweeps the same computation).

Example
-------
>>> import numpy as np
>>> from electrosense.validation.simulation.sweep.store import SweepStore
>>> poses = np.zeros((10, 4)); poses[:, 0] = np.linspace(-0.2, 0.2, 10)
>>> store = SweepStore.open_or_create("demo.zarr", poses, n_electrodes=2, emitter=2,
...                                   identity={"model": "demo"}, chunk_poses=4)  # doctest: +SKIP
>>> store.pending_chunks()  # doctest: +SKIP
[(0, 4), (4, 8), (8, 10)]
"""
from __future__ import annotations

import hashlib
import json
import shutil
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from electrosense.bem.conductance import ConductanceMatrix

__all__ = ["STORE_FORMAT", "StoreError", "SweepStore", "open_sweep", "as_map", "export_netcdf", "fingerprint"]

STORE_FORMAT = "esense-sweep 1"


class StoreError(ValueError):
    """A sweep store that cannot be used as asked (a different sweep, unfinished, damaged)."""


def _json_default(value):
    if isinstance(value, np.ndarray):
        return value.tolist()
    if isinstance(value, (np.integer, np.floating)):
        return value.item()
    if isinstance(value, Path):
        return str(value)
    return repr(value)


def _as_json(value) -> str:
    return json.dumps(value, sort_keys=True, default=_json_default)


def fingerprint(identity: dict, poses: np.ndarray) -> str:
    """A hash of what defines a sweep: the model, scene, options, code version, and the poses."""
    digest = hashlib.sha256(_as_json(identity).encode())
    digest.update(np.ascontiguousarray(poses, dtype="<f8").tobytes())
    return digest.hexdigest()[:32]


@dataclass
class SweepStore:
    """A zarr sweep store on disk; open one with :meth:`open_or_create`."""

    path: Path
    n_poses: int
    chunk_poses: int
    n_electrodes: int
    emitter: int

    # ---------------------------------------------------------------- creation
    @classmethod
    def open_or_create(
        cls,
        path,
        poses: np.ndarray,
        n_electrodes: int,
        emitter: int,
        identity: dict,
        chunk_poses: int,
        attrs: dict | None = None,
    ) -> "SweepStore":
        """Open the store at ``path`` to resume it, or create it.

        Parameters
        ----------
        path : str or Path
            The ``.zarr`` folder.
        poses : array (P, 4)
        n_electrodes, emitter : int
        identity : dict
            What defines the computation (model, scene, options, code version).
            An existing store is resumed only if its identity and poses match.
        chunk_poses : int
            Poses per stored chunk (an existing store keeps its own).
        attrs : dict, optional
            More attributes that do not define the computation (command line, grid).
        """
        path = Path(path)
        poses = np.asarray(poses, dtype=float)
        fp = fingerprint(identity, poses)
        if path.exists():
            return cls._open_existing(path, fp, identity)
        return cls._create(path, poses, n_electrodes, emitter, identity, int(chunk_poses), fp, attrs or {})

    @classmethod
    def _open_existing(cls, path: Path, fp: str, identity: dict) -> "SweepStore":
        import zarr

        try:
            group = zarr.open_group(str(path), mode="r")
            stored = dict(group.attrs)
        except Exception as exc:
            raise StoreError(f"{path} exists but is not a readable zarr store ({exc}); remove it or choose another output") from None
        if stored.get("format") != STORE_FORMAT:
            raise StoreError(f"{path} exists but is not an esense sweep store; remove it or choose another output")
        if stored.get("fingerprint") != fp:
            old = json.loads(stored.get("identity", "{}"))
            new = json.loads(_as_json(identity))
            differ = sorted(k for k in set(old) | set(new) if old.get(k) != new.get(k)) or ["poses"]
            raise StoreError(
                f"{path} holds a different sweep (differs in: {', '.join(differ)}); "
                "it cannot be resumed with these settings: remove it or choose another output"
            )
        K = group["K_S"]
        return cls(path, int(K.shape[0]), int(K.chunks[0]), int(K.shape[1]), int(stored["emitter"]))

    @classmethod
    def _create(cls, path, poses, n_electrodes, emitter, identity, chunk_poses, fp, attrs) -> "SweepStore":
        """The empty store, written with zarr alone in the layout ``xarray.to_zarr`` gives (zarr format 2,
        ``_ARRAY_DIMENSIONS``, consolidated metadata): importing xarray and dask to write a few metadata files
        cost a fast model's sweep of 10 000 poses more than the poses themselves."""
        import zarr

        if chunk_poses < 1:
            raise StoreError(f"chunk_poses must be a positive number of poses, got {chunk_poses}")
        P, n = len(poses), int(n_electrodes)
        receivers = [k for k in range(1, n + 1) if k != emitter]
        chunks = (min(chunk_poses, max(P, 1)),)
        all_attrs = {k: (v if isinstance(v, (str, int, float, bool)) else _as_json(v)) for k, v in attrs.items()}
        all_attrs.update(
            {
                "format": STORE_FORMAT,
                "emitter": int(emitter),
                "fingerprint": fp,
                "identity": _as_json(identity),
                "convention": (
                    "K_S[pose, i, j]: current (A) leaving electrode i into the water with electrode j at 1 V, "
                    "others at 0 V; I_A: receiver currents (into the receiver) with the emitter 1 V above the "
                    "receivers; R_ohm = 1 V / I_A; electrodes 1-based from the head"
                ),
            }
        )
        for key, value in identity.items():
            all_attrs[key] = value if isinstance(value, (str, int, float, bool)) else _as_json(value)
        if Path(path).exists():
            raise StoreError(f"{path} exists; remove it or choose another output")
        group = zarr.open_group(str(path), mode="w-", zarr_format=2)
        group.attrs.update(all_attrs)
        coords = "x_m y_m yaw_rad z_m"

        def array(name, dims, data=None, shape=None, dtype="<f8", fill=np.nan, **attributes):
            shape = np.shape(data) if data is not None else shape
            # uncompressed: float64 conductances hardly compress, and compressing costs a fast model ~20 % more
            a = group.create_array(name, shape=shape, chunks=(chunks[0] if dims[0] == "pose" else shape[0],)
                                   + tuple(shape[1:]), dtype=dtype, fill_value=fill, compressors=None,
                                   attributes={**attributes, "_ARRAY_DIMENSIONS": list(dims)})
            if data is not None:
                a[...] = data

        array("K_S", ("pose", "electrode", "driven"), shape=(P, n, n), units="S", coordinates=coords)
        array("I_A", ("pose", "receiver"), shape=(P, n - 1), units="A", long_name="receiver current at U = 1 V",
              coordinates=coords)
        array("R_ohm", ("pose", "receiver"), shape=(P, n - 1), units="ohm", long_name="U / I", coordinates=coords)
        array("computed", ("pose",), np.zeros(P, dtype="i1"), dtype="|i1", fill=None, long_name="1 where computed",
              coordinates=coords)
        array("pose", ("pose",), np.arange(P, dtype="<i8"), dtype="<i8", fill=None)
        for name in ("electrode", "driven"):
            array(name, (name,), np.arange(1, n + 1, dtype="<i8"), dtype="<i8", fill=None)
        array("receiver", ("receiver",), np.asarray(receivers, dtype="<i8"), dtype="<i8", fill=None)
        for k, (name, unit) in enumerate((("x_m", "m"), ("y_m", "m"), ("z_m", "m"), ("yaw_rad", "rad"))):
            array(name, ("pose",), np.ascontiguousarray(poses[:, k]), units=unit)
        zarr.consolidate_metadata(str(path), zarr_format=2)
        return cls(Path(path), P, chunks[0], n, int(emitter))

    # ------------------------------------------------------------------- state
    def _group(self, mode="r+"):
        import zarr

        return zarr.open_group(str(self.path), mode=mode)

    @property
    def chunks(self) -> list[tuple[int, int]]:
        """(start, stop) of every stored chunk, in pose order."""
        starts = range(0, self.n_poses, self.chunk_poses)
        return [(a, min(a + self.chunk_poses, self.n_poses)) for a in starts]

    @property
    def computed(self) -> np.ndarray:
        """(P,) bool: the poses already computed."""
        return np.asarray(self._group("r")["computed"][:]).astype(bool)

    def pending_chunks(self) -> list[tuple[int, int]]:
        """The chunks (start, stop) still to compute."""
        done = self.computed
        return [(a, b) for a, b in self.chunks if not done[a:b].all()]

    @property
    def attrs(self) -> dict:
        return dict(self._group("r").attrs)

    # ------------------------------------------------------------------ writes
    def write_chunk(self, start: int, K_S: np.ndarray) -> None:
        """Store the matrices (m, n, n) of the chunk starting at ``start``; mark it computed last."""
        K = np.asarray(K_S, dtype=float)
        stop = start + len(K)
        if start % self.chunk_poses or not (stop == self.n_poses or stop % self.chunk_poses == 0):
            raise StoreError(f"poses {start}:{stop} do not cover whole chunks of {self.chunk_poses} poses")
        reached = np.isfinite(K).all(axis=(1, 2))     # NaN rows: poses the model did not reach (--skip-blocked)
        I = np.full((len(K), K.shape[1] - 1), np.nan)
        if reached.any():
            I[reached] = ConductanceMatrix(K[reached], self.emitter, 1.0).receiver_currents_A(1.0)
        group = self._group()
        group["K_S"][start:stop] = K
        group["I_A"][start:stop] = I
        group["R_ohm"][start:stop] = 1.0 / I
        group["computed"][start:stop] = np.ones(stop - start, dtype="i1")  # after the data: a crash in between recomputes

    def update_attrs(self, **attrs) -> None:
        """Add attributes (e.g. the mesh the model reported after its first pose)."""
        import zarr

        group = self._group()
        group.attrs.update({k: (v if isinstance(v, (str, int, float, bool)) else _as_json(v)) for k, v in attrs.items()})
        zarr.consolidate_metadata(str(self.path))

    # ------------------------------------------------------------------- reads
    def dataset(self):
        """The store as an ``xarray.Dataset`` (lazy)."""
        return open_sweep(self.path)

    @property
    def reached(self) -> np.ndarray:
        """(P,) bool: the computed poses the model reached (finite matrices; a ``--skip-blocked`` sweep leaves
        NaN at the others)."""
        K = np.asarray(self._group("r")["K_S"][:])
        return self.computed & np.isfinite(K).all(axis=(1, 2))

    def conductance(self, sigma_S_per_m: float, reached_only: bool = False) -> ConductanceMatrix:
        """All matrices as one ConductanceMatrix of batch shape (P,); the sweep must be complete. A sweep with
        poses its model did not reach is refused unless ``reached_only``, which gives those it reached
        (:attr:`reached`) in pose order."""
        group = self._group("r")
        done = np.asarray(group["computed"][:]).astype(bool)
        if not done.all():
            raise StoreError(f"{self.path}: {np.count_nonzero(~done)} of {done.size} poses are not computed yet")
        K = np.asarray(group["K_S"][:])
        reached = np.isfinite(K).all(axis=(1, 2))
        if not reached.all() and not reached_only:
            raise StoreError(f"{self.path}: the model did not reach {np.count_nonzero(~reached)} of {reached.size} "
                             "poses (NaN); take the others with reached_only=True")
        return ConductanceMatrix(K[reached], self.emitter, sigma_S_per_m, self.attrs)


def open_sweep(path):
    """Open a sweep store (``.zarr``) or an exported sweep (``.nc``) as an ``xarray.Dataset``."""
    import xarray as xr

    path = Path(path)
    if not path.exists():
        raise StoreError(f"{path}: no such sweep")
    if path.suffix == ".nc":
        return xr.open_dataset(path)
    return xr.open_zarr(str(path))


def as_map(ds):
    """A grid sweep reshaped to dimensions (yaw_rad, y_m, x_m): a tank map per heading.

    >>> m = as_map(open_sweep("tank_map.zarr"))  # doctest: +SKIP
    >>> m.R_ohm.sel(receiver=1).isel(yaw_rad=0).plot()  # doctest: +SKIP
    """
    from electrosense.validation.simulation.sweep.grid import PoseGrid

    if "grid" not in ds.attrs:
        raise StoreError("this sweep is not a grid (it has no 'grid' attribute): it cannot be shown as a tank map")
    grid = PoseGrid.from_dict(ds.attrs["grid"])
    n_yaw, n_y, n_x = grid.shape
    data = {}
    for name in ("K_S", "I_A", "R_ohm", "computed"):
        v = ds[name]
        dims = ("yaw_rad", "y_m", "x_m") + v.dims[1:]
        data[name] = (dims, np.asarray(v.values).reshape((n_yaw, n_y, n_x) + v.shape[1:]), v.attrs)
    import xarray as xr

    coords = {
        "yaw_rad": ("yaw_rad", grid.yaw.values, {"units": "rad"}),
        "y_m": ("y_m", grid.y.values, {"units": "m"}),
        "x_m": ("x_m", grid.x.values, {"units": "m"}),
    }
    for dim in ("electrode", "driven", "receiver"):
        coords[dim] = ds[dim].values
    return xr.Dataset(data, coords=coords, attrs=dict(ds.attrs))


def export_netcdf(zarr_path, nc_path) -> Path:
    """Write a complete sweep store as one netCDF file (for tools that want one file)."""
    ds = open_sweep(zarr_path)
    if not bool(np.asarray(ds["computed"].values).all()):
        raise StoreError(f"{zarr_path}: the sweep is not complete; finish it before exporting")
    ds = ds.load()
    for v in ds.variables.values():
        v.encoding = {}
    nc_path = Path(nc_path)
    partial = nc_path.with_name(nc_path.name + ".partial")
    ds.to_netcdf(partial)
    partial.replace(nc_path)
    return nc_path


def remove_store(path) -> None:
    """Delete a sweep store folder (after exporting it)."""
    shutil.rmtree(path, ignore_errors=True)
