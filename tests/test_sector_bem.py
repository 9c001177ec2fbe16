"""The BEM of sector sensors: the symmetric solve against the full collocation, the all-sectors identity, equal
currents, the lateral gains by reciprocity, and the lateral signal in a tank. Coarse meshes (seconds each)."""
import numpy as np
import pytest

from electrosense.bem.boundary_conditions import WaterBoundary
from electrosense.bem.lateral import free_space_response
from electrosense.bem.solution import solve
from electrosense.bem.solve import conductance_matrix
from electrosense.bem.symmetric import solve_symmetric
from electrosense.meshes import Scene, Tank, preset
from electrosense.meshes.sector_mesh import block_symmetry
from electrosense.meshes.sensor_mesh import mesh_sensor

COARSE = 0.02


@pytest.mark.parametrize("sectors, gap", [({2: 4, 3: 4}, 0.002), ({2: 2, 3: 3}, 0.001), ({1: 3}, 0.0)])
def test_symmetric_solve_is_the_full_collocation(sectors, gap):
    s = preset("angels-4").with_sectors(sectors, gap)
    wb = WaterBoundary.from_meshes(mesh_sensor(s, COARSE), emitter=s.emitter, allow_touching=s.sectors_touch)
    order, mirror = block_symmetry(s)
    fast = solve_symmetric(wb, 0.05, 1e-3, s.emitter, order=order, mirror=mirror)
    full = solve(wb, 0.05, 1e-3, s.emitter)
    assert fast.info["blocks"] == order
    assert np.abs(fast.K_S - full.K_S).max() < 1e-10 * np.abs(full.K_S).max()


def test_sectors_without_gaps_sum_to_the_whole_ring():
    s = preset("angels-4").with_sectors({2: 4, 3: 3}, 0.0, emitter=1)
    K = conductance_matrix(Scene(s), 1.0, edge_length_m=COARSE).K_S
    whole = conductance_matrix(Scene(s.merged()), 1.0, edge_length_m=COARSE).K_S
    W = s.merge_matrix()
    err = np.abs(W.T @ K @ W - whole).max(axis=1) / np.abs(whole).max(axis=1)
    assert err.max() < 3e-3


def test_a_rings_sectors_carry_equal_currents_when_a_cap_emits():
    s = preset("angels-4").with_sectors({2: 4, 3: 4}, 0.002)
    K = conductance_matrix(Scene(s), 1.0, edge_length_m=COARSE).K_S
    for j in (1, 2):
        I = K[np.asarray(s.numbers_of(j)) - 1, s.emitter - 1]
        assert np.ptp(I) < 1e-9 * np.abs(I).max()
    assert np.abs(K - K.T).max() < 1e-4 * np.abs(K).max() and np.abs(K.sum(axis=1)).max() < 1e-12


def test_gradient_response_by_reciprocity_is_the_uniform_field_solve():
    s = preset("angels-2").with_sectors({1: 2}, gap_m=0.002)
    r = free_space_response(s, 1.0, edge_length_m=COARSE)
    # a uniform field E along d: the potential -E x_d, its value at each region's centre and its gradient -E e_d
    from_regions = -(r.potential_response @ r.region_centres_m) - r.gradient_response.sum(axis=1)
    scale = np.abs(r.uniform_field_A_per_V_per_m).max()
    assert np.abs(from_regions - r.uniform_field_A_per_V_per_m).max() < 5e-3 * scale
    assert r.uniform_field_A_per_V_per_m[0, 1] > 0 > r.uniform_field_A_per_V_per_m[1, 1]   # sector 1 faces +y


def test_lateral_signal_changes_sign_with_the_walls_side():
    from electrosense.bem.sweep import PoseSweep

    s = preset("angels-4").with_sectors({2: 2}, gap_m=0.003)
    d = 0.5 - s.radius_m - 0.04
    sweep = PoseSweep(s, Tank((1.0, 1.0, 1.0)), sigma_S_per_m=0.0354, edge_length_m=COARSE)
    K = sweep.conductance(np.array([[0.0, d, 0, 0], [0.0, -d, 0, 0], [0.0, -d, 0, np.pi]])).K_S
    I = -K[:, :, s.emitter - 1]
    lateral = I[:, 1] - I[:, 2]            # sector 1 (+y, left) minus sector 2 (right)
    assert lateral[0] * lateral[1] < 0 and abs(lateral[0] + lateral[1]) < 1e-3 * abs(lateral[0])
    assert lateral[2] == pytest.approx(lateral[0], rel=1e-3)     # turned round: the wall is on its left again
