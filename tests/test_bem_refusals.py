"""Every bad input the BEM refuses, with a message naming what is wrong."""
import numpy as np
import pytest
import trimesh

from electrosense import bem
from electrosense.bem.boundary_conditions import BoundaryError, WaterBoundary
from electrosense.bem.solve import SingularSystemError, conductance_matrix, solve
from electrosense.meshes import Pose, Scene, Sphere, Tank, preset
from electrosense.meshes.labelled_mesh import LabelledMesh, concatenate


def _sphere(centre=(0, 0, 0), electrode=1, radius=0.01, sub=1):
    s = trimesh.creation.icosphere(sub)
    return LabelledMesh(s.vertices * radius + np.asarray(centre, float), s.faces, np.full(len(s.faces), electrode),
                        None, ("sensor",))


def _pair(d=0.05):
    return concatenate([_sphere((0, 0, 0), 1), _sphere((d, 0, 0), 2)])


def test_open_mesh():
    m = _pair()
    m = m.select(np.arange(m.n_triangles) != 3)
    with pytest.raises(ValueError, match="open"):
        WaterBoundary.from_meshes(m)


def test_degenerate_triangle():
    m = _pair()
    v = m.vertices_m.copy()
    a, b, c = m.faces[0]
    v[c] = 0.5 * (v[a] + v[b])   # flattens face 0 (and distorts its neighbours)
    with pytest.raises(ValueError, match="degenerate"):
        WaterBoundary.from_meshes(LabelledMesh(v, m.faces, m.electrode, m.region, m.region_names))


def test_inward_normals():
    with pytest.raises(ValueError, match="pointing into the solid"):
        WaterBoundary.from_meshes(_pair().flipped())


def test_touching_electrodes():
    m = _sphere()
    electrode = np.where(m.centroids_m[:, 0] > 0, 1, 2)
    with pytest.raises(BoundaryError, match="electrodes 1 and 2 touch"):
        WaterBoundary.from_meshes(LabelledMesh(m.vertices_m, m.faces, electrode, None, ("sensor",)))


def test_no_electrode_and_single_electrode():
    with pytest.raises(BoundaryError, match="no electrode faces"):
        WaterBoundary.from_meshes(_sphere(electrode=0))
    with pytest.raises(BoundaryError, match="only one electrode"):
        WaterBoundary.from_meshes(_sphere(electrode=1))
    with pytest.raises(BoundaryError, match=r"electrode\(s\) \[2\] have no faces"):
        WaterBoundary.from_meshes(concatenate([_sphere(electrode=1), _sphere((0.05, 0, 0), electrode=3)]))


def test_emitter_not_an_electrode():
    with pytest.raises(BoundaryError, match="emitter 5"):
        solve(WaterBoundary.from_meshes(_pair()), 1.0, emitter=5)


def test_sensor_outside_the_water():
    scene = Scene(preset("angels-2"), Pose(0.45, 0.0, 0.0, 0.0), Tank((1.0, 1.0, 1.0)))
    with pytest.raises(ValueError, match="sensor"):
        conductance_matrix(scene, 1.0)


def test_singular_system_from_coincident_parts():
    m = concatenate([_pair(), _sphere((0, 0, 0), 1)])   # a second copy of electrode 1's sphere
    with pytest.raises(SingularSystemError, match="singular"):
        solve(WaterBoundary.from_meshes(m, check=False), 1.0)


def test_memory_refusal(monkeypatch):
    monkeypatch.setattr(bem.memory, "available_bytes", lambda: 1e5)
    with pytest.raises(MemoryError, match="raise edge_length_m"):
        solve(WaterBoundary.from_meshes(_pair()), 1.0)


@pytest.mark.parametrize("sigma", [0.0, -1.0, float("nan")])
def test_bad_conductivity(sigma):
    with pytest.raises(ValueError, match="sigma_S_per_m"):
        solve(WaterBoundary.from_meshes(_pair()), sigma)


@pytest.mark.parametrize("z_c, message", [((0.1, 0.2, 0.3), "one per electrode"), (-1.0, ">= 0")])
def test_bad_contact_impedance(z_c, message):
    with pytest.raises(ValueError, match=message):
        solve(WaterBoundary.from_meshes(_pair()), 1.0, z_c)


def test_object_of_finite_conductivity():
    scene = Scene(preset("angels-2"), objects=(Sphere(centre_m=(0.0, 0.1, 0.0), radius_m=0.02, conductivity_S_per_m=0.5),))
    with pytest.raises(ValueError, match="object_1"):
        conductance_matrix(scene, 1.0)


def test_sweeps_side_by_side_each_keep_to_their_share_of_the_memory(monkeypatch):
    """A tank block that fits alone is refused, with its size, by a sweep that shares the memory with three more
    (a tank map's two workers, each with a coarse and a reference sweep): several workers no longer each check
    the whole memory alone."""
    import electrosense.bem.sweep as sweep_module
    from electrosense.bem import PoseSweep
    from electrosense.meshes.tank import Tank

    asked = []
    check = sweep_module.check_bytes
    monkeypatch.setattr(sweep_module, "check_bytes", lambda need, *a, **k: asked.append(need) or check(need, *a, **k))
    pose = np.array([[0.0, 0.0, 0.0, 0.0]])
    scene = (preset("angels-2"), Tank((0.4, 0.3, 0.3)))
    PoseSweep(*scene, edge_length_m=0.012, tank_edge_length_m=0.04).conductance(pose)
    monkeypatch.setattr(bem.memory, "available_bytes", lambda: 2.0 * asked[-1])   # room for this one, not four
    PoseSweep(*scene, edge_length_m=0.012, tank_edge_length_m=0.04).conductance(pose)
    with pytest.raises(MemoryError, match=r"block.*needs about .* GB.*its share, 0.2"):
        PoseSweep(*scene, edge_length_m=0.012, tank_edge_length_m=0.04, memory_share=0.25).conductance(pose)
