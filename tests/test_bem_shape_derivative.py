"""The shape derivative of K for moved tank walls, from one solve, against the BEM solved again with the walls moved.

The reference is independent of the formula: central differences of the BEM's K in tanks a few millimetres
longer and shorter, on a random sensor whose tip comes within two centimetres of a wall. The tank's mesh is
stretched, not meshed anew: a new mesh moves K by more than the difference (its discretisation error changes).
"""
from dataclasses import replace

import numpy as np
import pytest

from electrosense.bem import PoseSweep
from electrosense.bem.shape_derivative import surface_gradient_operator
from electrosense.meshes.scene_mesh import DEFAULT_TANK_GRADING, trajectory_focus_m
from electrosense.meshes.tank import Tank
from electrosense.meshes.tank_mesh import mesh_tank
from electrosense.validation.diagnosis.unseen import random_sensor


def test_the_surface_gradient_is_exact_for_quadratic_potentials_on_a_graded_mesh():
    mesh = mesh_tank(Tank((0.5, 0.4, 0.3)), 0.03, np.array([[0.1, 0.0, 0.0]]), grading=1.0)
    op = surface_gradient_operator(mesh.triangles_m)
    c = op.centroids_m
    u = 3 * c[:, 0] ** 2 - c[:, 0] * c[:, 1] + 2 * c[:, 1] + 0.5 * c[:, 2] ** 2
    exact = np.c_[6 * c[:, 0] - c[:, 1], -c[:, 0] + 2, c[:, 2]]
    n = np.cross(mesh.triangles_m[:, 1] - mesh.triangles_m[:, 0], mesh.triangles_m[:, 2] - mesh.triangles_m[:, 0])
    n /= np.linalg.norm(n, axis=1, keepdims=True)
    exact -= np.einsum("fk,fk->f", exact, n)[:, None] * n   # along the boundary
    g = op.gradient(u[:, None])[:, 0]
    # faces on an edge of the box have neighbours on one side only: still exact for a quadratic if enough of them
    err = np.linalg.norm(g - exact, axis=1) / np.linalg.norm(exact, axis=1).max()
    on_edge = np.isclose(np.abs(c), 0.5 * np.array([0.5, 0.4, 0.3]), atol=0.04).sum(axis=1) >= 2
    assert err[~on_edge].max() < 1e-8   # a quadratic fit is exact for a quadratic
    assert np.median(err[on_edge]) < 0.05   # one-sided near an edge of the box: first order there


@pytest.fixture(scope="module")
def scene():
    rng = np.random.default_rng(4)
    sensor = random_sensor(rng, 3)
    tank = Tank((0.42, 0.3, 0.25), 0.2)
    lx = tank.size_m[0]
    # the head's tip 2 cm from the +x wall, a little off the middle
    pose = np.array([[0.5 * lx - 0.5 * sensor.length_m - 0.02, 0.02, -0.02, 0.1]])
    options = {"edge_length_m": 0.012, "tank_edge_length_m": 0.012}
    return sensor, tank, pose, options


def _K(sensor, tank, pose, options, stretch=None, **kw):
    """K at ``pose``; ``stretch = (axis, factor)``: the tank's mesh stretched along that axis about its floor (z) or
    its middle (x, y), for the tank ``factor`` times as long there."""
    mesh = mesh_tank(tank, options["tank_edge_length_m"], trajectory_focus_m(sensor, pose), grading=DEFAULT_TANK_GRADING)
    if stretch is not None:
        axis, factor = stretch
        lo = tank.floor_z_m if axis == 2 else 0.0
        v = mesh.vertices_m.copy()
        v[:, axis] = lo + (v[:, axis] - lo) * factor
        mesh = replace(mesh, vertices_m=v)
        lx, ly, lz = tank.size_m
        d = tank.water_depth_m
        tank = Tank((lx * factor, ly, lz), d) if axis == 0 else Tank((lx, ly, lz), d * factor)
    return PoseSweep(sensor, tank, (), 1.0, tank_mesh=mesh, edge_length_m=options["edge_length_m"]).conductance(
        pose, **kw)


def test_walls_and_surface_moved_against_the_bem_solved_again(scene):
    sensor, tank, pose, options = scene
    g = _K(sensor, tank, pose, options, None, wall_derivatives=True)
    names = g.info["wall_regions"]
    dK = g.info["dK_dwall_S_per_m"][0]
    lx, ly, lz = tank.size_m
    d = tank.water_depth_m
    h = 0.003
    n = sensor.n_electrodes
    iu = np.triu_indices(n, 1)
    # the whole tank longer: both x walls move out by h / 2 (poses stay in the tank frame, centred)
    fd_x = (_K(sensor, tank, pose, options, (0, 1 + h / lx)).K_S[0]
            - _K(sensor, tank, pose, options, (0, 1 - h / lx)).K_S[0]) / (2 * h)
    had_x = 0.5 * (dK[names.index("wall_x-")] + dK[names.index("wall_x+")])
    fd_s = (_K(sensor, tank, pose, options, (2, 1 + h / d)).K_S[0]
            - _K(sensor, tank, pose, options, (2, 1 - h / d)).K_S[0]) / (2 * h)
    had_s = dK[names.index("free_surface")]
    for fd, had in ((fd_x, had_x), (fd_s, had_s)):
        a, b = fd[iu], had[iu]
        assert np.abs(b - a).max() < 0.03 * np.abs(a).max(), (a, b)
    # more water, more conductance: every diagonal entry grows when a wall moves out
    assert np.all(np.diagonal(dK, axis1=1, axis2=2) > 0)
    # zero row sums (a derivative of K is a Laplacian too), to the sweep's low-rank truncation
    assert np.abs(dK.sum(axis=-1)).max() < 1e-4 * np.abs(dK).max()


def test_the_sensors_pose_derivatives_against_the_bem_at_moved_poses(scene):
    """Moving the sensor is moving every wall the other way as it sees them: the same formula, checked against
    central differences of the BEM (one mesh, the sensor moved by 1 mm and 0.01 rad)."""
    sensor, tank, pose, options = scene
    sweep = PoseSweep(sensor, tank, (), 1.0, focus_m=trajectory_focus_m(sensor, pose), **options)
    dP = sweep.conductance(pose, wall_derivatives=True).info["dK_dpose"][0]
    iu = np.triu_indices(sensor.n_electrodes, 1)
    for k, (axis, h) in enumerate(((0, 1e-3), (1, 1e-3), (3, 1e-2))):
        plus, minus = pose.copy(), pose.copy()
        plus[0, axis] += h
        minus[0, axis] -= h
        fd = (sweep.conductance(plus).K_S[0] - sweep.conductance(minus).K_S[0])[iu] / (2 * h)
        # on these coarse meshes (12 mm sensor edge) the formula is 0.05 % off towards the wall, 2-5 % along it
        # and in yaw, whatever the tank's edge near the sensor (0.35x or 0.25x its gap, 12 or 6 mm at the axis)
        assert np.abs(dP[k][iu] - fd).max() < 0.06 * np.abs(fd).max(), (k, fd, dP[k][iu])
