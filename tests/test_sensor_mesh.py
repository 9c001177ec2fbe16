"""The graded sensor mesher: closed, outward, labelled, edges on rings, graded."""
import numpy as np
import pytest

from electrosense.meshes.sensor import Electrode, SensorDescription, preset
from electrosense.meshes.sensor_mesh import SensorProfile, mesh_sensor


def _custom():
    # head cap reaching onto the cylinder, tail cap edge on the hemisphere, one ring
    return SensorDescription("custom", 0.01, 0.16, (Electrode("cap", 0.06, 0.08), Electrode("ring", -0.01, 0.01),
                                                    Electrode("cap", -0.08, -0.075)))


@pytest.mark.parametrize("sensor", [preset("angels-2"), preset("angels-4"), _custom()], ids=lambda s: s.name)
def test_closed_outward_and_labelled(sensor):
    m = mesh_sensor(sensor)
    tm = m.to_trimesh()
    assert tm.is_watertight and tm.is_winding_consistent
    # normals out of the body: positive enclosed volume, close to the capsule's
    R, L = sensor.radius_m, sensor.length_m
    volume = np.pi * R**2 * (L - 2 * R) + 4 / 3 * np.pi * R**3
    assert tm.volume > 0 and abs(tm.volume / volume - 1) < 0.02
    assert m.electrodes == tuple(range(1, sensor.n_electrodes + 1))
    assert m.region_names == ("sensor",)


@pytest.mark.parametrize("sensor", [preset("angels-4"), _custom()], ids=lambda s: s.name)
def test_electrode_edges_lie_on_vertex_rings(sensor):
    m = mesh_sensor(sensor)
    x = m.vertices_m[m.faces][:, :, 0]
    half = sensor.length_m / 2
    for e in sensor.electrodes:
        for edge in (e.x_min_m, e.x_max_m):
            if abs(abs(edge) - half) < 1e-12:
                continue
            assert np.any(np.abs(m.vertices_m[:, 0] - edge) < 1e-12), f"no ring at x = {edge}"
            straddle = (x.min(axis=1) < edge - 1e-12) & (x.max(axis=1) > edge + 1e-12)
            assert not straddle.any(), f"{straddle.sum()} triangles straddle the edge at x = {edge}"


def test_areas_against_closed_forms():
    s = _custom()
    m = mesh_sensor(s, edge_length_m=0.003)
    R = s.radius_m
    areas = m.electrode_areas_m2()
    c = s.length_m / 2 - R
    head = 2 * np.pi * R**2 + 2 * np.pi * R * (c - 0.06)            # hemisphere + collar
    ring = 2 * np.pi * R * 0.02
    tail = 2 * np.pi * R * (0.08 - 0.075)  # a spherical zone: 2 pi R times its height
    np.testing.assert_allclose(areas, [head, ring, tail], rtol=0.01)
    total = 4 * np.pi * R**2 + 2 * np.pi * R * 2 * c
    assert abs(m.areas_m2.sum() / total - 1) < 0.01


def test_grading_towards_edges():
    s = preset("angels-2")
    h, refine, g = 0.006, 20.0, 1.25
    m = mesh_sensor(s, edge_length_m=h, edge_refinement=refine, grading=g)
    profile = SensorProfile(s)
    edge_s = profile.arc_length(s.electrodes[0].x_min_m)
    rings = np.unique(np.round(m.vertices_m[:, 0], 12))
    s_rings = np.sort([profile.arc_length(x) for x in rings])
    gaps = np.diff(s_rings)
    assert gaps.min() == pytest.approx(h / refine, rel=0.3)
    assert gaps.max() <= h * 1.3
    k = np.argmin(np.abs(s_rings - edge_s))
    assert gaps[k] < 2 * h / refine and gaps[k - 1] < 2 * h / refine   # fine on both sides of the edge
    ratios = gaps[1:] / gaps[:-1]
    assert np.all(ratios < g * 1.35) and np.all(ratios > 1 / (g * 1.35))


def test_finer_edge_length_gives_more_triangles():
    s = preset("angels-4")
    assert mesh_sensor(s, edge_length_m=0.004).n_triangles > mesh_sensor(s, edge_length_m=0.008).n_triangles


@pytest.mark.parametrize("kwargs, message", [
    (dict(edge_length_m=-1.0), "edge_length_m"),
    (dict(edge_length_m=0.05), "coarser than the sensor"),
    (dict(grading=1.0), "grading"),
    (dict(edge_refinement=0.5), "edge_refinement"),
    (dict(ring_radius="square"), "ring_radius"),
])
def test_refusals(kwargs, message):
    with pytest.raises(ValueError, match=message):
        mesh_sensor(preset("angels-2"), **kwargs)
