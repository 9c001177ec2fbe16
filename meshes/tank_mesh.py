"""Mesh of the tank's water box: four walls, the floor and the free surface.

The water box ``|x| <= Lx/2, |y| <= Ly/2, floor <= z <= free surface`` (tank
frame, :mod:`electrosense.meshes.tank`) is meshed as one closed, watertight shell with six
labelled regions (``TANK_REGIONS``) whose normals point OUT OF THE WATER.
Neighbouring faces share their edge nodes, so the mesh is conforming where
walls meet.

Grading. With ``focus_m`` (one point, or many: a whole trajectory of sensor
positions) the target edge length grows with the distance ``d`` to the
nearest focus point,

    h(p) = min(max_edge_length_m, edge_length_m + grading * d(p)),

so the walls near the sensor are fine and the far walls stay coarse: the
wall's influence on the sensor varies on the scale of its distance to it.
With ``near_ratio`` the edge is also at most ``near_ratio`` times the
distance from the focus's surface (a tube of ``focus_radius_m`` around the
focus points, the sensor's body around its axis),

    h(p) <= max(min_edge_length_m, near_ratio * (d(p) - focus_radius_m)),

which is what decides K with a tip a few millimetres from a wall: the field
there varies on the scale of the gap, not of the sensor.
Without a focus the mesh is uniform at ``edge_length_m``.

Each planar face is meshed by :func:`mesh_convex_polygon`: graded edge nodes
from equidistribution of ``1/h`` along the box edges, interior nodes from a
quadtree, a few Persson-Strang (distmesh) smoothing steps, then Delaunay.

Example
-------
>>> from electrosense.meshes.tank import Tank
>>> from electrosense.meshes.tank_mesh import mesh_tank
>>> m = mesh_tank(Tank((1.0, 0.6, 0.5), water_depth_m=0.4), edge_length_m=0.1)
>>> m.region_names[-1], m.to_trimesh().is_watertight
('free_surface', True)
"""
from __future__ import annotations

from typing import Callable

import numpy as np
from scipy.spatial import Delaunay, cKDTree

from electrosense.meshes.labelled_mesh import LabelledMesh, concatenate
from electrosense.meshes.tank import TANK_REGIONS, Tank

__all__ = ["mesh_tank", "mesh_axis_box", "mesh_convex_polygon", "graded_size_function", "equidistributed_nodes"]

SizeFunction = Callable[[np.ndarray], np.ndarray]


# --------------------------------------------------------------------------- sizing
def graded_size_function(edge_length_m: float, focus_m=None, grading: float = 0.5,
                         max_edge_length_m: float | None = None, *, near_ratio: float | None = None,
                         focus_radius_m: float = 0.0, min_edge_length_m: float | None = None) -> SizeFunction:
    """Target edge length h(p) (m) at points (..., 3), graded away from focus points.

    Parameters
    ----------
    edge_length_m : float
        Edge length at the focus (or everywhere, without a focus).
    focus_m : (3,) or (P, 3) array, optional
        Points the mesh is refined towards (e.g. the sensor's axis, or every
        position of a trajectory).
    grading : float
        Growth of the edge length per metre of distance from the focus.
    max_edge_length_m : float, optional
        Cap on the edge length (default: unbounded).
    near_ratio : float, optional
        The edge at most this times the distance from the focus's surface (module doc); default: no such bound.
    focus_radius_m : float
        Radius of the tube around the focus points whose surface ``near_ratio`` measures from (the sensor's).
    min_edge_length_m : float, optional
        Floor of the ``near_ratio`` bound (default: a twentieth of ``edge_length_m``).

    Example
    -------
    >>> h = graded_size_function(0.01, focus_m=[0, 0, 0], grading=0.5, max_edge_length_m=0.1)
    >>> h(np.array([[0.0, 0, 0], [0.1, 0, 0], [1.0, 0, 0]])).round(3).tolist()
    [0.01, 0.06, 0.1]
    >>> h = graded_size_function(0.01, [0, 0, 0], 0.5, 0.1, near_ratio=0.35, focus_radius_m=0.01)
    >>> h(np.array([[0.015, 0, 0], [0.03, 0, 0], [1.0, 0, 0]])).round(5).tolist()
    [0.00175, 0.007, 0.1]
    """
    if not edge_length_m > 0:
        raise ValueError(f"edge_length_m must be positive, got {edge_length_m}")
    h_max = np.inf if max_edge_length_m is None else float(max_edge_length_m)
    if focus_m is None:
        return lambda p: np.full(np.shape(p)[:-1], min(edge_length_m, h_max))
    focus = np.asarray(focus_m, dtype=float).reshape(-1, 3)
    if not np.all(np.isfinite(focus)):
        raise ValueError("focus_m contains non-finite coordinates")
    if grading < 0:
        raise ValueError(f"grading must be >= 0, got {grading}")
    if near_ratio is not None and not near_ratio > 0:
        raise ValueError(f"near_ratio must be positive, got {near_ratio}")
    h_min = edge_length_m / 20 if min_edge_length_m is None else float(min_edge_length_m)
    tree = cKDTree(focus)

    def h(p):
        p = np.asarray(p, dtype=float)
        d, _ = tree.query(p.reshape(-1, 3))
        size = np.minimum(h_max, edge_length_m + grading * d)
        if near_ratio is not None:
            size = np.minimum(size, np.maximum(h_min, near_ratio * (d - focus_radius_m)))
        return size.reshape(p.shape[:-1])

    return h


def equidistributed_nodes(a_m: np.ndarray, b_m: np.ndarray, size: SizeFunction, n_samples: int = 2001) -> np.ndarray:
    """Nodes on the segment a-b (both ends included) spaced by the local target length.

    The nodes equidistribute ``integral 1/h ds``, so the spacing follows
    ``h`` wherever it varies slowly on the scale of one element.
    """
    a, b = np.asarray(a_m, float), np.asarray(b_m, float)
    s = np.linspace(0.0, 1.0, n_samples)
    pts = a + s[:, None] * (b - a)
    inv_h = 1.0 / size(pts)
    length = np.linalg.norm(b - a)
    cumulative = np.concatenate([[0.0], np.cumsum(0.5 * (inv_h[1:] + inv_h[:-1]) * np.diff(s) * length)])
    n = max(1, int(round(cumulative[-1])))
    s_nodes = np.interp(np.linspace(0.0, cumulative[-1], n + 1), cumulative, s)
    s_nodes[0], s_nodes[-1] = 0.0, 1.0
    return a + s_nodes[:, None] * (b - a)


# ------------------------------------------------------------------ planar meshing
def _signed_distance_inside(uv: np.ndarray, polygon_uv: np.ndarray) -> np.ndarray:
    """Distance of points to the boundary of a convex CCW polygon, positive inside."""
    a = polygon_uv
    b = np.roll(polygon_uv, -1, axis=0)
    t = b - a
    inward = np.stack([-t[:, 1], t[:, 0]], axis=1) / np.linalg.norm(t, axis=1)[:, None]
    return np.min(np.einsum("pkj,kj->pk", uv[:, None, :] - a[None], inward), axis=1)


def _polygon_corners(polygon_uv: np.ndarray) -> np.ndarray:
    """The corners of a polygon given with extra nodes along its straight sides."""
    prev = polygon_uv - np.roll(polygon_uv, 1, axis=0)
    nxt = np.roll(polygon_uv, -1, axis=0) - polygon_uv
    cross = prev[:, 0] * nxt[:, 1] - prev[:, 1] * nxt[:, 0]
    scale = np.linalg.norm(prev, axis=1) * np.linalg.norm(nxt, axis=1)
    return polygon_uv[np.abs(cross) > 1e-9 * scale]


def _quadtree_points(lo: np.ndarray, hi: np.ndarray, size_uv: Callable[[np.ndarray], np.ndarray]) -> np.ndarray:
    """Leaf centres of a quadtree over [lo, hi] refined until each leaf fits the local size."""
    extent = hi - lo
    root = float(extent.max())
    centres = np.array([lo + 0.5 * root])
    half = np.array([0.5 * root])
    leaves = []
    for _ in range(40):
        if not len(centres):
            break
        split = 2 * half > size_uv(centres)
        leaves.append(centres[~split])
        centres, half = centres[split], half[split]
        offsets = np.array([[-1, -1], [1, -1], [-1, 1], [1, 1]], float)
        centres = (centres[:, None, :] + 0.5 * half[:, None, None] * offsets[None]).reshape(-1, 2)
        half = np.repeat(0.5 * half, 4)
    pts = np.concatenate(leaves) if leaves else np.zeros((0, 2))
    inside = np.all((pts > lo) & (pts < hi), axis=1)
    return pts[inside]


def _unique_edges(tri: np.ndarray) -> np.ndarray:
    """(E, 2) edges of a triangulation, each once (smaller vertex first)."""
    e = np.sort(np.concatenate([tri[:, [0, 1]], tri[:, [1, 2]], tri[:, [2, 0]]]), axis=1).astype(np.int64)
    n = int(e.max()) + 1
    key = np.unique(e[:, 0] * n + e[:, 1])
    return np.stack([key // n, key % n], axis=1)


def _drop_crowded(boundary: np.ndarray, interior: np.ndarray, size_uv, ratio: float = 0.3) -> np.ndarray:
    """The free interior nodes without those nearer than ``ratio`` times the target length to another node.

    Where the target length varies steeply (a tank wall a few millimetres from the sensor) smoothing can bring
    two nodes together, and they make a sliver (a tank mesh had two nodes 0.15 mm apart among 3 mm edges, an
    angle of 2 deg). Of each such pair the later free node goes (the boundary and fixed nodes stay)."""
    if not len(interior):
        return interior
    p = np.concatenate([boundary, interior])
    bars = _unique_edges(Delaunay(p).simplices)
    short = np.linalg.norm(p[bars[:, 0]] - p[bars[:, 1]], axis=1) < ratio * size_uv(
        0.5 * (p[bars[:, 0]] + p[bars[:, 1]]))
    drop = bars[short].max(axis=1)
    drop = drop[drop >= len(boundary)] - len(boundary)
    return np.delete(interior, np.unique(drop), axis=0)


def mesh_convex_polygon(boundary_uv: np.ndarray, size_uv: Callable[[np.ndarray], np.ndarray],
                        n_smoothing: int = 25, fixed_uv: np.ndarray | None = None,
                        allowed_uv: Callable[[np.ndarray], np.ndarray] | None = None) -> tuple[np.ndarray, np.ndarray]:
    """Triangulate a convex polygon whose boundary nodes are given and kept.

    Parameters
    ----------
    boundary_uv : (B, 2) array
        The boundary nodes in counter-clockwise order (corners and every node
        on the sides); they are kept exactly and appear first in the output.
    size_uv : callable
        Target edge length at points (N, 2).
    n_smoothing : int
        Distmesh smoothing steps for the interior nodes.
    fixed_uv : (M, 2) array, optional
        Interior nodes that are kept exactly (e.g. the rim of an electrode);
        they follow ``boundary_uv`` in the output.
    allowed_uv : callable, optional
        True where a free interior node may lie (e.g. not too near a fixed
        rim); free nodes elsewhere are dropped or stay where they were.

    Returns
    -------
    points_uv : (N, 2) array
        ``boundary_uv``, then ``fixed_uv``, then the free interior nodes.
    triangles : (T, 3) int array
        Counter-clockwise triangles.
    """
    sides = _polygon_corners(np.asarray(boundary_uv, dtype=float))
    fixed = np.zeros((0, 2)) if fixed_uv is None else np.asarray(fixed_uv, dtype=float).reshape(-1, 2)
    boundary = np.concatenate([np.asarray(boundary_uv, dtype=float), fixed])
    n_fix = len(boundary)
    lo, hi = boundary.min(axis=0), boundary.max(axis=0)
    interior = _quadtree_points(lo, hi, size_uv)

    def ok_place(p):
        ok = _signed_distance_inside(p, sides) > 0.45 * size_uv(p)
        return ok & allowed_uv(p) if allowed_uv is not None and len(p) else ok

    def keep_clear(p):  # interior nodes too close to the boundary make slivers
        return p[ok_place(p)] if len(p) else p

    interior = keep_clear(interior)
    bars = None
    for step in range(n_smoothing if len(interior) else 0):
        p = np.concatenate([boundary, interior])
        if step % 5 == 0:  # re-triangulate now and then; the nodes move little in between
            bars = _unique_edges(Delaunay(p).simplices)
        vec = p[bars[:, 0]] - p[bars[:, 1]]
        length = np.linalg.norm(vec, axis=1)
        h_bar = size_uv(0.5 * (p[bars[:, 0]] + p[bars[:, 1]]))
        target = 1.2 * h_bar * np.sqrt(np.sum(length**2) / np.sum(h_bar**2))
        force = np.maximum(target - length, 0.0)[:, None] * vec / np.maximum(length, 1e-300)[:, None]
        total = np.zeros_like(p)
        for axis in (0, 1):
            total[:, axis] = (np.bincount(bars[:, 0], force[:, axis], minlength=len(p))
                              - np.bincount(bars[:, 1], force[:, axis], minlength=len(p)))
        moved = interior + 0.2 * total[n_fix:]
        # a node that would leave the polygon (or come too close to its sides) stays where it was
        ok = _signed_distance_inside(moved, sides) > 0.2 * size_uv(moved)
        if allowed_uv is not None:
            ok &= allowed_uv(moved)
        interior = np.where(ok[:, None], moved, interior)
    interior = _drop_crowded(boundary, keep_clear(interior), size_uv)
    points = np.concatenate([boundary, interior])
    tri = Delaunay(points).simplices
    a, b, c = points[tri[:, 0]], points[tri[:, 1]], points[tri[:, 2]]
    cross = (b - a)[:, 0] * (c - a)[:, 1] - (b - a)[:, 1] * (c - a)[:, 0]
    tri = np.where((cross < 0)[:, None], tri[:, [0, 2, 1]], tri)
    return points, tri


def _mesh_rectangle_3d(corners: np.ndarray, side_nodes: list[np.ndarray], size: SizeFunction,
                       outward: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Mesh a planar rectangle in 3D from its 4 corners and the nodes of its 4 sides.

    ``side_nodes[k]`` runs from ``corners[k]`` to ``corners[k+1]`` (both
    included). Triangles are wound so that their normal is ``outward``.
    """
    origin = corners[0]
    eu = corners[1] - corners[0]
    eu = eu / np.linalg.norm(eu)
    ev = np.cross(outward, eu)  # (eu, ev, outward) right-handed: CCW in (u, v) is outward
    ring = np.concatenate([s[:-1] for s in side_nodes])
    uv = np.stack([(ring - origin) @ eu, (ring - origin) @ ev], axis=1)
    area2 = np.sum(uv[:, 0] * np.roll(uv[:, 1], -1) - np.roll(uv[:, 0], -1) * uv[:, 1])
    order = np.arange(len(ring)) if area2 > 0 else np.r_[0, np.arange(len(ring) - 1, 0, -1)]
    ring, uv = ring[order], uv[order]

    def size_uv(q):
        return size(origin + q[:, :1] * eu + q[:, 1:2] * ev)

    points_uv, tri = mesh_convex_polygon(uv, size_uv)
    interior = origin + points_uv[len(ring):, :1] * eu + points_uv[len(ring):, 1:2] * ev
    return np.concatenate([ring, interior]), tri


def _weld(vertices: np.ndarray, faces: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Merge bit-identical vertices (shared edge nodes)."""
    unique, inverse = np.unique(vertices, axis=0, return_inverse=True)
    return unique, inverse.ravel()[faces]


# ----------------------------------------------------------------------- the tank
def mesh_tank(tank: Tank, edge_length_m: float | None = None, focus_m=None, *, grading: float = 0.5,
              max_edge_length_m: float | None = None, near_ratio: float | None = None,
              focus_radius_m: float = 0.0) -> LabelledMesh:
    """Closed, labelled, outward-oriented mesh of the tank's water box.

    Parameters
    ----------
    tank : Tank
        Inner size and water depth.
    edge_length_m : float, optional
        Edge length at the focus (uniform edge length without a focus).
        Default: 1/15 of the water box's smallest dimension.
    focus_m : (3,) or (P, 3) array, optional
        Tank-frame points to refine towards (sensor axis, trajectory).
    grading : float
        Growth of the edge length per metre from the focus (default 0.5).
    max_edge_length_m : float, optional
        Largest edge length (default: a quarter of the smaller horizontal
        side, but not below ``edge_length_m``).
    near_ratio, focus_radius_m : float, optional
        The edge at most ``near_ratio`` times the distance from a tube of ``focus_radius_m`` around the focus
        (:func:`graded_size_function`); default: no such bound.

    Returns
    -------
    LabelledMesh
        Regions ``TANK_REGIONS`` (walls x-, x+, y-, y+, floor, free surface),
        electrode label 0 everywhere, normals out of the water.
    """
    lo, hi = tank.water_bounds_m
    smallest = float(np.min(hi - lo))
    h0 = smallest / 15 if edge_length_m is None else float(edge_length_m)
    if not h0 > 0:
        raise ValueError(f"mesh_tank: edge_length_m must be positive, got {edge_length_m}")
    horizontal = float(min(hi[:2] - lo[:2]))
    h_max = max(h0, horizontal / 4) if max_edge_length_m is None else max(h0, float(max_edge_length_m))
    size = graded_size_function(h0, focus_m, grading, h_max, near_ratio=near_ratio, focus_radius_m=focus_radius_m)
    return mesh_axis_box(lo, hi, size)


def mesh_axis_box(lo_m, hi_m, size: SizeFunction, region_names=TANK_REGIONS) -> LabelledMesh:
    """Closed, outward-oriented mesh of the axis-aligned box [lo_m, hi_m] with a size function.

    The six faces get regions 0..5 in the order x-, x+, y-, y+, z-, z+ (the
    order of ``TANK_REGIONS``); the faces share their edge nodes.
    """
    lo, hi = np.asarray(lo_m, float), np.asarray(hi_m, float)
    # the 8 corners, index bits (x, y, z) -> lo/hi
    corner = lambda i, j, k: np.array([(lo, hi)[i][0], (lo, hi)[j][1], (lo, hi)[k][2]])  # noqa: E731
    edge_cache: dict[tuple, np.ndarray] = {}

    def side(c0, c1):
        key = (c0, c1) if c0 < c1 else (c1, c0)
        if key not in edge_cache:
            edge_cache[key] = equidistributed_nodes(corner(*key[0]), corner(*key[1]), size)
        nodes = edge_cache[key]
        return nodes if key == (c0, c1) else nodes[::-1]

    # each face: 4 corners (as index triples) in a loop, and the outward normal
    faces_def = {
        "wall_x-": ([(0, 0, 0), (0, 1, 0), (0, 1, 1), (0, 0, 1)], (-1, 0, 0)),
        "wall_x+": ([(1, 0, 0), (1, 1, 0), (1, 1, 1), (1, 0, 1)], (1, 0, 0)),
        "wall_y-": ([(0, 0, 0), (1, 0, 0), (1, 0, 1), (0, 0, 1)], (0, -1, 0)),
        "wall_y+": ([(0, 1, 0), (1, 1, 0), (1, 1, 1), (0, 1, 1)], (0, 1, 0)),
        "floor": ([(0, 0, 0), (1, 0, 0), (1, 1, 0), (0, 1, 0)], (0, 0, -1)),
        "free_surface": ([(0, 0, 1), (1, 0, 1), (1, 1, 1), (0, 1, 1)], (0, 0, 1)),
    }
    parts = []
    for region, name in enumerate(TANK_REGIONS):
        loop, outward = faces_def[name]  # geometric order, whatever the names
        corners = np.array([corner(*c) for c in loop])
        sides = [side(loop[k], loop[(k + 1) % 4]) for k in range(4)]
        verts, tri = _mesh_rectangle_3d(corners, sides, size, np.array(outward, float))
        parts.append(LabelledMesh(verts, tri, None, np.full(len(tri), region), TANK_REGIONS))
    joined = concatenate(parts)
    vertices, faces = _weld(joined.vertices_m, joined.faces)
    return LabelledMesh(vertices, faces, joined.electrode, joined.region, tuple(region_names))
