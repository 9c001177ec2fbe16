"""LabelledMesh: geometry, labels, pose transforms, joining parts."""
import numpy as np
import pytest

from electrosense.meshes.labelled_mesh import LabelledMesh, concatenate
from electrosense.meshes.pose import Pose


def unit_cube(electrode_on_top=1):
    """A closed unit cube [0, 1]^3, wound outward, the top (z = 1) face on an electrode."""
    import trimesh

    box = trimesh.creation.box(extents=(1, 1, 1))
    v = np.asarray(box.vertices) + 0.5
    f = np.asarray(box.faces)
    top = np.all(np.isclose(v[f][:, :, 2], 1.0), axis=1)
    return LabelledMesh(v, f, np.where(top, electrode_on_top, 0), np.zeros(len(f), int), ("sensor",))


def test_areas_centroids_normals_of_a_cube():
    m = unit_cube()
    assert m.n_triangles == 12
    assert m.areas_m2.sum() == pytest.approx(6.0)
    assert np.allclose(np.linalg.norm(m.normals, axis=1), 1.0)
    # outward: from the cube's centre to each face's centroid
    assert np.all(np.einsum("ij,ij->i", m.normals, m.centroids_m - 0.5) > 0)
    assert m.electrode_areas_m2() == pytest.approx([1.0])
    assert m.electrodes == (1,)


def test_transformed_moves_rigidly_and_keeps_orientation():
    m = unit_cube()
    pose = Pose(0.3, -0.2, 0.1, np.pi / 3)
    t = m.transformed(pose)
    assert np.allclose(t.areas_m2, m.areas_m2)
    assert np.allclose(t.centroids_m, pose.to_tank(m.centroids_m))
    assert np.allclose(t.normals, m.normals @ pose.rotation.T)
    assert np.array_equal(t.electrode, m.electrode) and t.region_names == m.region_names
    assert t.to_trimesh().volume == pytest.approx(1.0)  # still outward
    assert np.allclose(m.vertices_m.min(axis=0), 0.0)  # the original is untouched


def test_flipped_reverses_normals():
    m = unit_cube()
    assert np.allclose(m.flipped().normals, -m.normals)
    assert m.flipped().to_trimesh().volume == pytest.approx(-1.0)


def test_concatenate_merges_regions_by_name_and_offsets_faces():
    a = unit_cube()
    b = LabelledMesh(a.vertices_m + 3, a.faces, None, np.zeros(12, int), ("floor",))
    c = concatenate([a, b, a.transformed(Pose(-3, 0, 0, 0))])
    assert c.region_names == ("sensor", "floor")
    assert c.n_triangles == 36 and c.n_vertices == 3 * a.n_vertices
    assert np.array_equal(c.region, np.r_[np.zeros(12), np.ones(12), np.zeros(12)])
    assert np.allclose(c.triangles_m[12:24], b.triangles_m)
    assert c.region_mesh("floor").n_triangles == 12


def test_select_and_trimesh_keep_face_order():
    m = unit_cube()
    top = m.select(m.electrode == 1)
    assert top.n_triangles == 2 and top.n_vertices == 4
    tm = m.to_trimesh()
    assert np.array_equal(np.asarray(tm.faces), m.faces)
    assert np.array_equal(tm.face_attributes["electrode"], m.electrode)
    back = LabelledMesh.from_trimesh(tm, region_names=("sensor",))
    assert np.array_equal(back.electrode, m.electrode)


@pytest.mark.parametrize(
    "kwargs, message",
    [
        (dict(faces=[[0, 1, 7]]), "outside"),
        (dict(electrode=[-1]), "electrode labels must be >= 0"),
        (dict(electrode=[0, 1]), "electrode has 2 labels for 1 faces"),
        (dict(region=[1]), "region labels must index region_names"),
        (dict(vertices_m=[[0, 0, np.nan], [1, 0, 0], [0, 1, 0]]), "non-finite"),
    ],
)
def test_bad_meshes_are_refused(kwargs, message):
    args = dict(vertices_m=np.eye(3), faces=[[0, 1, 2]], electrode=[0], region=[0], region_names=("sensor",))
    args.update(kwargs)
    with pytest.raises(ValueError, match=message):
        LabelledMesh(**args)


def test_unknown_region_name_lists_the_known_ones():
    with pytest.raises(KeyError, match="regions: sensor"):
        unit_cube().region_mask("floor")
