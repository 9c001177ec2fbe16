"""Scenes that do not change with depth, solved exactly by cosine modes in depth: a 2-D BEM per mode and the
complete electrode model of rectangular wall electrodes.

In a vertical tank whose floor and free surface are insulating and whose
objects are upright prisms through the water
(:class:`~electrosense.meshes.prism_scene.PrismScene`), the potential is a sum
of modes ``phi(x, y, z) = sum_n phi_n(x, y) e_n(z)``, ``e_0 = 1/sqrt(D)``,
``e_n = sqrt(2/D) cos(k_n z)``, ``k_n = n pi / D`` (``D`` the water depth):
each mode satisfies ``Delta phi_n - k_n^2 phi_n = 0`` on the cross-section,
and the wall current density's mode ``j_n`` is its Neumann datum. Only the
electrodes, which need not span the water, couple the modes. So:

1. **Per mode** (:func:`wall_responses`), a 2-D collocation BEM
   (:mod:`electrosense.bem.helmholtz2d`) on the cross-section's segments
   (:mod:`electrosense.meshes.section_mesh`) gives ``g_n[s, s']``, the
   potential on wall segment ``s`` per unit current density on segment
   ``s'`` (conductivity 1). Insulating prisms: no flux. A conducting prism
   is one equipotential ``W`` at every depth, so its potential is ``W sqrt(D)``
   in mode 0 (with no net current) and 0 in every other mode; behind a
   contact impedance, ``u = W - zeta q``. Mode 0 is the Laplace equation's
   Neumann problem: each unit current is returned uniformly over the wall
   (what no current pattern, summing to zero, sees) and the wall's mean
   potential is fixed.
2. **The electrodes** (:func:`cell_impedance`): each is cut into cells
   (a wall segment under it times an interval of height); the cells' mean
   potentials per unit current density follow from the modes, summed to
   ``n_modes``.
3. **The complete electrode model** (:func:`electrode_impedance`): on every
   cell of electrode ``k``, ``phi + zeta_k J = U_k`` (``zeta = z_c sigma``, m,
   the contact impedance over the water's resistivity), and the cells'
   currents add up to the electrode's. The result is the matrix ``Z`` of
   electrode potentials per ampere (ohm), for currents that sum to zero; the
   voltages of any current pattern follow (:func:`~electrosense.bem.protocol.pattern_voltages_V`).

Everything scales with ``1 / sigma`` once the contact impedances are given as
``zeta``: the solver works at ``sigma = 1`` and :func:`solve_prism_scene`
divides.

Example
-------
Two electrodes spanning the water of a tank 2 cm deep: the 2-D answer divided
by the depth (the modes above 0 carry nothing):

>>> from electrosense.meshes.prism_scene import PrismScene, ring_patches
>>> s = PrismScene(0.1, 0.02, ring_patches(2, 0.0, 20.0, 0.0, 0.02))
>>> full = solve_prism_scene(s, 1.0, n_modes=4)
>>> s3 = PrismScene(0.1, 0.04, ring_patches(2, 0.0, 20.0, 0.0, 0.04))
>>> half = solve_prism_scene(s3, 1.0, n_modes=4)
>>> r = lambda sol: sol.Z_ohm[0, 0] - sol.Z_ohm[0, 1] - sol.Z_ohm[1, 0] + sol.Z_ohm[1, 1]
>>> round(float(r(full) / r(half)), 6)
2.0
"""
from __future__ import annotations

import time
from dataclasses import dataclass, field

import numpy as np
import scipy.linalg as sla

from electrosense.bem.helmholtz2d import PairGeometry, layer_matrices_2d
from electrosense.meshes.prism_scene import PrismScene
from electrosense.meshes.section_mesh import SectionMesh, mesh_section, z_cells

__all__ = ["ElectrodeCells", "PrismSolution", "wall_responses", "electrode_cells", "mode_weights",
           "cell_impedance", "electrode_impedance", "solve_prism_scene", "default_n_modes", "PrismModel"]


def wall_responses(mesh: SectionMesh, depth_m: float, n_modes: int, conducting=(), contact_zeta_m=()) -> dict:
    """Per mode n < ``n_modes``: ``g[n]`` (S_e, S_e), the potential on each wall electrode segment per unit current
    density on each (conductivity 1), ``seg`` the segments' indices, ``k`` the wavenumbers (1/m).

    ``conducting[i]`` (bool) and ``contact_zeta_m[i]`` (m) of object i (contour i + 1).
    """
    S_n = mesh.n_segments
    L = mesh.lengths
    wall = mesh.contour == 0
    seg = np.flatnonzero(mesh.electrode > 0)
    n_obj = int(mesh.contour.max())
    conducting = tuple(conducting) + (False,) * (n_obj - len(conducting))
    zeta = tuple(contact_zeta_m) + (0.0,) * (n_obj - len(contact_zeta_m))
    cond_of = np.full(S_n, -1)
    for i in range(n_obj):
        if conducting[i]:
            cond_of[mesh.contour == i + 1] = i
    qface = cond_of >= 0
    conductors = sorted(set(cond_of[qface].tolist()))
    mid = mesh.midpoints
    own = np.arange(S_n)
    geom = PairGeometry(mid, mesh.a, mesh.b, own)
    zeta_face = np.array([zeta[c] if c >= 0 else 0.0 for c in cond_of])
    k_all = np.pi * np.arange(n_modes) / depth_m
    g = np.zeros((n_modes, len(seg), len(seg)))
    Lw = L[wall].sum()
    for n, k in enumerate(k_all):
        S, D = layer_matrices_2d(mid, mesh.a, mesh.b, float(k), own=own, geometry=geom)
        H = D + 0.5 * np.eye(S_n)
        M = H.copy()
        M[:, qface] = -(S[:, qface] + zeta_face[qface][None] * H[:, qface])
        rhs = S[:, seg].copy()
        extra_cols, extra_rows = [], []
        if n == 0:
            rhs -= np.outer(S[:, wall].sum(axis=1), L[seg] / Lw)
            for c in conductors:
                on = cond_of == c
                extra_cols.append(H[:, on].sum(axis=1))
                row = np.zeros(S_n)
                row[on] = L[on] / L[on].mean()
                extra_rows.append(row)
            extra_cols.append(np.ones(S_n))                 # the gauge's multiplier
            row = np.zeros(S_n)
            row[wall] = L[wall] / L[wall].mean()
            extra_rows.append(row)
        m = len(extra_cols)
        if m:
            big = np.zeros((S_n + m, S_n + m))
            big[:S_n, :S_n] = M
            big[:S_n, S_n:] = np.stack(extra_cols, axis=1)
            big[S_n:, :S_n] = np.stack(extra_rows)
            M = big
            rhs = np.vstack([rhs, np.zeros((m, len(seg)))])
        sol = _solve(M, rhs, k, mesh)
        g[n] = sol[seg]
    return {"g": g, "seg": seg, "k": k_all}


def _solve(M, rhs, k, mesh):
    """Dense LU, or sparse LU where the mode's kernel reaches only near neighbours."""
    nnz = np.count_nonzero(M)
    if k > 0 and nnz < 0.05 * M.size:
        from scipy.sparse import csc_matrix
        from scipy.sparse.linalg import splu

        return splu(csc_matrix(M)).solve(rhs)
    return sla.lu_solve(sla.lu_factor(M, check_finite=False), rhs, check_finite=False)


@dataclass(frozen=True)
class ElectrodeCells:
    """The electrodes' cells: wall segment (index into the responses' ``seg``), height interval, electrode (0-based),
    area (m^2)."""

    seg: np.ndarray
    z_lo: np.ndarray
    z_hi: np.ndarray
    electrode: np.ndarray
    area: np.ndarray
    n_electrodes: int

    @property
    def incidence(self) -> np.ndarray:
        """(C, E) 1 where cell c is on electrode e."""
        E = np.zeros((len(self.seg), self.n_electrodes))
        E[np.arange(len(self.seg)), self.electrode] = 1.0
        return E


def electrode_cells(scene: PrismScene, mesh: SectionMesh, seg: np.ndarray, cells_in_height: int = 6) -> ElectrodeCells:
    """The cells of every electrode: its wall segments times ``cells_in_height`` intervals of its height."""
    rows = []
    lengths = mesh.lengths
    for local, s in enumerate(seg):
        k = int(mesh.electrode[s]) - 1
        e = scene.electrodes[k]
        z = z_cells(e.z_bottom_m, e.z_top_m, scene.water_depth_m, cells_in_height)
        for lo, hi in zip(z[:-1], z[1:]):
            rows.append((local, lo, hi, k, lengths[s] * (hi - lo)))
    a = np.array(rows, dtype=float)
    return ElectrodeCells(a[:, 0].astype(int), a[:, 1], a[:, 2], a[:, 3].astype(int), a[:, 4], scene.n_electrodes)


def mode_weights(z_lo, z_hi, depth_m: float, n_modes: int) -> np.ndarray:
    """(C, N): ``int e_n dz`` over each cell ``[z_lo, z_hi]``."""
    n = np.arange(n_modes)[None]
    lo, hi = np.asarray(z_lo)[:, None], np.asarray(z_hi)[:, None]
    k = np.pi * n / depth_m
    with np.errstate(divide="ignore", invalid="ignore"):
        w = np.sqrt(2 / depth_m) * (np.sin(k * hi) - np.sin(k * lo)) / np.where(k > 0, k, 1.0)
    w[:, 0] = (hi - lo)[:, 0] / np.sqrt(depth_m)
    return w


def cell_impedance(responses: dict, cells: ElectrodeCells, depth_m: float) -> np.ndarray:
    """(C, C): mean potential on cell p per unit current density on cell q (conductivity 1)."""
    g = responses["g"]
    zz = np.stack([cells.z_lo, cells.z_hi], axis=1)
    uz, u = np.unique(zz, axis=0, return_inverse=True)
    u = u.ravel()
    B = mode_weights(uz[:, 0], uz[:, 1], depth_m, len(g))                 # (U, N)
    Bh = B / (uz[:, 1] - uz[:, 0])[:, None]
    if len(uz) ** 2 * g.shape[1] ** 2 <= 5e7:
        # T[a, b, s, t] = sum_n Bh[a, n] B[b, n] g_n[s, t], then each cell pair's entry gathered
        W = (Bh[:, None, :] * B[None, :, :]).reshape(-1, len(g))
        T = (W @ g.reshape(len(g), -1)).reshape(len(uz), len(uz), g.shape[1], g.shape[2])
        return T[u[:, None], u[None, :], cells.seg[:, None], cells.seg[None, :]]
    Z = np.zeros((len(u), len(u)))
    for n in range(len(g)):
        Z += np.outer(Bh[u, n], B[u, n]) * g[n][np.ix_(cells.seg, cells.seg)]
    return Z


def electrode_impedance(Z_cell: np.ndarray, cells: ElectrodeCells, zeta_m, derivatives: bool = False):
    """The complete electrode model: ``Z`` (E, E), electrode potentials per ampere (conductivity 1).

    ``zeta_m`` (E,) or a float: contact impedance times conductivity (m).
    With ``derivatives``, also ``dZ / dzeta_k`` (E, E, E), ``[k]`` the k-th.
    """
    E = cells.incidence
    zeta = np.broadcast_to(np.asarray(zeta_m, float), (cells.n_electrodes,))
    A = Z_cell + np.diag(zeta[cells.electrode])
    lu = sla.lu_factor(A, check_finite=False)
    X = sla.lu_solve(lu, E, check_finite=False)                      # (C, E) cell current densities per U
    Y = (E * cells.area[:, None]).T @ X                              # electrode currents per unit potentials
    Z = np.linalg.inv(Y)
    if not derivatives:
        return Z
    # dY/dzeta_k = -(E^T W A^-1)[:, cells of k] X[cells of k]; dZ = -Z dY Z
    WAinv = sla.lu_solve(lu, E * cells.area[:, None], trans=1, check_finite=False).T     # (E, C) = E^T W A^-1
    dZ = np.zeros((cells.n_electrodes,) * 3)
    for k in range(cells.n_electrodes):
        on = cells.electrode == k
        dY = -WAinv[:, on] @ X[on]
        dZ[k] = -Z @ dY @ Z
    return Z, dZ


def default_n_modes(scene: PrismScene, cells_in_height: int = 6) -> int:
    """Modes enough for the electrodes' smallest cells in height (two per cell), 8 to 60 (2 when nothing varies
    with depth). On a KTC-like ring (32 electrodes of 11 mm, 3 cm high, 7 cm of water) 60 modes are within
    0.2 % of 120, and the default cells within 0.35 % of twice as many."""
    hmin = min(np.diff(z_cells(e.z_bottom_m, e.z_top_m, scene.water_depth_m, cells_in_height)).min()
               for e in scene.electrodes)
    if all(e.z_bottom_m <= 1e-9 and e.z_top_m >= scene.water_depth_m * (1 - 1e-9) for e in scene.electrodes) \
            and not scene.objects:
        return 2
    return int(np.clip(np.ceil(2 * scene.water_depth_m / hmin), 8, 60))


@dataclass
class PrismSolution:
    """``Z_ohm`` (E, E): electrode potentials per ampere (for currents summing to zero; a common constant is
    arbitrary). ``info``: sizes and seconds."""

    Z_ohm: np.ndarray
    sigma_S_per_m: float
    info: dict = field(default_factory=dict)

    @property
    def K_S(self) -> np.ndarray:
        """The electrodes' conductance matrix (S): zero row sums, the pseudo-inverse of the centred ``Z``."""
        n = len(self.Z_ohm)
        P = np.eye(n) - 1.0 / n
        return np.linalg.pinv(P @ self.Z_ohm @ P, rcond=1e-12)


class PrismModel:
    """A scene's modal responses kept, so that the contact impedances (and the conductivity) change at no cost.

    ``PrismModel(scene, n_modes=None, ...)``; :meth:`impedance` ``(zeta_m) -> Z`` at conductivity 1.
    ``responses``: the modal responses of a scene with the same cross-section and depth (the electrodes' heights
    may differ: only their cells are rebuilt); ``object_zeta_m``: each conducting object's contact impedance
    times the water's conductivity (m).
    """

    def __init__(self, scene: PrismScene, n_modes: int | None = None, cells_in_height: int = 6,
                 segments_per_electrode: int = 6, segments_per_gap: int = 4, object_spacing_m: float | None = None,
                 responses: dict | None = None, object_zeta_m=None):
        problems = scene.problems()
        if problems:
            raise ValueError("prism scene: " + "; ".join(problems))
        t0 = time.perf_counter()
        self.scene = scene
        self.mesh = mesh_section(scene, segments_per_electrode, segments_per_gap, object_spacing_m=object_spacing_m)
        self.n_modes = default_n_modes(scene, cells_in_height) if n_modes is None else int(n_modes)
        cond = tuple(o.is_conducting for o in scene.objects)
        # a conductor's contact impedance times the water's conductivity (m): given, or 0
        self._zeta_objects = tuple(object_zeta_m) if object_zeta_m is not None else tuple(0.0 for _ in scene.objects)
        self.responses = responses if responses is not None else wall_responses(
            self.mesh, scene.water_depth_m, self.n_modes, cond, self._zeta_objects)
        t1 = time.perf_counter()
        self.cells = electrode_cells(scene, self.mesh, self.responses["seg"], cells_in_height)
        self.Z_cell = cell_impedance(self.responses, self.cells, scene.water_depth_m)
        self.info = {"segments": int(self.mesh.n_segments), "modes": self.n_modes, "cells": len(self.cells.seg),
                     "modes_s": t1 - t0, "cells_s": time.perf_counter() - t1}

    def impedance(self, zeta_m, derivatives: bool = False):
        """``Z`` (E, E) at conductivity 1 (ohm S/m): see :func:`electrode_impedance`."""
        return electrode_impedance(self.Z_cell, self.cells, zeta_m, derivatives)


def solve_prism_scene(scene: PrismScene, sigma_S_per_m: float, contact_impedance_ohm_m2=None,
                      n_modes: int | None = None, cells_in_height: int = 6, **mesh_options) -> PrismSolution:
    """Solve a prism scene: electrode potentials per ampere (see the module docstring).

    ``contact_impedance_ohm_m2``: one value or one per electrode (default 0).
    """
    from electrosense.bem.system import contact_impedances

    sigma = float(sigma_S_per_m)
    if not (np.isfinite(sigma) and sigma > 0):
        raise ValueError(f"conductivity must be positive, got {sigma_S_per_m}")
    t0 = time.perf_counter()
    model = PrismModel(scene, n_modes, cells_in_height, **mesh_options,
                       object_zeta_m=[o.contact_impedance_ohm_m2 * sigma for o in scene.objects])
    z = contact_impedances(contact_impedance_ohm_m2, scene.n_electrodes)
    Z = model.impedance(z * sigma) / sigma
    return PrismSolution(Z, sigma, {**model.info, "seconds": time.perf_counter() - t0})
