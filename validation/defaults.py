"""The project's nominal values, in one place: every command and module takes them from here.

Example
-------
>>> from electrosense.validation.defaults import NOMINAL_SIGMA_S_PER_M, BENCH_CURRENT_NOISE_REL
>>> NOMINAL_SIGMA_S_PER_M, BENCH_CURRENT_NOISE_REL
(0.0354, 0.0005)
"""
from __future__ import annotations

__all__ = ["NOMINAL_SIGMA_S_PER_M", "BENCH_CURRENT_NOISE_REL", "BENCH_POSITION_NOISE_M", "NOMINAL_TANK_M"]

NOMINAL_SIGMA_S_PER_M = 0.0354
"""Water conductivity (S/m) when none is given: the paper's tank water (354 uS/cm)."""

BENCH_CURRENT_NOISE_REL = 5e-4
"""Relative precision (1 sigma) of the bench's current measurement: the paper's 0.05 %."""

BENCH_POSITION_NOISE_M = 1e-4
"""Precision (1 sigma, m) of the bench's cartesian robot: the paper's 0.1 mm."""

NOMINAL_TANK_M = (1.0, 1.0, 1.0)
"""Inner tank size (m) when a command needs a tank and none is given: the paper's 1 m cube."""
