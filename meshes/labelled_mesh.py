"""Labelled triangle meshes: the one surface type that every package shares.

A :class:`LabelledMesh` is a triangle soup with two integer labels per face:

* ``electrode``: 0 on insulating faces, ``k`` on the faces of electrode ``k``
  (1-based, head to tail, see :mod:`electrosense.meshes.sensor`);
* ``region``: an index into ``region_names`` that says which part of a scene
  the face belongs to (``"sensor"``, ``"wall_x-"``, ..., ``"free_surface"``,
  ``"object_1"``).

Orientation convention: faces are wound counter-clockwise seen from the side
the normal points to, and the normals point OUT OF THE ENCLOSED SOLID: for a
sensor or an object, into the water; for the tank's water box, out of the
water.

Example
-------
>>> import numpy as np
>>> from electrosense.meshes.labelled_mesh import LabelledMesh
>>> tet = LabelledMesh(
...     vertices_m=np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0], [0, 0, 1]], float),
...     faces=np.array([[0, 2, 1], [0, 1, 3], [0, 3, 2], [1, 2, 3]]),
...     electrode=np.array([0, 0, 0, 1]),
...     region=np.zeros(4, int),
...     region_names=("sensor",),
... )
>>> round(float(tet.areas_m2.sum()), 6), tet.n_triangles
(2.366025, 4)
"""
from __future__ import annotations

from dataclasses import dataclass
from typing import Iterable, Sequence

import numpy as np

__all__ = ["LabelledMesh", "concatenate"]


@dataclass
class LabelledMesh:
    """A triangle mesh with an electrode label and a region label per face.

    Parameters
    ----------
    vertices_m : (V, 3) float array
        Vertex coordinates (m).
    faces : (F, 3) int array
        Vertex indices of each triangle, wound so that the right-hand normal
        points out of the enclosed solid.
    electrode : (F,) int array
        0 for insulating faces, k for faces of electrode k.
    region : (F,) int array
        Index into ``region_names`` for each face.
    region_names : tuple of str
        Names of the regions (``"sensor"``, ``"wall_x-"``, ``"object_1"``...).
    """

    vertices_m: np.ndarray
    faces: np.ndarray
    electrode: np.ndarray = None
    region: np.ndarray = None
    region_names: tuple[str, ...] = ("surface",)

    def __post_init__(self):
        self.vertices_m = np.ascontiguousarray(self.vertices_m, dtype=float).reshape(-1, 3)
        self.faces = np.ascontiguousarray(self.faces, dtype=np.int64).reshape(-1, 3)
        n_faces = len(self.faces)
        self.electrode = (
            np.zeros(n_faces, np.int64) if self.electrode is None else np.asarray(self.electrode, dtype=np.int64).ravel()
        )
        self.region = np.zeros(n_faces, np.int64) if self.region is None else np.asarray(self.region, dtype=np.int64).ravel()
        self.region_names = tuple(str(n) for n in self.region_names)
        if not np.all(np.isfinite(self.vertices_m)):
            raise ValueError("LabelledMesh: vertices_m contain non-finite coordinates")
        if n_faces and (self.faces.min() < 0 or self.faces.max() >= len(self.vertices_m)):
            raise ValueError(
                f"LabelledMesh: faces index vertices outside 0..{len(self.vertices_m) - 1} "
                f"(found {self.faces.min()}..{self.faces.max()})"
            )
        for name, labels in (("electrode", self.electrode), ("region", self.region)):
            if labels.shape != (n_faces,):
                raise ValueError(f"LabelledMesh: {name} has {labels.size} labels for {n_faces} faces")
        if n_faces and self.electrode.min() < 0:
            raise ValueError("LabelledMesh: electrode labels must be >= 0 (0 insulating, k electrode k)")
        if n_faces and (self.region.min() < 0 or self.region.max() >= len(self.region_names)):
            raise ValueError(
                f"LabelledMesh: region labels must index region_names (0..{len(self.region_names) - 1}), "
                f"found {self.region.min()}..{self.region.max()}"
            )

    # ------------------------------------------------------------------ geometry
    @property
    def n_triangles(self) -> int:
        return int(len(self.faces))

    @property
    def n_vertices(self) -> int:
        return int(len(self.vertices_m))

    @property
    def triangles_m(self) -> np.ndarray:
        """(F, 3, 3) corner coordinates of every triangle (m)."""
        return self.vertices_m[self.faces]

    @property
    def centroids_m(self) -> np.ndarray:
        """(F, 3) triangle centroids (m)."""
        return self.triangles_m.mean(axis=1)

    @property
    def _cross(self) -> np.ndarray:
        t = self.triangles_m
        return np.cross(t[:, 1] - t[:, 0], t[:, 2] - t[:, 0])

    @property
    def areas_m2(self) -> np.ndarray:
        """(F,) triangle areas (m^2)."""
        return 0.5 * np.linalg.norm(self._cross, axis=1)

    @property
    def normals(self) -> np.ndarray:
        """(F, 3) unit normals, out of the enclosed solid (zero for degenerate faces)."""
        c = self._cross
        norm = np.linalg.norm(c, axis=1, keepdims=True)
        return np.divide(c, norm, out=np.zeros_like(c), where=norm > 0)

    @property
    def edge_lengths_m(self) -> np.ndarray:
        """(F, 3) lengths of the edges v0-v1, v1-v2, v2-v0 of every triangle (m)."""
        t = self.triangles_m
        return np.linalg.norm(t[:, [1, 2, 0]] - t, axis=2)

    @property
    def electrodes(self) -> tuple[int, ...]:
        """Electrode numbers present on the mesh (sorted, 0 excluded)."""
        return tuple(int(k) for k in np.unique(self.electrode) if k > 0)

    @property
    def n_electrodes(self) -> int:
        """Largest electrode number on the mesh (0 when it has none)."""
        return int(self.electrode.max()) if self.n_triangles else 0

    def electrode_areas_m2(self) -> np.ndarray:
        """(n_electrodes,) total area of electrodes 1..n (m^2)."""
        return np.bincount(self.electrode, weights=self.areas_m2, minlength=self.n_electrodes + 1)[1:]

    def region_index(self, name: str) -> int:
        """Index of the region called ``name``; ``KeyError`` listing the known names otherwise."""
        try:
            return self.region_names.index(name)
        except ValueError:
            raise KeyError(f"no region {name!r} in this mesh; regions: {', '.join(self.region_names)}") from None

    def region_mask(self, name: str) -> np.ndarray:
        """(F,) boolean mask of the faces of region ``name``."""
        return self.region == self.region_index(name)

    # ------------------------------------------------------------ derived meshes
    def select(self, mask: np.ndarray) -> "LabelledMesh":
        """The sub-mesh of the faces where ``mask`` is true (unused vertices dropped)."""
        mask = np.asarray(mask)
        faces = self.faces[mask]
        used, inverse = np.unique(faces, return_inverse=True)
        return LabelledMesh(
            self.vertices_m[used], inverse.reshape(-1, 3), self.electrode[mask], self.region[mask], self.region_names
        )

    def region_mesh(self, name: str) -> "LabelledMesh":
        """The faces of one region as their own mesh."""
        return self.select(self.region_mask(name))

    def transformed(self, pose) -> "LabelledMesh":
        """A new mesh moved rigidly from the sensor frame to the tank frame by ``pose``.

        ``pose`` is a :class:`electrosense.meshes.pose.Pose` or anything with a ``to_tank``
        method; a rigid motion keeps the winding and so the outward normals.
        """
        return LabelledMesh(
            pose.to_tank(self.vertices_m), self.faces.copy(), self.electrode.copy(), self.region.copy(), self.region_names
        )

    def flipped(self) -> "LabelledMesh":
        """The same surface with every face's winding (and normal) reversed."""
        return LabelledMesh(self.vertices_m.copy(), self.faces[:, ::-1].copy(), self.electrode.copy(),
                            self.region.copy(), self.region_names)

    def with_region_names(self, region_names: Sequence[str]) -> "LabelledMesh":
        """The same mesh with its regions renamed (same number of names)."""
        if len(region_names) != len(self.region_names):
            raise ValueError(f"expected {len(self.region_names)} region names, got {len(region_names)}")
        return LabelledMesh(self.vertices_m, self.faces, self.electrode, self.region, tuple(region_names))

    def to_trimesh(self):
        """A :class:`trimesh.Trimesh` of the same vertices and faces (labels in ``face_attributes``).

        Nothing is merged or reordered (``process=False``), so face ``i`` of
        the trimesh is face ``i`` here.
        """
        import trimesh

        return trimesh.Trimesh(
            vertices=self.vertices_m,
            faces=self.faces,
            face_attributes={"electrode": self.electrode, "region": self.region},
            process=False,
            validate=False,
        )

    @classmethod
    def from_trimesh(cls, tm, electrode=None, region=None, region_names=("surface",)) -> "LabelledMesh":
        """Wrap a :class:`trimesh.Trimesh`; labels default to its ``face_attributes`` or 0."""
        attrs = getattr(tm, "face_attributes", {}) or {}
        electrode = attrs.get("electrode") if electrode is None else electrode
        region = attrs.get("region") if region is None else region
        return cls(np.asarray(tm.vertices), np.asarray(tm.faces), electrode, region, tuple(region_names))

    def __repr__(self) -> str:
        return (
            f"LabelledMesh({self.n_triangles} triangles, {self.n_vertices} vertices, "
            f"electrodes {list(self.electrodes)}, regions {list(self.region_names)})"
        )


def concatenate(meshes: Iterable[LabelledMesh]) -> LabelledMesh:
    """Join meshes into one; regions with the same name are merged.

    Vertices are not welded: parts that do not touch stay separate shells.
    The electrode labels are kept as they are.

    Example
    -------
    >>> import numpy as np
    >>> a = LabelledMesh(np.eye(3), [[0, 1, 2]], [1], [0], ("sensor",))
    >>> b = LabelledMesh(np.eye(3) + 1, [[0, 1, 2]], [0], [0], ("floor",))
    >>> c = concatenate([a, b, a])
    >>> c.region_names, c.region.tolist(), c.faces.tolist()[2]
    (('sensor', 'floor'), [0, 1, 0], [6, 7, 8])
    """
    meshes = list(meshes)
    if not meshes:
        raise ValueError("concatenate: no meshes given")
    names: list[str] = []
    for m in meshes:
        names += [n for n in m.region_names if n not in names]
    vertices, faces, electrode, region = [], [], [], []
    offset = 0
    for m in meshes:
        remap = np.array([names.index(n) for n in m.region_names], dtype=np.int64)
        vertices.append(m.vertices_m)
        faces.append(m.faces + offset)
        electrode.append(m.electrode)
        region.append(remap[m.region])
        offset += m.n_vertices
    return LabelledMesh(
        np.concatenate(vertices), np.concatenate(faces), np.concatenate(electrode), np.concatenate(region), tuple(names)
    )
