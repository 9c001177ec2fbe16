"""The paper's printed numbers (Jawad et al.), as data for tests and studies.

All lengths in metres here (the paper prints centimetres). The printed
S_BEM of the 4-electrode sensor (free space, emitter 4 at the tail) is
``gamma / 100 x TABLE`` with gamma in S/m, i.e. the TABLE entries are in
gamma-centimetres; see ``docs/psm-model.md`` of the shared notes.

Example
-------
>>> ref = paper_reference()
>>> ref.emitter, ref.receivers
(4, (1, 2, 3))
>>> round(float(ref.S_S[0, 0] / ref.sigma_S_per_m), 6)
0.07197
"""
from __future__ import annotations

import numpy as np

from electrosense.bem.conductance import ConductanceMatrix, K_from_S

__all__ = [
    "S_BEM_N4_GAMMA_CM", "SIGMA_MEASURED_S_PER_M", "FIT_N4", "RADIUS_N2_M", "LENGTH_N2_M",
    "ERRORS", "TANK_SIZE_M", "paper_reference",
]

#: printed S_BEM of the 4-electrode sensor in units of gamma x cm (receivers 1, 2, 3; emitter 4)
S_BEM_N4_GAMMA_CM = np.array([
    [7.1970, -2.7412, -2.2540],
    [-2.7412, 7.6781, -2.6875],
    [-2.2540, -2.6875, 7.6781],
])

#: half a unit of the last printed digit (gamma x cm): the rounding of the table
S_BEM_N4_ROUNDING_GAMMA_CM = 0.5e-4

#: measured water conductivity (354 uS/cm)
SIGMA_MEASURED_S_PER_M = 0.0354

#: the paper's symmetric 4-electrode fit (m) and its printed criterion (17)
FIT_N4 = {"a_e": 0.72e-2, "a_i": 0.74e-2, "L_e": 7.85e-2, "L_i": 7.69e-2, "gamma_criterion": 4.48e-5}

#: the 2-electrode model: equal radii, centre distance fixed to the sensor length
RADIUS_N2_M = 0.71e-2
LENGTH_N2_M = 0.20

#: mean relative errors printed in the paper (fractions)
ERRORS = {
    "angels-2": {"bem_vs_psm": 0.0022, "bench_vs_model": 0.0206},
    "angels-4": {"bem_vs_psm": 0.0097, "bench_vs_model": 0.0237},
}

#: the tank (about 1 m^3; the paper's trajectory runs wall to wall at y = 0 in the mid-plane)
TANK_SIZE_M = (1.0, 1.0, 1.0)


def paper_reference(sigma_S_per_m: float = SIGMA_MEASURED_S_PER_M) -> ConductanceMatrix:
    """The printed S_BEM (n = 4, emitter 4) as a ConductanceMatrix at ``sigma_S_per_m``."""
    S = S_BEM_N4_GAMMA_CM * 1e-2 * sigma_S_per_m
    return ConductanceMatrix(
        K_from_S(S, 4), 4, sigma_S_per_m,
        {"source": "Jawad et al., printed S_BEM of the 4-electrode sensor (free space)",
         "sensor": "angels-4",
         "rounding_uncertainty_S": S_BEM_N4_ROUNDING_GAMMA_CM * 1e-2 * sigma_S_per_m},
    )
