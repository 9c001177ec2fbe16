"""Graded, exactly symmetric surface mesh of a sensor whose electrodes are split into sectors.

:func:`electrosense.meshes.sensor_mesh.mesh_sensor` calls :func:`mesh_sector_sensor`
for a sensor with sectors (:mod:`electrosense.meshes.sensor`). The rings along the axis
are those of a whole sensor (graded towards every axial electrode edge);
what changes is where the vertices sit around each ring:

* **Symmetry.** The mesh is built in one wedge of angle ``2 pi / M`` and
  copied ``M`` times by rotation about +x, so it is exactly invariant under
  rotations by ``2 pi / M`` (triangle ``t`` of wedge ``w`` has index
  ``w T + t``, which the BEM's symmetric solver uses). ``M`` is the greatest
  common divisor of the sector counts. Beyond that, the rings of a split
  electrode are invariant under all of its own sector rotations, and the
  other rings under those of every split electrode (their vertex counts are
  multiples of the least common multiple of the sector counts, when that is at
  most :data:`MAX_SYMMETRY_ORDER`): sectors that the sensor's symmetry makes
  equal get equal currents, up to the effect of the other electrodes' gaps,
  which break it physically too. The wedges end on sector edges (a split
  cap's first, else those of the electrode with the most sectors). When no
  rotation maps the sensor onto itself (``M`` = 1: say 2 and 3 sectors), the
  mesh is a half turn ``[0, pi]`` and its mirror image in the x-y plane
  (every sector pattern is symmetric about +y), the mirrored triangles after
  the others: still two blocks for the symmetric solver.
* **Sector edges.** The rings of a split ring carry one azimuthal vertex set
  (and its half-step staggered copy, ring by ring): every sector edge is a
  vertex, and between edges the spacing is graded as along the axis,
  ``h = min(h_band, h_edge + (sector_grading - 1) d)`` with ``d`` the distance
  along the circumference to the nearest sector edge,
  ``h_band = edge_length / (1.25 azimuthal_refinement)`` and
  ``h_edge = edge_length / sector_refinement``. The edges are lines of the
  mesh, so no triangle straddles one. Rings beside a split electrode, and the
  smaller rings of a split cap, are graded the same way with ``h_edge`` grown
  by ``(sector_grading - 1)`` times their axial distance from the electrode,
  until the grading dies out.
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

__all__ = ["mesh_sector_sensor", "symmetry_order", "block_symmetry", "MAX_SYMMETRY_ORDER", "wedge_triangles"]

#: far edge length over the spacing at a sector edge, by default
DEFAULT_SECTOR_REFINEMENT = 12.0
#: growth ratio of the spacings away from a sector edge, by default
DEFAULT_SECTOR_GRADING = 1.3

#: largest rotational symmetry order a sector mesh is built with (every ring then has a multiple of it vertices)
MAX_SYMMETRY_ORDER = 24


def symmetry_order(sensor: SensorDescription) -> int:
    """Order ``M`` of the rotations about +x that map a sector sensor's mesh onto itself: the greatest common
    divisor of the sector counts (each split electrode's own rings are symmetric under all its sector rotations)."""
    counts = [e.sectors for e in sensor.electrodes if e.is_split]
    return math.gcd(*counts) if counts else 1


def block_symmetry(sensor: SensorDescription) -> tuple[int, bool]:
    """(number of copies, mirror) of the block structure of a sector sensor's mesh: ``M`` rotated wedges, or,
    when no rotation maps the sensor onto itself (``M`` = 1), a half turn and its mirror image (z -> -z).
    A sensor without sectors (meshed ring by ring, :func:`electrosense.meshes.sensor_mesh.mesh_sensor`): (1, False)."""
    if not sensor.has_sectors:
        return 1, False
    M = symmetry_order(sensor)
    return (2, True) if M == 1 else (M, False)


def _plain_order(sensor: SensorDescription) -> int:
    """Vertex counts of the rings away from split electrodes are multiples of this (the least common multiple of
    the sector counts, if at most :data:`MAX_SYMMETRY_ORDER`)."""
    counts = [e.sectors for e in sensor.electrodes if e.is_split]
    lcm = math.lcm(*counts) if counts else 1
    return lcm if lcm <= MAX_SYMMETRY_ORDER else symmetry_order(sensor)


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


def _graded_angles(edges_rad, theta0, period, radius_m, h_band, h_edge, grading, width):
    """Angles in [theta0, theta0 + width] (ends included) of a ring beside or on a split electrode.

    The electrode's pattern is periodic with its sector pitch ``period``: every
    sector edge is a vertex and the spacing is graded towards all of them. The
    pattern is laid around the ring and cut to the wedge at points of its own
    (the wedge's ends and their images under the sector rotations are
    vertices of every period).
    """
    from electrosense.meshes.sensor_mesh import _ring_positions

    tol = 1e-9
    edges = np.sort(np.asarray(edges_rad) % (2 * np.pi))
    e0 = edges[0]
    folded = np.sort((edges - e0) % period)
    folded = folded[(folded > tol) & (folded < period - tol)]
    folded = folded[np.concatenate([[True], np.diff(folded) > tol])] if folded.size else folded
    edge_offsets = np.concatenate([[0.0], folded])
    images = np.concatenate([edge_offsets + period * k for k in range(-int(np.ceil(np.pi / period)) - 1,
                                                                      int(np.ceil(np.pi / period)) + 2)])
    # the wedge's end, and its images under the electrode's own sector rotations, are vertices of the pattern
    # too: the pattern stays periodic (each sector meshed alike) and no wedge end cuts it
    extra = []
    for end in ((theta0 - e0) % period, (theta0 + width - e0) % period):
        known = np.concatenate([folded, extra])
        if tol < end < period - tol and np.min(np.abs(known - end), initial=np.inf) > tol:
            extra.append(end)
    breaks = np.sort(np.concatenate([edge_offsets, extra, [period]]))
    positions, _ = _ring_positions(breaks * radius_m, images * radius_m, h_band, h_edge, grading)
    pattern = positions[:-1] / radius_m
    pattern[np.searchsorted(pattern, breaks[:-1] - tol)] = breaks[:-1]    # the breakpoints exactly
    first = int(np.floor((theta0 - e0) / period)) - 1
    copies = int(np.ceil(width / period)) + 3
    ring = np.concatenate([e0 + pattern + period * k for k in range(first, first + copies)])
    keep = (ring > theta0 + tol) & (ring < theta0 + width - tol)
    return np.concatenate([[theta0], ring[keep], [theta0 + width]])


def _breakpoints(angles, edges_rad, theta0, period, width):
    """Which of a pattern's angles are sector edges or images of the wedge's ends (kept by :func:`_staggered`)."""
    marks = np.concatenate([np.asarray(edges_rad), [theta0, theta0 + width]])
    off = (angles[:, None] - marks[None, :] + 0.5 * period) % period - 0.5 * period
    return np.min(np.abs(off), axis=1) < 1e-9


def _staggered(angles, fixed):
    """The midpoints of a ring's intervals, with its ``fixed`` points (sector edges, wedge ends): zipped with the
    set itself it gives isosceles triangles (the whole sensor's half-step offset), not split quadrilaterals."""
    return np.unique(np.concatenate([angles[fixed], 0.5 * (angles[1:] + angles[:-1])]))


def _zip_open(a_idx, a_ang, b_idx, b_ang):
    """Triangles joining two open polylines of a wedge (A at larger x), advancing by the shorter diagonal."""
    if len(a_idx) == 1:   # tip
        return [(a_idx[0], b_idx[j], b_idx[j + 1]) for j in range(len(b_idx) - 1)]
    if len(b_idx) == 1:
        return [(a_idx[i], b_idx[0], a_idx[i + 1]) for i in range(len(a_idx) - 1)]
    tris, i, j = [], 0, 0
    m, n = len(a_idx) - 1, len(b_idx) - 1
    while i < m or j < n:
        # the shorter new diagonal (in angle) wins; ties go to the ring whose next vertex comes first. A vertex
        # that both rings share (a sector edge) is never straddled: the diagonal across it is the longer one.
        if i < m and j < n:
            advance_a = (a_ang[i + 1] - b_ang[j], a_ang[i + 1]) < (b_ang[j + 1] - a_ang[i], b_ang[j + 1])
        else:
            advance_a = i < m
        if advance_a:
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
                       ring_radius: str = "area", uniform_cylinder: bool = False, sector_refinement: float = DEFAULT_SECTOR_REFINEMENT,
                       sector_grading: float = DEFAULT_SECTOR_GRADING) -> LabelledMesh:
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
    plain = _plain_order(sensor)
    mirror = M == 1
    if mirror:   # no rotation: the half turn [0, pi] (every sector pattern is symmetric about 0 and pi), mirrored
        width, theta0 = np.pi, 0.0
    else:
        # the wedge's ends on sector edges (of a split cap first: no needle at the tip, where its rings shrink
        # to a point; else of the electrode with the most sectors), so that they cut no graded pattern
        width = 2 * np.pi / M
        split = sorted((e for e in sensor.electrodes if e.is_split), key=lambda e: (e.kind != "cap", -e.sectors))
        half = sector_azimuths_rad(split[0], sensor.radius_m)[1]
        theta0 = (-half + 0.5 * width) % width - 0.5 * width
    R = sensor.radius_m
    h_band = h_far / (1.25 * azimuthal_refinement)   # a little finer than whole rings: no half-step offset
    h_edge = min(h_far / sector_refinement, h_band)
    band_sets, staggered = {}, {}
    for index, e in enumerate(sensor.electrodes):
        if e.is_split:
            band_sets[index] = _graded_angles(_sector_edges_rad(e, R), theta0, 2 * np.pi / e.sectors, R, h_band,
                                              h_edge, sector_grading, width)
            period = 2 * np.pi / e.sectors
            fixed = _breakpoints(band_sets[index], _sector_edges_rad(e, R), theta0, period, width)
            fixed[[0, -1]] = True
            staggered[index] = _staggered(band_sets[index], fixed)

    reach = (h_band - h_edge) / (sector_grading - 1.0)   # axial distance at which the grading has died out

    def band_of(x):
        """The split electrode nearest to axial position ``x`` within ``reach``, and the distance to it."""
        best, dist = None, reach
        for index, e in enumerate(sensor.electrodes):
            if index in band_sets:
                d = max(e.x_min_m - x, x - e.x_max_m, 0.0)
                if d < dist:
                    best, dist = index, d
        return best, dist

    ring_angles = []
    for k, (x, r, m) in enumerate(zip(x_rings, r_rings, counts)):
        if m == 1:
            ring_angles.append(None)
            continue
        index, d = band_of(x)
        if index is not None and (d > 0 or r < R * (1 - 1e-9)):
            # beside a split electrode, or on a split cap (smaller rings, fewer vertices): graded towards the
            # sector edges' lines, less and less finely further away along the axis
            e = sensor.electrodes[index]
            ring_angles.append(_graded_angles(_sector_edges_rad(e, R), theta0, 2 * np.pi / e.sectors, r, h_band,
                                              h_edge + (sector_grading - 1.0) * d, sector_grading, width))
        elif index is not None:   # on a split ring: the band's set and its staggered copy, ring by ring
            ring_angles.append(band_sets[index] if k % 2 == 0 else staggered[index])
        elif mirror:   # 2 m vertices, a multiple of every sector count, 0 and pi among them
            even = math.lcm(2, plain)
            per_wedge = max(1, int(np.ceil(m / even))) * even // 2
            ring_angles.append(theta0 + width * np.arange(per_wedge + 1) / per_wedge)
        else:
            per_wedge = max(1, int(np.ceil(m / plain))) * (plain // M)
            ring_angles.append(theta0 + width * np.arange(per_wedge + 1) / per_wedge)

    # vertices: ring by ring, wedge by wedge (mirror: the half turn, then its mirror image z -> -z)
    copies = 2 if mirror else M
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
        rho = r * np.sqrt(2 * np.pi / (copies * np.sum(np.sin(np.diff(angles)))))
        if mirror:
            phi = np.concatenate([angles, -angles[-2:0:-1]])
        else:
            phi = (angles[:-1][None, :] + width * np.arange(M)[:, None]).ravel()
        vertices.append(np.column_stack([np.full(copies * m, x), rho * np.cos(phi), rho * np.sin(phi)]))
        if mirror:   # exactly mirrored coordinates
            vertices[-1][m + 1:, 2] = -vertices[-1][m - 1:0:-1, 2]
            vertices[-1][m + 1:, :2] = vertices[-1][m - 1:0:-1, :2]
        per_ring.append(copies * m)
        n_vertices += copies * m

    # triangles of wedge 0 as (ring, local index) pairs (local index m: the wedge's far end), then every copy
    wedge, wedge_x = [], []
    for k in range(len(x_rings) - 1):
        a, b = ring_angles[k], ring_angles[k + 1]
        a_idx = [(k, 0)] if a is None else [(k, j) for j in range(len(a))]
        b_idx = [(k + 1, 0)] if b is None else [(k + 1, j) for j in range(len(b))]
        tris = _zip_open(a_idx, a, b_idx, b)
        wedge.extend(tris)
        wedge_x.extend([0.5 * (x_rings[k] + x_rings[k + 1])] * len(tris))

    def vertex(ring, j, w):
        n = per_ring[ring]
        if n == 1:
            return base[ring]
        if mirror:
            return base[ring] + (j if w == 0 or j in (0, n // 2) else n - j)
        return base[ring] + (w * (n // M) + j) % n

    faces, x_mids = [], []
    for w in range(copies):
        for t in wedge:
            tri = [vertex(ring, j, w) for ring, j in t]
            faces.append(tri[::-1] if mirror and w == 1 else tri)   # a mirror image keeps its normal outwards
        x_mids.extend(wedge_x)
    vertices = np.concatenate(vertices)
    faces = np.asarray(faces, dtype=np.int64)
    centre = vertices[faces].mean(axis=1)
    phis = np.arctan2(centre[:, 2], centre[:, 1])
    labels = [_label(sensor, x_mid, phi) for x_mid, phi in zip(x_mids, phis)]
    return LabelledMesh(
        vertices_m=vertices,
        faces=faces,
        electrode=np.asarray(labels, dtype=np.int64),
        region=np.zeros(len(faces), dtype=np.int64),
        region_names=("sensor",),
    )
