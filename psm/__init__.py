"""psm: the poly-spherical model of Jawad et al. (images for the tank, objects, calibration).

The sensor is n spherical electrodes; its conductance matrix, in exactly the
conventions of :mod:`electrosense.bem.conductance`, follows from the spheres' potential
coefficients (eq. 8), the tank's image sources, small spherical objects and
the contact impedance, for whole trajectories at once.

Example
-------
>>> import numpy as np
>>> from electrosense.psm import PolySphericalModel, conductance
>>> m = PolySphericalModel.collinear([0.0071, 0.0071], [0.2])
>>> C = conductance(m, np.zeros((1, 4)), 0.0354)
>>> bool(C.S_S[0, 0, 0] > 0)
True
"""
from electrosense.psm.calibration import Calibration, CalibrationError, calibrate, gamma_criterion
from electrosense.psm.conductance import PlacementError, conductance
from electrosense.psm.images import IMAGE_KINDS, image_sources
from electrosense.psm.jacobian import receiver_current_jacobian
from electrosense.psm.model import ModelError, PolySphericalModel
from electrosense.psm.potential_coefficients import current_projector, isolated_conductance, potential_coefficients

__all__ = [
    "PolySphericalModel", "ModelError", "conductance", "PlacementError", "image_sources", "IMAGE_KINDS",
    "receiver_current_jacobian", "calibrate", "Calibration", "CalibrationError", "gamma_criterion",
    "potential_coefficients", "current_projector", "isolated_conductance",
]
