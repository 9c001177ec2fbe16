"""Sensitivities of transfer impedances to electrode positions from one solve (reciprocity) against finite differences."""

import numpy as np

from electrosense.bem.protocol import adjacent_protocol, involves_drive, transfer_impedances_ohm
from electrosense.bem.sensitivity import combine_shift_sensitivities, shift_sensitivities_ohm_per_m
from electrosense.bem.solve import solve_scene
from electrosense.meshes import Scene
from electrosense.meshes.cylinder_tank import CylinderTank
from electrosense.meshes.surface_electrodes import DiscElectrode


def _scene(R, H, phis, z, a, shift=None):
    ph = np.array(phis, float)
    if shift is not None:
        ph = ph + shift / R
    es = tuple(DiscElectrode((R * np.cos(p), R * np.sin(p), z), a) for p in ph)
    return Scene(sensor=None, tank=CylinderTank(R, H), electrodes=es)


def test_combination_follows_reciprocity():
    g = {(1, 2): np.array([0.5, 0.7, 1.5, 3.0]), (3, 4): np.array([4.0, 5.0, 2.0, 0.1])}
    J = combine_shift_sensitivities([(1, 2)], [(3, 4)], g, electrodes=[1, 2, 3, 4])
    # a drive electrode moves in the measurement pair's field, a measurement electrode in the drive's
    np.testing.assert_allclose(J[0, 0], [4.0, -5.0, 1.5, -3.0])


def test_one_solve_sensitivity_matches_finite_differences_of_two_solves():
    rng = np.random.default_rng(11)
    R, H = rng.uniform(0.08, 0.12), rng.uniform(0.08, 0.12)
    n = 6
    phis = rng.uniform(0, 2 * np.pi) + 2 * np.pi * np.arange(n) / n + rng.uniform(-0.1, 0.1, n)
    z, a = -H / 2 + 0.4 * H, 0.04 * R
    opts = dict(edge_length_m=R / 3, edge_fraction=0.5, electrode_grading=1.0)
    sol = solve_scene(_scene(R, H, phis, z, a), 1.0, **opts)
    drv, mea = adjacent_protocol(range(1, n + 1))
    c = np.array([[R * np.cos(p), R * np.sin(p), z] for p in phis])
    normal = c * [1 / R, 1 / R, 0]
    tangent = np.c_[-normal[:, 1], normal[:, 0], 0 * phis]
    J = shift_sensitivities_ohm_per_m(sol, drv, mea, range(1, n + 1), c, normal, tangent, np.full(n, a))
    e, ds = int(rng.integers(n)), 0.25 * a
    Z = []
    for sign in (1, -1):
        shift = np.zeros(n)
        shift[e] = sign * ds
        Z.append(transfer_impedances_ohm(solve_scene(_scene(R, H, phis, z, a, shift), 1.0, **opts).K_S, drv, mea))
    fd = (Z[0] - Z[1]) / (2 * ds)
    use = ~involves_drive(drv, mea) & (np.abs(J[:, :, e]) > 0)
    assert use.sum() >= 4
    np.testing.assert_allclose(J[:, :, e][use], fd[use], rtol=0.15, atol=0.05 * np.abs(fd[use]).max())
