"""Scenes that do not change with depth: a vertical cylindrical tank, rectangular wall electrodes, upright prisms.

A saline tank whose objects stand on the floor and reach through the free
surface, as the tanks of an EIT phantom series often do, is the same at every
depth except for its wall electrodes: those are rectangles on the wall (an
arc of angle times a range of height, :class:`WallPatch`) that need not span
the water. Such a scene (:class:`PrismScene`) is solved exactly by cosine
modes in depth (:mod:`electrosense.bem.prism_modes`).

Objects are upright prisms (:class:`Prism`): a polygon of the cross-section,
through the whole water column, insulating (0 S/m) or a floating conductor
(``inf``, an equipotential carrying no net current, optionally behind a
contact impedance). :func:`polygons_from_mask` traces them from a pixel mask
(a truth image): each connected region (its holes filled: water enclosed by
an object through the water column carries no current) becomes one polygon,
the mask smoothed by a Gaussian of 0.7 pixel before the contour at the
half level, so that the staircase of the pixels goes and the shape stays.

Frame: the tank's axis is z, the floor at ``z = 0`` and the free surface at
``z = water_depth_m``; angles from +x counter-clockwise.

Example
-------
>>> ring = ring_patches(4, first_centre_deg=90.0, width_deg=10.0, z_bottom_m=0.0, z_top_m=0.02)
>>> s = PrismScene(radius_m=0.1, water_depth_m=0.05, electrodes=ring)
>>> [round(float(np.degrees(e.phi_centre_rad)), 6) for e in s.electrodes], s.problems()
([90.0, 180.0, 270.0, 360.0], [])
>>> m = np.zeros((20, 20), bool); m[5:12, 8:15] = True
>>> poly = polygons_from_mask(m, np.arange(20) + 0.5, 19.5 - np.arange(20))[0]
>>> round(float(polygon_area(poly)), 1)                          # 7 x 7 pixels, corners rounded
45.3
"""
from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

__all__ = ["WallPatch", "Prism", "PrismScene", "ring_patches", "polygons_from_mask", "polygon_area",
           "resample_polygon"]


@dataclass(frozen=True)
class WallPatch:
    """A rectangular electrode on the wall: angles ``phi_start_rad`` to ``phi_end_rad`` (counter-clockwise),
    heights ``z_bottom_m`` to ``z_top_m`` above the floor."""

    phi_start_rad: float
    phi_end_rad: float
    z_bottom_m: float
    z_top_m: float
    name: str = ""

    def __post_init__(self):
        vals = [float(v) for v in (self.phi_start_rad, self.phi_end_rad, self.z_bottom_m, self.z_top_m)]
        if not all(np.isfinite(vals)):
            raise ValueError(f"wall electrode {self.name!r}: non-finite angle or height {vals}")
        if not 0 < vals[1] - vals[0] < 2 * math.pi:
            raise ValueError(f"wall electrode {self.name!r}: the arc must run counter-clockwise and be shorter than "
                             f"the circle, got {vals[0]} to {vals[1]} rad")
        if not vals[3] > vals[2]:
            raise ValueError(f"wall electrode {self.name!r}: its top ({vals[3]} m) must lie above its bottom "
                             f"({vals[2]} m)")
        for name, v in zip(("phi_start_rad", "phi_end_rad", "z_bottom_m", "z_top_m"), vals):
            object.__setattr__(self, name, v)

    @property
    def phi_centre_rad(self) -> float:
        return 0.5 * (self.phi_start_rad + self.phi_end_rad)

    @property
    def height_m(self) -> float:
        return self.z_top_m - self.z_bottom_m


@dataclass(frozen=True)
class Prism:
    """An upright prism through the water column: ``polygon_m`` (V, 2), counter-clockwise, of its cross-section.

    ``conductivity_S_per_m``: 0 insulating, ``inf`` a floating conductor (behind ``contact_impedance_ohm_m2``).
    """

    polygon_m: np.ndarray
    conductivity_S_per_m: float = 0.0
    contact_impedance_ohm_m2: float = 0.0
    name: str = ""

    def __post_init__(self):
        p = np.asarray(self.polygon_m, dtype=float)
        if p.ndim != 2 or p.shape[1] != 2 or len(p) < 3 or not np.all(np.isfinite(p)):
            raise ValueError(f"prism {self.name!r}: the polygon must be (V >= 3, 2) finite points, got {p.shape}")
        a = polygon_area(p)
        if a == 0:
            raise ValueError(f"prism {self.name!r}: the polygon has no area")
        p = p if a > 0 else p[::-1]
        object.__setattr__(self, "polygon_m", p)
        s = float(self.conductivity_S_per_m)
        if not (s == 0.0 or math.isinf(s)):
            raise ValueError(f"prism {self.name!r}: conductivity {s} S/m; only insulating (0) or a perfect conductor "
                             "(inf) is modelled")
        z = float(self.contact_impedance_ohm_m2)
        if not (np.isfinite(z) and z >= 0):
            raise ValueError(f"prism {self.name!r}: contact impedance must be finite and >= 0 ohm m^2, got {z}")
        object.__setattr__(self, "conductivity_S_per_m", s)
        object.__setattr__(self, "contact_impedance_ohm_m2", z)

    @property
    def is_conducting(self) -> bool:
        return math.isinf(self.conductivity_S_per_m)


@dataclass(frozen=True)
class PrismScene:
    """A vertical cylinder of ``radius_m`` filled to ``water_depth_m``, wall electrodes and prisms.

    Electrodes are numbered 1.. in the order given.
    """

    radius_m: float
    water_depth_m: float
    electrodes: tuple = ()
    objects: tuple = field(default_factory=tuple)

    def __post_init__(self):
        object.__setattr__(self, "electrodes", tuple(self.electrodes))
        object.__setattr__(self, "objects", tuple(self.objects))
        r, d = float(self.radius_m), float(self.water_depth_m)
        if not (np.isfinite(r) and np.isfinite(d) and r > 0 and d > 0):
            raise ValueError(f"prism scene: radius and water depth must be positive (m), got {r}, {d}")
        object.__setattr__(self, "radius_m", r)
        object.__setattr__(self, "water_depth_m", d)

    @property
    def n_electrodes(self) -> int:
        return len(self.electrodes)

    def problems(self, margin_m: float | None = None) -> list[str]:
        """Every reason why the scene cannot be solved (empty: it can): electrodes out of the water or overlapping,
        objects outside the tank (closer than ``margin_m`` to the wall, default 0.5 % of the radius) or overlapping."""
        out = []
        margin = 0.005 * self.radius_m if margin_m is None else float(margin_m)
        if len(self.electrodes) < 2:
            out.append(f"{len(self.electrodes)} electrode(s): at least two are needed")
        for i, e in enumerate(self.electrodes, start=1):
            if e.z_bottom_m < -1e-12 or e.z_top_m > self.water_depth_m * (1 + 1e-9):
                out.append(f"electrode {i} spans {e.z_bottom_m:.4g} to {e.z_top_m:.4g} m, outside the water "
                           f"(0 to {self.water_depth_m:.4g} m)")
        arcs = sorted((np.mod(e.phi_start_rad, 2 * np.pi), e.phi_end_rad - e.phi_start_rad, i)
                      for i, e in enumerate(self.electrodes, start=1))
        for (a0, w0, i0), (a1, _, i1) in zip(arcs, arcs[1:] + arcs[:1]):
            gap = np.mod(a1 - a0, 2 * np.pi) if len(arcs) > 1 else 2 * np.pi
            if gap < w0 + 1e-12:
                out.append(f"electrodes {i0} and {i1} overlap on the wall")
        for i, o in enumerate(self.objects, start=1):
            r = np.hypot(o.polygon_m[:, 0], o.polygon_m[:, 1]).max()
            if r > self.radius_m - margin:
                out.append(f"object {i} ({o.name or 'prism'}) reaches {r:.4g} m from the axis: closer than "
                           f"{margin:.3g} m to the wall (radius {self.radius_m:.4g} m)")
        out += _overlapping_objects(self.objects)
        return out


def _overlapping_objects(objects) -> list[str]:
    from matplotlib.path import Path as MplPath

    out = []
    for i, a in enumerate(objects, start=1):
        for j, b in enumerate(objects[i:], start=i + 1):
            if (MplPath(a.polygon_m).contains_points(b.polygon_m).any()
                    or MplPath(b.polygon_m).contains_points(a.polygon_m).any()):
                out.append(f"objects {i} and {j} overlap")
    return out


def ring_patches(n: int, first_centre_deg: float, width_deg: float, z_bottom_m: float, z_top_m: float,
                 step_deg: float | None = None) -> tuple[WallPatch, ...]:
    """``n`` equal patches round the wall, the first centred at ``first_centre_deg``, then every ``step_deg``
    (default 360 / n) counter-clockwise."""
    step = 360.0 / n if step_deg is None else float(step_deg)
    out = []
    for k in range(n):
        c = math.radians(first_centre_deg + k * step)
        w = math.radians(width_deg)
        out.append(WallPatch(c - w / 2, c + w / 2, z_bottom_m, z_top_m, name=f"e{k + 1}"))
    return tuple(out)


def polygon_area(p) -> float:
    """Signed area of a polygon (V, 2) (positive: counter-clockwise)."""
    p = np.asarray(p, float)
    x, y = p[:, 0], p[:, 1]
    return 0.5 * float(np.dot(x, np.roll(y, -1)) - np.dot(np.roll(x, -1), y))


def resample_polygon(p, spacing: float) -> np.ndarray:
    """The closed polygon's outline at about ``spacing`` between vertices (at least 8 vertices)."""
    p = np.asarray(p, float)
    closed = np.vstack([p, p[:1]])
    s = np.r_[0.0, np.cumsum(np.linalg.norm(np.diff(closed, axis=0), axis=1))]
    n = max(8, int(round(s[-1] / spacing)))
    t = np.linspace(0.0, s[-1], n + 1)[:-1]
    return np.stack([np.interp(t, s, closed[:, 0]), np.interp(t, s, closed[:, 1])], axis=1)


def polygons_from_mask(mask, x_centres, y_centres, smoothing_px: float = 0.7, spacing_px: float = 2.0,
                       min_pixels: int = 4) -> list[np.ndarray]:
    """One counter-clockwise polygon (V, 2) per connected region of a boolean mask, in the coordinates of the
    pixel centres (``x_centres`` by column, ``y_centres`` by row, both uniform).

    Each region's holes are filled; its indicator is smoothed by a Gaussian of
    ``smoothing_px`` pixels and traced at the half level (marching squares),
    then resampled at ``spacing_px`` pixels. Regions under ``min_pixels`` are
    left out.
    """
    from contourpy import contour_generator
    from scipy import ndimage

    m = np.asarray(mask, bool)
    x = np.asarray(x_centres, float)
    y = np.asarray(y_centres, float)
    w = float(abs(x[1] - x[0]))
    labels, n = ndimage.label(m)
    out = []
    for k in range(1, n + 1):
        region = ndimage.binary_fill_holes(labels == k)
        if region.sum() < min_pixels:
            continue
        padded = np.pad(region.astype(float), 3)
        smooth = ndimage.gaussian_filter(padded, smoothing_px) if smoothing_px > 0 else padded
        xp = np.r_[x[0] - w * np.arange(3, 0, -1) * np.sign(x[1] - x[0]), x,
                   x[-1] + w * np.arange(1, 4) * np.sign(x[1] - x[0])]
        dy = y[1] - y[0]
        yp = np.r_[y[0] - dy * np.arange(3, 0, -1), y, y[-1] + dy * np.arange(1, 4)]
        lines = contour_generator(xp, yp, smooth).lines(0.5)
        if not lines:
            continue
        line = max(lines, key=lambda c: abs(polygon_area(c)))
        if np.allclose(line[0], line[-1]):
            line = line[:-1]
        poly = resample_polygon(line, spacing_px * w)
        out.append(poly if polygon_area(poly) > 0 else poly[::-1])
    return out
