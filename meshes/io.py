"""Mesh files: VTK PolyData (.vtp) with labels, PLY and STL for export.

* ``.vtp`` (opens in ParaView): double-precision points, triangles, integer
  cell arrays ``electrode`` and ``region``, and the region names in the
  field data ``region_names``. Any other cell or point arrays (a surface
  solution, say) may ride along via ``cell_data``/``point_data``.
* ``.ply``: the labels as integer face properties ``electrode`` and
  ``region`` (coordinates in single precision, as most PLY readers expect),
  the region names in a header comment ``region_names a;b;c``.
* ``.stl``: geometry only (STL has no per-face data); for export.

A user's own labelled mesh (.vtp, .vtk, .vtu, .ply, .obj...) is read by
:func:`read_mesh`; it must carry an integer cell array ``electrode``
(0 insulating, k electrode k); ``region`` is optional.

Example
-------
>>> import tempfile, pathlib
>>> from electrosense.meshes import preset
>>> from electrosense.meshes.sensor_mesh import mesh_sensor
>>> from electrosense.meshes.io import read_mesh, write_mesh
>>> m = mesh_sensor(preset("angels-2"))
>>> path = pathlib.Path(tempfile.mkdtemp()) / "sensor.vtp"
>>> _ = write_mesh(m, path)
>>> back = read_mesh(path)
>>> back.n_triangles == m.n_triangles, back.region_names
(True, ('sensor',))
"""
from __future__ import annotations

from pathlib import Path

import numpy as np

from electrosense.meshes.labelled_mesh import LabelledMesh

__all__ = ["write_mesh", "read_mesh", "to_polydata", "from_polydata", "MeshFileError", "MESH_SUFFIXES"]

MESH_SUFFIXES = (".vtp", ".vtk", ".vtu", ".ply", ".stl", ".obj")


class MeshFileError(ValueError):
    """A mesh file that cannot be read as a labelled mesh."""


def _pyvista():
    """pyvista, imported when needed (reading and writing draw nothing: no OpenGL window is chosen here)."""
    import pyvista

    return pyvista


def to_polydata(mesh: LabelledMesh, cell_data: dict | None = None, point_data: dict | None = None):
    """A :class:`pyvista.PolyData` of the mesh with its labels (and extra arrays) attached."""
    pv = _pyvista()
    cells = np.c_[np.full(mesh.n_triangles, 3), mesh.faces].ravel()
    poly = pv.PolyData(mesh.vertices_m.astype(np.float64), cells)
    poly.cell_data["electrode"] = mesh.electrode.astype(np.int32)
    poly.cell_data["region"] = mesh.region.astype(np.int32)
    poly.field_data["region_names"] = np.array(mesh.region_names, dtype=str)
    for name, values in (cell_data or {}).items():
        poly.cell_data[name] = np.asarray(values)
    for name, values in (point_data or {}).items():
        poly.point_data[name] = np.asarray(values)
    return poly


def _integer_labels(values, array: str, source: str) -> np.ndarray:
    values = np.asarray(values)
    if values.ndim != 1:
        raise MeshFileError(f"{source}: cell array {array!r} must have one value per cell, got shape {values.shape}")
    if not np.issubdtype(values.dtype, np.integer):
        if not (np.all(np.isfinite(values)) and np.all(values == np.round(values))):
            raise MeshFileError(f"{source}: cell array {array!r} must hold integers (0 insulating, k electrode k)")
    values = values.astype(np.int64)
    if values.size and values.min() < 0:
        raise MeshFileError(f"{source}: cell array {array!r} has negative labels (min {values.min()})")
    return values


def from_polydata(poly, source: str = "mesh", require_electrode: bool = True) -> LabelledMesh:
    """A :class:`LabelledMesh` from any pyvista/VTK surface with a cell array ``electrode``."""
    pv = _pyvista()
    if not isinstance(poly, pv.PolyData):
        poly = poly.extract_surface(pass_pointid=False, pass_cellid=False)
    if poly.n_cells == 0:
        raise MeshFileError(f"{source}: the file holds no surface cells")
    if not poly.is_all_triangles:
        poly = poly.triangulate()  # cell data are copied to the triangles of each polygon
    if poly.n_lines or poly.n_verts:
        raise MeshFileError(f"{source}: only a triangle surface can be used, the file also holds lines or points")
    faces = np.asarray(poly.faces).reshape(-1, 4)[:, 1:]
    if "electrode" in poly.cell_data:
        electrode = _integer_labels(poly.cell_data["electrode"], "electrode", source)
    elif require_electrode:
        found = ", ".join(poly.cell_data.keys()) or "none"
        raise MeshFileError(
            f"{source}: no integer cell array 'electrode' (0 insulating, k electrode k) in the file "
            f"(cell arrays found: {found}); label the faces of each electrode, e.g. in ParaView or with "
            f"pyvista: mesh.cell_data['electrode'] = labels"
        )
    else:
        electrode = np.zeros(len(faces), np.int64)
    if "region" in poly.cell_data:
        region = _integer_labels(poly.cell_data["region"], "region", source)
    else:
        region = np.zeros(len(faces), np.int64)
    names = None
    if "region_names" in poly.field_data:
        names = tuple(str(n) for n in np.atleast_1d(poly.field_data["region_names"]))
    n_regions = int(region.max()) + 1 if len(region) else 1
    if names is None or len(names) < n_regions:
        names = ("sensor",) if n_regions == 1 and "region" not in poly.cell_data else tuple(f"region_{i}" for i in range(n_regions))
    return LabelledMesh(np.asarray(poly.points, dtype=float), faces, electrode, region, names)


def _ply_region_names(path: Path, n_regions: int) -> tuple[str, ...]:
    """Region names from a ``comment region_names a;b`` PLY header line, else region_0, region_1..."""
    with open(path, "rb") as f:
        for raw in f:
            line = raw.decode("ascii", errors="replace").strip()
            if line.startswith("comment region_names "):
                names = tuple(line[len("comment region_names "):].split(";"))
                if len(names) >= n_regions:
                    return names
            if line == "end_header":
                break
    return tuple(f"region_{i}" for i in range(n_regions))


def write_mesh(mesh: LabelledMesh, path: str | Path, cell_data: dict | None = None, point_data: dict | None = None) -> Path:
    """Write a labelled mesh: ``.vtp`` (labels and region names), ``.ply`` (labels) or ``.stl`` (geometry).

    Extra ``cell_data``/``point_data`` arrays are written to ``.vtp`` only.
    """
    path = Path(path)
    suffix = path.suffix.lower()
    if suffix in (".vtp", ".vtk"):
        to_polydata(mesh, cell_data, point_data).save(str(path))
    elif suffix in (".ply", ".stl"):
        if cell_data or point_data:
            raise ValueError(f"{path}: extra data arrays can only be written to .vtp")
        tm = mesh.to_trimesh()
        if suffix == ".ply":
            tm.face_attributes = {"electrode": mesh.electrode.astype(np.int32), "region": mesh.region.astype(np.int32)}
            data = tm.export(file_type="ply", include_attributes=True)
            comment = ("comment region_names " + ";".join(mesh.region_names) + "\n").encode()
            head = data.index(b"\n", data.index(b"\n") + 1) + 1  # after the "ply" and "format" lines
            path.write_bytes(data[:head] + comment + data[head:])
        else:
            path.write_bytes(tm.export(file_type="stl"))
    else:
        raise ValueError(f"{path}: unknown mesh format {suffix!r}; use .vtp, .vtk, .ply or .stl")
    return path


def read_mesh(path: str | Path, require_electrode: bool = True) -> LabelledMesh:
    """Read a labelled triangle mesh (.vtp/.vtk/.vtu via VTK; .ply/.stl/.obj via trimesh).

    Raises :class:`MeshFileError` naming the file when it cannot be read, is
    not a triangle surface, or (with ``require_electrode``) lacks the
    integer cell array ``electrode``.
    """
    path = Path(path)
    if not path.exists():
        raise MeshFileError(f"{path}: no such file")
    suffix = path.suffix.lower()
    if suffix in (".vtp", ".vtk", ".vtu"):
        pv = _pyvista()
        try:
            poly = pv.read(str(path))
        except Exception as exc:  # VTK readers raise a variety of errors
            raise MeshFileError(f"{path}: cannot be read as VTK data ({exc})") from None
        return from_polydata(poly, str(path), require_electrode)
    if suffix in (".ply", ".stl", ".obj"):
        import trimesh

        try:
            tm = trimesh.load(str(path), process=False, force="mesh")
        except Exception as exc:
            raise MeshFileError(f"{path}: cannot be read as a mesh ({exc})") from None
        faces_raw = tm.metadata.get("_ply_raw", {}).get("face", {}).get("data")
        names = faces_raw.dtype.names if faces_raw is not None and hasattr(faces_raw, "dtype") else ()
        labels = {k: np.asarray(faces_raw[k]).ravel() for k in ("electrode", "region") if names and k in names}
        if "electrode" not in labels and require_electrode:
            what = "STL files have no per-face data" if suffix == ".stl" else "no integer face property 'electrode'"
            raise MeshFileError(
                f"{path}: {what}; the electrode labels (cell array 'electrode', 0 insulating, k electrode k) are "
                f"missing. Save the labelled mesh as .vtp or .ply with an 'electrode' face property."
            )
        electrode = _integer_labels(labels["electrode"], "electrode", str(path)) if "electrode" in labels else None
        region = _integer_labels(labels["region"], "region", str(path)) if "region" in labels else None
        n_regions = int(region.max()) + 1 if region is not None and len(region) else 1
        names = ("sensor",) if region is None else _ply_region_names(path, n_regions)
        return LabelledMesh(np.asarray(tm.vertices, float), np.asarray(tm.faces), electrode, region, names)
    raise MeshFileError(f"{path}: unknown mesh format {suffix!r}; use one of {', '.join(MESH_SUFFIXES)}")
