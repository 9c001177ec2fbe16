"""The tank's water box: closed, six labelled regions, normals out of the water, graded."""
import numpy as np
import pytest

from electrosense.meshes.quality import check_mesh, mesh_quality
from electrosense.meshes.tank import TANK_REGIONS, Tank
from electrosense.meshes.tank_mesh import equidistributed_nodes, graded_size_function, mesh_tank

TANK = Tank((1.0, 0.6, 0.5), water_depth_m=0.4)


@pytest.fixture(scope="module")
def uniform():
    return mesh_tank(TANK, edge_length_m=0.08)


def test_closed_and_outward(uniform):
    q = check_mesh(uniform, min_angle_deg=20)
    assert q.is_watertight and q.is_consistently_oriented and q.is_outward and q.n_shells == 1
    assert uniform.to_trimesh().volume == pytest.approx(1.0 * 0.6 * 0.4)


def test_regions_lie_on_their_planes_with_outward_normals(uniform):
    assert uniform.region_names == TANK_REGIONS
    lo, hi = TANK.water_bounds_m
    assert hi[2] == pytest.approx(-0.25 + 0.4)  # free surface at the water depth
    planes = {  # region: (axis, coordinate, outward sign)
        "wall_x-": (0, lo[0], -1), "wall_x+": (0, hi[0], 1), "wall_y-": (1, lo[1], -1),
        "wall_y+": (1, hi[1], 1), "floor": (2, lo[2], -1), "free_surface": (2, hi[2], 1),
    }
    areas = {"wall_x-": 0.6 * 0.4, "wall_x+": 0.6 * 0.4, "wall_y-": 1.0 * 0.4, "wall_y+": 1.0 * 0.4,
             "floor": 1.0 * 0.6, "free_surface": 1.0 * 0.6}
    for name, (axis, coord, sign) in planes.items():
        part = uniform.region_mesh(name)
        assert np.allclose(part.vertices_m[:, axis], coord), name
        expected_normal = np.zeros(3)
        expected_normal[axis] = sign
        assert np.allclose(part.normals, expected_normal), name
        assert part.areas_m2.sum() == pytest.approx(areas[name]), name
    assert np.all(uniform.electrode == 0)


def test_uniform_edge_length(uniform):
    q = mesh_quality(uniform)
    assert q.min_angle_deg > 25
    assert 0.5 * 0.08 < q.mean_edge_m < 1.2 * 0.08


def test_graded_towards_a_focus_point():
    focus = np.array([0.45, 0.0, -0.05])  # 5 cm from the wall x+
    m = mesh_tank(TANK, edge_length_m=0.005, focus_m=focus, grading=0.5)
    check_mesh(m, min_angle_deg=15)
    size = np.sqrt(m.areas_m2 * 4 / np.sqrt(3))  # equilateral-equivalent edge length
    d = np.linalg.norm(m.centroids_m - focus, axis=1)
    near, far = d < 0.08, d > 0.6
    assert near.any() and far.any()
    h_max = 0.6 / 4  # the default cap: a quarter of the smaller horizontal side
    assert size[far].mean() > 2 * size[near].mean()
    assert 0.5 * h_max < size[far].mean() < 1.2 * h_max
    # edges follow the size function h = 0.005 + 0.5 d within a factor of two
    h = 0.005 + 0.5 * d[near]
    assert np.all((size[near] > 0.4 * h) & (size[near] < 2.0 * h))


def test_graded_towards_a_trajectory_keeps_far_walls_coarse():
    track = np.c_[np.linspace(-0.4, 0.4, 50), np.full(50, 0.27), np.full(50, -0.1)]  # along the wall y+
    m = mesh_tank(TANK, edge_length_m=0.005, focus_m=track)
    size = np.sqrt(m.areas_m2 * 4 / np.sqrt(3))
    near_wall, far_wall = m.region_mask("wall_y+"), m.region_mask("wall_y-")
    assert size[near_wall].min() < 0.02
    assert size[far_wall].min() > 3 * size[near_wall].min()
    assert m.region_mesh("wall_y+").n_triangles > 5 * m.region_mesh("wall_y-").n_triangles


def test_equidistributed_nodes_follow_the_size():
    h = graded_size_function(0.01, focus_m=[0, 0, 0], grading=0.5, max_edge_length_m=0.2)
    nodes = equidistributed_nodes(np.zeros(3), np.array([1.0, 0, 0]), h)
    steps = np.diff(nodes[:, 0])
    assert nodes[0, 0] == 0.0 and nodes[-1, 0] == 1.0
    assert np.all(np.diff(steps) > -1e-12)  # growing away from the focus
    assert steps[0] < 0.02 and steps[-1] > 0.1


def test_bad_edge_length_is_refused():
    with pytest.raises(ValueError, match="edge_length_m must be positive"):
        mesh_tank(TANK, edge_length_m=0.0)


def test_two_free_nodes_brought_together_by_smoothing_lose_one():
    """Nodes nearer than 0.3x the target length make slivers (a cylinder's wall 5 mm from a sensor had two 0.15 mm
    apart among 3 mm edges): the later free node goes, boundary nodes stay."""
    from electrosense.meshes.tank_mesh import _drop_crowded

    boundary = np.array([[0.0, 0.0], [1.0, 0.0], [1.0, 1.0], [0.0, 1.0]])
    interior = np.array([[0.5, 0.5], [0.5 + 1e-3, 0.5], [0.2, 0.8], [0.999, 0.001]])
    kept = _drop_crowded(boundary, interior, lambda p: np.full(len(p), 0.2))
    assert kept.tolist() == [[0.5, 0.5], [0.2, 0.8]]
