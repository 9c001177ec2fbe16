"""Graded, exactly symmetric surface mesh of a sensor whose electrodes are split into sectors.

:func:`electrosense.meshes.sensor_mesh.mesh_sensor` calls :func:`mesh_sector_sensor`
for a sensor with sectors (:mod:`electrosense.meshes.sensor`). The rings along the axis
are those of a whole sensor (graded towards every axial electrode edge);
what changes is where the vertices sit around each ring:

* **Symmetry.** The mesh is built in one wedge of angle ``2 pi / M``
  and copied ``M`` times by rotation about +x, so it is exactly
  invariant under rotations by ``2 pi / M`` (triangle ``t`` of wedge ``w`` has
  index ``w T + t``, which the BEM's symmetric solver uses). ``M`` is the least
  common multiple of the sector counts when that is at most
  :data:`MAX_SYMMETRY_ORDER`, else their greatest common divisor (a split
  cap's wedges end on its sector edges, else they are centred on +y): every
  rotation that maps the sensor onto itself and its sectors onto sectors maps
  the mesh onto itself, so sectors that physics makes equal get equal currents.
* **Sector edges.** The rings of a split electrode, and those within half a
  far edge length of it along the axis, carry one azimuthal vertex set: every
  sector edge is a vertex, and between edges the spacing is graded as along
  the axis, ``h = min(h_band, h_edge + (grading - 1) d)`` with ``d`` the
  distance along the circumference to the nearest sector edge,
  ``h_band = edge_length / azimuthal_refinement`` and
  ``h_edge = edge_length / sector_refinement``. The edges are straight lines
  of the mesh, so no triangle straddles one.
* **Other rings** have as many equally spaced vertices as the whole sensor's
  rings, rounded up to a multiple of ``M``; rings of different vertex sets are
  zipped by angle, which keeps every vertex shared by both rings on a mesh edge.
* **Radius.** Each ring's vertices sit where the faceted ring encloses the
  circle's area (the ``"area"`` rule of the whole sensor's mesh, for unequal spacings).

Example
-------
>>> from electrosense.meshes.sensor import preset
>>> s = preset("angels-4").with_sectors({2: 4, 3: 4}, gap_m=0.002)
>>> m = mesh_sector_sensor(s, 0.006)
>>> m.to_trimesh().is_watertight, m.electrodes
(True, (1, 2, 3, 4, 5, 6, 7, 8, 9, 10))
>>> symmetry_order(s)
4
"""
from __future__ import annotations

import math

import numpy as np

from electrosense.meshes.labelled_mesh import LabelledMesh
from electrosense.meshes.sensor import SensorDescription, sector_azimuths_rad

__all__ = ["mesh_sector_sensor", "symmetry_order", "MAX_SYMMETRY_ORDER", "wedge_triangles"]

#: largest rotational symmetry order a sector mesh is built with (every ring then has a multiple of it vertices)
MAX_SYMMETRY_ORDER = 24


def symmetry_order(sensor: SensorDescription) -> int:
    """Order ``M`` of the rotations about +x that map a sector sensor's mesh onto itself."""
    counts = [e.sectors for e in sensor.electrodes if e.is_split]
    if not counts:
        return 1
    lcm = math.lcm(*counts)
    return lcm if lcm <= MAX_SYMMETRY_ORDER else math.gcd(*counts)


def wedge_triangles(mesh: LabelledMesh, order: int) -> int:
    """Triangles per wedge of a mesh made by :func:`mesh_sector_sensor` with symmetry ``order``."""
    if mesh.n_triangles % order:
        raise ValueError(f"a mesh of {mesh.n_triangles} triangles is not made of {order} equal wedges")
    return mesh.n_triangles // order


def _sector_edges_rad(electrode, radius_m: float) -> np.ndarray:
    """Azimuths of every sector edge of a split electrode, sorted in [0, 2 pi)."""
    centres, half = sector_azimuths_rad(electrode, radius_m)
    edges = np.concatenate([centres - half, centres + half]) % (2 * np.pi)
    edges = np.sort(edges)
    keep = np.concatenate([[True], np.diff(edges) > 1e-12])
    edges = edges[keep]
    if len(edges) > 1 and edges[-1] - edges[0] > 2 * np.pi - 1e-12:
        edges = edges[:-1]
    return edges


def _graded_angles(edges_rad, theta0, width, radius_m, h_band, h_edge, grading):
    """Angles in [theta0, theta0 + width] (ends included): every sector edge inside, graded towards all of them."""
    from electrosense.meshes.sensor_mesh import _ring_positions

    images = np.concatenate([edges_rad + 2 * np.pi * k for k in (-2, -1, 0, 1, 2)])
    inside = images[(images > theta0 + 1e-12) & (images < theta0 + width - 1e-12)]
    breaks = np.concatenate([[theta0], inside, [theta0 + width]]) * radius_m
    near = images[(images > theta0 - np.pi) & (images < theta0 + width + np.pi)] * radius_m
    positions, _ = _ring_positions(breaks, near, h_band, h_edge, grading)
    angles = positions / radius_m
    angles[0], angles[-1] = theta0, theta0 + width
    for e in inside:   # the edges exactly (the same float in every ring that carries this set)
        angles[np.argmin(np.abs(angles - e))] = e
    return angles


def _staggered(angles, edges_rad):
    """The midpoints of a ring's intervals, with its ends and sector edges: zipped with the set itself it gives
    isosceles triangles (the whole sensor's half-step offset) instead of split quadrilaterals."""
    fixed = [angles[0], angles[-1]] + [a for a in angles if np.min(np.abs((a - edges_rad + np.pi) % (2 * np.pi)
                                                                          - np.pi)) < 1e-12]
    out = np.unique(np.concatenate([fixed, 0.5 * (angles[1:] + angles[:-1])]))
    return out


def _zip_open(a_idx, a_ang, b_idx, b_ang):
    """Triangles joining two open polylines of a wedge (A at larger x), advancing by angle."""
    if len(a_idx) == 1:   # tip
        return [(a_idx[0], b_idx[j], b_idx[j + 1]) for j in range(len(b_idx) - 1)]
    if len(b_idx) == 1:
        return [(a_idx[i], b_idx[0], a_idx[i + 1]) for i in range(len(a_idx) - 1)]
    tris, i, j = [], 0, 0
    m, n = len(a_idx) - 1, len(b_idx) - 1
    while i < m or j < n:
        if j >= n or (i < m and a_ang[i + 1] <= b_ang[j + 1]):
            tris.append((a_idx[i], b_idx[j], a_idx[i + 1]))
            i += 1
        else:
            tris.append((a_idx[i], b_idx[j], b_idx[j + 1]))
            j += 1
    return tris


def _label(sensor: SensorDescription, x_mid: float, phi: float) -> int:
    """Electrode number of a face at axial position ``x_mid`` and azimuth ``phi`` (0: insulator)."""
    for index, e in enumerate(sensor.electrodes):
        if not e.x_min_m <= x_mid <= e.x_max_m:
            continue
        numbers = sensor.numbers_of(index)
        if not e.is_split:
            return numbers[0]
        centres, half = sector_azimuths_rad(e, sensor.radius_m)
        k = int(np.round(phi / (2 * np.pi / e.sectors))) % e.sectors
        off = (phi - centres[k] + np.pi) % (2 * np.pi) - np.pi
        return numbers[k] if abs(off) <= half else 0
    return 0


def mesh_sector_sensor(sensor: SensorDescription, edge_length_m: float | None = None, grading: float = 1.15,
                       edge_refinement: float = 30.0, max_aspect: float = 3.0, azimuthal_refinement: float = 2.5,
                       ring_radius: str = "area", uniform_cylinder: bool = False, sector_refinement: float = 12.0,
                       sector_grading: float = 1.3) -> LabelledMesh:
    """Closed, graded, labelled, exactly symmetric mesh of a sector sensor in its own frame.

    Parameters are those of :func:`electrosense.meshes.sensor_mesh.mesh_sensor`, plus
    ``sector_refinement`` (far edge length over the spacing at a sector edge)
    and ``sector_grading`` (growth ratio of the spacings away from a sector edge).
    ``ring_radius`` must be ``"area"`` (the rule for unequal spacings).
    """
    from electrosense.meshes.sensor_mesh import _ring_layout, default_edge_length_m

    if ring_radius != "area":
        raise ValueError(f"mesh_sensor: a sensor with sectors is meshed with ring_radius='area', got {ring_radius!r}")
    if not sector_refinement >= 1.0:
        raise ValueError(f"mesh_sensor: sector_refinement must be >= 1, got {sector_refinement}")
    if not sector_grading > 1.0:
        raise ValueError(f"mesh_sensor: sector_grading must exceed 1, got {sector_grading}")
    h_far = default_edge_length_m(sensor) if edge_length_m is None else float(edge_length_m)
    profile, x_rings, r_rings, counts = _ring_layout(sensor, edge_length_m, grading, edge_refinement, max_aspect,
                                                     azimuthal_refinement, uniform_cylinder)
    M = symmetry_order(sensor)
    width = 2 * np.pi / M
    theta0 = -0.5 * width
    caps = [e for e in sensor.electrodes if e.is_split and e.kind == "cap"]
    if caps:   # a wedge's end on a cap's sector edge: no needle at the tip, where every ring shrinks to a point
        half = sector_azimuths_rad(caps[0], sensor.radius_m)[1]
        theta0 = (-half + 0.5 * width) % width - 0.5 * width
    R = sensor.radius_m
    h_band = h_far / (1.25 * azimuthal_refinement)   # a little finer than whole rings: no half-step offset
    h_edge = min(h_far / sector_refinement, h_band)
    band_sets, staggered = {}, {}
    for index, e in enumerate(sensor.electrodes):
        if e.is_split:
            band_sets[index] = _graded_angles(_sector_edges_rad(e, R), theta0, width, R, h_band, h_edge,
                                              sector_grading)
            staggered[index] = _staggered(band_sets[index], _sector_edges_rad(e, R))

    def band_of(x):
        best, dist = None, 0.5 * h_far
        for index, e in enumerate(sensor.electrodes):
            if index in band_sets:
                d = max(e.x_min_m - x, x - e.x_max_m, 0.0)
                if d <= dist + 1e-15:
                    best, dist = index, d - 1e-15
        return best

    ring_angles = []
    for k, (x, r, m) in enumerate(zip(x_rings, r_rings, counts)):
        if m == 1:
            ring_angles.append(None)
            continue
        index = band_of(x)
        if index is not None and r < R * (1 - 1e-9):   # on a cap: fewer vertices on smaller rings
            e = sensor.electrodes[index]
            ring_angles.append(_graded_angles(_sector_edges_rad(e, R), theta0, width, r, h_band, h_edge,
                                              sector_grading))
        elif index is not None:   # on the cylinder: the band's set and its staggered copy, ring by ring
            ring_angles.append(band_sets[index] if k % 2 == 0 else staggered[index])
        else:
            per_wedge = max(1, int(np.ceil(m / M)))
            ring_angles.append(theta0 + width * np.arange(per_wedge + 1) / per_wedge)

    # vertices: ring by ring, wedge by wedge
    vertices, base, per_ring = [], [], []
    n_vertices = 0
    for x, r, angles in zip(x_rings, r_rings, ring_angles):
        base.append(n_vertices)
        if angles is None:
            vertices.append(np.array([[x, 0.0, 0.0]]))
            per_ring.append(1)
            n_vertices += 1
            continue
        m = len(angles) - 1
        rho = r * np.sqrt(2 * np.pi / (M * np.sum(np.sin(np.diff(angles)))))
        phi = (angles[:-1][None, :] + width * np.arange(M)[:, None]).ravel()
        vertices.append(np.column_stack([np.full(M * m, x), rho * np.cos(phi), rho * np.sin(phi)]))
        per_ring.append(M * m)
        n_vertices += M * m

    # triangles of wedge 0, as (ring, local index) triples, local index m = the next wedge's first vertex
    wedge, labels_x, phis = [], [], []
    for k in range(len(x_rings) - 1):
        a, b = ring_angles[k], ring_angles[k + 1]
        a_idx = [(k, 0)] if a is None else [(k, j) for j in range(len(a))]
        b_idx = [(k + 1, 0)] if b is None else [(k + 1, j) for j in range(len(b))]
        tris = _zip_open(a_idx, a, b_idx, b)
        x_mid = 0.5 * (x_rings[k] + x_rings[k + 1])
        for t in tris:
            angs = [ring_angles[ring][j] for ring, j in t if ring_angles[ring] is not None]
            wedge.append(t)
            labels_x.append(x_mid)
            phis.append(float(np.mean(angs)))

    faces, labels = [], []
    for w in range(M):
        for t, x_mid, phi in zip(wedge, labels_x, phis):
            tri = []
            for ring, j in t:
                n = per_ring[ring]
                m = n // M
                tri.append(base[ring] if n == 1 else base[ring] + (w * m + j) % n)
            faces.append(tri)
            labels.append(_label(sensor, x_mid, phi + w * width))
    return LabelledMesh(
        vertices_m=np.concatenate(vertices),
        faces=np.asarray(faces, dtype=np.int64),
        electrode=np.asarray(labels, dtype=np.int64),
        region=np.zeros(len(faces), dtype=np.int64),
        region_names=("sensor",),
    )
