"""Conductance matrices of the PSM for whole trajectories (the contract's ``electrosense.psm.conductance``).

For each pose the sphere centres are mapped into the tank frame, the
potential coefficients ``M = (R + dR) / (4 pi sigma) + diag(z_c / A)`` are
assembled (``dR``: tank images, :mod:`electrosense.psm.images`; objects,
:mod:`electrosense.psm.objects`; contact impedance, :mod:`electrosense.psm.contact`) and the isolated
``K = P (P^T M P)^-1 P^T`` is returned as a :class:`electrosense.bem.conductance.ConductanceMatrix`
of batch shape (P,), in exactly the conventions of the BEM.

The complete image series is summed in symmetric shells until K changes by
less than ``image_tolerance`` (relative to max |K|) from one shell to the
next on a probe set of poses (those nearest the boundaries); the shell count
and the last change are recorded in ``info``.

Example
-------
>>> import numpy as np
>>> from electrosense.meshes.tank import Tank
>>> from electrosense.psm.model import PolySphericalModel
>>> m = PolySphericalModel.collinear([0.0071, 0.0071], [0.2])
>>> C = conductance(m, np.array([[0.0, 0, 0, 0], [0.3, 0, 0, 0]]), 0.0354, tank=Tank((1.0, 1.0, 1.0)))
>>> C.batch_shape, bool(C.resistance_ohm[1, 0] > C.resistance_ohm[0, 0])
((2,), True)
"""
from __future__ import annotations

import numpy as np

from electrosense.bem.conductance import ConductanceMatrix, check_conductivity
from electrosense.meshes.pose import poses_array
from electrosense.meshes.tank import TANK_REGIONS, Tank
from electrosense.psm.contact import electrode_areas_m2, series_resistance_ohm
from electrosense.psm.images import IMAGE_KINDS, ImageSet, image_sources
from electrosense.psm.kernels import conductance_kernel
from electrosense.psm.model import PolySphericalModel
from electrosense.psm.objects import object_terms
from electrosense.psm.potential_coefficients import potential_coefficients

__all__ = ["conductance", "conductance_array", "sphere_centres_m", "placement_fits", "boundary_probe_indices", "PlacementError", "MAX_IMAGE_SHELLS"]

#: the complete series gives up (with an error) beyond this many shells
MAX_IMAGE_SHELLS = 16


class PlacementError(ValueError):
    """A sensor sphere or an object outside the water, or an object touching an electrode."""


def sphere_centres_m(model: PolySphericalModel, poses: np.ndarray) -> np.ndarray:
    """Sphere centres (P, n, 3) in the tank frame; ``poses`` (P, 4) may be complex (complex step)."""
    yaw = poses[:, 3]
    c, s = np.cos(yaw), np.sin(yaw)
    cx, cy, cz = model.centres_m[:, 0], model.centres_m[:, 1], model.centres_m[:, 2]
    X = np.empty(poses.shape[:1] + model.centres_m.shape, dtype=np.result_type(poses, float))
    X[..., 0] = c[:, None] * cx - s[:, None] * cy + poses[:, 0, None]
    X[..., 1] = s[:, None] * cx + c[:, None] * cy + poses[:, 1, None]
    X[..., 2] = cz + poses[:, 2, None]
    return X


def _placement_gaps(model, X, tank, obj_centres, obj_radii):
    """The gaps (m) that decide a placement: each sphere's to each boundary of the water (P, n, 6), each
    object's (O, 6) and each sphere's clearance from each object (P, n, O); ``None`` where there is none."""
    Xr = X.real
    wall = obj_wall = clearance = None
    if tank is not None:
        wall = tank.distance_to_boundary_m(Xr) - model.radii_m[None, :, None]
        if obj_centres.size:
            obj_wall = tank.distance_to_boundary_m(obj_centres) - obj_radii[:, None]
    if obj_centres.size:
        d = np.linalg.norm(Xr[:, :, None, :] - obj_centres[None, None], axis=-1)
        clearance = d - model.radii_m[None, :, None] - obj_radii[None, None, :]
    return wall, obj_wall, clearance


def placement_fits(model: PolySphericalModel, poses: np.ndarray, tank=None, objects=()) -> np.ndarray:
    """(P,) bool: the poses where every sphere of the model is in the water and clear of every object (those
    :func:`conductance` computes; the others it refuses with a :class:`PlacementError`).

    >>> from electrosense.psm import PolySphericalModel
    >>> from electrosense.meshes.tank import Tank
    >>> m = PolySphericalModel(radii_m=[0.01, 0.01], centres_m=[[-0.05, 0, 0], [0.05, 0, 0]], emitter=1)
    >>> placement_fits(m, np.array([[0.0, 0, 0, 0], [0.46, 0, 0, 0]]), Tank((1.0, 1.0, 1.0))).tolist()
    [True, False]
    """
    poses = np.asarray(poses, float).reshape(-1, 4)
    obj_centres, obj_radii, _ = object_terms(tuple(objects), 1.0)
    wall, obj_wall, clearance = _placement_gaps(model, sphere_centres_m(model, poses), tank, obj_centres, obj_radii)
    fits = np.ones(len(poses), bool)
    if obj_wall is not None and np.any(obj_wall < 0):
        fits[:] = False
    if wall is not None:
        fits &= (wall >= 0).all(axis=(1, 2))
    if clearance is not None:
        fits &= (clearance > 0).all(axis=(1, 2))
    return fits


def _check_placement(model, X, tank, obj_centres, obj_radii):
    Xr = X.real
    gap, ogap, clearance = _placement_gaps(model, X, tank, obj_centres, obj_radii)
    if gap is not None and np.any(gap < 0):
        ip, k, b = np.unravel_index(np.argmin(gap), gap.shape)
        raise PlacementError(
            f"pose {ip} (x, y, z = {Xr[ip].mean(0).round(4).tolist()} m): sphere {k + 1} of the PSM "
            f"(radius {model.radii_m[k] * 1e3:.2f} mm) reaches {-gap[ip, k, b] * 1e3:.2f} mm beyond the "
            f"{TANK_REGIONS[b]} boundary of the water; the PSM's wall images do not hold where its spheres "
            "cross a wall (the sensor itself may be in the water): a tank map (esense map build, then "
            "--model map or --map FILE) reaches 5 mm from a wall"
        )
    if ogap is not None and np.any(ogap < 0):
        o, b = np.unravel_index(np.argmin(ogap), ogap.shape)
        raise PlacementError(f"object {o + 1} reaches beyond the {TANK_REGIONS[b]} boundary of the water")
    if clearance is not None and np.any(clearance <= 0):
        ip, k, o = np.unravel_index(np.argmin(clearance), clearance.shape)
        raise PlacementError(f"pose {ip}: object {o + 1} overlaps sphere {k + 1} of the PSM")


def _series_ohm(model, contact_impedance_ohm_m2, sensor):
    if contact_impedance_ohm_m2 is None:
        return np.zeros(model.n)
    if sensor is not None:
        areas = electrode_areas_m2(sensor)
        if areas.size != model.n:
            raise ValueError(f"sensor {sensor.name} has {areas.size} electrodes, the PSM {model.n}")
    elif model.electrode_areas_m2 is not None:
        areas = model.electrode_areas_m2
    else:
        raise ValueError(
            "a contact impedance needs the areas of the real electrodes: pass sensor=... or use a model "
            "with electrode_areas_m2 (calibrate(..., sensor=...) records them)"
        )
    return series_resistance_ohm(contact_impedance_ohm_m2, areas)


def _kernel_call(model, X, sigma, images: ImageSet, obj_centres, obj_coef, series):
    n = model.n
    e = model.emitter - 1
    receivers = np.array([k for k in range(n) if k != e], dtype=np.int64)
    R0 = potential_coefficients(model.radii_m, model.centres_m)
    K = np.empty(X.shape[:1] + (n, n), dtype=X.dtype)
    conductance_kernel(
        np.ascontiguousarray(X), R0, np.ascontiguousarray(images.signs, dtype=float),
        np.ascontiguousarray(images.offsets_m, dtype=float),
        np.ascontiguousarray(images.weights, dtype=float), obj_centres, obj_coef,
        series.astype(float), 1.0 / (4 * np.pi * sigma), receivers, e, K,
    )
    return K


def boundary_probe_indices(X: np.ndarray, tank: Tank, max_probes: int = 24) -> np.ndarray:
    """Indices of the poses (sphere centres ``X`` (P, n, 3)) nearest each boundary, where the image series
    converges slowest, plus a spread of the others: at most ``max_probes``."""
    P = X.shape[0]
    if P <= max_probes:
        return np.arange(P)
    gap = tank.distance_to_boundary_m(X.real).min(axis=1)  # (P, 6)
    idx = set(np.argmin(gap, axis=0).tolist())
    idx |= set(np.linspace(0, P - 1, max_probes - len(idx)).astype(int).tolist())
    return np.array(sorted(idx))


def conductance_array(model, poses, sigma_S_per_m, tank=None, images="complete", objects=(),
                      contact_impedance_ohm_m2=None, sensor=None, image_shells=None, image_tolerance=1e-5):
    """K (P, n, n) as an array (float, or complex for complex poses) and an info dict; see :func:`conductance`."""
    if images not in IMAGE_KINDS:
        raise ValueError(f"images={images!r}: expected one of {', '.join(IMAGE_KINDS)}")
    sigma = check_conductivity(sigma_S_per_m)
    poses = np.asarray(poses)
    if not np.iscomplexobj(poses):
        poses = poses_array(poses)
    elif poses.ndim != 2 or poses.shape[1] != 4:
        raise ValueError(f"poses must be (P, 4), got {poses.shape}")
    X = sphere_centres_m(model, poses)
    obj_centres, obj_radii, obj_coef = object_terms(objects, sigma)
    _check_placement(model, X, tank, obj_centres, obj_radii)
    series = _series_ohm(model, contact_impedance_ohm_m2, sensor)
    kind = "none" if tank is None else images
    info = {"model": "psm", "images": kind, "objects": len(obj_coef)}
    if X.shape[0] == 0:
        return np.zeros((0, model.n, model.n), dtype=X.dtype), info
    if kind != "complete":
        K = _kernel_call(model, X, sigma, image_sources(tank, kind), obj_centres, obj_coef, series)
        return K, info
    if image_shells is not None:
        K = _kernel_call(model, X, sigma, image_sources(tank, "complete", int(image_shells)), obj_centres, obj_coef, series)
        info.update(image_shells=int(image_shells))
        return K, info
    # complete series: Richardson pairs (N/2, N), N = 4, 8, 12, ...; the next N is much more accurate,
    # so |K_N - K_next| estimates the error of K_N: keep the first N whose estimate is below the tolerance
    probe = X[boundary_probe_indices(X, tank)]
    previous = _kernel_call(model, probe, sigma, image_sources(tank, "complete", 4), obj_centres, obj_coef, series)
    for shells in range(4, MAX_IMAGE_SHELLS + 1, 4):
        nxt = _kernel_call(model, probe, sigma, image_sources(tank, "complete", shells + 4), obj_centres, obj_coef, series)
        change = float(np.max(np.abs(nxt - previous)) / np.max(np.abs(nxt)))
        previous = nxt
        if change < image_tolerance:
            break
    else:
        raise RuntimeError(
            f"the complete image series did not settle to {image_tolerance:g} within {MAX_IMAGE_SHELLS} shells "
            f"(last change {change:.2e}); pass image_shells or a larger image_tolerance"
        )
    K = _kernel_call(model, X, sigma, image_sources(tank, "complete", shells), obj_centres, obj_coef, series)
    info.update(image_shells=shells, image_series_error=change, image_tolerance=image_tolerance)
    return K, info


def conductance(model: PolySphericalModel, poses, sigma_S_per_m: float, tank: Tank | None = None,
                images: str = "complete", objects=(), contact_impedance_ohm_m2=None, *, sensor=None,
                image_shells: int | None = None, image_tolerance: float = 1e-5) -> ConductanceMatrix:
    """Conductance matrices of the PSM at every pose, batched: K of shape (P, n, n).

    Parameters
    ----------
    model : PolySphericalModel
    poses : (P, 4) array or sequence of meshes.pose.Pose
        Sensor centre (x, y, z, m) and yaw (rad) in the tank frame.
    sigma_S_per_m : float
        Water conductivity.
    tank : meshes.tank.Tank or None
        ``None``: unbounded water (no images whatever ``images`` says).
    images : {"complete", "paper8", "none"}
        Image series for the tank (:mod:`electrosense.psm.images`).
    objects : sequence of meshes.objects.Sphere
        Small spheres (tank frame), any conductivity (0 and inf included).
    contact_impedance_ohm_m2 : float or (n,) array, optional
        Series contact impedance per electrode (needs the real electrode
        areas: ``sensor`` or ``model.electrode_areas_m2``).
    sensor : meshes.sensor.SensorDescription, optional
        The real sensor, for the electrode areas.
    image_shells : int, optional
        Fix the outer shell (a multiple of 4) of the complete series instead of adapting it.
    image_tolerance : float
        Relative error (of max |K|) allowed to the complete series: shells
        N = 4, 8, 12, ... (Richardson-extrapolated) are tried on probe poses
        and the first N whose K differs from the next one's by less than this
        is used (default 1e-5: a hundred times below the BEM's discretisation
        error). The estimate is recorded as ``info["image_series_error"]``.

    Raises
    ------
    PlacementError
        A sphere of the model or an object outside the water, or an object
        overlapping a sphere of the model.
    """
    K, info = conductance_array(model, poses, sigma_S_per_m, tank, images, objects, contact_impedance_ohm_m2,
                                sensor, image_shells, image_tolerance)
    return ConductanceMatrix(K, model.emitter, float(sigma_S_per_m), info)
