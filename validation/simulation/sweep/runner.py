"""One way to run a sweep or a study: on this machine's cores, or on a dask.distributed cluster.

* Default: the cores of this machine. With one worker everything runs in this
  process (nothing is started); with more, a ``dask.distributed.LocalCluster``
  of worker processes on the loopback interface is started and stopped around
  the run.
* ``scheduler="tcp://host:8786"`` (``--scheduler``), or the Dask configuration
  key ``scheduler-address`` (e.g. ``DASK_SCHEDULER_ADDRESS``): the run goes to
  that cluster. Every worker must have electrosense installed.

Dask does the distributed work: the pose-invariant part of the model (a
:class:`electrosense.bem.PoseSweep` with its assembled blocks, or a PSM) is sent to every
worker once with ``client.scatter(..., broadcast=True)``; then only poses go
out and conductance matrices come back, as futures. Batches adapt: the first
tasks are one stored chunk each; once the time per pose is known, chunks are
grouped so that a task lasts about ``target_task_s`` while every worker still
gets several tasks. Finished chunks are written to the store at once, in the
order they finish, so a killed run loses only the tasks in flight and a re-run
computes only what is missing. The results are the same whichever way the run
went: every pose is evaluated by the same code on the same inputs.

Example
-------
>>> from electrosense.validation.simulation.models import pose_evaluator
>>> from electrosense.validation.simulation.sweep.runner import run_sweep
>>> ev = pose_evaluator("psm", preset("angels-4"), Tank((1, 1, 1)), 0.0354)  # doctest: +SKIP
>>> result = run_sweep(ev, poses, workers=2)  # doctest: +SKIP
>>> result.conductance.resistance_ohm.shape  # doctest: +SKIP
(1000, 3)
"""
from __future__ import annotations

import logging
import math
import os
import time
from collections import deque
from contextlib import contextmanager
from dataclasses import dataclass, field

import numpy as np

from electrosense.bem.conductance import ConductanceMatrix
from electrosense.validation.simulation.models import poses_array
from electrosense.validation.simulation.workers import one_thread

__all__ = ["SchedulerError", "SweepResult", "dask_client", "run_sweep", "map_tasks", "local_cores", "default_chunk_poses"]

#: Seconds to wait for a scheduler (and for its first worker) before giving up.
CONNECT_TIMEOUT_S = 5.0


class SchedulerError(RuntimeError):
    """The dask scheduler cannot be reached or has no workers."""


def local_cores() -> int:
    """Cores this process may use."""
    try:
        return len(os.sched_getaffinity(0))
    except AttributeError:  # not on Linux
        return os.cpu_count() or 1


def scheduler_address(scheduler: str | None = None) -> str | None:
    """The scheduler to use: ``scheduler`` or Dask's ``scheduler-address`` configuration, else None."""
    if scheduler:
        return str(scheduler)
    import dask

    return dask.config.get("scheduler-address", None) or None


@contextmanager
def dask_client(scheduler: str | None = None, workers: int | None = None, processes: bool = True,
                timeout_s: float = CONNECT_TIMEOUT_S):
    """A ``dask.distributed.Client`` for the run, or ``None`` to run in this process.

    Parameters
    ----------
    scheduler : str, optional
        Address of a running scheduler (``tcp://host:port``); default: Dask's
        ``scheduler-address`` configuration, else this machine.
    workers : int, optional
        Local workers (default: the cores of this machine); 1 runs in this
        process. Ignored with a scheduler.
    processes : bool
        Local workers as processes (default; safe for kernels that hold the
        GIL) or as threads of this process.
    timeout_s : float
        How long to wait for the scheduler and its first worker.

    Raises
    ------
    SchedulerError
        Unreachable scheduler, or one without workers, after ``timeout_s``.
    """
    address = scheduler_address(scheduler)
    if address:
        from dask.distributed import Client

        try:
            client = Client(address, timeout=f"{timeout_s}s", set_as_default=False)
        except Exception as exc:  # OSError, TimeoutError, ValueError for a malformed address
            raise SchedulerError(
                f"cannot reach the dask scheduler at {address!r} within {timeout_s:g} s ({exc}). "
                "Check the address and port, start one with `dask scheduler` and `dask worker ADDRESS`, "
                "or leave out --scheduler to run on this machine's cores."
            ) from None
        try:
            try:
                client.wait_for_workers(1, timeout=timeout_s)
            except Exception:
                raise SchedulerError(
                    f"the dask scheduler at {address!r} has no workers after {timeout_s:g} s; "
                    f"start some with `dask worker {address}`"
                ) from None
            yield client
        finally:
            client.close()
        return
    n = local_cores() if workers is None else int(workers)
    if n < 1:
        raise ValueError(f"workers must be at least 1, got {workers}")
    if n == 1:
        yield None
        return
    import signal

    from dask.distributed import Client, LocalCluster

    if hasattr(signal, "pthread_sigmask"):   # POSIX
        from multiprocessing import resource_tracker

        # the resource tracker, started by the first worker process, unblocks SIGINT in the thread that starts
        # it (the cluster's event loop, and then every thread and worker that loop starts): started here, before
        resource_tracker.ensure_running()
    with ctrl_c_held() as release:   # the workers never see Ctrl-C; this process's waits for the start
        cluster = LocalCluster(
            n_workers=n,
            threads_per_worker=1,
            processes=processes,
            host="127.0.0.1",
            dashboard_address=None,
            memory_limit=0,  # the models check their own memory needs
            silence_logs=logging.ERROR,
        )
        with cluster, Client(cluster, set_as_default=False) as client:
            # dask sets the BLAS's threads through the environment, not numba's or scipy's; a plugin reaches every
            # worker, also one the nanny starts again after a crash
            client.register_plugin(_one_thread_plugin())
            try:
                release()   # a Ctrl-C while the cluster started is raised here, and handled as any other
                yield client
            except KeyboardInterrupt:
                # the user stopped the run: as the cluster closes, the scheduler's handlers of the operations in
                # flight (a scatter of the next chunk's model) and the workers' heartbeats fail and would log
                # their tracebacks under the one line the interrupt prints
                logging.getLogger("distributed").setLevel(logging.CRITICAL)
                try:
                    client.run(_quiet_distributed_logs, wait=True)
                except Exception:   # a worker already gone: nothing of it left to log
                    pass
                raise


def _quiet_distributed_logs() -> None:
    """Only critical messages from dask.distributed in this process (a worker of an interrupted run)."""
    logging.getLogger("distributed").setLevel(logging.CRITICAL)


def _one_thread_plugin():
    """A dask worker plugin that calls :func:`~electrosense.validation.simulation.workers.one_thread` in each
    worker as it starts (dask is optional: imported here)."""
    from dask.distributed import WorkerPlugin

    class OneThread(WorkerPlugin):
        name = "electrosense-one-thread"

        def setup(self, worker) -> None:
            one_thread()

    return OneThread()


@contextmanager
def ctrl_c_held():
    """Hold Ctrl-C through a step that must not stop halfway, and start processes that never see it.

    Inside the block SIGINT is blocked in this thread: the threads and processes started from it meanwhile
    inherit the mask and never receive it (a dask cluster's event loop and its nannies' workers: a terminal
    sends Ctrl-C to every process of the foreground group, and a worker that got it would print its own
    KeyboardInterrupt traceback). The kernel hands a SIGINT that arrives meanwhile to a thread started before
    (zarr's event loop), whose note of it this process's handler keeps. Calling the yielded ``release()``
    restores the handler and the mask and raises KeyboardInterrupt for a Ctrl-C held meanwhile, where the
    caller handles it (inside the cluster's context, which then closes it; after a store is whole); leaving
    the block releases without raising. An interrupt used to be ignored while the cluster started, and one in
    those seconds (3-10 s on 2 busy cores) was lost; one while a sweep's store was written left zarr's
    tasks pending, each said at exit. A process started with Ctrl-C ignored (a background job) keeps it
    ignored. Without ``signal.pthread_sigmask`` (Windows), or off the main thread, nothing is held.

    >>> with ctrl_c_held() as release:
    ...     release()        # nothing held: returns
    """
    import signal
    import threading

    if threading.current_thread() is not threading.main_thread() or not hasattr(signal, "pthread_sigmask"):
        yield lambda: None
        return
    held = []
    previous = signal.signal(signal.SIGINT, lambda signum, frame: held.append(signum))
    mask = signal.pthread_sigmask(signal.SIG_BLOCK, {signal.SIGINT})
    released = False

    def release(raise_held: bool = True) -> None:
        nonlocal released
        if released:
            return
        released = True
        if signal.SIGINT in signal.sigpending():   # one sent to this thread: noted, not delivered
            held.append(signal.SIGINT)
            signal.signal(signal.SIGINT, signal.SIG_IGN)     # discards the pending one
            signal.pthread_sigmask(signal.SIG_SETMASK, mask)
        signal.signal(signal.SIGINT, signal.default_int_handler if previous is None else previous)
        signal.pthread_sigmask(signal.SIG_SETMASK, mask)
        if held and raise_held and previous is not signal.SIG_IGN:   # an ignored Ctrl-C stays ignored
            raise KeyboardInterrupt

    try:
        yield release
    finally:
        release(raise_held=False)


def default_chunk_poses(n_poses: int, workers: int) -> int:
    """Poses per stored chunk: about 16 chunks per worker, at most 4096 poses each."""
    return int(max(1, min(4096, math.ceil(n_poses / (16 * max(1, workers))))))


def _evaluate_block(evaluator, poses: np.ndarray, expected_version: str | None = None):
    """Worker side: the conductance matrices of a block of poses, the seconds it took, and the model's info.

    ``expected_version`` is the client's :func:`electrosense.validation.simulation.models.code_version`: a worker running other
    model code (another install, or files edited since the run started) refuses rather than mixing results.
    """
    if expected_version is not None:
        from electrosense.validation.simulation.models import code_version

        if code_version() != expected_version:
            raise RuntimeError(
                f"this dask worker runs {code_version()} but the sweep was started with {expected_version}: "
                "install the same electrosense on every worker (and do not edit it during a run)"
            )
    t0 = time.perf_counter()
    C = evaluator.conductance(poses)
    meta = {"emitter": C.emitter, "sigma_S_per_m": C.sigma_S_per_m, "info": _plain_info(C.info)}
    return np.asarray(C.K_S, dtype=float), time.perf_counter() - t0, meta


def _plain_info(info: dict) -> dict:
    """The JSON-able scalars of a result's ``info`` (the mesh size, the solver...)."""
    out = {}
    for key, value in (info or {}).items():
        if isinstance(value, (str, bool, int, float)) or value is None:
            out[str(key)] = value
        elif isinstance(value, (np.integer, np.floating)):
            out[str(key)] = value.item()
    return out


@dataclass
class SweepResult:
    """What a sweep gives back."""

    conductance: ConductanceMatrix  #: batch shape (P,), or (reached poses,) where ``reached`` is not all True
    n_computed: int  #: poses computed by this run
    n_resumed: int  #: poses found already computed in the store
    seconds: float
    workers: int  #: 1 for an in-process run
    info: dict = field(default_factory=dict)  #: the model's info from the first computed block
    reached: np.ndarray | None = None  #: (P,) bool, the poses the model reached (a ``skip_blocked`` evaluator)

    @property
    def poses_per_s(self) -> float:
        return self.n_computed / self.seconds if self.seconds > 0 else math.inf


def run_sweep(
    evaluator,
    poses,
    store=None,
    *,
    scheduler: str | None = None,
    workers: int | None = None,
    client=None,
    processes: bool = True,
    chunk_poses: int | None = None,
    target_task_s: float = 1.0,
    progress: bool = True,
    timeout_s: float = CONNECT_TIMEOUT_S,
) -> SweepResult:
    """Evaluate ``evaluator.conductance`` at every pose, in chunks, locally or on a dask cluster.

    Parameters
    ----------
    evaluator : object with ``.conductance(poses (m, 4)) -> ConductanceMatrix``
        The pose-invariant part of a model (:func:`electrosense.validation.simulation.models.pose_evaluator`);
        it must be picklable to run on workers.
    poses : array (P, 4)
    store : SweepStore, optional
        Where chunks land as they finish; an existing store is resumed (only
        its pending chunks are computed). Without one the results stay in memory.
    scheduler, workers, processes, timeout_s
        Where to run (see :func:`dask_client`).
    client : dask.distributed.Client, optional
        Use this client as is (overrides ``scheduler`` and ``workers``).
    chunk_poses : int, optional
        Poses per chunk without a store (default :func:`default_chunk_poses`).
    target_task_s : float
        Aimed duration of one task once the time per pose is known.
    progress : bool
        A progress bar with the rate and the time left.

    Returns
    -------
    SweepResult
    """
    poses = poses_array(poses)
    P = len(poses)
    if P == 0:
        raise ValueError("a sweep needs at least one pose")
    if store is not None and store.n_poses != P:
        raise ValueError(f"the store holds {store.n_poses} poses but {P} poses were given")
    if client is not None:
        return _run(evaluator, poses, store, client, chunk_poses, target_task_s, progress)
    with dask_client(scheduler, workers, processes, timeout_s) as c:
        return _run(evaluator, poses, store, c, chunk_poses, target_task_s, progress)


def _run(evaluator, poses, store, client, chunk_poses, target_task_s, progress) -> SweepResult:
    from tqdm.auto import tqdm

    t0 = time.perf_counter()
    P = len(poses)
    n_workers = 1 if client is None else max(1, len(client.scheduler_info().get("workers", {})))
    if store is not None:
        pending = store.pending_chunks()
    else:
        size = chunk_poses or default_chunk_poses(P, n_workers)
        pending = [(a, min(a + size, P)) for a in range(0, P, size)]
    n_todo = sum(b - a for a, b in pending)
    state = {"meta": None, "K_all": None}

    def land(chunk, K, meta):
        """A finished chunk: into the store (or memory), and the info of the first one into the attributes."""
        a, b = chunk
        if store is not None:
            store.write_chunk(a, K)
        else:
            if state["K_all"] is None:
                state["K_all"] = np.full((P,) + K.shape[1:], np.nan)
            state["K_all"][a:b] = K
        if state["meta"] is None:
            state["meta"] = meta
            if store is not None and meta["info"]:
                store.update_attrs(mesh=meta["info"])
        bar.update(b - a)

    with tqdm(total=P, initial=P - n_todo, unit="pose", desc="sweep", disable=not progress, smoothing=0.1) as bar:
        if client is None:
            for chunk in pending:
                K, _, meta = _evaluate_block(evaluator, poses[chunk[0]:chunk[1]])
                land(chunk, K, meta)
        else:
            _run_on_dask(client, evaluator, poses, pending, n_workers, target_task_s, land)

    info = dict(state["meta"]["info"]) if state["meta"] else {}
    sigma = state["meta"]["sigma_S_per_m"] if state["meta"] else getattr(evaluator, "sigma_S_per_m", None)
    if sigma is None:
        raise ValueError("the evaluator has no sigma_S_per_m and nothing was computed to learn it from")
    if store is not None:
        reached = store.reached
        conductance = store.conductance(float(sigma), reached_only=True)
    else:
        reached = np.isfinite(state["K_all"]).all(axis=(1, 2))
        conductance = ConductanceMatrix(state["K_all"][reached], state["meta"]["emitter"], float(sigma), info)
    return SweepResult(conductance, n_todo, P - n_todo, time.perf_counter() - t0, n_workers, info, reached)


def _run_on_dask(client, evaluator, poses, pending, n_workers, target_task_s, land) -> None:
    """Submit chunk batches as futures, keep every worker busy, land results as they finish."""
    from dask.distributed import as_completed

    if not pending:
        return
    from electrosense.validation.simulation.models import code_version

    version = code_version()  # pinned when the model was built (validation.simulation.models.pose_evaluator)
    shared = client.scatter(evaluator, broadcast=True, hash=False)
    queue = deque(pending)
    in_flight = {}
    seconds_per_pose = None
    max_in_flight = 2 * n_workers

    def batch_size() -> int:
        if seconds_per_pose is None:
            return 1
        chunk = max(1, queue[0][1] - queue[0][0])
        by_time = max(1, round(target_task_s / max(seconds_per_pose * chunk, 1e-9)))
        balance = max(1, len(queue) // (2 * n_workers))  # leave several tasks per worker
        return int(min(by_time, balance))

    def submit_next(ac):
        chunks = [queue.popleft() for _ in range(min(batch_size(), len(queue)))]
        block = np.concatenate([poses[a:b] for a, b in chunks])
        future = client.submit(_evaluate_block, shared, block, version, pure=False)
        in_flight[future] = chunks
        ac.add(future)

    ac = as_completed(loop=client.loop)
    try:
        while queue and len(in_flight) < max_in_flight:
            submit_next(ac)
        for future in ac:
            chunks = in_flight.pop(future)
            K, seconds, meta = future.result()  # re-raises a worker's exception here
            offset = 0
            for a, b in chunks:
                land((a, b), K[offset:offset + (b - a)], meta)
                offset += b - a
            rate = seconds / max(1, offset)
            seconds_per_pose = rate if seconds_per_pose is None else 0.5 * (seconds_per_pose + rate)
            while queue and len(in_flight) < max_in_flight:
                submit_next(ac)
    finally:
        if in_flight:
            client.cancel(list(in_flight))
        client.cancel([shared])


def map_tasks(function, items, shared=None, *, scheduler=None, workers=None, client=None, processes=True,
              progress=True, timeout_s: float = CONNECT_TIMEOUT_S) -> list:
    """``[function(item, shared) for item in items]`` on the same machinery as :func:`run_sweep`.

    For studies whose tasks are not poses (a family of sensor designs, blind
    diagnosis cases): ``shared`` (e.g. a PSM, a calibration) is scattered to
    every worker once; the results come back in the order of ``items``.
    ``function`` must be importable on the workers (a module-level function).
    """
    from tqdm.auto import tqdm

    items = list(items)

    def go(c):
        if c is None:
            return [function(item, shared) for item in tqdm(items, disable=not progress, unit="task")]
        from dask.distributed import as_completed

        shared_future = c.scatter(shared, broadcast=True, hash=False) if shared is not None else None
        futures = [c.submit(function, item, shared_future, pure=False) for item in items]
        with tqdm(total=len(futures), disable=not progress, unit="task") as bar:
            for _ in as_completed(futures, loop=c.loop):
                bar.update(1)
        return c.gather(futures)

    if client is not None:
        return go(client)
    with dask_client(scheduler, workers, processes, timeout_s) as c:
        return go(c)
