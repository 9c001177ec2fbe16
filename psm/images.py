"""Image sources of a point current in the insulating tank (section II.C of the paper).

Every boundary of the water (walls, floor, free surface) is insulating: the
normal current vanishes there, so each current source gets an image of the
SAME sign mirrored across the boundary, and the images get images in turn.
An image is the affine map ``x -> signs * x + offsets`` (component-wise), so
a set of images is two (K, 3) arrays, with a weight per image.

Two sets are offered:

``"paper8"``
    The paper's 8 images in the horizontal plane: the 4 walls and the 4
    vertical corner edges (second-order images). Floor and free surface are
    ignored, as in the paper (kept for reproduction).
``"complete"``
    The full image series of the closed box. Along one axis with water in
    ``[lo, lo + W]`` the images of ``s`` are ``s + j W`` for even ``j`` and
    ``2 lo - s + (j + 1) W`` for odd ``j``; in 3-D every combination
    ``(jx, jy, jz)``. The series is summed in symmetric shells
    ``max(|jx|, |jy|, |jz|) <= N``. It converges only conditionally, but the
    terms that make it so depend on one electrode alone (the constant, the
    linear and the quadratic terms of each image's Taylor expansion, summed
    over a symmetric shell), and those cancel in ``P^T dR P`` because the
    currents sum to zero. With equal weights the cube holds, along each
    axis, one more translated than mirrored image (or the reverse), a net
    dipole per source, and the partial sums drift like ``1/N``; giving the
    outermost layer half weight (trapezoid) balances them, and what remains
    converges like ``1/N^2``. Two partial sums N/2 and N (N a multiple of 4,
    so that both have the same parity) are combined by Richardson
    extrapolation, and :func:`electrosense.psm.conductance` takes N = 4, 8, 12, ... until
    K stops changing to a stated tolerance.
``"none"``
    Unbounded water.

Example
-------
>>> from electrosense.meshes.tank import Tank
>>> imgs = image_sources(Tank((1.0, 1.0, 1.0)), "paper8")
>>> len(imgs), [0.9, 0.0, 0.0] in imgs.apply([0.1, 0.0, 0.0]).round(12).tolist()
(8, True)
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from electrosense.meshes.tank import Tank

__all__ = ["ImageSet", "IMAGE_KINDS", "image_sources", "paper8_images", "box_images"]

IMAGE_KINDS = ("complete", "paper8", "none")


@dataclass(frozen=True)
class ImageSet:
    """Images ``x -> signs * x + offsets_m`` (each (K, 3)) of a source, all of the same sign."""

    signs: np.ndarray
    offsets_m: np.ndarray
    weights: np.ndarray | None = None
    kind: str = ""
    shells: int = 0

    def __post_init__(self):
        if self.weights is None:
            object.__setattr__(self, "weights", np.ones(self.signs.shape[0]))

    def __len__(self) -> int:
        return self.signs.shape[0]

    def apply(self, points_m) -> np.ndarray:
        """Images (K, ..., 3) of points (..., 3)."""
        p = np.asarray(points_m)
        extra = (1,) * (p.ndim - 1)
        return self.signs.reshape((-1,) + extra + (3,)) * p + self.offsets_m.reshape((-1,) + extra + (3,))


def _axis_images(lo: float, width: float, shells: int, trapezoid: bool):
    """1-D images of the interval [lo, lo + width]: index j, sign, offset, weight (see the module docstring)."""
    j = np.arange(-shells, shells + 1)
    odd = (j % 2) != 0
    sign = np.where(odd, -1.0, 1.0)
    offset = np.where(odd, 2 * lo + (j + 1) * width, j * width)
    weight = np.where((np.abs(j) == shells) & trapezoid & (shells > 0), 0.5, 1.0)
    return j, sign, offset, weight


def _cube_images(tank: Tank, shells: int, horizontal_only: bool, trapezoid: bool):
    """Index (K, 3), signs, offsets and weights of the images with max |j| <= shells (identity included)."""
    lo, hi = tank.water_bounds_m
    axes = [_axis_images(lo[k], hi[k] - lo[k], 0 if (horizontal_only and k == 2) else shells, trapezoid) for k in range(3)]
    grids = [np.stack(np.meshgrid(*[a[i] for a in axes], indexing="ij"), -1).reshape(-1, 3) for i in range(4)]
    J, S, T, W = grids
    return J, S, T, np.prod(W, axis=1)


def box_images(tank: Tank, shells: int, *, horizontal_only: bool = False, trapezoid: bool = True,
               extrapolate: bool = False) -> ImageSet:
    """All images of the closed box with ``max |j| <= shells`` (the source itself excluded).

    ``horizontal_only`` keeps the vertical index at 0 (walls only, no floor
    or free surface). ``trapezoid`` gives the outermost layer along each
    axis the weight 1/2 (per axis, so 1/8 at the corners of the shell):
    then every truncated series holds as many mirrored as translated images
    along each axis, symmetrically, so it has no net dipole per source and
    ``P^T dR P`` converges like ``1/shells^2``. ``extrapolate``
    (``shells`` = 2N) returns the Richardson combination
    ``(4 S_2N - S_N) / 3`` of the two partial sums as one weighted set,
    which removes that leading error term (``shells`` a multiple of 4:
    partial sums of opposite parity do not share the error constant).
    """
    if shells < 1:
        raise ValueError(f"the image series needs at least 1 shell, got {shells}")
    J, S, T, W = _cube_images(tank, shells, horizontal_only, trapezoid)
    if extrapolate:
        if shells % 4:
            raise ValueError(f"the extrapolated image series needs a shell count that is a multiple of 4, got {shells}")
        half = shells // 2
        Jh, _, _, Wh = _cube_images(tank, half, horizontal_only, trapezoid)
        inner = np.abs(J).max(axis=1) <= half
        W = 4.0 * W / 3.0
        # both grids enumerate indices in the same lexicographic order
        W[inner] -= Wh / 3.0
    keep = np.any(J != 0, axis=1)
    order = np.argsort(np.abs(J[keep]).max(axis=1), kind="stable")
    return ImageSet(S[keep][order], T[keep][order], W[keep][order], "complete", shells)


def paper8_images(tank: Tank) -> ImageSet:
    """The paper's 8 mid-plane images: 4 walls and 4 vertical edges (corners of the plan)."""
    imgs = box_images(tank, 1, horizontal_only=True, trapezoid=False)
    return ImageSet(imgs.signs, imgs.offsets_m, imgs.weights, "paper8", 1)


def has_images(tank) -> bool:
    """Whether the PSM can model ``tank``: unbounded water (None) or a box, whose walls are mirrors.

    A cylindrical tank's curved wall has no image: the BEM (or a tank map of it) simulates it.

    >>> from electrosense.meshes.cylinder_tank import CylinderTank
    >>> has_images(Tank((1.0, 1.0, 1.0))), has_images(None), has_images(CylinderTank(0.2, 0.3))
    (True, True, False)
    """
    return tank is None or isinstance(tank, Tank)


def image_sources(tank: Tank | None, kind: str = "complete", shells: int = 4) -> ImageSet:
    """Image set of ``kind`` ("complete", "paper8", "none") for ``tank`` (None: no images).

    For "complete", ``shells`` (a multiple of 4) is the outer shell of the Richardson-extrapolated
    pair (``shells/2``, ``shells``); see :func:`box_images`.
    """
    if kind not in IMAGE_KINDS:
        raise ValueError(f"images={kind!r}: expected one of {', '.join(IMAGE_KINDS)}")
    if tank is None or kind == "none":
        return ImageSet(np.zeros((0, 3)), np.zeros((0, 3)), np.zeros(0), "none", 0)
    if not has_images(tank):
        raise ValueError(f"the PSM's images are a box tank's mirror images; a {type(tank).__name__} has none (its "
                         "curved wall is no mirror): simulate it with the BEM, or a tank map of it (esense map build)")
    if kind == "paper8":
        return paper8_images(tank)
    return box_images(tank, shells, extrapolate=True)
