"""Mesh files: .vtp/.ply round trips, .stl export, users' own labelled meshes."""
import numpy as np
import pytest

from electrosense.meshes.io import MeshFileError, read_mesh, to_polydata, write_mesh
from electrosense.meshes.labelled_mesh import LabelledMesh, concatenate
from electrosense.meshes.object_mesh import mesh_object
from electrosense.meshes.objects import Box, Sphere


@pytest.fixture(scope="module")
def labelled():
    """Two closed parts, three regions, electrode labels 0..2."""
    a = mesh_object(Sphere((0, 0, 0), radius_m=0.01), 0.004, region_name="sensor")
    a.electrode[:] = np.where(a.centroids_m[:, 0] > 0.005, 1, np.where(a.centroids_m[:, 0] < -0.005, 2, 0))
    b = mesh_object(Box((0.1, 0, 0), size_m=(0.02, 0.02, 0.02)), 0.01, region_name="object_1")
    return concatenate([a, b])


def same(a: LabelledMesh, b: LabelledMesh, atol=0.0):
    assert np.allclose(a.vertices_m, b.vertices_m, atol=atol, rtol=0)
    assert np.array_equal(a.faces, b.faces)
    assert np.array_equal(a.electrode, b.electrode) and np.array_equal(a.region, b.region)
    assert a.region_names == b.region_names


def test_vtp_round_trip_is_exact(labelled, tmp_path):
    back = read_mesh(write_mesh(labelled, tmp_path / "m.vtp"))
    same(labelled, back)


def test_vtp_carries_extra_arrays(labelled, tmp_path):
    import pyvista as pv

    phi = labelled.centroids_m[:, 0]
    write_mesh(labelled, tmp_path / "s.vtp", cell_data={"potential_V": phi})
    poly = pv.read(tmp_path / "s.vtp")
    assert np.allclose(poly.cell_data["potential_V"], phi)
    assert poly.cell_data["electrode"].dtype.kind == "i"
    same(labelled, read_mesh(tmp_path / "s.vtp"))


def test_ply_round_trip_keeps_labels_and_names(labelled, tmp_path):
    back = read_mesh(write_mesh(labelled, tmp_path / "m.ply"))
    same(labelled, back, atol=1e-7)  # PLY stores single-precision coordinates


def test_stl_is_geometry_only(labelled, tmp_path):
    import trimesh

    path = write_mesh(labelled, tmp_path / "m.stl")
    assert len(trimesh.load(path).faces) == labelled.n_triangles
    with pytest.raises(MeshFileError, match="STL files have no per-face data.*'electrode'"):
        read_mesh(path)
    assert read_mesh(path, require_electrode=False).n_triangles == labelled.n_triangles


def test_a_users_own_mesh(tmp_path):
    import pyvista as pv

    # a user's quad-meshed sensor with float labels in ParaView: triangulated, labels kept
    cyl = pv.Cylinder(radius=0.01, height=0.2, resolution=24, capping=True).clean()
    cyl.cell_data["electrode"] = (cyl.cell_centers().points[:, 0] > 0.05).astype(float)
    cyl.save(tmp_path / "user.vtp")
    m = read_mesh(tmp_path / "user.vtp")
    assert m.n_triangles >= cyl.n_cells and set(np.unique(m.electrode)) == {0, 1}
    assert m.region_names == ("sensor",)
    assert np.all(m.centroids_m[m.electrode == 1, 0] > 0.04)


def test_missing_or_bad_labels_are_refused(labelled, tmp_path):
    poly = to_polydata(labelled)
    del poly.cell_data["electrode"]
    poly.save(tmp_path / "nolabels.vtp")
    with pytest.raises(MeshFileError, match="no integer cell array 'electrode'.*cell arrays found: region"):
        read_mesh(tmp_path / "nolabels.vtp")
    poly.cell_data["electrode"] = np.full(poly.n_cells, 0.5)
    poly.save(tmp_path / "halves.vtp")
    with pytest.raises(MeshFileError, match="must hold integers"):
        read_mesh(tmp_path / "halves.vtp")
    with pytest.raises(MeshFileError, match="no such file"):
        read_mesh(tmp_path / "absent.vtp")
    with pytest.raises(ValueError, match="unknown mesh format"):
        write_mesh(labelled, tmp_path / "m.xyz")
