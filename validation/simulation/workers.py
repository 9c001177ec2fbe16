"""What a worker process of a build or a sweep does for itself: one thread of computation, and an end with its parent.

A build's or a sweep's workers share the machine's cores, one process each; every library that would start a
thread per core in each of them (OpenBLAS, numba) oversubscribes the cores, and a worker whose parent was killed
without a word (``kill PID``) would wait for work forever.

>>> restore = one_thread()      # this process's BLAS and numba on one thread from here on
>>> restore()                   # (a worker never restores them)
"""
from __future__ import annotations

import os
import time

__all__ = ["exit_with_parent", "one_thread", "one_thread_environment"]

#: the environment variables a thread pool loaded after :func:`one_thread` reads its size from
THREAD_VARIABLES = ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS")


def one_thread_environment() -> None:
    """Ask the thread pools of the libraries loaded after this call for one thread each, by their environment
    variables (unless the user set them): a study that measures speed on one core calls it before it imports
    numpy. numba's variable only while numba is not loaded: once its threads are launched, numba refuses a
    change of it at its next compilation (``Cannot set NUMBA_NUM_THREADS to a different value once the threads
    have been launched``), which a study imported by a process that had used numba (a test run) met."""
    import sys

    for name in THREAD_VARIABLES + (() if "numba" in sys.modules else ("NUMBA_NUM_THREADS",)):
        os.environ.setdefault(name, "1")


def one_thread():
    """Limit this process's BLAS (numpy's and scipy's OpenBLAS, or MKL) and numba to one thread. A build's workers
    share the cores: each with a thread per core, two workers on two cores ran the first 20 poses of a random
    sensor's map in 106 s of wall clock against 21 s on one thread each (OpenBLAS's threads spin while they wait).
    The environment variables (``OMP_NUM_THREADS``) come too late in a spawned worker, whose unpickled task has
    imported numpy already. Returns a function that restores the limits as they were."""
    import numba
    from threadpoolctl import threadpool_limits

    before = numba.get_num_threads()
    numba.set_num_threads(1)            # first: it loads numba's threading layer (libgomp), which the limit then takes
    limits = threadpool_limits(1)
    variables = {k: os.environ.get(k) for k in THREAD_VARIABLES}
    os.environ.update({k: "1" for k in THREAD_VARIABLES})    # for a library loaded later (libgomp reads it then)

    def restore():
        limits.restore_original_limits()
        numba.set_num_threads(before)
        for k, v in variables.items():
            if v is None:
                os.environ.pop(k, None)
            else:
                os.environ[k] = v

    return restore


def exit_with_parent(period_s: float = 1.0) -> None:
    """End this process (a worker) once its parent has gone: a build killed by a signal its workers do not get
    (``kill PID``, a scheduler's time limit; Ctrl-C reaches them all) left them holding their memory, one 0.7 GB,
    waiting for work that never came. A daemon thread compares the parent's pid every ``period_s`` seconds."""
    import threading

    parent = os.getppid()

    def watch():
        while os.getppid() == parent:
            time.sleep(period_s)
        os._exit(1)

    threading.Thread(target=watch, name="exit-with-parent", daemon=True).start()
