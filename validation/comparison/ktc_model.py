"""The KTC2023 tank as a prism scene, its unknowns, and the voltages of any current pattern.

The geometry the sources give (the README of the data): a cylinder of radius
0.115 m, 32 electrodes equally spaced, electrode 1 centred at 84.375 degrees
from +x (counter-clockwise, 11.25 degrees apart), 5.625 degrees of arc in
the organisers' mesh; the objects from the truth masks
(:func:`truth_objects`: each region an upright prism through the water,
plastic insulating, metal a floating conductor).

What no source gives is an unknown (:data:`SCENE_UNKNOWNS`): the current's
unit over the water's conductivity (one scale: the two only ever appear as a
ratio), the electrodes' arc (the mesh's 5.625 degrees is a model, not a
measurement), the water depth, the electrodes' height (as a fraction of the
depth) and where they sit (0 on the floor, 0.5 centred: a mirror image in
the water's mid-plane reads the same), each electrode's contact impedance
(times the conductivity, m: ``zeta = z_c sigma``) and the metal's; and of the
instrument, an offset per measurement channel.

:class:`KtcForward` evaluates the electrode impedance of each tank (the
empty one and those with objects) at a geometry, keeping the modal responses
(:mod:`electrosense.bem.prism_modes`) so that what changes only the
electrodes' height or contact costs no new solve.

Example
-------
>>> g = KtcGeometry(depth_m=0.05, height_frac=0.5, position=0.0)
>>> e = g.electrodes()
>>> len(e), round(float(np.degrees(e[0].phi_centre_rad)), 3), round(e[0].z_top_m, 4)
(32, 84.375, 0.025)
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from electrosense.bem.prism_modes import PrismModel
from electrosense.meshes.prism_scene import Prism, PrismScene, WallPatch, polygons_from_mask

__all__ = ["KtcGeometry", "KtcForward", "truth_objects", "volts", "RADIUS_M", "FIRST_CENTRE_DEG", "STEP_DEG",
           "WIDTH_DEG"]

#: the tank's radius (m), electrode 1's centre and the spacing (degrees), the arc of the organisers' mesh
RADIUS_M = 0.115
FIRST_CENTRE_DEG = 0.5 * (81.5625 + 87.1875)
STEP_DEG = 11.25
WIDTH_DEG = 5.625


@dataclass(frozen=True)
class KtcGeometry:
    """What shapes the tank's field: electrode arc (deg), water depth (m), electrode height (fraction of the depth),
    its position (0: from the floor up, 0.5: centred in the water), the metal's contact impedance times the water's
    conductivity (m), per-electrode angle offsets (deg, or None); the electrode ring's rotation from the sources'
    angles (deg, counter-clockwise) and the shift of the truth masks' frame (m): where the objects are seen from the
    electrodes, which no empty tank can tell."""

    width_deg: float = WIDTH_DEG
    depth_m: float = 0.07
    height_frac: float = 1.0
    position: float = 0.0
    zeta_metal_m: float = 0.0
    angle_offsets_deg: tuple | None = None
    n_electrodes: int = 32
    radius_m: float = RADIUS_M
    ring_rotation_deg: float = 0.0
    frame_shift_m: tuple = (0.0, 0.0)

    def electrodes(self) -> tuple:
        h = min(1.0, self.height_frac) * self.depth_m
        zb = min(max(self.position, 0.0), 1.0) * (self.depth_m - h)
        step = 360.0 / self.n_electrodes
        off = np.zeros(self.n_electrodes) if self.angle_offsets_deg is None else np.asarray(self.angle_offsets_deg)
        out = []
        for k in range(self.n_electrodes):
            c = math.radians(FIRST_CENTRE_DEG + self.ring_rotation_deg + k * step + off[k])
            w = math.radians(self.width_deg)
            out.append(WallPatch(c - w / 2, c + w / 2, zb, min(zb + h, self.depth_m), name=f"e{k + 1}"))
        return tuple(out)

    def scene(self, objects=()) -> PrismScene:
        """The prism scene with these electrodes and the objects moved by the frame's shift."""
        dx, dy = self.frame_shift_m
        moved = tuple(o if (dx, dy) == (0.0, 0.0) else
                      Prism(o.polygon_m + np.array([dx, dy]), o.conductivity_S_per_m, o.contact_impedance_ohm_m2,
                            o.name) for o in objects)
        return PrismScene(self.radius_m, self.depth_m, self.electrodes(), moved)

    @property
    def section_key(self) -> tuple:
        """What the modal responses depend on (the cross-section, the depth, the metal's contact)."""
        off = None if self.angle_offsets_deg is None else tuple(round(float(v), 12) for v in self.angle_offsets_deg)
        return (round(self.width_deg, 12), round(self.depth_m, 12), round(self.zeta_metal_m, 15), off,
                round(self.ring_rotation_deg, 12), tuple(round(float(v), 12) for v in self.frame_shift_m))


def truth_objects(truth, radius_m: float = RADIUS_M, margin_m: float = 1e-3, smoothing_px: float = 0.7) -> tuple:
    """The prisms of a truth mask: each region of 1 (plastic) insulating, of 2 (metal) a floating conductor; a
    polygon's points farther than ``radius - margin`` from the axis are pulled in to it. Regions so close that
    their smoothed outlines overlap are traced again without smoothing (the half level between pixels keeps
    regions apart that water pixels separate)."""
    from electrosense.meshes.prism_scene import _overlapping_objects

    objs = _truth_prisms(truth, radius_m, margin_m, smoothing_px)
    if smoothing_px > 0 and _overlapping_objects(objs):
        objs = _truth_prisms(truth, radius_m, margin_m, 0.0)
    return objs


def _truth_prisms(truth, radius_m, margin_m, smoothing_px) -> tuple:
    x, y = truth.centres_m()
    out = []
    for value, conductivity, kind in ((1, 0.0, "plastic"), (2, math.inf, "metal")):
        for i, poly in enumerate(polygons_from_mask(truth.mask == value, x, y, smoothing_px=smoothing_px), start=1):
            r = np.hypot(poly[:, 0], poly[:, 1])
            lim = radius_m - margin_m
            poly = np.where((r > lim)[:, None], poly * (lim / np.maximum(r, 1e-300))[:, None], poly)
            out.append(Prism(poly, conductivity, name=f"{kind} {i}"))
    return tuple(out)


def volts(Z, injection, measurement_pattern) -> np.ndarray:
    """(P, M) voltages of every pattern from the electrode impedance ``Z`` (E, E), or (..., E, E) -> (..., P, M)."""
    return np.einsum("em,...ef,fp->...pm", measurement_pattern, Z, injection)


class KtcForward:
    """The electrode impedance (conductivity 1) of each tank at a geometry, with the modal responses kept.

    ``objects``: {tank name: prisms} (the empty tank is ``"ref"`` with none).
    ``n_modes`` is fixed for every geometry, so that finite differences see
    a smooth model.
    """

    def __init__(self, objects: dict, n_modes: int = 40, cells_in_height: int = 6, segments_per_electrode: int = 6,
                 segments_per_gap: int = 4, object_spacing_m: float = 0.002, keep: int = 64):
        self.objects = {"ref": (), **objects}
        self.options = dict(n_modes=n_modes, cells_in_height=cells_in_height,
                            segments_per_electrode=segments_per_electrode, segments_per_gap=segments_per_gap,
                            object_spacing_m=object_spacing_m)
        self._responses: dict = {}
        self._keep = keep
        self.solves = 0

    def model(self, tank: str, geom: KtcGeometry) -> PrismModel:
        key = (tank, geom.section_key if self.objects[tank] else geom.section_key[:2] + geom.section_key[3:4])
        objs = self.objects[tank]
        zeta_o = [geom.zeta_metal_m if o.is_conducting else 0.0 for o in objs]
        resp = self._responses.get(key)
        m = PrismModel(geom.scene(objs), responses=resp, object_zeta_m=zeta_o, **self.options)
        if resp is None:
            self.solves += 1
            if len(self._responses) >= self._keep:
                self._responses.pop(next(iter(self._responses)))
            self._responses[key] = m.responses
        return m

    def impedance(self, tank: str, geom: KtcGeometry, zeta_m, derivatives: bool = False):
        """``Z`` (E, E) (and ``dZ/dzeta`` (E, E, E)) of ``tank`` at ``geom`` and the electrodes' ``zeta_m``."""
        return self.model(tank, geom).impedance(zeta_m, derivatives)
