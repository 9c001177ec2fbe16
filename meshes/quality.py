"""Mesh quality, and refusing meshes that a boundary-element solver cannot use.

A collocation BEM needs every surface to be closed (an open edge leaks
current), two-manifold, consistently wound with the normals out of each
enclosed solid, and free of degenerate or needle triangles (their
quadrature and their collocation points are meaningless).

* :func:`mesh_quality` measures: minimum angle, aspect ratio (1 for an
  equilateral triangle: longest edge times perimeter over 4 sqrt(3) area),
  edge lengths, degenerate faces, open and non-manifold edges, shells and
  their orientation.
* :func:`check_mesh` raises :class:`MeshError` (a ``ValueError``) naming
  each problem and where it is (triangle numbers, coordinates, region).

Example
-------
>>> from electrosense.meshes import preset
>>> from electrosense.meshes.sensor_mesh import mesh_sensor
>>> from electrosense.meshes.quality import check_mesh
>>> q = check_mesh(mesh_sensor(preset("angels-2")))
>>> q.is_watertight, q.is_outward
(True, True)
"""
from __future__ import annotations

from dataclasses import asdict, dataclass

import numpy as np

from electrosense.meshes.labelled_mesh import LabelledMesh

__all__ = ["MeshQuality", "MeshError", "mesh_quality", "check_mesh", "triangle_angles_deg", "aspect_ratios",
           "overlapping_shells"]


def triangle_angles_deg(mesh: LabelledMesh) -> np.ndarray:
    """(F, 3) interior angles of every triangle (degrees); NaN-free (0 for degenerate corners)."""
    t = mesh.triangles_m
    angles = np.empty((mesh.n_triangles, 3))
    for i in range(3):
        u = t[:, (i + 1) % 3] - t[:, i]
        v = t[:, (i + 2) % 3] - t[:, i]
        nu, nv = np.linalg.norm(u, axis=1), np.linalg.norm(v, axis=1)
        cos = np.divide(np.einsum("ij,ij->i", u, v), nu * nv, out=np.ones(len(t)), where=(nu * nv) > 0)
        angles[:, i] = np.degrees(np.arccos(np.clip(cos, -1.0, 1.0)))
    return angles


def aspect_ratios(mesh: LabelledMesh) -> np.ndarray:
    """(F,) longest edge x perimeter / (4 sqrt(3) area): 1 for equilateral, inf for degenerate."""
    edges = mesh.edge_lengths_m
    area = mesh.areas_m2
    num = edges.max(axis=1) * edges.sum(axis=1)
    return np.divide(num, 4 * np.sqrt(3) * area, out=np.full(len(area), np.inf), where=area > 0)


@dataclass(frozen=True)
class MeshQuality:
    """Figures of a mesh's quality (see :func:`mesh_quality`)."""

    n_triangles: int
    n_vertices: int
    min_angle_deg: float
    max_aspect_ratio: float
    min_edge_m: float
    mean_edge_m: float
    max_edge_m: float
    n_degenerate: int
    n_open_edges: int
    n_nonmanifold_edges: int
    n_inconsistent_edges: int
    n_shells: int
    n_inward_shells: int
    total_area_m2: float

    @property
    def is_watertight(self) -> bool:
        return self.n_open_edges == 0 and self.n_nonmanifold_edges == 0

    @property
    def is_consistently_oriented(self) -> bool:
        return self.n_inconsistent_edges == 0

    @property
    def is_outward(self) -> bool:
        return self.n_inward_shells == 0

    def as_dict(self) -> dict:
        d = asdict(self)
        d.update(is_watertight=self.is_watertight, is_consistently_oriented=self.is_consistently_oriented,
                 is_outward=self.is_outward)
        return d

    def __str__(self) -> str:
        return (
            f"{self.n_triangles} triangles, {self.n_vertices} vertices, {self.n_shells} closed shell(s)\n"
            f"  edge length   {self.min_edge_m * 1e3:.3g} .. {self.max_edge_m * 1e3:.3g} mm (mean {self.mean_edge_m * 1e3:.3g} mm)\n"
            f"  min angle     {self.min_angle_deg:.1f} deg\n"
            f"  max aspect    {self.max_aspect_ratio:.2f} (1 = equilateral)\n"
            f"  degenerate    {self.n_degenerate}\n"
            f"  watertight    {'yes' if self.is_watertight else f'no ({self.n_open_edges} open, {self.n_nonmanifold_edges} non-manifold edges)'}\n"
            f"  oriented      {'yes, normals out of every solid' if self.is_consistently_oriented and self.is_outward else 'no'}"
        )


def _edge_table(faces: np.ndarray):
    """Directed half-edges, their undirected keys, and how many faces share each undirected edge."""
    directed = np.concatenate([faces[:, [0, 1]], faces[:, [1, 2]], faces[:, [2, 0]]])
    face_of = np.tile(np.arange(len(faces)), 3)
    key = np.sort(directed, axis=1).astype(np.int64)
    n = int(key.max()) + 1 if len(key) else 1
    _, inverse, counts = np.unique(key[:, 0] * n + key[:, 1], return_inverse=True, return_counts=True)
    return directed, key, face_of, inverse.ravel(), counts


def _shells(n_faces: int, key_inverse: np.ndarray, face_of: np.ndarray) -> np.ndarray:
    """(F,) connected-component number of each face (faces joined through shared edges)."""
    from scipy.sparse import coo_matrix
    from scipy.sparse.csgraph import connected_components

    n_edges = key_inverse.max() + 1 if len(key_inverse) else 0
    incidence = coo_matrix((np.ones(len(face_of)), (face_of, key_inverse)), shape=(n_faces, n_edges)).tocsr()
    _, labels = connected_components(incidence @ incidence.T, directed=False)
    return labels


def _signed_volumes(mesh: LabelledMesh, shell: np.ndarray) -> np.ndarray:
    t = mesh.triangles_m
    t = t - t.reshape(-1, 3).mean(axis=0)  # better conditioned
    v = np.einsum("ij,ij->i", t[:, 0], np.cross(t[:, 1], t[:, 2])) / 6.0
    return np.bincount(shell, weights=v)


def mesh_quality(mesh: LabelledMesh, degenerate_area_fraction: float = 1e-10) -> MeshQuality:
    """Measure a mesh (see :class:`MeshQuality`).

    A triangle is degenerate when its area is below ``degenerate_area_fraction``
    times its longest edge squared (collinear or repeated corners).
    """
    if mesh.n_triangles == 0:
        raise ValueError("mesh_quality: the mesh has no triangles")
    edges = mesh.edge_lengths_m
    degenerate = mesh.areas_m2 <= degenerate_area_fraction * edges.max(axis=1) ** 2
    angles = triangle_angles_deg(mesh)
    directed, key, face_of, inverse, counts = _edge_table(mesh.faces)
    # consistent winding: an interior edge is walked once in each direction
    forward = directed[:, 0] < directed[:, 1]
    n_forward = np.bincount(inverse, weights=forward, minlength=len(counts))
    inconsistent = (counts == 2) & (n_forward != 1)
    shell = _shells(mesh.n_triangles, inverse, face_of)
    volumes = _signed_volumes(mesh, shell)
    return MeshQuality(
        n_triangles=mesh.n_triangles,
        n_vertices=int(len(np.unique(mesh.faces))),
        min_angle_deg=float(angles.min()),
        max_aspect_ratio=float(aspect_ratios(mesh).max()),
        min_edge_m=float(edges.min()),
        mean_edge_m=float(edges.mean()),
        max_edge_m=float(edges.max()),
        n_degenerate=int(degenerate.sum()),
        n_open_edges=int(np.sum(counts == 1)),
        n_nonmanifold_edges=int(np.sum(counts > 2)),
        n_inconsistent_edges=int(inconsistent.sum()),
        n_shells=int(shell.max() + 1),
        n_inward_shells=int(np.sum(volumes <= 0)),
        total_area_m2=float(mesh.areas_m2.sum()),
    )


class MeshError(ValueError):
    """A mesh that a BEM cannot use; ``problems`` lists every reason."""

    def __init__(self, problems: list[str], name: str = "mesh"):
        self.problems = list(problems)
        self.name = name
        super().__init__(f"{name} refused: " + "; ".join(self.problems))

    def __reduce__(self):   # rebuilt from its problems in another process (a map's workers), not from its message
        return type(self), (self.problems, self.name)


def _where(mesh: LabelledMesh, faces: np.ndarray, limit: int = 3) -> str:
    """'triangle 12 at (x, y, z) m in region sensor, ...' for the first few faces."""
    faces = np.asarray(faces)[:limit]
    c = mesh.centroids_m
    parts = [
        f"triangle {f} at ({c[f, 0]:.4g}, {c[f, 1]:.4g}, {c[f, 2]:.4g}) m in region {mesh.region_names[mesh.region[f]]!r}"
        for f in faces
    ]
    return ", ".join(parts)


def check_mesh(mesh: LabelledMesh, min_angle_deg: float = 5.0, max_aspect_ratio: float = 20.0,
               name: str = "mesh") -> MeshQuality:
    """Return the mesh's quality, or raise :class:`MeshError` naming what a BEM cannot use and where.

    Refused: degenerate triangles, open or non-manifold edges, inconsistent
    winding, shells whose normals point into the solid they enclose,
    triangles with an angle below ``min_angle_deg`` or an aspect ratio above
    ``max_aspect_ratio``.
    """
    q = mesh_quality(mesh)
    problems = []
    area = mesh.areas_m2
    edges = mesh.edge_lengths_m
    degenerate = np.flatnonzero(area <= 1e-10 * edges.max(axis=1) ** 2)
    if len(degenerate):
        problems.append(f"{len(degenerate)} degenerate triangle(s) (zero area): {_where(mesh, degenerate)}")
    directed, key, face_of, inverse, counts = _edge_table(mesh.faces)
    for label, bad in (("open", counts == 1), ("non-manifold (shared by 3 or more triangles)", counts > 2)):
        if bad.any():
            at = face_of[np.isin(inverse, np.flatnonzero(bad))]
            problems.append(f"{int(bad.sum())} {label} edge(s), the surface is not closed there: {_where(mesh, np.unique(at))}")
    if q.n_inconsistent_edges:
        forward = directed[:, 0] < directed[:, 1]
        n_forward = np.bincount(inverse, weights=forward, minlength=len(counts))
        bad = np.flatnonzero((counts == 2) & (n_forward != 1))
        at = np.unique(face_of[np.isin(inverse, bad)])
        problems.append(f"inconsistent winding across {q.n_inconsistent_edges} edge(s): {_where(mesh, at)}")
    elif q.n_inward_shells:
        shell = _shells(mesh.n_triangles, inverse, face_of)
        volumes = _signed_volumes(mesh, shell)
        for s in np.flatnonzero(volumes <= 0):
            first = np.flatnonzero(shell == s)
            regions = sorted({mesh.region_names[r] for r in mesh.region[first]})
            problems.append(f"the shell of region(s) {', '.join(regions)} has its normals pointing into the solid "
                            f"it encloses (they must point out): {_where(mesh, first, 1)}")
    angles = triangle_angles_deg(mesh).min(axis=1)
    needles = np.flatnonzero((angles < min_angle_deg) & (area > 1e-10 * edges.max(axis=1) ** 2))
    if len(needles):
        worst = needles[np.argsort(angles[needles])]
        problems.append(f"{len(needles)} triangle(s) with an angle below {min_angle_deg:g} deg "
                        f"(smallest {angles[worst[0]]:.2g} deg): {_where(mesh, worst)}")
    ratios = aspect_ratios(mesh)
    stretched = np.flatnonzero(np.isfinite(ratios) & (ratios > max_aspect_ratio))
    if len(stretched):
        worst = stretched[np.argsort(-ratios[stretched])]
        problems.append(f"{len(stretched)} triangle(s) with an aspect ratio above {max_aspect_ratio:g} "
                        f"(largest {ratios[worst[0]]:.3g}): {_where(mesh, worst)}")
    if problems:
        raise MeshError(problems, name)
    return q


def _winding_numbers(points: np.ndarray, triangles: np.ndarray, block: int = 256) -> np.ndarray:
    """(P,) winding number of a closed triangle surface around each point (1 inside, 0 outside).

    The solid angle of each triangle seen from the point (Van Oosterom and
    Strackee), summed and divided by 4 pi; blocks of points keep memory small.
    """
    out = np.empty(len(points))
    for a in range(0, len(points), block):
        r = triangles[None, :, :, :] - points[a:a + block, None, None, :]  # (p, F, 3, 3)
        n = np.linalg.norm(r, axis=-1)
        det = np.einsum("pfi,pfi->pf", r[:, :, 0], np.cross(r[:, :, 1], r[:, :, 2]))
        dots = (n[:, :, 0] * n[:, :, 1] * n[:, :, 2]
                + np.einsum("pfi,pfi->pf", r[:, :, 0], r[:, :, 1]) * n[:, :, 2]
                + np.einsum("pfi,pfi->pf", r[:, :, 1], r[:, :, 2]) * n[:, :, 0]
                + np.einsum("pfi,pfi->pf", r[:, :, 2], r[:, :, 0]) * n[:, :, 1])
        out[a:a + block] = 2 * np.arctan2(det, dots).sum(axis=1) / (4 * np.pi)
    return out


def overlapping_shells(mesh: LabelledMesh) -> list[tuple[int, int, int]]:
    """Pairs of closed shells of which one has vertices inside the other: ``[(a, b, n_inside), ...]``.

    Shells are numbered as connected components of the faces. ``b``'s
    vertices inside shell ``a``: the two solids intersect, or ``b`` lies in
    ``a``. A sensor's or an object's solids must be apart: water between them.

    Example
    -------
    >>> import trimesh
    >>> from electrosense.meshes.labelled_mesh import LabelledMesh
    >>> a, b = trimesh.creation.icosphere(2, 0.01), trimesh.creation.icosphere(2, 0.01)
    >>> both = trimesh.util.concatenate([a, b.apply_translation([0.015, 0, 0])])
    >>> m = LabelledMesh(both.vertices, both.faces, np.zeros(len(both.faces), dtype=int))
    >>> [(i, j) for i, j, _ in overlapping_shells(m)]
    [(0, 1), (1, 0)]
    """
    _, _, face_of, inverse, _ = _edge_table(mesh.faces)
    shell = _shells(mesh.n_triangles, inverse, face_of)
    tris = mesh.triangles_m
    found = []
    n_shells = int(shell.max()) + 1 if len(shell) else 0
    for a in range(n_shells):
        faces_a = np.flatnonzero(shell == a)
        lo, hi = tris[faces_a].reshape(-1, 3).min(axis=0), tris[faces_a].reshape(-1, 3).max(axis=0)
        for b in range(n_shells):
            if a == b:
                continue
            verts_b = np.unique(mesh.faces[shell == b])
            points = mesh.vertices_m[verts_b]
            near = points[np.all((points >= lo) & (points <= hi), axis=1)]  # only those in a's bounding box
            if len(near) == 0:
                continue
            inside = int(np.sum(np.abs(_winding_numbers(near, tris[faces_a])) > 0.5))
            if inside:
                found.append((a, b, inside))
    return found
