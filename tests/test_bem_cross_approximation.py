"""The cross approximation of a low-rank block (electrosense.bem.cross_approximation) and the sensor's own image
built with it (PoseSweep._sensor_image_low_rank): checked against the assembled block and the assembled image."""
import numpy as np
import pytest

import electrosense.bem.sweep as sweep_module
from electrosense.bem import PoseSweep
from electrosense.bem.cross_approximation import cross_approximation, recompressed
from electrosense.meshes import Tank, preset


def _kernel_block(rng, m=300, n=250):
    """1 / |x - y| between two random point clouds a short distance apart (numerically low rank)."""
    x = rng.uniform(-0.5, 0.5, (m, 3))
    y = rng.uniform(-0.5, 0.5, (n, 3)) + [2.5, 0.0, 0.0]
    return 1.0 / np.linalg.norm(x[:, None] - y[None], axis=2)


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_the_block_is_recovered_to_the_tolerance_from_few_rows_and_columns(seed):
    M = _kernel_block(np.random.default_rng(seed))
    seen = {"rows": 0, "columns": 0}

    def row(i):
        seen["rows"] += 1
        return M[i]

    def column(j):
        seen["columns"] += 1
        return M[:, j]

    for tol in (1e-4, 1e-7):
        seen.update(rows=0, columns=0)
        U, V = cross_approximation(row, column, M.shape, tol)
        assert np.linalg.norm(U @ V - M) < 3 * tol * np.linalg.norm(M)
        assert seen["columns"] < M.shape[1] / 2 and seen["rows"] < M.shape[0] / 2, seen
    P, Qt, s = recompressed(U, V, 1e-6)
    assert np.allclose(Qt @ Qt.T, np.eye(len(s)))
    assert np.linalg.norm(P @ Qt - M, 2) < 2e-6 * s[0]


def test_a_part_the_pivots_never_visit_is_found_by_the_check_rows():
    rng = np.random.default_rng(4)
    M = _kernel_block(rng, 400, 300)
    hidden = np.zeros_like(M)
    hidden[350:360, 10:20] = 1e-3 * np.abs(M).max()      # a patch of rows the smooth part's pivots never pick
    M = M + hidden
    U, V = cross_approximation(lambda i: M[i], lambda j: M[:, j], M.shape, 1e-6, checks=64)
    assert np.linalg.norm(U @ V - M) < 3e-6 * np.linalg.norm(M)


def test_a_block_of_full_rank_is_left_to_the_caller():
    M = np.random.default_rng(5).standard_normal((60, 60))
    assert cross_approximation(lambda i: M[i], lambda j: M[:, j], M.shape, 1e-6) is None


def test_the_sensors_image_cross_approximated_gives_the_assembled_images_K(monkeypatch):
    """A sensor at a corner of a random box, 5-8 mm from two walls: its K with the sensor's own images
    cross-approximated (forced on a small mesh) against the images assembled, at the tank map's ``tol``."""
    rng = np.random.default_rng(3)
    sensor = preset("angels-2")
    tank = Tank(tuple(rng.uniform([0.4, 0.3, 0.15], [0.6, 0.45, 0.25])))
    lo, hi = tank.water_bounds_m
    gaps = rng.uniform(0.005, 0.008, 2)
    pose = np.array([[hi[0] - 0.5 * sensor.length_m - gaps[0], lo[1] + sensor.radius_m + gaps[1], 0.0, 0.0]])
    sweep = PoseSweep(sensor, tank, sigma_S_per_m=1.0, edge_length_m=0.012, tol=1e-5, block_cache=False,
                      edge_correction=False, image_face=("wall_x+", "wall_y-"), tank_near_ratio=0.7)
    monkeypatch.setattr(sweep_module, "IMAGE_CROSS_MIN_TRIANGLES", 0)      # and no cap on its rank: its accuracy
    monkeypatch.setattr(sweep_module, "COUPLING_CROSS_MIN_TRIANGLES", 10**9)   # is checked here, not its cost;
    calls = []                                                              # the coupling's is the next test's

    def uncapped(row, column, shape, tol, max_rank=None, first_row=0):
        calls.append(1)
        return cross_approximation(row, column, shape, tol, max_rank=shape[0], first_row=first_row)

    monkeypatch.setattr(sweep_module, "cross_approximation", uncapped)
    K_cross = sweep.conductance(pose).K_S[0]
    assert calls, "the cross approximation was not taken"
    monkeypatch.setattr(PoseSweep, "image_by_cross_approximation", False)
    K_assembled = sweep.conductance(pose).K_S[0]
    assert np.abs(K_cross - K_assembled).max() < 1e-5 * np.abs(K_assembled).max()


def test_the_coupling_cross_approximated_gives_the_assembled_couplings_K(monkeypatch):
    """A random sensor pose 5-15 mm from a wall of a random box at the tank map's ``tol``, the wall an image plane
    and the other faces meshed (a map's pose): its K with the sensor-tank coupling from rows and columns
    (:meth:`PoseSweep._coupling_low_rank`, forced on a small mesh) against the coupling assembled. Its receiver
    currents move by a few 1e-6 on the coarse meshes of two random sensors (the module's constants): bounded
    here at 3e-5 of the largest."""
    from electrosense.validation.diagnosis.unseen import random_sensor

    rng = np.random.default_rng(11)
    for _ in range(2):
        sensor = random_sensor(rng)
        tank = Tank(tuple(rng.uniform([0.5, 0.35, 0.2], [0.8, 0.5, 0.3])))
        lo, hi = tank.water_bounds_m
        gap = rng.uniform(0.005, 0.015)
        pose = np.array([[rng.uniform(-0.05, 0.05), hi[1] - sensor.radius_m - gap, 0.0, rng.uniform(-0.2, 0.2)]])
        sweep = PoseSweep(sensor, tank, sigma_S_per_m=1.0, edge_length_m=1.8 * sensor.radius_m, tol=1e-5,
                          block_cache=False, image_face="wall_y+", tank_near_ratio=0.7)
        monkeypatch.setattr(sweep_module, "COUPLING_CROSS_MIN_TRIANGLES", 0)
        K_cross = sweep.conductance(pose).K_S[0]
        assert sweep._coupling_cross_tally["converged"] == 1, sweep._coupling_cross_tally
        monkeypatch.setattr(PoseSweep, "coupling_by_cross_approximation", False)
        K_assembled = sweep.conductance(pose).K_S[0]
        monkeypatch.undo()
        e = sensor.emitter - 1
        I_cross, I = np.delete(K_cross[:, e], e), np.delete(K_assembled[:, e], e)
        assert np.abs(I_cross - I).max() < 3e-5 * np.abs(I).max()
        assert np.abs(I_cross - I).max() > 0.0    # it was taken


def test_a_coupling_that_does_not_converge_is_assembled_after_one_try(monkeypatch):
    sensor = preset("angels-2")
    tank = Tank((0.5, 0.35, 0.2))
    sweep = PoseSweep(sensor, tank, sigma_S_per_m=1.0, edge_length_m=0.012, tol=1e-5, block_cache=False,
                      edge_correction=False, tank_near_ratio=0.7)
    monkeypatch.setattr(sweep_module, "COUPLING_CROSS_MIN_TRIANGLES", 0)
    tries = []
    monkeypatch.setattr(sweep_module, "cross_approximation", lambda *a, **k: tries.append(1))   # never converges
    K = [sweep.with_focus().conductance([[x, 0.0, 0.0, 0.0]]).K_S[0] for x in (0.0, 0.02, 0.04)]
    assert len(tries) == 1
    monkeypatch.setattr(PoseSweep, "coupling_by_cross_approximation", False)
    assert np.allclose(K[0], sweep.with_focus().conductance([[0.0, 0.0, 0.0, 0.0]]).K_S[0], rtol=0, atol=0)


def test_a_sensor_whose_image_does_not_converge_is_assembled_after_three_tries(monkeypatch):
    sensor = preset("angels-2")
    tank = Tank((0.5, 0.35, 0.2))
    sweep = PoseSweep(sensor, tank, sigma_S_per_m=1.0, edge_length_m=0.012, tol=1e-5, block_cache=False,
                      edge_correction=False, image_face="wall_y+", tank_near_ratio=0.7)
    monkeypatch.setattr(sweep_module, "IMAGE_CROSS_MIN_TRIANGLES", 0)
    monkeypatch.setattr(sweep_module, "COUPLING_CROSS_MIN_TRIANGLES", 10**9)
    tries = []
    monkeypatch.setattr(sweep_module, "cross_approximation", lambda *a, **k: tries.append(1))   # never converges
    y = 0.175 - sensor.radius_m - np.linspace(0.006, 0.02, 4)
    K = [sweep.with_focus(image_face="wall_y+").conductance([[0.0, yy, 0.0, 0.0]]).K_S[0] for yy in y]
    assert len(tries) == 3
    assert all(np.isfinite(k).all() for k in K)
