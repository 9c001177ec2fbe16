"""Sweeps: many poses through one model, on this machine or a dask cluster, into a resumable zarr store.

* :mod:`.grid`: pose lines (``--from/--to/--steps``) and grids (``--grid``);
* :mod:`.runner`: :func:`run_sweep` and :func:`map_tasks`, locally or on dask.distributed;
* :mod:`.store`: the chunked zarr store (resume, attributes, xarray access);
* :mod:`.plot`: tank maps as pyvista images.
"""
from electrosense.validation.simulation.sweep.grid import GridError, PoseGrid, line_poses, parse_grid, parse_xy
from electrosense.validation.simulation.sweep.runner import (
    SchedulerError,
    SweepResult,
    dask_client,
    map_tasks,
    run_sweep,
)
from electrosense.validation.simulation.sweep.store import StoreError, SweepStore, as_map, export_netcdf, open_sweep

__all__ = [
    "GridError", "PoseGrid", "line_poses", "parse_grid", "parse_xy",
    "SchedulerError", "SweepResult", "dask_client", "map_tasks", "run_sweep",
    "StoreError", "SweepStore", "as_map", "export_netcdf", "open_sweep",
]
