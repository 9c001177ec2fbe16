"""Object meshes: closed, outward, areas and volumes against closed forms."""
import numpy as np
import pytest

from electrosense.meshes.object_mesh import mesh_object
from electrosense.meshes.objects import Box, Cylinder, Sphere
from electrosense.meshes.quality import check_mesh


def test_sphere_area_volume_and_vertices_on_the_sphere():
    s = Sphere(centre_m=(0.1, -0.2, 0.05), radius_m=0.02)
    m = mesh_object(s, edge_length_m=0.004, region_name="object_3")
    check_mesh(m, min_angle_deg=30)
    assert m.region_names == ("object_3",) and np.all(m.electrode == 0)
    assert np.allclose(np.linalg.norm(m.vertices_m - s.centre_m, axis=1), 0.02)
    # an inscribed polyhedron: a little less than the sphere, by ~ (h/r)^2
    assert m.areas_m2.sum() == pytest.approx(4 * np.pi * 0.02**2, rel=0.02)
    assert m.to_trimesh().volume == pytest.approx(4 / 3 * np.pi * 0.02**3, rel=0.03)
    assert np.all(np.einsum("ij,ij->i", m.normals, m.centroids_m - s.centre_m) > 0)


def test_box_exact_area_volume_and_yaw():
    b = Box(centre_m=(0.0, 0.1, -0.1), size_m=(0.1, 0.04, 0.02), yaw_rad=np.pi / 6)
    m = mesh_object(b, edge_length_m=0.01)
    check_mesh(m, min_angle_deg=25)
    assert m.areas_m2.sum() == pytest.approx(2 * (0.1 * 0.04 + 0.1 * 0.02 + 0.04 * 0.02))
    assert m.to_trimesh().volume == pytest.approx(0.1 * 0.04 * 0.02)
    # the long side points along the yaw direction
    axis = np.array([np.cos(np.pi / 6), np.sin(np.pi / 6), 0.0])
    extent = (m.vertices_m - b.centre_m) @ axis
    assert extent.max() == pytest.approx(0.05) and extent.min() == pytest.approx(-0.05)


def test_cylinder_area_volume():
    c = Cylinder(centre_m=(0.2, 0.0, 0.0), radius_m=0.015, height_m=0.12)
    m = mesh_object(c, edge_length_m=0.004)
    check_mesh(m, min_angle_deg=25)
    exact_area = 2 * np.pi * 0.015 * 0.12 + 2 * np.pi * 0.015**2
    assert m.areas_m2.sum() == pytest.approx(exact_area, rel=0.01)
    assert m.to_trimesh().volume == pytest.approx(np.pi * 0.015**2 * 0.12, rel=0.01)
    z = m.vertices_m[:, 2]
    assert z.min() == pytest.approx(-0.06) and z.max() == pytest.approx(0.06)


def test_default_edge_length_and_bad_sizes():
    for obj in (Sphere((0, 0, 0), radius_m=0.05), Box((0, 0, 0), size_m=(0.1, 0.1, 0.1)),
                Cylinder((0, 0, 0), radius_m=0.02, height_m=0.1)):
        m = mesh_object(obj)
        assert m.to_trimesh().is_watertight and 50 < m.n_triangles < 20000
    with pytest.raises(ValueError, match="radius_m must be positive"):
        mesh_object(Sphere((0, 0, 0), radius_m=-0.01), edge_length_m=0.01)
    with pytest.raises(TypeError, match="Sphere, Box or Cylinder"):
        mesh_object("a cone")
