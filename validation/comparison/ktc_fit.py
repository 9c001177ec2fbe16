"""The KTC2023 scene's unknowns fitted to the empty tank and the tanks with objects, with standard errors.

The data are blocks (:class:`Block`): the empty tank's voltages (``total``)
and each tank's change, data minus reference (``difference``), both over
the voltages that can be scored (NaN and patterns that drive an electrode
out of use left out: :func:`~electrosense.validation.bench.transfer.ktc_mat.usable`).
The model of a block:

* total: ``s * Mpat^T Z(theta) Inj + o``, ``s`` the current's unit over the
  water's conductivity, ``Z`` the electrode impedance at conductivity 1
  (:class:`~electrosense.validation.comparison.ktc_model.KtcForward`), ``o``
  an offset per measurement channel (the instrument's; they cancel in a
  difference);
* difference: ``s * Mpat^T (Z_tank - Z_empty) Inj``.

Noise model: independent errors of one standard deviation per block, the
block's own linear floor's per-voltage noise (``noise_rms`` of
:func:`~electrosense.validation.bench.transfer.ktc_mat.linear_floor`): the
residuals are divided by it, so each file weighs by what it can tell.
The unknowns (:func:`ktc_unknowns`) are fitted by
:func:`~electrosense.validation.diagnosis.scene_fit.fit_unknowns`: the scale
and contact impedances through analytic derivatives, the offsets linearly,
the geometry by finite differences (a new modal solve for the arc, the
depth and the metal's contact; only new electrode cells for the height and
position).
"""
from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np

from electrosense.validation.comparison.ktc_model import WIDTH_DEG, KtcForward, KtcGeometry, volts
from electrosense.validation.diagnosis.scene_fit import SceneFit, Unknown, fit_unknowns

__all__ = ["Block", "KtcProblem", "ktc_unknowns", "GEOMETRY", "fit_blocks"]

#: unknowns that move the geometry (finite differences), with their step and whether a new modal solve is needed
GEOMETRY = {"width_deg": (0.02, True), "depth_m": (2e-4, True), "height_frac": (2e-3, False),
            "position": (2e-3, False), "log_zeta_metal": (0.05, True), "ring_rotation_deg": (0.05, True),
            "frame_dx_m": (1e-4, True), "frame_dy_m": (1e-4, True)}
#: the unknowns only tanks with objects can tell (an empty tank is the same turned or shifted)
OBJECT_ONLY = ("ring_rotation_deg", "frame_dx_m", "frame_dy_m", "log_zeta_metal")


@dataclass
class Block:
    """One file's data: ``kind`` ``total`` (the empty tank) or ``difference`` (a tank minus the empty one), the
    measured array (P, M), the mask of what is scored, the weight (1 / noise), the currents and measurement pattern."""

    tank: str
    kind: str
    measured: np.ndarray
    mask: np.ndarray
    weight: float
    injection: np.ndarray
    measurement_pattern: np.ndarray


def ktc_unknowns(n_electrodes: int, n_channels: int, start: dict | None = None, tanks=()) -> list[Unknown]:
    """The scene's and instrument's unknowns with their bounds (``start`` overrides start values by name); with
    ``tanks``, each one's drift (the relative change of every voltage between the reference and that tank: the
    water's conductivity or the current changed meanwhile; a nuisance of the training tanks, never predicted)."""
    s = dict(start or {})
    us = [Unknown("log_scale", s.get("log_scale", np.log(0.03)), -30, 30, 0.1, "log(A_unit / (S/m))",
                  "the current's unit over the water's conductivity (one scale)"),
          Unknown("width_deg", s.get("width_deg", WIDTH_DEG), 1.0, 10.5, 0.3, "deg", "the electrodes' arc"),
          Unknown("depth_m", s.get("depth_m", 0.07), 0.01, 0.5, 0.005, "m", "the water depth"),
          Unknown("height_frac", s.get("height_frac", 0.5), 0.05, 1.0, 0.05, "",
                  "the electrodes' height over the water depth"),
          Unknown("position", s.get("position", 0.25), 0.0, 0.5, 0.05, "",
                  "where the electrodes sit: 0 from the floor up, 0.5 centred in the water")]
    us += [Unknown(f"log_zeta_e{k}", s.get(f"log_zeta_e{k}", np.log(1e-3)), np.log(1e-7), np.log(1.0), 0.3,
                   "log(m)", f"electrode {k}'s contact impedance times the water's conductivity")
           for k in range(1, n_electrodes + 1)]
    us.append(Unknown("log_zeta_metal", s.get("log_zeta_metal", np.log(1e-4)), np.log(1e-7), np.log(1.0), 0.3,
                      "log(m)", "the metal objects' contact impedance times the water's conductivity"))
    us += [Unknown("ring_rotation_deg", s.get("ring_rotation_deg", 0.0), -8.0, 8.0, 0.5, "deg",
                   "the electrode ring turned from the sources' angles (counter-clockwise)"),
           Unknown("frame_dx_m", s.get("frame_dx_m", 0.0), -0.01, 0.01, 0.001, "m", "the truth frame's shift in x"),
           Unknown("frame_dy_m", s.get("frame_dy_m", 0.0), -0.01, 0.01, 0.001, "m", "the truth frame's shift in y")]
    us += [Unknown(f"offset_ch{m}", s.get(f"offset_ch{m}", 0.0), -10.0, 10.0, 0.01, "V",
                   f"the instrument's offset on measurement channel {m}") for m in range(1, n_channels + 1)]
    us += [Unknown(f"drift_{t}", s.get(f"drift_{t}", 0.0), -0.5, 0.5, 0.005, "",
                   f"every voltage's relative change between the reference and {t} (nuisance)") for t in tanks]
    return us


class KtcProblem:
    """Residuals and Jacobian of the blocks for the vector of :func:`ktc_unknowns`; unknowns in ``fixed`` get no
    derivative (their columns are zero and cost nothing)."""

    def __init__(self, forward: KtcForward, blocks: list[Block], n_electrodes: int, n_channels: int,
                 fixed=(), angle_offsets_deg=None):
        self.forward = forward
        self.blocks = blocks
        self.E, self.M = n_electrodes, n_channels
        self.drift_tanks = [b.tank for b in blocks if b.kind == "difference"]
        self.unknowns = ktc_unknowns(n_electrodes, n_channels, tanks=self.drift_tanks)
        self.names = [u.name for u in self.unknowns]
        self.index = {n: i for i, n in enumerate(self.names)}
        self.fixed = set(fixed)
        self.angle_offsets_deg = angle_offsets_deg
        self._cache = (None, None)

    def geometry(self, x) -> KtcGeometry:
        i = self.index
        return KtcGeometry(width_deg=float(x[i["width_deg"]]), depth_m=float(x[i["depth_m"]]),
                           height_frac=float(x[i["height_frac"]]), position=float(x[i["position"]]),
                           zeta_metal_m=float(np.exp(x[i["log_zeta_metal"]])), n_electrodes=self.E,
                           angle_offsets_deg=self.angle_offsets_deg, ring_rotation_deg=float(x[i["ring_rotation_deg"]]),
                           frame_shift_m=(float(x[i["frame_dx_m"]]), float(x[i["frame_dy_m"]])))

    def zeta(self, x) -> np.ndarray:
        i = self.index["log_zeta_e1"]
        return np.exp(np.asarray(x[i:i + self.E], float))

    def offsets(self, x) -> np.ndarray:
        i = self.index["offset_ch1"]
        return np.asarray(x[i:i + self.M], float)

    def _tanks(self):
        need = {"ref"}
        for b in self.blocks:
            need.add(b.tank)
        return sorted(need)

    def impedances(self, x, derivatives: bool = False, geom: KtcGeometry | None = None) -> dict:
        geom = self.geometry(x) if geom is None else geom
        return {t: self.forward.impedance(t, geom, self.zeta(x), derivatives) for t in self._tanks()}

    def predictions(self, x, Zs: dict | None = None) -> list[np.ndarray]:
        """Each block's model (P, M) (before masking and weighting)."""
        Zs = self.impedances(x) if Zs is None else Zs
        s = float(np.exp(x[self.index["log_scale"]]))
        out = []
        for b in self.blocks:
            if b.kind == "total":
                out.append(s * volts(Zs[b.tank], b.injection, b.measurement_pattern) + self.offsets(x)[None])
            else:
                Vt = volts(Zs[b.tank], b.injection, b.measurement_pattern)
                drift = float(x[self.index[f"drift_{b.tank}"]])
                out.append(s * ((1 + drift) * Vt - volts(Zs["ref"], b.injection, b.measurement_pattern)))
        return out

    def residual(self, x) -> np.ndarray:
        pred = self.predictions(x)
        return np.concatenate([b.weight * (p - b.measured)[b.mask] for b, p in zip(self.blocks, pred)])

    def jacobian(self, x) -> np.ndarray:
        x = np.asarray(x, float)
        Zd = self.impedances(x, derivatives=True)
        Zs = {t: v[0] for t, v in Zd.items()}
        dZ = {t: v[1] for t, v in Zd.items()}
        s = float(np.exp(x[self.index["log_scale"]]))
        zeta = self.zeta(x)
        base = self.residual(x)
        cols = np.zeros((len(base), len(x)))
        row = 0
        i_z, i_o = self.index["log_zeta_e1"], self.index["offset_ch1"]
        for b in self.blocks:
            n = int(b.mask.sum())
            sl = slice(row, row + n)
            if b.kind == "total":
                V = volts(Zs[b.tank], b.injection, b.measurement_pattern)
                dV = volts(dZ[b.tank], b.injection, b.measurement_pattern)            # (E, P, M)
                chan = np.broadcast_to(np.arange(self.M)[None], b.mask.shape)[b.mask]
                cols[np.arange(row, row + n), i_o + chan] = b.weight
            else:
                drift = float(x[self.index[f"drift_{b.tank}"]])
                Vt = volts(Zs[b.tank], b.injection, b.measurement_pattern)
                V = (1 + drift) * Vt - volts(Zs["ref"], b.injection, b.measurement_pattern)
                dV = volts((1 + drift) * dZ[b.tank] - dZ["ref"], b.injection, b.measurement_pattern)
                cols[sl, self.index[f"drift_{b.tank}"]] = b.weight * s * Vt[b.mask]
            cols[sl, self.index["log_scale"]] = b.weight * s * V[b.mask]
            cols[sl, i_z:i_z + self.E] = (b.weight * s * zeta[:, None] * dV[:, b.mask]).T
            row += n
        lo = {u.name: u.lower for u in self.unknowns}
        hi = {u.name: u.upper for u in self.unknowns}
        for name, (h, _) in GEOMETRY.items():
            if name in self.fixed:
                continue
            if name == "log_zeta_metal" and not any(o.is_conducting for b in self.blocks
                                                    for o in self.forward.objects[b.tank]):
                continue
            if name in OBJECT_ONLY and not any(self.forward.objects[b.tank] for b in self.blocks):
                continue
            j = self.index[name]
            step = h if x[j] + h <= hi[name] else -h
            if x[j] + step < lo[name]:
                continue
            x2 = x.copy()
            x2[j] += step
            cols[:, j] = (self.residual(x2) - base) / step
        return cols


def fit_blocks(forward: KtcForward, blocks: list[Block], n_electrodes: int, n_channels: int, start: dict | None = None,
               fixed=(), max_nfev: int = 25, angle_offsets_deg=None) -> tuple[SceneFit, KtcProblem]:
    """Fit the unknowns not in ``fixed`` to the blocks (see the module docstring)."""
    fixed = set(fixed)
    if not any(b.kind == "total" for b in blocks):
        fixed |= {f"offset_ch{m}" for m in range(1, n_channels + 1)}
    if not any(o.is_conducting for b in blocks for o in forward.objects.get(b.tank, ())):
        fixed.add("log_zeta_metal")
    if not any(forward.objects.get(b.tank, ()) for b in blocks):
        fixed |= set(OBJECT_ONLY)
    problem = KtcProblem(forward, blocks, n_electrodes, n_channels, fixed, angle_offsets_deg)
    unknowns = ktc_unknowns(n_electrodes, n_channels, start, tanks=problem.drift_tanks)
    if not start or "log_scale" not in start:       # the scale from a linear fit at the start values
        x0 = np.array([u.value for u in unknowns])
        pred = problem.predictions(x0)
        num = sum(float(np.sum((b.weight * p)[b.mask] * (b.weight * b.measured)[b.mask]))
                  for b, p in zip(blocks, pred))
        den = sum(float(np.sum((b.weight * p)[b.mask] ** 2)) for b, p in zip(blocks, pred))
        unknowns[0] = replace(unknowns[0], value=float(unknowns[0].value + np.log(max(num / den, 1e-12))))
    fit = fit_unknowns(problem.residual, problem.jacobian, unknowns, max_nfev=max_nfev, fixed=sorted(fixed))
    return fit, problem
