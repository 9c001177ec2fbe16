"""The sensor's mixed problem with bempp-cl (validation.studies.bempp_sensor): sign conventions and
closed forms, then the sensor against our BEM. Skipped without bempp-cl; about a minute (compilation)."""
import numpy as np
import pytest
import trimesh

pytest.importorskip("bempp_cl")

from electrosense.bem.boundary_conditions import WaterBoundary  # noqa: E402
from electrosense.bem.closed_forms import two_sphere_resistance_ohm  # noqa: E402
from electrosense.bem.conductance import isolate  # noqa: E402
from electrosense.bem.solve import solve  # noqa: E402
from electrosense.meshes.labelled_mesh import LabelledMesh, concatenate  # noqa: E402
from electrosense.validation.studies.bempp_sensor import (  # noqa: E402
    bempp_conductance,
    bempp_grounded_conductance,
    double_layer_of_one,
)


def sphere(radius_m, centre_x_m=0.0, electrode=1, subdivisions=2):
    """Icosphere with the sphere's volume, normals outwards (into the water)."""
    s = trimesh.creation.icosphere(subdivisions)
    scale = radius_m * (4 / 3 * np.pi / s.volume) ** (1 / 3)
    return LabelledMesh(s.vertices * scale + [centre_x_m, 0, 0], s.faces, np.full(len(s.faces), electrode),
                        None, ("sensor",))


def test_double_layer_of_one_is_minus_half_with_outward_normals():
    # bempp's double layer uses the grid normal: int dG/dn_y dA = -1/2 on the surface for n out of the body
    assert double_layer_of_one(sphere(0.01, subdivisions=1)) == pytest.approx(-0.5, abs=1e-4)


def test_one_sphere_capacitance():
    a, sigma = 0.01, 2.0
    C, _ = bempp_grounded_conductance(sphere(a), sigma)
    assert C[0, 0] == pytest.approx(4 * np.pi * sigma * a, rel=1e-3)


def test_two_spheres_against_the_exact_series():
    mesh = concatenate([sphere(0.01, 0.0, 1), sphere(0.01, 0.03, 2)])
    C, _ = bempp_grounded_conductance(mesh, 1.0)
    assert C == pytest.approx(C.T, rel=1e-3)
    assert 1 / isolate(C)[0, 0] == pytest.approx(two_sphere_resistance_ohm(0.01, 0.03), rel=1e-3)


def test_sensor_agrees_with_our_bem():
    from electrosense.meshes import preset
    from electrosense.meshes.sensor_mesh import default_edge_length_m, mesh_sensor

    s = preset("angels-4")
    mesh = mesh_sensor(s, edge_length_m=default_edge_length_m(s) / 0.5, grading=1.3)
    C, _ = bempp_grounded_conductance(mesh, 1.0)
    assert np.abs(C - C.T).max() < 1e-3 * np.abs(C).max()           # reciprocity of the mixed problem
    theirs = bempp_conductance(mesh, 1.0, s.emitter)
    assert np.abs(theirs.K_S.sum(axis=1)).max() < 1e-9 * theirs.K_S.max()
    ours = solve(WaterBoundary.from_meshes(mesh, emitter=s.emitter), 1.0).conductance
    assert theirs.S_S == pytest.approx(ours.S_S, rel=0.03)
