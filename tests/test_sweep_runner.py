"""Sweeps: local and dask runs agree, resume computes nothing twice, bad schedulers fail fast.

The model here is a cheap analytic stand-in with real physics: point-like
spherical electrodes (radius a_i) on the sensor axis next to one insulating
wall (the plane x = WALL_X), whose effect is the same-sign image of every
electrode. Potential coefficients P_ij = (1/|r_i - r_j| + 1/|r_i - r_j'|) /
(4 pi sigma) (1/a_i on the diagonal), grounded conductance C = P^-1, and the
isolated K by :func:`electrosense.bem.conductance.isolate`.
"""
from __future__ import annotations

import threading
import time
from dataclasses import dataclass, field

import numpy as np
import pytest

from electrosense.bem.conductance import ConductanceMatrix, isolate
from electrosense.meshes.pose import sensor_to_tank
from electrosense.validation.simulation.sweep import (
    SchedulerError,
    SweepStore,
    dask_client,
    line_poses,
    map_tasks,
    parse_grid,
    run_sweep,
)

WALL_X = 0.5


@dataclass
class WallImageEvaluator:
    """Stand-in for a BEM PoseSweep / PSM: ``.conductance(poses)`` of spheres beside an insulating wall."""

    radii_m: tuple = (0.007, 0.006, 0.006, 0.007)
    xs_m: tuple = (0.08, 0.03, -0.03, -0.08)
    sigma_S_per_m: float = 0.05
    emitter: int = 4
    calls: list = field(default_factory=list, repr=False)
    fail_after_calls: int | None = None

    def conductance(self, poses, progress=False) -> ConductanceMatrix:
        poses = np.asarray(poses, dtype=float)
        if self.fail_after_calls is not None and len(self.calls) >= self.fail_after_calls:
            raise KeyboardInterrupt("simulated kill")
        self.calls.append(poses.copy())
        centres = np.zeros((len(self.radii_m), 3))
        centres[:, 0] = self.xs_m
        r = sensor_to_tank(centres, poses)  # (P, n, 3)
        mirrored = r.copy()
        mirrored[..., 0] = 2 * WALL_X - r[..., 0]
        d = np.linalg.norm(r[:, :, None, :] - r[:, None, :, :], axis=-1)
        d_img = np.linalg.norm(r[:, :, None, :] - mirrored[:, None, :, :], axis=-1)
        n = len(self.radii_m)
        eye = np.eye(n, dtype=bool)
        P = np.where(eye, 1.0 / np.asarray(self.radii_m), 1.0 / np.where(eye, 1.0, d)) + 1.0 / d_img
        P /= 4 * np.pi * self.sigma_S_per_m
        K = isolate(np.linalg.inv(P))
        return ConductanceMatrix(K, self.emitter, self.sigma_S_per_m, {"model": "wall-image stand-in", "triangles": 0})


@pytest.fixture(scope="module")
def grid_poses():
    return parse_grid("-0.3:0.3:6,-0.2:0.2:4,0:1.5:2").poses  # 48 poses


def _serial(evaluator, poses):
    return evaluator.conductance(poses).K_S


def _resistance_at_x(x_m, evaluator):
    """A study task: the receivers' resistances with the sensor at (x_m, 0, 0), yaw 0."""
    return evaluator.conductance(np.array([[x_m, 0.0, 0.0, 0.0]])).resistance_ohm[0]


def test_in_process_sweep_equals_the_direct_call(grid_poses):
    ev = WallImageEvaluator()
    result = run_sweep(ev, grid_poses, workers=1, chunk_poses=7, progress=False)
    np.testing.assert_array_equal(result.conductance.K_S, _serial(WallImageEvaluator(), grid_poses))
    assert result.n_computed == len(grid_poses) and result.n_resumed == 0 and result.workers == 1
    assert [len(c) for c in ev.calls] == [7] * 6 + [6]


def test_local_cluster_of_two_processes_equals_serial(grid_poses, tmp_path):
    """A LocalCluster of two worker processes on loopback, started and stopped here: same numbers, same store."""
    from dask.distributed import Client, LocalCluster

    serial = _serial(WallImageEvaluator(), grid_poses)
    with LocalCluster(n_workers=2, threads_per_worker=1, processes=True, host="127.0.0.1",
                      dashboard_address=None) as cluster, Client(cluster, set_as_default=False) as client:
        assert cluster.scheduler_address.startswith("tcp://127.0.0.1:")
        store = SweepStore.open_or_create(tmp_path / "map.zarr", grid_poses, 4, 4, {"model": "stand-in"}, 5)
        result = run_sweep(WallImageEvaluator(), grid_poses, store, client=client, progress=False)
        assert result.workers == 2
        # the same run through --scheduler ADDRESS
        by_address = run_sweep(WallImageEvaluator(), grid_poses, scheduler=cluster.scheduler_address, progress=False)
        # a study's tasks through the same machinery, the shared model scattered once
        xs = [-0.2, 0.0, 0.2, 0.3]
        study = map_tasks(_resistance_at_x, xs, shared=WallImageEvaluator(), client=client, progress=False)
    local = map_tasks(_resistance_at_x, xs, shared=WallImageEvaluator(), workers=1, progress=False)
    np.testing.assert_array_equal(np.array(study), np.array(local))
    assert np.all(np.diff(np.array(local)[:, 0]) > 0)  # nearer the insulating wall at x = 0.5: larger R
    np.testing.assert_array_equal(result.conductance.K_S, serial)
    np.testing.assert_array_equal(by_address.conductance.K_S, serial)
    ds = store.dataset()
    np.testing.assert_array_equal(ds.K_S.values, serial)
    assert ds.attrs["model"] == "stand-in" and bool(ds.computed.all())
    assert '"triangles": 0' in ds.attrs["mesh"]  # the model's info lands in the attributes


def test_killed_sweep_resumes_and_computes_nothing_twice(grid_poses, tmp_path):
    path = tmp_path / "sweep.zarr"
    identity = {"model": "stand-in", "sigma_S_per_m": 0.05}
    store = SweepStore.open_or_create(path, grid_poses, 4, 4, identity, chunk_poses=5)
    first = WallImageEvaluator(fail_after_calls=4)
    with pytest.raises(KeyboardInterrupt):
        run_sweep(first, grid_poses, store, workers=1, progress=False)
    assert store.computed.sum() == 20 and len(store.pending_chunks()) == 6

    # the re-run opens the same store and computes only what is missing
    store = SweepStore.open_or_create(path, grid_poses, 4, 4, identity, chunk_poses=999)
    second = WallImageEvaluator()
    result = run_sweep(second, grid_poses, store, workers=1, progress=False)
    assert (result.n_resumed, result.n_computed) == (20, 28)
    seen = np.concatenate(first.calls + second.calls)
    assert len(seen) == len(grid_poses)  # every pose evaluated exactly once over both runs
    np.testing.assert_array_equal(np.unique(seen, axis=0), np.unique(grid_poses, axis=0))
    np.testing.assert_array_equal(result.conductance.K_S, _serial(WallImageEvaluator(), grid_poses))

    # a third run finds nothing to do
    third = WallImageEvaluator()
    again = run_sweep(third, grid_poses, SweepStore.open_or_create(path, grid_poses, 4, 4, identity, 5),
                      workers=1, progress=False)
    assert again.n_computed == 0 and third.calls == []


def test_a_store_of_another_sweep_is_not_resumed(grid_poses, tmp_path):
    path = tmp_path / "sweep.zarr"
    SweepStore.open_or_create(path, grid_poses, 4, 4, {"model": "stand-in", "sigma_S_per_m": 0.05}, 8)
    with pytest.raises(ValueError, match="differs in: sigma_S_per_m"):
        SweepStore.open_or_create(path, grid_poses, 4, 4, {"model": "stand-in", "sigma_S_per_m": 0.06}, 8)
    with pytest.raises(ValueError, match="differs in: poses"):
        SweepStore.open_or_create(path, grid_poses[:-1], 4, 4, {"model": "stand-in", "sigma_S_per_m": 0.05}, 8)


def test_bad_scheduler_address_fails_clearly_within_seconds():
    t0 = time.perf_counter()
    with pytest.raises(SchedulerError, match=r"cannot reach the dask scheduler at 'tcp://127.0.0.1:9'.*--scheduler"):
        run_sweep(WallImageEvaluator(), line_poses((0, 0), (0.1, 0), 3), scheduler="tcp://127.0.0.1:9",
                  timeout_s=2, progress=False)
    assert time.perf_counter() - t0 < 10


def test_dask_config_names_the_scheduler(monkeypatch):
    import dask

    with dask.config.set({"scheduler-address": "tcp://127.0.0.1:9"}):
        with pytest.raises(SchedulerError, match="127.0.0.1:9"):
            with dask_client(timeout_s=1):
                pass


def test_one_local_worker_starts_nothing():
    before = set(threading.enumerate())
    with dask_client(workers=1) as client:
        assert client is None
    assert set(threading.enumerate()) <= before  # threads of earlier tests may end meanwhile; none may start


def _thread_pools():
    import numba
    from threadpoolctl import threadpool_info

    return numba.get_num_threads(), tuple(sorted({p["num_threads"] for p in threadpool_info()}))


def test_every_worker_computes_on_one_thread_also_one_started_again():
    """Two local workers: numba and every BLAS or OpenMP pool on one thread in each, and in a worker the nanny
    starts again (the limit is a worker plugin, not a call made once at the cluster's start)."""
    with dask_client(workers=2) as client:
        assert set(client.run(_thread_pools).values()) == {(1, (1,))}
        client.restart_workers([next(iter(client.scheduler_info()["workers"]))])
        assert set(client.run(_thread_pools).values()) == {(1, (1,))}


def test_tiny_bem_grid_on_two_worker_processes_equals_the_serial_sweep(tmp_path):
    """The real BEM: one tank mesh for the whole grid, blocks built once and scattered; chunks on two
    worker processes give the serial sweep's numbers (to round-off)."""
    from dask.distributed import Client, LocalCluster

    from electrosense.meshes.sensor import preset
    from electrosense.meshes.tank import Tank
    from electrosense.validation.simulation.models import pose_evaluator

    poses = parse_grid("-0.1:0.1:3,-0.06:0.06:2").poses
    ev = pose_evaluator("bem", preset("angels-2"), Tank((0.5, 0.4, 0.3)), 0.0354, poses=poses,
                        edge_length_m=0.02, tank_edge_length_m=0.1)
    serial = ev.conductance(poses)
    with LocalCluster(n_workers=2, threads_per_worker=1, processes=True, host="127.0.0.1",
                      dashboard_address=None) as cluster, Client(cluster, set_as_default=False) as client:
        store = SweepStore.open_or_create(tmp_path / "electrosense.bem.zarr", poses, 2, 2, {"model": "bem"}, 2)
        result = run_sweep(ev, poses, store, client=client, progress=False)
    # equal to the truncation: the workers' BLAS runs single-threaded, this process's may not (other sums'
    # order); the coupling's truncated SVD (tol 1e-6, its range sampled in single precision) turns that into
    # up to ~1e-7, below the truncation's own effect on K (~1e-6 against tol 1e-10)
    np.testing.assert_allclose(result.conductance.K_S, serial.K_S, rtol=1e-6, atol=1e-6 * np.abs(serial.K_S).max())
    R = result.conductance.resistance_ohm[:, 0]
    assert np.all(np.isfinite(R)) and np.all(R > 0)
    assert '"triangles"' in store.attrs["mesh"]


def test_a_worker_with_other_model_code_refuses():
    from electrosense.validation.simulation.sweep.runner import _evaluate_block

    with pytest.raises(RuntimeError, match="install the same electrosense on every worker"):
        _evaluate_block(WallImageEvaluator(), line_poses((0, 0), (0.1, 0), 2), "electrosense 0.0 src 000000000000")
    K, seconds, meta = _evaluate_block(WallImageEvaluator(), line_poses((0, 0), (0.1, 0), 2),
                                       __import__("electrosense.validation.simulation.models", fromlist=["x"]).code_version())
    assert K.shape == (2, 4, 4) and meta["emitter"] == 4 and meta["info"]["triangles"] == 0


def test_a_ctrl_c_inside_the_held_block_waits_for_release_and_the_handler_comes_back():
    """SIGINT sent to this process inside ``ctrl_c_held`` raises nothing there; ``release()`` raises it once, and the
    handler and the signal mask are what they were."""
    import os
    import signal

    from electrosense.validation.simulation.sweep.runner import ctrl_c_held

    # Python's own handler, as in a terminal's foreground job (a test run started in the background ignores
    # SIGINT from its start, and the held block then rightly raises nothing: the next test)
    before = signal.signal(signal.SIGINT, signal.default_int_handler)
    try:
        handler, mask = signal.getsignal(signal.SIGINT), signal.pthread_sigmask(signal.SIG_BLOCK, [])
        with ctrl_c_held() as release:
            os.kill(os.getpid(), signal.SIGINT)
            time.sleep(0.05)                      # a step that must not stop halfway goes on
            with pytest.raises(KeyboardInterrupt):
                release()
            release()                             # once only
        assert signal.getsignal(signal.SIGINT) is handler and signal.pthread_sigmask(signal.SIG_BLOCK, []) == mask
        with ctrl_c_held() as release:            # nothing sent: nothing raised
            release()
    finally:
        signal.signal(signal.SIGINT, before)


def test_a_ctrl_c_ignored_by_the_process_stays_ignored_through_the_held_block():
    """A process started with SIGINT ignored (a background job): the held block raises nothing at release and
    leaves the signal ignored."""
    import os
    import signal

    from electrosense.validation.simulation.sweep.runner import ctrl_c_held

    before = signal.signal(signal.SIGINT, signal.SIG_IGN)
    try:
        with ctrl_c_held() as release:
            os.kill(os.getpid(), signal.SIGINT)
            time.sleep(0.05)
            release()
        assert signal.getsignal(signal.SIGINT) is signal.SIG_IGN
    finally:
        signal.signal(signal.SIGINT, before)
