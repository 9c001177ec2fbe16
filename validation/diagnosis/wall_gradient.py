"""The BEM's own change of K when the tank's walls, floor or free surface are elsewhere than believed.

A wall candidate (``tank_size``, ``water_depth``) is fitted through the effect
model, a fast model whose change of K with the walls is off the BEM's by tens
of percent near them: fitted so, a tank 2 cm longer than believed is found at
1.6 cm and explains nothing held out. Here the change comes from the BEM:

1. at every BEM pose of the anchored baseline the sweep gives ``dK/dn`` for
   each region of the tank moving outward (Hadamard's shape derivative from
   that pose's own solution, :mod:`electrosense.bem.shape_derivative`); the four
   scene parameters of the candidates follow: ``dLx`` (both x walls out by
   half of it), ``dLy``, the free surface up by ``d_surface``, the floor up by
   ``d_floor``; as derivatives of log |K| of every electrode pair, ``G_bem``;
2. the effect model's derivatives ``G_eff`` at every sample, by central
   differences (the effect model is fast);
3. their difference, known at the BEM poses, interpolated along each pass
   (monotone cubic in the distance travelled, :func:`~.pose_gradient.along_passes`,
   with its leave-one-out error): the effect model's derivative is the shape,
   the BEM corrects it;
4. a changed scene is predicted as the effect model's relative change (its
   nonlinearity in the wall's position) plus the first-order correction
   ``theta . (G_bem - G_eff)``. At a BEM pose and to first order in
   ``theta`` it *is* the BEM.

Example
-------
>>> import numpy as np
>>> from electrosense.meshes.tank import TANK_REGIONS
>>> dW = np.zeros((1, 6, 2, 2))
>>> dW[0, TANK_REGIONS.index("free_surface")] = [[1.0, -1.0], [-1.0, 1.0]]
>>> K = np.array([[[2.0, -2.0], [-2.0, 2.0]]])
>>> wall_log_derivatives(dW, K, TANK_REGIONS)[0, :, 0].round(3).tolist()   # d log|K_12| / d(dLx, dLy, surface, floor)
[-0.0, -0.0, 0.5, 0.0]
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from electrosense.validation.diagnosis.pose_gradient import along_passes, arc_length, pair_log

__all__ = ["WALL_PARAMETERS", "WALL_STEPS_M", "WallGradient", "wall_log_derivatives", "wall_parameters",
           "wall_gradient"]

#: the scene parameters of the wall candidates (m): the tank longer along x and y (both walls move out by
#: half), the free surface higher, the floor higher
WALL_PARAMETERS = ("dLx_m", "dLy_m", "d_surface_m", "d_floor_m")

#: central-difference steps of the effect model along them (m)
WALL_STEPS_M = np.array([2e-3, 2e-3, 2e-3, 2e-3])


def wall_log_derivatives(dK_regions: np.ndarray, K: np.ndarray, region_names) -> np.ndarray:
    """(A, 4, pairs) d log|K_ij| / d(:data:`WALL_PARAMETERS`) from the regions' shape derivatives (A, R, n, n)
    (each region outward by one metre) and K (A, n, n) at the same conductivity."""
    names = list(region_names)
    R = lambda name: dK_regions[:, names.index(name)]  # noqa: E731
    dK = np.stack([0.5 * (R("wall_x-") + R("wall_x+")), 0.5 * (R("wall_y-") + R("wall_y+")),
                   R("free_surface"), -R("floor")], axis=1)  # (A, 4, n, n)
    n = K.shape[-1]
    iu = np.triu_indices(n, 1)
    return dK[..., iu[0], iu[1]] / K[:, None, iu[0], iu[1]]


def wall_parameters(obs, tank, poses: np.ndarray, idx: np.ndarray) -> np.ndarray:
    """(p, 4) the :data:`WALL_PARAMETERS` of a scene (``tank``, ``poses`` (p, 4) of the samples ``idx``) against
    the believed one: the sizes' differences, and the free surface and the floor as seen from the sensor."""
    believed = obs.tank
    z0 = obs.poses[idx, 2]
    z1 = np.asarray(poses, float)[:, 2]
    out = np.empty((len(z0), 4))
    out[:, 0] = tank.size_m[0] - believed.size_m[0]
    out[:, 1] = tank.size_m[1] - believed.size_m[1]
    out[:, 2] = (tank.free_surface_z_m - z1) - (believed.free_surface_z_m - z0)
    out[:, 3] = (z0 - believed.floor_z_m) - (z1 - tank.floor_z_m)
    return out


@dataclass
class WallGradient:
    """The first-order correction of the effect model's change of K with the walls (module doc).

    ``dG`` (P, 4, pairs): G_bem - G_eff at every sample; ``nodes`` (A,) the samples where the BEM gave it;
    ``loo`` (A, 4, pairs) its leave-one-out interpolation error there; ``G_bem`` (A, 4, pairs).
    """

    dG: np.ndarray
    nodes: np.ndarray
    loo: np.ndarray
    G_bem: np.ndarray

    def log_change(self, idx: np.ndarray, theta: np.ndarray) -> np.ndarray:
        """(p, pairs): the correction of log|K| at samples ``idx`` for wall parameters ``theta`` (p, 4)."""
        return np.einsum("pk,pkq->pq", np.asarray(theta, float), self.dG[np.asarray(idx)])

    def summary(self, rec: list) -> dict:
        """RMS of the BEM's and the correction's change of the receiver currents for a 1 cm move of each
        parameter, beside the correction's leave-one-out error: how far the effect model was from the BEM."""
        rms = lambda x: float(np.sqrt(np.mean(np.square(x)))) if np.size(x) else 0.0  # noqa: E731
        out = {}
        for k, name in enumerate(WALL_PARAMETERS):
            out[name] = {"bem_change_per_cm": rms(0.01 * self.G_bem[:, k, rec]),
                         "correction_per_cm": rms(0.01 * self.dG[self.nodes][:, k, rec]),
                         "loo_per_cm": rms(0.01 * self.loo[:, k, rec])}
        out["bem_poses"] = int(len(self.nodes))
        out["how"] = ("the BEM's shape derivative at its poses (each pose's own solution), less the effect model's "
                      "central differences, interpolated along each pass; a changed scene is the effect model's "
                      "change plus this first-order correction")
        return out


def wall_gradient(problem, dK_regions: np.ndarray, region_names, K_bem: np.ndarray) -> WallGradient | None:
    """The :class:`WallGradient` of ``problem`` (its observations, passes and effect model) from the BEM's
    region derivatives ``dK_regions`` (P, R, n, n; NaN where the BEM was not run) and K there (P, n, n)."""
    from electrosense.validation.diagnosis.effects import library
    from electrosense.validation.diagnosis.fitting import scenario

    obs = problem.obs
    if obs.tank is None:
        return None
    have = np.flatnonzero(np.all(np.isfinite(dK_regions.reshape(len(dK_regions), -1)), axis=1))
    if not len(have):
        return None
    G_bem = wall_log_derivatives(dK_regions[have], K_bem[have], region_names)
    lib = library(obs)
    forms = [(lib["tank_size"][0], lambda h: (h, 0.0)), (lib["tank_size"][0], lambda h: (0.0, h)),
             (lib["water_depth"][0], lambda h: (h,)), (lib["water_depth"][1], lambda h: (h,))]
    every = np.arange(obs.n_poses)
    L0 = pair_log(problem.K_effect0)
    G_eff = np.zeros((obs.n_poses, 4, L0.shape[-1]))
    for k, ((effect, theta), h) in enumerate(zip(forms, WALL_STEPS_M)):
        sides = []
        for sign in (1.0, -1.0):
            try:
                sc = scenario(problem, [effect], np.array(theta(sign * h)), every)
                sides.append((sign, pair_log(problem._effect_K(sc))))
            except (ValueError, np.linalg.LinAlgError, FloatingPointError):
                continue
        if len(sides) == 2:
            G_eff[:, k] = (sides[0][1] - sides[1][1]) / (2 * h)
        elif sides:
            G_eff[:, k] = sides[0][0] * (sides[0][1] - L0) / h
    s = arc_length(obs.sensor, obs.poses, obs.pass_indices())
    dG, loo = along_passes(G_bem - G_eff[have], have, s, obs.pass_indices())
    return WallGradient(dG, have, loo, G_bem)
