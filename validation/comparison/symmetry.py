"""A scene's symmetries, and the least misfit of a measured signal that any scene sharing them can reach.

A round tank whose electrodes and balls are carried onto themselves by a rotation about its axis or a reflection
across a vertical plane through it has the same transfer impedance on a measurement row and on its image (the
drive and measurement pairs' electrodes mapped): physics has no preferred side. So a set-up's difference signal
``|Z_ball| / |Z_ref| - 1`` is the same on every row of an orbit of the scene's symmetry group, whatever the tank's
radius, taper or depth, the balls' size and height or the water's conductivity, and a per-row gain of the
instrument cancels in it. The spread of a measured signal about its orbit means is therefore the least relative
misfit any such scene reaches (:func:`symmetric_floor`): measured without a model, it says how much of a ball
set-up's signal only what breaks the stated symmetry can fit (the electrodes' places, the balls off their stated
places, a non-round tank, the instrument's common mode).

Example
-------
A ring of 8 electrodes on a round tank and one ball on the y axis: the mirror x -> -x is the scene's only
symmetry besides the identity.

>>> from electrosense.meshes import Scene
>>> from electrosense.meshes.cylinder_tank import CylinderTank
>>> from electrosense.meshes.surface_electrodes import DiscElectrode
>>> ring = [DiscElectrode((0.1 * np.cos(a), 0.1 * np.sin(a), 0.0), 0.005) for a in np.arange(8) * np.pi / 4]
>>> scene = Scene(None, tank=CylinderTank(0.1, 0.2), electrodes=ring)
>>> maps = scene_symmetries(scene, [[0.0, 0.05]])
>>> len(maps), maps[1][1], maps[1][3]       # electrode 1 (at +x) goes to 5 (at -x); 3 (on the y axis) stays
(2, 5, 3)
"""
from __future__ import annotations

import numpy as np

__all__ = ["scene_symmetries", "symmetric_floor"]


def _centre(electrode):
    c = getattr(electrode, "centre_m", None)
    if c is None:
        c = getattr(getattr(electrode, "body", None), "centre_m", None)
    return None if c is None else np.asarray(c, float)


def _kind(electrode):
    """What an electrode's image must match besides its centre (None: a body whose turn matters, a block)."""
    body = getattr(electrode, "body", None)
    if body is None:
        return type(electrode).__name__, round(float(getattr(electrode, "radius_m", 0.0)), 6)
    if type(body).__name__ not in ("Sphere", "Cylinder"):      # a ball, or a rod whose axis is vertical
        return None
    return type(body).__name__, round(float(body.radius_m), 6), round(float(getattr(body, "height_m", 0.0)), 6)


def _transforms(angles):
    """Candidate plane maps (x, y) -> (x', y') that carry the first angle to another: rotations, reflections."""
    out = []
    for a in angles:
        rot = a - angles[0]
        out.append(np.array([[np.cos(rot), -np.sin(rot)], [np.sin(rot), np.cos(rot)]]))
        beta = a + angles[0]                        # the reflection theta -> beta - theta
        out.append(np.array([[np.cos(beta), np.sin(beta)], [np.sin(beta), -np.cos(beta)]]))
    return out


def _matches(points, images, tol_m):
    """Index of the point each image lands on (None where one lands on none)."""
    d = np.linalg.norm(images[:, None, :] - points[None, :, :], axis=-1)
    j = np.argmin(d, axis=1)
    return None if np.any(d[np.arange(len(images)), j] > tol_m) else j


def scene_symmetries(scene, balls_xy=(), tol_m: float = 1e-3) -> list[dict]:
    """The rotations about a round tank's axis and reflections across vertical planes through it that carry every
    electrode of ``scene`` onto one of the same kind and size, and the balls at ``balls_xy`` (k, 2) onto
    themselves, each as a map of electrode numbers (1-based, the scene's); the identity first. Only the identity
    for a tank that is not round, an electrode without a centre (a plate) or a block whose turn would matter.
    """
    from electrosense.meshes.cylinder_tank import CylinderTank

    n = len(scene.electrodes)
    identity = {k + 1: k + 1 for k in range(n)}
    centres = [_centre(e) for e in scene.electrodes]
    kinds = [_kind(e) for e in scene.electrodes]
    if (not isinstance(scene.tank, CylinderTank) or not n or any(c is None for c in centres)
            or any(k is None for k in kinds)):
        return [identity]
    C = np.array(centres)
    balls = np.asarray(balls_xy, float).reshape(-1, 2)
    r = np.hypot(C[:, 0], C[:, 1])
    angles = np.arctan2(C[r > tol_m, 1], C[r > tol_m, 0])
    maps = [identity]
    for T in _transforms(angles) if len(angles) else []:
        if np.allclose(T, np.eye(2)):
            continue
        images = np.c_[C[:, :2] @ T.T, C[:, 2]]
        j = _matches(C, images, tol_m)
        if j is None or len(set(j.tolist())) != n or any(kinds[a] != kinds[b] for a, b in zip(range(n), j)):
            continue
        if len(balls) and _matches(balls, balls @ T.T, tol_m) is None:
            continue
        g = {k + 1: int(j[k]) + 1 for k in range(n)}
        if g not in maps:        # electrodes at one angle (two rings) propose each map more than once
            maps.append(g)
    return maps


def symmetric_floor(drive, measure, signal, maps) -> float:
    """The least relative RMS misfit of ``signal`` (R,) on the rows ``drive`` and ``measure`` (R, 2; electrode
    numbers) by any signal the same on each row's images under ``maps`` (:func:`scene_symmetries`):
    ``RMS(signal - its orbit means) / RMS(signal)``; rows whose image was not measured are their own orbit.

    >>> d = np.array([[1, 2], [2, 3], [3, 4], [4, 1]]); m = np.array([[3, 4], [4, 1], [1, 2], [2, 3]])
    >>> turn = {1: 2, 2: 3, 3: 4, 4: 1}
    >>> round(symmetric_floor(d, m, np.array([1.0, 1.0, 1.0, 1.0]), [turn]), 6)
    0.0
    >>> round(symmetric_floor(d, m, np.array([1.0, 3.0, 1.0, 3.0]), [turn]), 3)
    0.447
    """
    signal = np.asarray(signal, float)
    rows = [(frozenset(map(int, a)), frozenset(map(int, b))) for a, b in zip(drive, measure)]
    where = {row: i for i, row in enumerate(rows)}
    parent = list(range(len(rows)))

    def root(i):
        while parent[i] != i:
            parent[i] = parent[parent[i]]
            i = parent[i]
        return i

    for i, (a, b) in enumerate(rows):
        for g in maps:
            j = where.get((frozenset(g[e] for e in a), frozenset(g[e] for e in b)))
            if j is not None:
                parent[root(i)] = root(j)
    labels = np.array([root(i) for i in range(len(rows))])
    means = np.zeros_like(signal)
    for lab in np.unique(labels):
        means[labels == lab] = signal[labels == lab].mean()
    return float(np.sqrt(np.mean((signal - means) ** 2)) / np.sqrt(np.mean(signal**2)))
