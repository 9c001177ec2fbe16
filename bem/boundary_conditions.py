"""The water's boundary, with the boundary condition of every triangle.

The BEM works on the surfaces that bound the water, with every triangle
wound so that its normal points OUT OF THE WATER (into the sensor, into an
object, out of the tank). :class:`WaterBoundary` holds those triangles and
what each one is:

* ``electrode[f] = k > 0``: a face of electrode ``k`` (potential ``V_k``
  imposed, behind an optional contact impedance);
* ``conductor[f] = c >= 0``: a face of the ``c``-th perfectly conducting
  object (a floating equipotential carrying no net current);
* otherwise insulating (sensor body, tank walls, floor, free surface,
  insulating objects): zero normal current.

``LabelledMesh`` normals point out of the enclosed solid: for the sensor and
the objects that is into the water, so their faces are reversed here; the
tank's water box already has its normals out of the water.

Example
-------
>>> from electrosense.meshes.sensor import preset
>>> from electrosense.meshes.sensor_mesh import mesh_sensor
>>> wb = WaterBoundary.from_meshes(mesh_sensor(preset("angels-2")))
>>> wb.n_electrodes, wb.unbounded
(2, True)
"""
from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from electrosense.meshes.labelled_mesh import LabelledMesh, concatenate

__all__ = ["WaterBoundary", "BoundaryError", "check_electrodes"]


class BoundaryError(ValueError):
    """A boundary the BEM cannot solve on (names the part and what is wrong)."""


def _touching_electrodes(mesh: LabelledMesh) -> list[tuple[int, int]]:
    """Pairs of different electrodes that share a vertex."""
    pairs = set()
    on = mesh.electrode > 0
    if not on.any():
        return []
    faces, labels = mesh.faces[on], mesh.electrode[on]
    vertex = faces.ravel()
    label = np.repeat(labels, 3)
    order = np.lexsort((label, vertex))
    v, lab = vertex[order], label[order]
    same_vertex = v[1:] == v[:-1]
    differ = lab[1:] != lab[:-1]
    for a, b in zip(lab[:-1][same_vertex & differ], lab[1:][same_vertex & differ]):
        pairs.add((int(min(a, b)), int(max(a, b))))
    return sorted(pairs)


def check_electrodes(mesh: LabelledMesh, emitter: int | None = None, name: str = "sensor",
                     allow_touching: bool = False) -> int:
    """Number of electrodes of a sensor mesh; ``BoundaryError`` if they are unusable.

    Refused: fewer than 2 electrodes, numbers with no faces (1..n must all be
    present), electrodes that touch each other (unless ``allow_touching``: the
    sectors of a split electrode with no gap), an emitter that is not one of
    them.
    """
    present = mesh.electrodes
    if len(present) == 0:
        raise BoundaryError(f"{name}: the mesh has no electrode faces (cell array 'electrode' is 0 everywhere): "
                            "there is no emitter and no receiver")
    n = max(present)
    missing = sorted(set(range(1, n + 1)) - set(present))
    if missing:
        raise BoundaryError(f"{name}: electrode(s) {missing} have no faces (electrodes must be numbered 1..{n})")
    if n < 2:
        raise BoundaryError(f"{name}: only one electrode; a sensor needs an emitter and at least one receiver")
    touching = [] if allow_touching else _touching_electrodes(mesh)
    if touching:
        text = ", ".join(f"{a} and {b}" for a, b in touching)
        raise BoundaryError(f"{name}: electrodes {text} touch (share mesh vertices); they need an insulating gap")
    if emitter is not None and not 1 <= emitter <= n:
        raise BoundaryError(f"{name}: emitter {emitter} is not an electrode (1..{n})")
    return n


@dataclass
class WaterBoundary:
    """Triangles bounding the water (normals out of the water) and their boundary conditions.

    Attributes
    ----------
    triangles_m : (F, 3, 3)
        Corners, wound with the normal out of the water.
    electrode : (F,) int
        Electrode number (0: not an electrode).
    conductor : (F,) int
        Index of the floating conducting object (-1: none).
    part : (F,) int
        Index into ``part_names`` ("sensor", "tank", "object_1", ...).
    part_names : tuple of str
    unbounded : bool
        True when the water extends to infinity (no tank).
    mesh : LabelledMesh
        The same faces with their original (solid-outward) orientation, for output.
    n_sensor : int
        The first ``n_sensor`` faces are the sensor's.
    """

    triangles_m: np.ndarray
    electrode: np.ndarray
    conductor: np.ndarray
    part: np.ndarray
    part_names: tuple
    unbounded: bool
    mesh: LabelledMesh
    n_sensor: int
    n_conductors: int = 0
    conductor_names: tuple = field(default_factory=tuple)

    @property
    def n_triangles(self) -> int:
        return len(self.triangles_m)

    @property
    def n_electrodes(self) -> int:
        return int(self.electrode.max())

    @classmethod
    def from_meshes(cls, sensor: LabelledMesh, tank: LabelledMesh | None = None,
                    objects: tuple = (), conducting: tuple = (), check: bool = True,
                    emitter: int | None = None, allow_touching: bool = False) -> "WaterBoundary":
        """Build from a sensor mesh (already at its pose), an optional tank mesh and object meshes.

        Parameters
        ----------
        sensor : LabelledMesh or None
            Closed mesh with electrode labels, normals into the water; ``None``
            for a scene without a sensor (electrodes on the tank or objects).
        tank : LabelledMesh, optional
            The water box, normals out of the water; ``None``: unbounded water.
            Its electrode labels (wall and floor electrodes) are kept, as are
            the objects'; electrode numbers run 1..n over the whole scene.
        objects : tuple of LabelledMesh
            Closed object meshes, normals into the water.
        conducting : tuple of bool
            For each object, whether it is a perfect conductor (default: insulating).
        check : bool
            Refuse open, badly oriented or degenerate meshes and unusable electrodes.
        allow_touching : bool
            Accept electrodes that share vertices (the sectors of a split
            electrode with no gap, :attr:`electrosense.meshes.sensor.SensorDescription.sectors_touch`).
        """
        conducting = tuple(conducting) + (False,) * (len(objects) - len(conducting))
        parts = ([] if sensor is None else [sensor]) + ([] if tank is None else [tank]) + list(objects)
        names = (([] if sensor is None else ["sensor"]) + ([] if tank is None else ["tank"])
                 + [f"object_{i}" for i in range(1, len(objects) + 1)])
        flip = ([] if sensor is None else [True]) + ([] if tank is None else [False]) + [True] * len(objects)
        if not parts:
            raise BoundaryError("nothing bounds the water: no sensor, no tank, no object")
        if check:
            from electrosense.meshes.quality import check_mesh

            for mesh, name in zip(parts, names):
                check_mesh(mesh, min_angle_deg=1.0, max_aspect_ratio=60.0, name=f"{name} mesh")
            if sensor is not None and len(parts) == 1:
                check_electrodes(sensor, emitter, allow_touching=allow_touching)
            else:  # electrodes anywhere in the scene: numbered 1..n over all parts
                check_electrodes(concatenate(parts), emitter, name="scene", allow_touching=allow_touching)
        tris, electrode, conductor, part = [], [], [], []
        conductor_names = []
        for p, (mesh, reverse) in enumerate(zip(parts, flip)):
            t = mesh.triangles_m
            tris.append(t[:, ::-1] if reverse else t)
            electrode.append(mesh.electrode)
            c = -1
            if p >= len(parts) - len(objects) and conducting[p - (len(parts) - len(objects))]:
                c = len(conductor_names)
                conductor_names.append(names[p])
            conductor.append(np.full(mesh.n_triangles, c, np.int64))
            part.append(np.full(mesh.n_triangles, p, np.int64))
        return cls(
            triangles_m=np.ascontiguousarray(np.concatenate(tris)),
            electrode=np.concatenate(electrode),
            conductor=np.concatenate(conductor),
            part=np.concatenate(part),
            part_names=tuple(names),
            unbounded=tank is None,
            mesh=concatenate(parts),
            n_sensor=0 if sensor is None else sensor.n_triangles,
            n_conductors=len(conductor_names),
            conductor_names=tuple(conductor_names),
        )
