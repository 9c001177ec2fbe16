"""Jacobian of the bench currents with respect to the pose, for navigation filters.

``d I_k / d (x, y, yaw)`` for every receiver k (bench sign: current into the
receiver, all receivers at one potential, emitter ``U_V`` above them), by the
complex step: the whole PSM (images, objects, contact) is analytic in the
pose, so ``dI/dp = Im I(p + i h e_p) / h`` to machine precision with
``h = 1e-30``, with no subtractive cancellation. One call evaluates every
pose of a trajectory (3 complex evaluations of the batched kernel).

Example
-------
>>> import numpy as np
>>> from meshes.tank import Tank
>>> from psm.model import PolySphericalModel
>>> m = PolySphericalModel.collinear([0.0071, 0.0071], [0.2])
>>> J = receiver_current_jacobian(m, np.array([[0.2, 0.0, 0.0, 0.0]]), 0.0354, tank=Tank((1.0, 1.0, 1.0)))
>>> J.shape, bool(J[0, 0, 0] < 0)  # closer to the wall: less current
((1, 1, 3), True)
"""
from __future__ import annotations

import numpy as np

from meshes.pose import poses_array

from .conductance import conductance_array

__all__ = ["receiver_current_jacobian", "POSE_COLUMNS"]

#: pose columns the Jacobian differentiates against, with their index in a (P, 4) pose array
POSE_COLUMNS = {"x_m": 0, "y_m": 1, "yaw_rad": 3}

_STEP = 1e-30


def receiver_current_jacobian(model, poses, sigma_S_per_m, tank=None, images="complete", objects=(),
                              contact_impedance_ohm_m2=None, *, U_V: float = 1.0, sensor=None,
                              image_shells=None, image_tolerance=1e-5) -> np.ndarray:
    """d I / d (x, y, yaw): (P, n-1, 3) in A/m, A/m and A/rad, receivers in electrode order.

    Same arguments as :func:`psm.conductance.conductance`; ``U_V`` is the
    emitter voltage above the receivers.
    """
    poses = poses_array(poses)
    if tank is not None and images == "complete" and image_shells is None:
        # fix the shell count once, from the real poses, so that all three steps use the same series
        _, info = conductance_array(model, poses, sigma_S_per_m, tank, images, objects, contact_impedance_ohm_m2,
                                    sensor, None, image_tolerance)
        image_shells = info.get("image_shells")
    e = model.emitter - 1
    receivers = [k for k in range(model.n) if k != e]
    J = np.empty((poses.shape[0], model.n - 1, 3))
    for j, col in enumerate(POSE_COLUMNS.values()):
        p = poses.astype(complex)
        p[:, col] += 1j * _STEP
        K, _ = conductance_array(model, p, sigma_S_per_m, tank, images, objects, contact_impedance_ohm_m2,
                                 sensor, image_shells, image_tolerance)
        J[:, :, j] = -K[:, receivers, e].imag / _STEP * U_V
    return J
