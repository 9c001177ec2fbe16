"""Mesh of a cylindrical tank's water, with disc and plate electrodes on its boundary.

The water cylinder is one closed, watertight shell with three regions
(``wall``, ``floor``, ``free_surface``), normals OUT OF THE WATER. Disc
electrodes (:class:`electrosense.meshes.surface_electrodes.DiscElectrode`) on the wall, the
floor or the free surface are embedded: their rim is a polygon of mesh nodes
(with the disc's true area) and the mesh is graded towards every rim
(:func:`electrosense.meshes.surface_electrodes.electrode_size_function`). Faces of
electrode k carry the label k.

The wall is meshed in its developed (arc length, z) plane and rolled up; the
floor and the free surface share the wall's rim nodes, so the shell is
conforming. The seam of the developed wall is put where no electrode is.

Example
-------
>>> from electrosense.meshes.cylinder_tank import CylinderTank
>>> from electrosense.meshes.surface_electrodes import DiscElectrode
>>> from electrosense.meshes.cylinder_tank_mesh import mesh_cylinder_tank
>>> t = CylinderTank(0.1, 0.1)
>>> m = mesh_cylinder_tank(t, [DiscElectrode((0.1, 0.0, 0.0), 0.01), DiscElectrode((0.0, 0.0, -0.05), 0.01)],
...                        edge_length_m=0.03)
>>> m.electrodes, m.to_trimesh().is_watertight
((1, 2), True)
"""
from __future__ import annotations

import numpy as np

from electrosense.meshes.cylinder_tank import CYLINDER_TANK_REGIONS, CylinderTank
from electrosense.meshes.labelled_mesh import LabelledMesh, concatenate
from electrosense.meshes.surface_electrodes import (
    DEFAULT_EDGE_FRACTION,
    DEFAULT_ELECTRODE_GRADING,
    DiscElectrode,
    PlateElectrode,
    disc_rim_nodes,
    electrode_size_function,
)
from electrosense.meshes.tank_mesh import _weld, equidistributed_nodes, graded_size_function, mesh_convex_polygon

__all__ = ["mesh_cylinder_tank", "default_far_edge_length_m", "electrode_surface", "disc_problems", "mesh_plane_with_discs"]

def electrode_surface(tank: CylinderTank, electrode: DiscElectrode, index: int) -> str:
    """Which region (``wall``, ``floor``, ``free_surface``) the disc lies on; ``ValueError`` if none or outside."""
    tol = tank.boundary_tolerance_m
    d = tank.distance_to_boundary_m(np.asarray(electrode.centre_m))
    on = [name for name, g in zip(CYLINDER_TANK_REGIONS, d) if abs(g) <= tol]
    label = f"electrode {index}{' (' + electrode.name + ')' if electrode.name else ''}"
    if np.any(d < -tol) or not on:
        raise ValueError(f"{label} at {electrode.centre_m} m is not on the tank's boundary "
                         f"(distances to wall, floor, free surface: {np.round(d, 6).tolist()} m)")
    if len(on) > 1:
        raise ValueError(f"{label} at {electrode.centre_m} m sits on an edge of the tank ({' and '.join(on)})")
    a = electrode.radius_m
    if on[0] == "wall":
        gap = min(electrode.centre_m[2] - tank.floor_z_m, tank.free_surface_z_m - electrode.centre_m[2])
        if gap <= a or a >= 0.5 * np.pi * float(tank.radius_at(electrode.centre_m[2])):
            raise ValueError(f"{label} (radius {a} m) does not fit on the wall: its rim reaches the floor or the "
                             "free surface")
    elif float(tank.radius_at(electrode.centre_m[2])) - np.hypot(*electrode.centre_m[:2]) <= a:
        raise ValueError(f"{label} (radius {a} m) does not fit on the {on[0]}: its rim reaches the wall")
    return on[0]


def disc_problems(tank: CylinderTank, electrodes, first_label: int = 1) -> list[str]:
    """Every reason why these disc electrodes cannot sit on the tank (empty list: they can).

    A disc must lie on one boundary region, its rim clear of the region's
    edges (:func:`electrode_surface`), and clear of every other disc (their
    centres farther apart than the sum of their radii, measured along the
    chord: a lower bound of the distance on the surface).

    >>> from electrosense.meshes.cylinder_tank import CylinderTank
    >>> t = CylinderTank(0.1, 0.2)
    >>> disc_problems(t, [DiscElectrode((0.1, 0.0, 0.0), 0.005), DiscElectrode((0.1, 0.0, 0.008), 0.005)])
    ['electrodes 1 and 2 overlap (centres 0.008 m apart, radii 0.005 and 0.005 m)']
    >>> disc_problems(t, [DiscElectrode((0.1, 0.0, 0.3), 0.005)])[0][:48]
    'electrode 1 at (0.1, 0.0, 0.3) m is not on the t'
    """
    problems, discs = [], []
    for i, e in enumerate(electrodes, start=first_label):
        if not isinstance(e, DiscElectrode):
            continue
        try:
            electrode_surface(tank, e, i)
            discs.append((i, np.asarray(e.centre_m, float), e.radius_m))
        except ValueError as exc:
            problems.append(str(exc))
    for k, (i, c, a) in enumerate(discs):
        for j, c2, a2 in discs[k + 1:]:
            d = float(np.linalg.norm(c - c2))
            if d <= a + a2:
                problems.append(f"electrodes {i} and {j} overlap (centres {d:.3g} m apart, radii {a:.3g} and "
                                f"{a2:.3g} m)")
    return problems


def mesh_plane_with_discs(boundary_uv: np.ndarray, discs_uv: list, size_uv) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Triangulate a convex polygon with embedded discs ``(centre_uv, radius, h_edge, label[, stretch_uv])``.

    ``stretch_uv`` (default (1, 1)): (u, v) lengths in the plane per unit of
    true length at the disc (a developed surface that is not isometric, e.g.
    a tapered wall): the disc is an ellipse in the plane and a circle on the
    surface. A triangle belongs to a disc when all its nodes lie in the disc's
    rim polygon (rim nodes included), so the electrode is exactly the
    polygon, whose area is the disc's. Returns points (N, 2) (the boundary
    first, kept), CCW triangles and a label per triangle (0 outside every disc).
    """
    stretch = np.array([d[4] if len(d) > 4 else (1.0, 1.0) for d in discs_uv], float).reshape(-1, 2)
    centres = np.array([c for c, *_ in discs_uv], float).reshape(-1, 2)
    radii = np.array([d[1] for d in discs_uv], float)
    rims = [c + disc_rim_nodes((0.0, 0.0), a, h) * st for (c, a, h, *_), st in zip(discs_uv, stretch)]
    fixed = np.concatenate([r.reshape(-1, 2) for r in rims]) if rims else np.zeros((0, 2))
    band = np.array([np.ptp(np.linalg.norm((r[:, 0] - c) / st, axis=1)) / 2
                     for r, c, st in zip(rims, centres, stretch)])
    r_eq = np.array([np.linalg.norm((r[0, 0] - c) / st) for r, c, st in zip(rims, centres, stretch)])

    def true_radius(p):          # (N, D) distance from each disc's centre in true length
        return np.linalg.norm((p[:, None] - centres[None]) / stretch[None], axis=2)

    def allowed(p):
        if not len(discs_uv):
            return np.ones(len(p), bool)
        gap = np.abs(true_radius(p) - radii[None]) - band[None]
        return np.all(gap * stretch.min(axis=1)[None] > 0.5 * size_uv(p)[:, None], axis=1)

    points, tri = mesh_convex_polygon(boundary_uv, size_uv, fixed_uv=fixed, allowed_uv=allowed)
    label = np.zeros(len(tri), np.int64)
    if len(discs_uv):
        inside_node = true_radius(points) <= r_eq[None] * (1 + 1e-9)       # (N, D)
        inside = np.all(inside_node[tri], axis=1)                           # (T, D)
        labels = np.array([d[3] for d in discs_uv])
        hit = inside.any(axis=1)
        label[hit] = labels[np.argmax(inside[hit], axis=1)]
    return points, tri, label


def _circle_angles(radius: float, z: float, size, phi0: float) -> np.ndarray:
    """Angles phi0 <= phi < phi0 + 2 pi of nodes along the circle, spaced by the local size."""
    phi = np.linspace(phi0, phi0 + 2 * np.pi, 4001)
    pts = np.stack([radius * np.cos(phi), radius * np.sin(phi), np.full_like(phi, z)], axis=1)
    inv_h = 1.0 / size(pts)
    cum = np.concatenate([[0.0], np.cumsum(0.5 * (inv_h[1:] + inv_h[:-1]) * np.diff(phi) * radius)])
    n = max(8, int(round(cum[-1])))
    return np.interp(np.linspace(0.0, cum[-1], n + 1)[:-1], cum, phi)


def _seam_angle(wall_discs: list[DiscElectrode]) -> float:
    """The middle of the widest angular gap between wall electrodes (0 without any)."""
    if not wall_discs:
        return 0.0
    phi = np.sort(np.mod([np.arctan2(d.centre_m[1], d.centre_m[0]) for d in wall_discs], 2 * np.pi))
    gaps = np.diff(np.r_[phi, phi[0] + 2 * np.pi])
    k = int(np.argmax(gaps))
    return float(phi[k] + 0.5 * gaps[k])


def default_far_edge_length_m(tank: CylinderTank) -> float:
    """The tank mesh's edge far from electrodes and focus (m): a sixth of the smaller of the mean radius and the
    water depth (the wall's facets then lie within R / 290 of the curved wall).

    >>> round(default_far_edge_length_m(CylinderTank(0.3, 0.4, 0.36)), 6)
    0.05
    """
    R = 0.5 * float(tank.radius_at(tank.floor_z_m) + tank.radius_at(tank.free_surface_z_m))
    return min(R, float(tank.water_depth_m)) / 6


def mesh_cylinder_tank(tank: CylinderTank, electrodes=(), edge_length_m: float | None = None, focus_m=None, *,
                       grading: float = 0.5, edge_fraction: float = DEFAULT_EDGE_FRACTION,
                       electrode_grading: float = DEFAULT_ELECTRODE_GRADING, first_label: int = 1,
                       near_ratio: float | None = None, focus_radius_m: float = 0.0,
                       focus_edge_length_m: float | None = None) -> LabelledMesh:
    """Closed, labelled, outward-oriented mesh of a cylindrical tank's water with its electrodes.

    Parameters
    ----------
    tank : CylinderTank
    electrodes : sequence of DiscElectrode / PlateElectrode
        Electrodes on the tank, labelled ``first_label``, ``first_label + 1``... in order.
    edge_length_m : float, optional
        Edge length far from electrodes and focus (default: a sixth of the
        smaller of the radius and the water depth).
    focus_m : (P, 3) array, optional
        Points (a sensor, objects) to grade towards, from ``focus_edge_length_m`` at the point.
    grading, edge_fraction, electrode_grading : float
        Growth per metre away from the focus; rim edge length over the disc
        radius; growth per metre away from a rim.
    near_ratio, focus_radius_m : float, optional
        The edge at most ``near_ratio`` times the distance from a tube of ``focus_radius_m`` around the focus
        (:func:`~electrosense.meshes.tank_mesh.graded_size_function`); default: no such bound.
    focus_edge_length_m : float, optional
        Edge length at the focus (default ``edge_length_m / 3``).
    """
    zf, zt = tank.floor_z_m, tank.free_surface_z_m
    # developed wall: u = R (phi - phi0) with R the radius at mid-water; on a tapered wall the map to the
    # surface stretches u by r(z) / R and z by the slant factor (discs are meshed as ellipses there)
    R = 0.5 * float(tank.radius_at(zf) + tank.radius_at(zt))
    slant = float(np.hypot(1.0, tank.wall_slope))
    h_far = default_far_edge_length_m(tank) if edge_length_m is None else float(edge_length_m)
    if not h_far > 0:
        raise ValueError(f"mesh_cylinder_tank: edge_length_m must be positive, got {edge_length_m}")
    h_focus = h_far / 3 if focus_edge_length_m is None else min(float(focus_edge_length_m), h_far)
    if not h_focus > 0:
        raise ValueError(f"mesh_cylinder_tank: focus_edge_length_m must be positive, got {focus_edge_length_m}")
    base = None if focus_m is None else graded_size_function(h_focus, focus_m, grading, h_far,
                                                             near_ratio=near_ratio, focus_radius_m=focus_radius_m)
    discs = [e for e in electrodes if isinstance(e, DiscElectrode)]
    size = electrode_size_function(discs, h_far, edge_fraction, electrode_grading, base)
    problems = disc_problems(tank, electrodes, first_label)
    if problems:
        raise ValueError("; ".join(problems))
    where = {}
    for i, e in enumerate(electrodes, start=first_label):
        if isinstance(e, DiscElectrode):
            where[i] = electrode_surface(tank, e, i)
        elif isinstance(e, PlateElectrode):
            if e.region not in CYLINDER_TANK_REGIONS:
                raise ValueError(f"electrode {i}: plate on region {e.region!r}; the cylindrical tank has "
                                 f"{', '.join(CYLINDER_TANK_REGIONS)}")
        else:
            raise TypeError(f"electrode {i}: {type(e).__name__} is not a tank electrode")
    phi0 = _seam_angle([e for i, e in enumerate(electrodes, start=first_label) if where.get(i) == "wall"])

    def rim(phi, z):
        r = tank.radius_at(z)
        return np.stack([r * np.cos(phi), r * np.sin(phi), np.full_like(phi, z)], axis=1)

    phi_floor = _circle_angles(float(tank.radius_at(zf)), zf, size, phi0)
    phi_top = _circle_angles(float(tank.radius_at(zt)), zt, size, phi0)
    seam = equidistributed_nodes(rim(np.array([phi0]), zf)[0], rim(np.array([phi0]), zt)[0], size)[:, 2]
    L = 2 * np.pi * R
    # developed wall: (s, z), s = R (phi - phi0); CCW = outward normal
    s_b, s_t = R * (phi_floor - phi0), R * (phi_top - phi0)
    # bottom s = 0 -> L, right side (s = L) up, top s = L -> 0, left side (s = 0) down; corners once
    bnd_uv = np.concatenate([np.stack([s_b, np.full_like(s_b, zf)], 1), np.stack([np.full(len(seam) - 1, L), seam[:-1]], 1),
                             np.stack([np.r_[L, s_t[::-1][:-1]], np.full(len(s_t), zt)], 1),
                             np.stack([np.zeros(len(seam) - 1), seam[::-1][:-1]], 1)])
    def wall_3d(uv):
        phi, r = phi0 + uv[:, 0] / R, tank.radius_at(uv[:, 1])
        return np.stack([r * np.cos(phi), r * np.sin(phi), uv[:, 1]], axis=1)

    seam_3d = wall_3d(np.c_[np.zeros(len(seam)), seam])          # both sides of the seam: bit-identical nodes
    bnd_3d = np.concatenate([rim(phi_floor, zf), seam_3d[:-1], rim(np.r_[phi0, phi_top[::-1][:-1]], zt),
                             seam_3d[::-1][:-1]])

    h_edge = {i: edge_fraction * e.radius_m for i, e in enumerate(electrodes, start=first_label)
              if isinstance(e, DiscElectrode)}
    wall_discs = []
    for i, e in enumerate(electrodes, start=first_label):
        if where.get(i) == "wall":
            phi = np.mod(np.arctan2(e.centre_m[1], e.centre_m[0]) - phi0, 2 * np.pi)
            stretch = (R / float(tank.radius_at(e.centre_m[2])), 1.0 / slant)
            wall_discs.append(((R * phi, e.centre_m[2]), e.radius_m, h_edge[i], i, stretch))
    pts, tri, lab = mesh_plane_with_discs(bnd_uv, wall_discs, lambda q: size(wall_3d(q)))
    verts = np.concatenate([bnd_3d, wall_3d(pts[len(bnd_3d):])])
    parts = [LabelledMesh(verts, tri, lab, np.zeros(len(tri), np.int64), CYLINDER_TANK_REGIONS)]

    for region, z, phis, flip in ((1, zf, phi_floor, True), (2, zt, phi_top, False)):
        name = CYLINDER_TANK_REGIONS[region]
        ring = rim(phis, z)
        ds = [((e.centre_m[0], e.centre_m[1]), e.radius_m, h_edge[i], i)
              for i, e in enumerate(electrodes, start=first_label) if where.get(i) == name]
        pts, tri, lab = mesh_plane_with_discs(ring[:, :2], ds, lambda q, z=z: size(np.c_[q, np.full(len(q), z)]))
        verts = np.concatenate([ring, np.c_[pts[len(ring):], np.full(len(pts) - len(ring), z)]])
        if flip:
            tri = tri[:, ::-1]
        parts.append(LabelledMesh(verts, tri, lab, np.full(len(tri), region), CYLINDER_TANK_REGIONS))
    joined = concatenate(parts)
    electrode = joined.electrode.copy()
    for i, e in enumerate(electrodes, start=first_label):
        if isinstance(e, PlateElectrode):
            electrode[joined.region == CYLINDER_TANK_REGIONS.index(e.region)] = i
    vertices, faces = _weld(joined.vertices_m, joined.faces)
    return LabelledMesh(vertices, faces, electrode, joined.region, CYLINDER_TANK_REGIONS)
