"""Comparisons of simulated and measured receiver currents.

* :mod:`.metrics`: relative errors and their summaries (mean |e|, max |e|, RMS, bias);
* :mod:`.regions`: the region of the path each pose lies in (mid-tank, near a wall, an object);
* :mod:`.correction`: the paper's conductivity correction (one fitted scale factor).
"""
from electrosense.validation.comparison.correction import ConductivityCorrection, fit_conductivity_scale
from electrosense.validation.comparison.metrics import Comparison, compare_currents, error_summary, relative_error
from electrosense.validation.comparison.regions import NEAR_OBJECT_M, NEAR_WALL_M, path_regions

__all__ = [
    "Comparison",
    "compare_currents",
    "error_summary",
    "relative_error",
    "ConductivityCorrection",
    "fit_conductivity_scale",
    "path_regions",
    "NEAR_WALL_M",
    "NEAR_OBJECT_M",
]
