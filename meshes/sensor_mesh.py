"""Graded surface mesh of an axisymmetric sensor (hemispherical ends + cylinder).

The sensor's surface is a surface of revolution about the x axis (sensor
frame, :mod:`electrosense.meshes.sensor`). Its meridian is parametrised by the arc length
``s`` from the head tip (``s = 0``, x = +L/2) to the tail tip. The mesh is
built ring by ring:

1. **Rings along the axis.** Every electrode/insulator edge and both
   cap/cylinder junctions are *breakpoints*: they fall exactly on a ring of
   vertices, so no triangle straddles an electrode edge. Between breakpoints
   the rings are placed by equidistributing ``1/h(s)``, with the target
   spacing

       h(s) = min(edge_length_m, h_edge + (grading - 1) * d(s)),

   ``d(s)`` the arc length to the nearest electrode edge and
   ``h_edge = edge_length_m / edge_refinement``. A linear size function is a
   geometric progression of element sizes with ratio ``grading`` away from
   the edge, where the current density is singular (~ r^-1/2).
2. **Vertices around each ring.** Ring ``i`` of radius ``r_i`` gets
   ``M_i = ceil(2 pi r_i / h_phi)`` vertices with
   ``h_phi = clip(max_aspect * h(s_i), edge_length_m / azimuthal_refinement,
   edge_length_m)``: triangles are close to equilateral where the axial
   spacing allows; near the electrode edges they are longer around than
   along the axis (the solution varies along the axis there, hardly around
   it), but the rings there are still ``azimuthal_refinement`` times finer
   around than far away, which the conductances need.
3. **Zipping.** Neighbouring rings of different counts are joined by the
   classic advancing-front zip (always advance the ring whose next vertex
   comes first in angle); the tips are fans.
4. **Ring radius.** A ring of ``M`` vertices on the circle of radius ``r``
   is an inscribed polygon that misses a fraction ~ (2 pi/M)^2 / 6 of the
   circle's area. By default (``ring_radius="area"``) the vertices sit at
   ``r * sqrt((2 pi/M) / sin(2 pi/M))`` so that every faceted ring encloses
   the circle's area, which removes most of the geometric error of flat
   facets from the conductances (``"perimeter"`` matches the perimeter).

Faces are wound so that the normals point out of the sensor body (into the
water); ``electrode`` holds the electrode number of each face (0 on the
insulator) and the only region is ``"sensor"``.

Example
-------
>>> from electrosense.meshes.sensor import preset
>>> from electrosense.meshes.sensor_mesh import mesh_sensor
>>> m = mesh_sensor(preset("angels-4"))
>>> m.to_trimesh().is_watertight, m.electrodes
(True, (1, 2, 3, 4))
"""
from __future__ import annotations

import numpy as np

from electrosense.meshes.labelled_mesh import LabelledMesh
from electrosense.meshes.sensor import SensorDescription

__all__ = ["mesh_sensor", "estimate_triangles", "MAX_SENSOR_TRIANGLES", "SensorProfile", "default_edge_length_m", "coarsest_edge_length_m", "electrode_edge_arc_lengths", "graded_arc_lengths"]


def default_edge_length_m(sensor: SensorDescription) -> float:
    """Default far-field edge length (m): 0.6 radius, at most length/30."""
    return float(min(0.6 * sensor.radius_m, sensor.length_m / 30.0))


def coarsest_edge_length_m(sensor: SensorDescription) -> float:
    """The coarsest far-field edge (m) the mesher accepts: the sensor's diameter (a coarser one cannot close a ring).

    >>> from electrosense.meshes.sensor import preset
    >>> coarsest_edge_length_m(preset("angels-2")) == 2 * preset("angels-2").radius_m
    True
    """
    return 2.0 * float(sensor.radius_m)


class SensorProfile:
    """The meridian of the sensor, parametrised by arc length from the head tip.

    Example
    -------
    >>> from electrosense.meshes.sensor import preset
    >>> p = SensorProfile(preset("angels-2"))
    >>> x, r = p.point(0.0)
    >>> float(x), float(r)
    (0.1, 0.0)
    """

    def __init__(self, sensor: SensorDescription):
        self.R = float(sensor.radius_m)
        self.c = 0.5 * float(sensor.length_m) - self.R  # centre of each hemisphere on the axis
        self.s_junction = (0.5 * np.pi * self.R, 0.5 * np.pi * self.R + 2 * self.c)
        self.total = np.pi * self.R + 2 * self.c

    def point(self, s):
        """Axial position x and radius r (m) at arc length ``s`` (m)."""
        s = np.asarray(s, dtype=float)
        R, c = self.R, self.c
        s1, s2 = self.s_junction
        theta_head = np.clip(s / R, 0, np.pi / 2)
        theta_tail = np.clip((s - s2) / R, 0, np.pi / 2)
        x = np.where(s <= s1, c + R * np.cos(theta_head), np.where(s <= s2, c - (s - s1), -c - R * np.sin(theta_tail)))
        r = np.where(s <= s1, R * np.sin(theta_head), np.where(s <= s2, R, R * np.cos(theta_tail)))
        return x, r

    def normal(self, s):
        """Unit normal (n_x, n_r) of the meridian at arc length ``s``, out of the body into the water."""
        x, r = self.point(s)
        s = np.asarray(s, dtype=float)
        s1, s2 = self.s_junction
        centre = np.where(s <= s1, self.c, np.where(s <= s2, x, -self.c))
        return (x - centre) / self.R, np.where((s > s1) & (s <= s2), 1.0, r / self.R)

    def arc_length(self, x: float) -> float:
        """Arc length (m) of the point of the meridian at axial position ``x``."""
        R, c = self.R, self.c
        s1, s2 = self.s_junction
        if x >= c:
            return float(R * np.arccos(np.clip((x - c) / R, -1, 1)))
        if x >= -c:
            return float(s1 + (c - x))
        return float(s2 + R * np.arcsin(np.clip((-c - x) / R, -1, 1)))


def _ring_radius_factor(m: int, mode: str) -> float:
    """Vertex radius / circle radius for a ring of ``m`` vertices."""
    if mode == "inscribed":
        return 1.0
    if mode == "perimeter":
        return (np.pi / m) / np.sin(np.pi / m)
    if mode == "area":
        return float(np.sqrt((2 * np.pi / m) / np.sin(2 * np.pi / m)))
    raise ValueError(f"mesh_sensor: ring_radius must be 'area', 'perimeter' or 'inscribed', got {mode!r}")


def electrode_edge_arc_lengths(sensor: SensorDescription) -> np.ndarray:
    """Arc lengths (m, from the head tip) of the electrode/insulator edges, sorted.

    Example
    -------
    >>> from electrosense.meshes.sensor import preset
    >>> electrode_edge_arc_lengths(preset("angels-2")).size
    2
    """
    profile = SensorProfile(sensor)
    half = 0.5 * sensor.length_m
    edge_x = sorted({x for e in sensor.electrodes for x in (e.x_min_m, e.x_max_m) if abs(abs(x) - half) > 1e-12})
    return np.array(sorted(profile.arc_length(x) for x in edge_x))


def graded_arc_lengths(sensor: SensorDescription, h_far_m: float, h_edge_m: float, grading: float):
    """Nodes of the meridian (arc lengths from the head tip, m), graded towards the electrode edges.

    The nodes include both tips, every electrode edge and both cap/cylinder
    junctions; between them they equidistribute ``1 / h(s)`` with
    ``h(s) = min(h_far_m, h_edge_m + (grading - 1) d(s))``, ``d`` the arc
    length to the nearest electrode edge. Returns the nodes and ``h``.

    Example
    -------
    >>> from electrosense.meshes.sensor import preset
    >>> s, h = graded_arc_lengths(preset("angels-2"), 0.005, 0.0005, 1.2)
    >>> bool(s[0] == 0.0 and np.all(np.diff(s) > 0))
    True
    """
    profile = SensorProfile(sensor)
    edges = electrode_edge_arc_lengths(sensor)
    breaks = np.unique(np.concatenate([[0.0, profile.total], edges, profile.s_junction]))
    breaks = breaks[np.concatenate([[True], np.diff(breaks) > 1e-9 * profile.total])]
    return _ring_positions(breaks, edges, h_far_m, h_edge_m, grading)


def _ring_positions(breaks: np.ndarray, edges: np.ndarray, h_far: float, h_edge: float, grading: float) -> np.ndarray:
    """Arc lengths of the rings: every breakpoint plus graded rings between them."""

    def size(s):
        if edges.size == 0:
            return np.full_like(s, h_far)
        d = np.min(np.abs(s[:, None] - edges[None, :]), axis=1)
        return np.minimum(h_far, h_edge + (grading - 1.0) * d)

    rings = [breaks[0]]
    for a, b in zip(breaks[:-1], breaks[1:]):
        t = np.linspace(a, b, 801)
        for e in edges[(edges >= a) & (edges <= b)]:   # resolve 1/h where it is steep, however fine h_edge
            offsets = np.geomspace(1e-3 * h_edge, b - a, 400)
            t = np.concatenate([t, e - offsets, e + offsets])
        t = np.unique(np.clip(t, a, b))
        inv_h = 1.0 / size(t)
        F = np.concatenate([[0.0], np.cumsum(0.5 * (inv_h[1:] + inv_h[:-1]) * np.diff(t))])
        n = max(1, int(np.round(F[-1])))
        rings.extend(np.interp(np.arange(1, n + 1) * F[-1] / n, F, t))
        rings[-1] = b
    return np.asarray(rings), size


def _zip(ring_a: np.ndarray, angles_a: np.ndarray, ring_b: np.ndarray, angles_b: np.ndarray) -> list:
    """Triangles joining ring A (larger x) to ring B (smaller x), normals outwards.

    ``ring_*`` are vertex indices, ``angles_*`` their increasing azimuths
    (within one turn). A ring of one vertex is a tip.
    """
    ma, mb = len(ring_a), len(ring_b)
    tris = []
    if ma == 1:
        for j in range(mb):
            tris.append((ring_a[0], ring_b[j], ring_b[(j + 1) % mb]))
        return tris
    if mb == 1:
        for i in range(ma):
            tris.append((ring_a[i], ring_b[0], ring_a[(i + 1) % ma]))
        return tris
    # start B at the vertex closest in angle to A's first vertex
    shift = int(np.argmin(np.abs(np.angle(np.exp(1j * (angles_b - angles_a[0]))))))
    ring_b = np.roll(ring_b, -shift)
    angles_b = np.roll(angles_b, -shift)
    angles_b = angles_a[0] + np.mod(angles_b - angles_a[0] + np.pi, 2 * np.pi) - np.pi
    angles_b = angles_b[0] + np.unwrap(angles_b - angles_b[0])
    next_a = np.append(angles_a[1:], angles_a[0] + 2 * np.pi)
    next_b = np.append(angles_b[1:], angles_b[0] + 2 * np.pi)
    i = j = 0
    while i < ma or j < mb:
        if j >= mb or (i < ma and next_a[i] - angles_a[0] <= next_b[j] - angles_a[0]):
            tris.append((ring_a[i], ring_b[j % mb], ring_a[(i + 1) % ma]))
            i += 1
        else:
            tris.append((ring_a[i % ma], ring_b[j], ring_b[(j + 1) % mb]))
            j += 1
    return tris


def _ring_layout(sensor: SensorDescription, edge_length_m, grading, edge_refinement, max_aspect,
                 azimuthal_refinement, uniform_cylinder):
    """The rings of the mesh (axial positions, radii, vertex counts) before any vertex is made."""
    h_far = default_edge_length_m(sensor) if edge_length_m is None else float(edge_length_m)
    if not (np.isfinite(h_far) and h_far > 0):
        raise ValueError(f"mesh_sensor: edge_length_m must be positive, got {edge_length_m}")
    if not grading > 1.0:
        raise ValueError(f"mesh_sensor: grading must exceed 1, got {grading}")
    if not edge_refinement >= 1.0:
        raise ValueError(f"mesh_sensor: edge_refinement must be >= 1, got {edge_refinement}")
    if not azimuthal_refinement >= 1.0:
        raise ValueError(f"mesh_sensor: azimuthal_refinement must be >= 1, got {azimuthal_refinement}")
    if not max_aspect >= 1.0:
        raise ValueError(f"mesh_sensor: max_aspect must be >= 1, got {max_aspect}")
    if h_far > coarsest_edge_length_m(sensor):
        raise ValueError(
            f"mesh_sensor: edge_length_m {h_far} m is coarser than the sensor's diameter {coarsest_edge_length_m(sensor)} m"
        )
    profile = SensorProfile(sensor)
    s_rings, size = graded_arc_lengths(sensor, h_far, h_far / edge_refinement, grading)
    x_rings, r_rings = profile.point(s_rings)
    r_rings[0] = r_rings[-1] = 0.0

    h_axial = size(s_rings)
    h_phi = np.clip(max_aspect * h_axial, h_far / azimuthal_refinement, h_far)
    counts = np.where(r_rings > 0, np.maximum(3, np.ceil(2 * np.pi * r_rings / h_phi)), 1).astype(int)
    if uniform_cylinder:
        on_cylinder = (s_rings >= profile.s_junction[0] - 1e-12) & (s_rings <= profile.s_junction[1] + 1e-12)
        m_cyl = int(np.ceil(2 * np.pi * sensor.radius_m / (h_far / azimuthal_refinement)))
        counts[on_cylinder] = m_cyl
        counts = np.minimum(counts, m_cyl)
    counts[0] = counts[-1] = 1
    return profile, x_rings, r_rings, counts


MAX_SENSOR_TRIANGLES = 1_000_000
"""Most triangles :func:`mesh_sensor` makes: a dense BEM of that many would need terabytes."""


def estimate_triangles(sensor: SensorDescription, edge_length_m: float | None = None, **options) -> int:
    """Triangles :func:`mesh_sensor` would make, counted from its rings (cheap: nothing is meshed).

    Example
    -------
    >>> from electrosense.meshes.sensor import preset
    >>> estimate_triangles(preset("angels-2"), 0.004) == mesh_sensor(preset("angels-2"), 0.004).n_triangles
    True
    """
    defaults = dict(grading=1.15, edge_refinement=30.0, max_aspect=3.0, azimuthal_refinement=2.5,
                    uniform_cylinder=False)
    defaults.update({k: v for k, v in options.items() if k in defaults})
    counts = _ring_layout(sensor, edge_length_m, **defaults)[3]
    return int(np.sum(counts[:-1] + counts[1:]) - 2)


def mesh_sensor(
    sensor: SensorDescription,
    edge_length_m: float | None = None,
    grading: float = 1.15,
    edge_refinement: float = 30.0,
    max_aspect: float = 3.0,
    azimuthal_refinement: float = 2.5,
    ring_radius: str = "area",
    uniform_cylinder: bool = False,
    max_triangles: int | None = MAX_SENSOR_TRIANGLES,
    **sector_options,
) -> LabelledMesh:
    """Closed, graded, labelled triangle mesh of a sensor in its own frame.

    Parameters
    ----------
    sensor : SensorDescription
        The sensor (cylinder with hemispherical ends and electrodes).
    edge_length_m : float, optional
        Edge length far from electrode edges (m); default
        :func:`default_edge_length_m`.
    grading : float
        Growth ratio of consecutive ring spacings away from an electrode edge (> 1).
    edge_refinement : float
        Far edge length divided by the ring spacing at an electrode edge.
    max_aspect : float
        Azimuthal edge length at most ``max_aspect`` times the local axial spacing...
    azimuthal_refinement : float
        ...but never below ``edge_length_m / azimuthal_refinement``: near the
        electrode edges the solution varies along the axis, hardly around it,
        so the rings there are fine axially and only moderately fine around.
    uniform_cylinder : bool
        Give every ring of the cylinder the count of the electrode edges'
        rings (``2 pi R`` over ``edge_length_m / azimuthal_refinement``). The
        default (False) coarsens the rings away from the edges: 17 % fewer
        triangles on angels-4 for the same conductance error.
    max_triangles : int or None
        Refuse (``ValueError``), before meshing, an ``edge_length_m`` that would
        make more triangles (default :data:`MAX_SENSOR_TRIANGLES`; None: no bound).
    ring_radius : {"area", "perimeter", "inscribed"}
        Where the ring vertices go: on the circle (``"inscribed"``), or further
        out so that each faceted ring encloses the circle's area (``"area"``,
        the default: best capacitance per triangle) or has its perimeter.

    Returns
    -------
    LabelledMesh
        Normals into the water, ``electrode`` per face, region ``"sensor"``.

    Example
    -------
    >>> from electrosense.meshes.sensor import preset
    >>> import numpy as np
    >>> s = preset("angels-2")
    >>> m = mesh_sensor(s, edge_length_m=0.004)
    >>> # a capsule's area is 2 pi r L; the faceted rings enclose the circles' areas, a little more
    >>> bool(abs(m.areas_m2.sum() / (2 * np.pi * s.radius_m * s.length_m) - 1) < 0.01)
    True
    """
    if max_triangles is not None:
        n = estimate_triangles(sensor, edge_length_m, grading=grading, edge_refinement=edge_refinement,
                               max_aspect=max_aspect, azimuthal_refinement=azimuthal_refinement,
                               uniform_cylinder=uniform_cylinder)
        if n > max_triangles:
            raise ValueError(
                f"mesh_sensor: edge_length_m {edge_length_m} m would make about {n:,} triangles on this sensor; "
                f"at most {max_triangles:,} are meshed: choose a larger edge length"
            )
    if sensor.has_sectors:
        from electrosense.meshes.sector_mesh import mesh_sector_sensor

        mesh = mesh_sector_sensor(sensor, edge_length_m, grading, edge_refinement, max_aspect, azimuthal_refinement,
                                  ring_radius, uniform_cylinder, **sector_options)
        if max_triangles is not None and mesh.n_triangles > max_triangles:
            raise ValueError(f"mesh_sensor: edge_length_m {edge_length_m} m makes {mesh.n_triangles:,} triangles on "
                             f"this sensor; at most {max_triangles:,} are meshed: choose a larger edge length")
        return mesh
    if sector_options:
        raise TypeError(f"mesh_sensor: unexpected options {sorted(sector_options)} (sector options need sectors)")
    profile, x_rings, r_rings, counts = _ring_layout(sensor, edge_length_m, grading, edge_refinement, max_aspect,
                                                     azimuthal_refinement, uniform_cylinder)

    vertices, rings, angles = [], [], []
    n_vertices = 0
    offset = 0.0
    for k, (x, r, m) in enumerate(zip(x_rings, r_rings, counts)):
        if m == 1:
            vertices.append([[x, 0.0, 0.0]])
            phi = np.zeros(1)
        else:
            offset = offset + np.pi / m if k > 0 and counts[k - 1] == m else 0.0
            phi = offset + 2 * np.pi * np.arange(m) / m
            rv = r * _ring_radius_factor(m, ring_radius)
            vertices.append(np.column_stack([np.full(m, x), rv * np.cos(phi), rv * np.sin(phi)]))
        rings.append(np.arange(n_vertices, n_vertices + m))
        angles.append(phi)
        n_vertices += m

    faces, labels = [], []
    for k in range(len(rings) - 1):
        tris = _zip(rings[k], angles[k], rings[k + 1], angles[k + 1])
        faces.extend(tris)
        x_mid = 0.5 * (x_rings[k] + x_rings[k + 1])
        label = 0
        for number, e in enumerate(sensor.electrodes, start=1):
            if e.x_min_m <= x_mid <= e.x_max_m:
                label = number
        labels.extend([label] * len(tris))
    return LabelledMesh(
        vertices_m=np.concatenate(vertices),
        faces=np.asarray(faces, dtype=np.int64),
        electrode=np.asarray(labels, dtype=np.int64),
        region=np.zeros(len(faces), dtype=np.int64),
        region_names=("sensor",),
    )
