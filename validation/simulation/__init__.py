"""Simulation of logged poses and sweeps: one way into the models (:mod:`.models`), pose sweeps
on local cores or dask (:mod:`.sweep`), and the potential on a plane (:mod:`.field`)."""
