"""The cross-section of a :class:`~electrosense.meshes.prism_scene.PrismScene` as straight segments, and the
electrodes' cells in height.

The 2-D boundary of the water's cross-section: the wall (a polygon inscribed
in the circle, its vertices at every electrode's edges, segments graded
towards them, where the current density is singular) and each object's
outline (its polygon resampled). Every contour is oriented with the water on
its left, so the right-hand normal of each segment points out of the water.
The electrodes' cells are the wall segments under each electrode times
intervals of height graded towards the electrode's top and bottom edges
(not towards an edge on the floor or at the free surface, where the
mirror symmetry of an insulating plane leaves no singularity).

Example
-------
>>> from electrosense.meshes.prism_scene import PrismScene, ring_patches
>>> s = PrismScene(0.1, 0.05, ring_patches(8, 0.0, 10.0, 0.0, 0.02))
>>> m = mesh_section(s, segments_per_electrode=4, segments_per_gap=3)
>>> m.n_segments, int((m.electrode > 0).sum()), round(float(m.lengths.sum()), 4)       # 2 pi r = 0.6283
(72, 32, 0.6278)
>>> z_cells(0.0, 0.02, 0.05, 4).round(5).tolist()       # floor at the bottom: graded only towards the top
[0.0, 0.00765, 0.01414, 0.01848, 0.02]
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from electrosense.meshes.prism_scene import PrismScene, resample_polygon

__all__ = ["SectionMesh", "mesh_section", "z_cells", "graded"]


@dataclass(frozen=True)
class SectionMesh:
    """Segments ``a`` -> ``b`` (S, 2) of the cross-section, water on the left.

    ``contour`` (S,): 0 the wall, i >= 1 object i; ``electrode`` (S,): k >= 1
    on a wall segment under electrode k, else 0.
    """

    a: np.ndarray
    b: np.ndarray
    contour: np.ndarray
    electrode: np.ndarray

    @property
    def n_segments(self) -> int:
        return len(self.a)

    @property
    def lengths(self) -> np.ndarray:
        return np.linalg.norm(self.b - self.a, axis=1)

    @property
    def midpoints(self) -> np.ndarray:
        return 0.5 * (self.a + self.b)

    @property
    def tangents(self) -> np.ndarray:
        return (self.b - self.a) / self.lengths[:, None]

    @property
    def normals(self) -> np.ndarray:
        """Unit normals out of the water (the right-hand normals)."""
        t = self.tangents
        return np.stack([t[:, 1], -t[:, 0]], axis=1)


def graded(n: int, both: bool = True) -> np.ndarray:
    """``n + 1`` points from 0 to 1 graded (cosine spacing) towards both ends, or towards 1 only."""
    i = np.arange(n + 1) / n
    return 0.5 * (1 - np.cos(np.pi * i)) if both else np.sin(0.5 * np.pi * i)


def z_cells(z_bottom_m: float, z_top_m: float, depth_m: float, n: int) -> np.ndarray:
    """Edges (n + 1,) of an electrode's cells in height, graded towards its edges that are off the floor and
    the free surface."""
    on_floor = z_bottom_m <= 1e-9 * depth_m
    at_top = z_top_m >= depth_m * (1 - 1e-9)
    h = z_top_m - z_bottom_m
    if on_floor and at_top:
        t = np.linspace(0.0, 1.0, n + 1)
    elif on_floor:
        t = graded(n, both=False)
    elif at_top:
        t = 1.0 - graded(n, both=False)[::-1]
    else:
        t = graded(n)
    return z_bottom_m + h * t


def mesh_section(scene: PrismScene, segments_per_electrode: int = 6, segments_per_gap: int = 4,
                 max_wall_segment_m: float | None = None, object_spacing_m: float | None = None) -> SectionMesh:
    """The segments of the scene's cross-section (see the module docstring).

    ``max_wall_segment_m`` (default: the radius / 8) bounds the segments of a
    long gap between electrodes; ``object_spacing_m`` (default: the radius / 50)
    the objects' segments.
    """
    R = scene.radius_m
    max_seg = R / 8 if max_wall_segment_m is None else float(max_wall_segment_m)
    spacing = R / 50 if object_spacing_m is None else float(object_spacing_m)
    edges = []          # (angle, +k start / -k end)
    for k, e in enumerate(scene.electrodes, start=1):
        edges.append((float(np.mod(e.phi_start_rad, 2 * np.pi)), k))
    if not edges:
        raise ValueError("a section needs at least one electrode")
    starts = sorted(edges)
    phi0 = starts[0][0]
    nodes, labels = [], []
    for idx, (phi_s, k) in enumerate(starts):
        e = scene.electrodes[k - 1]
        w = e.phi_end_rad - e.phi_start_rad
        nxt = starts[(idx + 1) % len(starts)][0]
        gap = np.mod(nxt - (phi_s + w), 2 * np.pi) if len(starts) > 1 else 2 * np.pi - w
        if len(starts) > 1 and abs(gap) > 2 * np.pi - 1e-12:
            gap = 0.0
        t_e = phi_s + w * graded(segments_per_electrode)[:-1]
        nodes.append(t_e)
        labels.append(np.full(len(t_e), k))
        if gap > 1e-12:
            n_gap = max(segments_per_gap, int(np.ceil(gap * R / max_seg)))
            t_g = phi_s + w + gap * graded(n_gap)[:-1]
            nodes.append(t_g)
            labels.append(np.zeros(len(t_g), int))
    phi = np.concatenate(nodes)
    lab = np.concatenate(labels).astype(np.int64)
    phi = np.mod(phi - phi0, 2 * np.pi) + phi0
    pts = R * np.stack([np.cos(phi), np.sin(phi)], axis=1)
    a, b = pts, np.roll(pts, -1, axis=0)
    contour = [np.zeros(len(a), np.int64)]
    electrode = [lab]
    A, B = [a], [b]
    for i, o in enumerate(scene.objects, start=1):
        p = resample_polygon(o.polygon_m, spacing)[::-1]       # clockwise: the water (outside) on the left
        A.append(p)
        B.append(np.roll(p, -1, axis=0))
        contour.append(np.full(len(p), i, np.int64))
        electrode.append(np.zeros(len(p), np.int64))
    return SectionMesh(np.concatenate(A), np.concatenate(B), np.concatenate(contour), np.concatenate(electrode))
