"""check_mesh refuses what a BEM cannot use, naming the problem and where."""
import numpy as np
import pytest
import trimesh

from electrosense.meshes.labelled_mesh import LabelledMesh, concatenate
from electrosense.meshes.quality import MeshError, aspect_ratios, check_mesh, mesh_quality, triangle_angles_deg


def sphere(centre=(0, 0, 0), name="sensor"):
    s = trimesh.creation.icosphere(subdivisions=2, radius=0.01)
    return LabelledMesh(np.asarray(s.vertices) + centre, np.asarray(s.faces), None, None, (name,))


def test_equilateral_measures():
    tri = LabelledMesh([[0, 0, 0], [1, 0, 0], [0.5, np.sqrt(3) / 2, 0]], [[0, 1, 2]])
    assert np.allclose(triangle_angles_deg(tri), 60.0)
    assert aspect_ratios(tri) == pytest.approx([1.0])


def test_a_good_mesh_passes_with_its_figures():
    q = check_mesh(concatenate([sphere(), sphere((0.1, 0, 0), "object_1")]))
    assert q.is_watertight and q.is_consistently_oriented and q.is_outward
    assert q.n_shells == 2 and q.n_degenerate == 0
    assert 50 < q.min_angle_deg <= 60 and 1 <= q.max_aspect_ratio < 1.5
    assert "2 closed shell(s)" in str(q)


def test_open_surface_is_refused_with_its_place():
    m = sphere()
    holed = m.select(np.arange(m.n_triangles) != 7)
    with pytest.raises(MeshError, match=r"3 open edge\(s\).*triangle \d+ at \(.*\) m in region 'sensor'"):
        check_mesh(holed)
    assert mesh_quality(holed).n_open_edges == 3


def test_inward_normals_are_refused_naming_the_shell():
    m = concatenate([sphere(), sphere((0.1, 0, 0), "object_1").flipped()])
    with pytest.raises(MeshError, match="region\\(s\\) object_1 has its normals pointing into the solid"):
        check_mesh(m)


def test_inconsistent_winding_is_refused():
    m = sphere()
    faces = m.faces.copy()
    faces[3] = faces[3, ::-1]
    with pytest.raises(MeshError, match="inconsistent winding"):
        check_mesh(LabelledMesh(m.vertices_m, faces, None, None, ("sensor",)))


def test_degenerate_and_needle_triangles_are_refused():
    # a flat "tetrahedron" whose apex lies on the base plane edge: zero-area faces
    v = np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0], [0.5, 0, 0.0]], float)
    f = np.array([[0, 2, 1], [0, 1, 3], [0, 3, 2], [1, 2, 3]])
    with pytest.raises(MeshError, match="degenerate triangle"):
        check_mesh(LabelledMesh(v, f))
    # a long thin closed tetrahedron: needles
    v = np.array([[0, 0, 0], [1, 0, 0], [0.5, 0.01, 0], [0.5, 0.005, 0.01]], float)
    with pytest.raises(MeshError, match=r"angle below 5 deg \(smallest") as info:
        check_mesh(LabelledMesh(v, [[0, 2, 1], [0, 1, 3], [0, 3, 2], [1, 2, 3]]))
    assert "aspect ratio above 20" in str(info.value)


def test_non_manifold_edge_is_refused():
    m = sphere()
    a, b = m.faces[0, 0], m.faces[0, 1]
    extra = np.vstack([m.vertices_m, [[0.0, 0.0, 0.05]]])
    fin = LabelledMesh(extra, np.vstack([m.faces, [[b, a, len(extra) - 1]]]), None, None, ("sensor",))
    with pytest.raises(MeshError, match="non-manifold"):
        check_mesh(fin)


def test_mesh_and_scene_errors_come_back_whole_from_a_worker_process():
    """A map's workers raise these in another process: pickled, they keep their problems and message (rebuilt
    from the message alone, a message was split into its characters)."""
    import pickle

    from electrosense.meshes.quality import MeshError
    from electrosense.meshes.scene_mesh import SceneError

    for exc in (MeshError(["1 triangle(s) with an angle below 1 deg", "2 needles"], "tank mesh"),
                SceneError(["the sensor is out of the water"])):
        back = pickle.loads(pickle.dumps(exc))
        assert type(back) is type(exc) and back.problems == exc.problems and str(back) == str(exc)
