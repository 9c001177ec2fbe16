"""Jacobian of the bench currents with respect to the pose, for navigation filters.

``d I_k / d (x, y, yaw)`` for every receiver k (bench sign: current into the
receiver, all receivers at one potential, emitter ``U_V`` above them).

``method="analytic"`` (default): ``dK = -K dM K`` with the derivative of the
potential coefficients M written out for the images and the objects
(:func:`electrosense.psm.kernels.pose_derivative_kernel`). ``method="complex-step"``: the
whole PSM is analytic in the pose, so ``dI/dp = Im I(p + i h e_p) / h`` to
machine precision with ``h = 1e-30`` and no subtractive cancellation (3
complex evaluations of the batched kernel): an independent check, slower.

Example
-------
>>> import numpy as np
>>> from electrosense.meshes.tank import Tank
>>> from electrosense.psm.model import PolySphericalModel
>>> m = PolySphericalModel.collinear([0.0071, 0.0071], [0.2])
>>> J = receiver_current_jacobian(m, np.array([[0.2, 0.0, 0.0, 0.0]]), 0.0354, tank=Tank((1.0, 1.0, 1.0)))
>>> J.shape, bool(J[0, 0, 0] < 0)  # closer to the wall: less current
((1, 1, 3), True)
"""
from __future__ import annotations

import numpy as np

from electrosense.meshes.pose import poses_array
from electrosense.psm.conductance import conductance_array, sphere_centres_m
from electrosense.psm.images import image_sources
from electrosense.psm.kernels import pose_derivative_kernel
from electrosense.psm.objects import object_terms

__all__ = ["receiver_current_jacobian", "POSE_COLUMNS"]

#: pose columns the Jacobian differentiates against, with their index in a (P, 4) pose array
POSE_COLUMNS = {"x_m": 0, "y_m": 1, "yaw_rad": 3}

_STEP = 1e-30


def receiver_current_jacobian(model, poses, sigma_S_per_m, tank=None, images="complete", objects=(),
                              contact_impedance_ohm_m2=None, *, U_V: float = 1.0, sensor=None,
                              image_shells=None, image_tolerance=1e-5, method: str = "analytic") -> np.ndarray:
    """d I / d (x, y, yaw): (P, n-1, 3) in A/m, A/m and A/rad, receivers in electrode order.

    Same arguments as :func:`electrosense.psm.conductance.conductance`; ``U_V`` is the
    emitter voltage above the receivers; ``method`` "analytic" or "complex-step".
    """
    if method not in ("analytic", "complex-step"):
        raise ValueError(f"method={method!r}: expected 'analytic' or 'complex-step'")
    poses = poses_array(poses)
    e = model.emitter - 1
    receivers = [k for k in range(model.n) if k != e]
    # the real evaluation fixes the shell count of the complete series for the derivatives too
    K, info = conductance_array(model, poses, sigma_S_per_m, tank, images, objects, contact_impedance_ohm_m2,
                                sensor, image_shells, image_tolerance)
    image_shells = info.get("image_shells", image_shells)
    if method == "analytic":
        imgs = image_sources(tank, info["images"], image_shells if image_shells is not None else 4)
        obj_centres, _, obj_coef = object_terms(objects, float(sigma_S_per_m))
        X = sphere_centres_m(model, poses)
        dK = np.empty((poses.shape[0], 3) + K.shape[1:])
        pose_derivative_kernel(np.ascontiguousarray(X), np.ascontiguousarray(poses[:, :3]), K,
                               np.ascontiguousarray(imgs.signs, dtype=float), np.ascontiguousarray(imgs.offsets_m, dtype=float),
                               np.ascontiguousarray(imgs.weights, dtype=float), obj_centres, obj_coef,
                               1.0 / (4 * np.pi * float(sigma_S_per_m)), dK)
        return -np.moveaxis(dK[:, :, receivers, e], 1, 2) * U_V
    J = np.empty((poses.shape[0], model.n - 1, 3))
    for j, col in enumerate(POSE_COLUMNS.values()):
        p = poses.astype(complex)
        p[:, col] += 1j * _STEP
        K, _ = conductance_array(model, p, sigma_S_per_m, tank, images, objects, contact_impedance_ohm_m2,
                                 sensor, image_shells, image_tolerance)
        J[:, :, j] = -K[:, receivers, e].imag / _STEP * U_V
    return J
