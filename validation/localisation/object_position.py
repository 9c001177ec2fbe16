"""An object that a log passes, from its currents: whether it is there, where, and how strong.

**Model.** Where a log passes an object that the tank map does not hold, each receiver current differs from the
map's by the object's change of K. For a sphere of centre ``c`` and dipole strength ``m`` (m^3: a conductor of
radius ``a`` has ``m = a^3``, an insulator ``m = -a^3 / 2``;
:func:`~electrosense.validation.diagnosis.effects.object_sphere`) it is, to dipole and quadrupole order, the mutual
energy of the sensor's unit fields at ``c``, from the BEM's own field with the walls' first reflections
(:class:`~electrosense.validation.diagnosis.object_field.ObjectField`), added to the map's BEM-accurate tank. The
PSM's estimate beside it uses the PSM's own model of the sphere in the tank.

**Estimator.** The sensor's poses are the logged ones (a bench's robot knows them to 0.1 mm; fitting them as well
would let the track absorb part of the object's signal), and the object's height is given (default: the log's
depth, where a bench places its objects). The receiver currents, whitened by the relative noise measured on the
log, are fitted by least squares in ``(x, y, m)``: the linear best strength at every place of a 2 cm grid around
the path (the dipole term alone), then the best places at least three grid steps apart refined with the whole
model (trust-region least squares, the centre kept in the water; a trial sphere touching the sensor at a logged
pose is refused).

**Detection and its false-alarm rate.** Without an object the whitened residual ``r0`` of the baseline is white
noise, and the scan's statistic ``T = max_g (u_g . r0)^2`` (``u_g`` the unit response of a dipole at grid place
``g``) is the largest of correlated chi-square(1) variables; its null distribution is drawn by Monte Carlo on the
same grid, and an object is reported where ``T`` exceeds its ``1 - false_alarm`` quantile. A map's own error
enters the currents' covariance with its correlation along the pass (``TankMap.error_covariance``): between two
nodes it is one smooth error, as an object's signal is, and taken as independent from pose to pose it is called an
object. Measured on the seed-4 study's map (a random sensor in a 0.77 x 0.52 m box), its wall pass with no object:
``T`` = 36.7 against a threshold of 12.3 with the map's error independent (a false alarm near a corner), 4.8
against 11.9 with its covariance; the ball pass still finds the ball (242 against 12.8), 2.0 mm from it (bound
4.3 mm). On a toy pass whose model error is three times the noise, 3 cm long (test): 14 false alarms in 20 passes
taken independent, none with the covariance. Where the residuals at the fit still exceed that noise model (a model
error it does not hold), ``T`` and the covariance are scaled by the residuals' own variance factor
``chi2 / (N - 3)`` (never below 1), as a standard error is.
The PSM has no error estimate: its error (about 1 % in a tank, 20x the bench noise) swamps an object's signal.

**Bound, and what the data cannot separate.** The Cramer-Rao bound is ``(J^T J)^-1`` of the whitened residuals at
the fit (times the variance factor above): ``crb_position_rms_m`` the root of the trace of its (x, y) block, the
strength a nuisance parameter. A
sensor of revolution on a straight pass along its axis sees a place and its mirror image across the pass alike
(only the walls' reflections and changes of heading tell them apart): the best fit at least 2 cm from the best
is reported beside it with its excess chi-square, and one within 3.84 (chi-square(1), 95 %) is a place the data
do not separate from it.

Example
-------
>>> import numpy as np
>>> from electrosense.bem.free_field import meridian_field
>>> from electrosense.meshes import Tank, preset
>>> from electrosense.validation.diagnosis.object_field import ObjectField
>>> sensor, tank = preset("angels-4"), Tank((0.6, 0.6, 0.4))
>>> field = ObjectField(meridian_field(sensor, edge_length_m=0.012, reach_m=0.15, spacing_m=0.005), 0.05)
>>> poses = np.c_[np.linspace(-0.1, 0.1, 21), np.zeros(21), np.zeros(21), np.zeros(21)]
>>> base = np.full((21, 3), 1e-4)
>>> model = field_model(base, field, poses, tank, sensor)
>>> truth = np.array([0.02, 0.05, 0.0, 0.015 ** 3])
>>> fit = locate_object(model, model(truth), 1e-4, poses, tank, sensor, field, rng=0)
>>> found = [fit["centre_m"][:2], fit["alternative_centre_m"][:2]]   # the pass runs along the tank's middle:
>>> d = min(np.linalg.norm(np.subtract(c, truth[:2])) for c in found)   # its mirror image is seen alike
>>> fit["detected"], bool(d < 1e-3), fit["alternative_chi2_excess"] < 3.84
(True, True, True)
"""
from __future__ import annotations

import numpy as np
from scipy.linalg import cholesky, solve_triangular
from scipy.optimize import least_squares

from electrosense.validation.diagnosis.effects import object_sphere
from electrosense.validation.localisation.track import emitter_and_receivers

__all__ = ["locate_object", "field_model", "psm_model", "score_against", "describe", "FALSE_ALARM"]

#: probability of reporting an object where there is none (white noise of the measured level, a perfect model)
FALSE_ALARM = 0.01
#: the fit's unit of dipole strength (m^3): a conducting sphere of 1 cm radius
M_REF = 1e-6


def field_model(base_currents, field, poses, tank, sensor):
    """Receiver currents per volt (P, m) with a sphere ``theta = (x, y, z, m)`` (None: none) added to
    ``base_currents`` (a tank map's at ``poses``) by ``field`` (an ``ObjectField``)."""
    e, rec = emitter_and_receivers(sensor)
    base = np.asarray(base_currents, float)

    def currents(theta):
        sphere = None if theta is None else object_sphere(np.asarray(theta, float), field.sigma_S_per_m)
        if sphere is None:
            return base
        return base - field(poses, tank, (sphere,))[:, rec, e]

    return currents


def psm_model(psm, sensor, tank, poses, sigma_S_per_m: float, fixed_objects=()):
    """The same from the PSM, the sphere in its scene beside the ``fixed_objects`` (balls: the PSM's)."""
    from electrosense.psm import conductance

    e, rec = emitter_and_receivers(sensor)

    def currents(theta):
        sphere = None if theta is None else object_sphere(np.asarray(theta, float), sigma_S_per_m)
        objects = tuple(fixed_objects) + (() if sphere is None else (sphere,))
        return -conductance(psm, poses, sigma_S_per_m, tank=tank, objects=objects, sensor=sensor).K_S[:, rec, e]

    return currents


def _scan_places(poses, tank, sensor, z_m: float, spacing_m: float):
    """Grid places (G, 3) at height ``z_m`` around the path, in the water, clear of the sensor at every pose."""
    L = sensor.length_m
    lo, hi = tank.water_bounds_m
    margin = sensor.radius_m + 0.005
    x0, y0 = np.maximum(poses[:, :2].min(axis=0) - L, lo[:2] + margin)
    x1, y1 = np.minimum(poses[:, :2].max(axis=0) + L, hi[:2] - margin)
    g = np.stack(np.meshgrid(np.arange(x0, x1 + 1e-9, spacing_m), np.arange(y0, y1 + 1e-9, spacing_m),
                             [z_m], indexing="ij"), axis=-1).reshape(-1, 3)
    g = g[tank.distance_to_boundary_m(g).min(axis=-1) > margin]     # in the water (not the box around a cylinder)
    half = 0.5 * L - sensor.radius_m
    c, s = np.cos(poses[:, 3]), np.sin(poses[:, 3])
    clear = np.ones(len(g), bool)
    for p, ci, si in zip(poses, c, s):     # distance from the sensor's axis segment at each pose
        d = g - p[:3]
        along = np.clip(d[:, 0] * ci + d[:, 1] * si, -half, half)
        nearest = p[:3] + along[:, None] * np.array([ci, si, 0.0])
        clear &= np.linalg.norm(g - nearest, axis=1) > sensor.radius_m + 2 * margin
    return g[clear]


def _whitening(measured, noise_rel: float, model_error_rel=None, model_error_cov=None):
    """The map v -> L^-1 v for the currents' covariance ``L L^T``: white noise of ``noise_rel`` (relative), plus the
    model's error (independent, ``model_error_rel`` (P, m), or correlated, ``model_error_cov``: (N, N), or a list
    of square blocks along the diagonal, consecutive currents), each relative to ``|measured|``; ``v`` is (N,) or
    (N, k).

    >>> w = _whitening(np.ones((2, 1)), 0.1, model_error_cov=[np.zeros((1, 1)), np.zeros((1, 1))])
    >>> w(np.array([0.1, 0.2])).round(6).tolist()
    [1.0, 2.0]
    """
    a = np.abs(np.asarray(measured, float)).ravel()
    if model_error_cov is None:
        spread = float(noise_rel) if model_error_rel is None else np.hypot(noise_rel, np.asarray(model_error_rel, float))
        s = (spread * np.abs(measured)).ravel()
        return lambda v: v / (s if np.ndim(v) == 1 else s[:, None])
    blocks = [np.asarray(model_error_cov, float)] if not isinstance(model_error_cov, list) else model_error_cov
    sizes = [len(b) for b in blocks]
    if sum(sizes) != a.size or any(np.shape(b) != (k, k) for b, k in zip(blocks, sizes)):
        raise ValueError(f"model_error_cov has blocks of shapes {[np.shape(b) for b in blocks]}, the currents need "
                         f"{a.size} in all")
    edges = np.cumsum([0, *sizes])
    factors = [cholesky((b + float(noise_rel) ** 2 * np.eye(len(b))) * np.outer(a[i:j], a[i:j]), lower=True)
               for b, i, j in zip(blocks, edges[:-1], edges[1:])]
    return lambda v: np.concatenate([solve_triangular(L, v[i:j], lower=True)
                                     for L, i, j in zip(factors, edges[:-1], edges[1:])])


def locate_object(currents_of, measured, noise_rel: float, poses, tank, sensor, field, z_m: float | None = None,
                  false_alarm: float = FALSE_ALARM, spacing_m: float = 0.02, n_starts: int = 4,
                  n_null: int = 400, rng=0, model_error_rel=None, model_error_cov=None) -> dict:
    """Fit one sphere at height ``z_m`` (default: the logged poses' median height) to ``measured`` receiver
    currents (P, m, per volt) with ``currents_of(theta)``, ``theta = (x, y, z, m)`` (module doc).

    ``field``: the sensor's ``ObjectField`` (its dipole term scans the places); ``noise_rel``: relative noise
    of a current (1 sigma); ``model_error_rel``: the model's own estimated relative error (P, m), added to the
    noise in quadrature (a tank map's, written with it); ``model_error_cov``: instead, its covariance (N, N) over
    the currents in ``measured.ravel()``'s order (relative; a tank map's
    :meth:`~electrosense.validation.simulation.tank_map.TankMap.error_covariance`, smooth along a pass), added to
    the noise's: the currents are whitened by its Cholesky factor. Returns a dict: ``detected``, the scan's ``statistic``
    and ``threshold`` (at ``false_alarm``), ``centre_m``, ``strength_m3``, ``radius_m`` (of a conductor, or of
    an insulator where ``m < 0``), ``crb_position_rms_m`` (horizontal) and ``crb_sd`` of (x, y, m),
    ``crb_cov_xy_m2`` (the covariance's (x, y) block), ``chi2_without``, ``chi2_with``, ``n_currents``, and
    ``alternative_centre_m`` with its ``alternative_chi2_excess``: the best fit at least 2 cm away (a place the
    currents tell apart from the best by less than 3.84, chi-square(1) at 95 %, is one the
    data cannot separate from it: the mirror image across a straight pass, seen alike by a sensor of revolution).
    """
    measured = np.asarray(measured, float)
    poses = np.asarray(poses, float)
    z_m = float(np.median(poses[:, 2])) if z_m is None else float(z_m)
    whiten = _whitening(measured, noise_rel, model_error_rel, model_error_cov)
    r0 = whiten((measured - currents_of(None)).ravel())
    # the scan: the dipole term's unit response at each place, the linear best strength, its statistic
    places = _scan_places(poses, tank, sensor, z_m, spacing_m)
    if not len(places):
        raise ValueError(f"no place at z = {z_m:g} m around the logged path is clear of the sensor: no object to "
                         "look for")
    e, rec = emitter_and_receivers(sensor)
    D = np.concatenate([-field.unit_dipoles(poses, tank, places[i:i + 256])[:, :, rec, e]
                        for i in range(0, len(places), 256)], axis=1)                      # (P, G, m)
    D = whiten(np.moveaxis(D, 1, 0).reshape(len(places), -1).T).T                            # whitened (G, N)
    norm = np.linalg.norm(D, axis=1)
    ok = norm > 0
    U = D[ok] / norm[ok, None]
    places, norm = places[ok], norm[ok]
    proj = U @ r0
    statistic = float(np.max(proj**2))
    gen = np.random.default_rng(rng)
    null = np.max((U @ gen.standard_normal((U.shape[1], n_null))) ** 2, axis=0)
    threshold = float(np.quantile(null, 1.0 - false_alarm))
    # the best places refined with the whole model, in (x, y, m / M_REF)
    lo, hi = tank.water_bounds_m
    pad = 0.002
    s_max = 0.1**3 / M_REF     # a sphere of 10 cm radius at most

    def residual(v):
        theta = np.r_[v[:2], z_m, v[2] * M_REF]
        sphere = object_sphere(theta, field.sigma_S_per_m)
        try:
            if sphere is not None and tank.distance_to_boundary_m(theta[None, :3]).min() < sphere.radius_m:
                raise ValueError("the sphere would reach out of the water")
            return whiten((measured - currents_of(theta)).ravel())
        except ValueError:      # a sphere through the sensor or a wall: refused, as a step that does not pay
            return np.full(measured.size, 1e3)

    order = np.argsort(proj**2)[::-1]
    starts = [order[0]]
    for g in order[1:]:         # starts at least 3 grid steps apart: the best place's rivals, not its neighbours
        if len(starts) == n_starts:
            break
        if np.min(np.linalg.norm(places[starts, :2] - places[g, :2], axis=1)) >= 3 * spacing_m:
            starts.append(g)
    fits = []
    for g in starts:
        s0 = float(np.clip(proj[g] / norm[g] / M_REF, -0.5 * s_max, s_max))
        fits.append(least_squares(residual, np.r_[places[g, :2], s0 if s0 != 0 else 1e-3],
                                  bounds=(np.r_[lo[:2] + pad, -0.5 * s_max], np.r_[hi[:2] - pad, s_max]),
                                  x_scale=np.r_[0.01, 0.01, max(abs(s0), 0.1)], diff_step=1e-4))
    fits.sort(key=lambda f: f.cost)
    best = fits[0]
    rivals = [f for f in fits[1:] if np.linalg.norm(f.x[:2] - best.x[:2]) > 0.02]
    theta = np.r_[best.x[:2], z_m, best.x[2] * M_REF]
    # where the residuals exceed the noise model (a model error it does not hold), their own scatter scales the
    # statistic and the covariance, as a standard error does; never below the noise model's
    variance_factor = max(2 * best.cost / max(measured.size - 3, 1), 1.0)
    info = best.jac.T @ best.jac
    cov = (np.linalg.inv(info) if np.linalg.cond(info) < 1e14 else np.full((3, 3), np.inf)) * variance_factor
    sd = np.sqrt(np.maximum(np.diag(cov), 0.0)) * np.r_[1.0, 1.0, M_REF]
    sphere = object_sphere(theta, field.sigma_S_per_m)
    return {"detected": bool(statistic / variance_factor > threshold), "statistic": statistic / variance_factor,
            "statistic_noise_model": statistic, "residual_variance_factor": variance_factor, "threshold": threshold,
            "false_alarm": float(false_alarm), "centre_m": theta[:3].tolist(), "strength_m3": float(theta[3]),
            "conducting": bool(theta[3] > 0), "radius_m": None if sphere is None else float(sphere.radius_m),
            "crb_position_rms_m": float(np.sqrt(max(cov[0, 0] + cov[1, 1], 0.0))),
            "crb_sd": {"x_m": float(sd[0]), "y_m": float(sd[1]), "strength_m3": float(sd[2])},
            "crb_cov_xy_m2": cov[:2, :2].tolist(),
            "chi2_without": float(r0 @ r0), "chi2_with": float(2 * best.cost), "n_currents": int(measured.size),
            "places_scanned": int(len(places)),
            "alternative_centre_m": [*rivals[0].x[:2].tolist(), z_m] if rivals else None,
            "alternative_chi2_excess": float(2 * (rivals[0].cost - best.cost)) if rivals else None}


def score_against(fit: dict, true_centre_m) -> dict:
    """``fit`` with its horizontal error against ``true_centre_m`` (x, y[, z]): ``position_error_m`` of the best
    fit, and ``position_error_either_m`` of the nearer of it and an alternative the data do not separate from it
    (``alternative_chi2_excess`` below 3.84)."""
    true = np.asarray(true_centre_m, float)[:2]
    out = dict(fit)
    out["position_error_m"] = float(np.linalg.norm(np.asarray(fit["centre_m"][:2]) - true))
    either = [out["position_error_m"]]
    if fit.get("alternative_centre_m") is not None and fit["alternative_chi2_excess"] < 3.84:
        either.append(float(np.linalg.norm(np.asarray(fit["alternative_centre_m"][:2]) - true)))
    out["position_error_either_m"] = min(either)
    return out


def describe(f: dict) -> str:
    """One line on a fit of :func:`locate_object` (or :func:`score_against`)."""
    seen = (f"detected (statistic {f['statistic']:.3g} > {f['threshold']:.3g}, false alarm {f['false_alarm']:g})"
            if f["detected"] else f"none detected (statistic {f['statistic']:.3g} <= {f['threshold']:.3g})")
    x, y = (1e3 * v for v in f["centre_m"][:2])
    kind = "conducting" if f["conducting"] else "insulating"
    text = (f"{seen}; best sphere at ({x:.1f}, {y:.1f}) mm, {kind}, radius {1e3 * f['radius_m']:.1f} mm, bound "
            f"{1e3 * f['crb_position_rms_m']:.2f} mm")
    if "position_error_m" in f:
        text += f"; error {1e3 * f['position_error_m']:.2f} mm"
    if f.get("alternative_chi2_excess") is not None and f["alternative_chi2_excess"] < 3.84:
        ax, ay = (1e3 * v for v in f["alternative_centre_m"][:2])
        text += (f"; ({ax:.1f}, {ay:.1f}) mm fits as well (chi2 +{f['alternative_chi2_excess']:.2g}: the data do "
                 "not separate them" + (f", error there {1e3 * f['position_error_either_m']:.2f} mm)"
                                        if "position_error_m" in f else ")"))
    return text
