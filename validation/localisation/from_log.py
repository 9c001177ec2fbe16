"""``esense localise``'s work: a bench log's track from its currents, by a tank map and by the PSM, with their bounds.

For each model: the track, by default the maximum a posteriori track under a motion model
(:func:`~electrosense.validation.localisation.smoother.smooth_track`; ``motion=None``: each sample alone,
:func:`~electrosense.validation.localisation.track.track`), its error against the logged poses
(``position_rms_m``, ``heading_rms_rad``), and the Cramer-Rao bound of that estimator and model at the logged poses
with the noise measured on the log (``crb_position_rms_m``: the posterior bound with the motion prior, or the
per-sample bound; ``crb_per_sample_position_rms_m``: the per-sample bound, always); written to ``localise.json``
with the motion model and its parameters, and a figure of the tracks against the logged one (``localise.png``).

The noise is measured from the log itself: second differences of log |I| along each pass
(:func:`electrosense.validation.comparison.metrics.noise_level`), which a smooth path leaves to the noise
(``noise_rel`` overrides it, e.g. with the bench's specified noise).

Example
-------
>>> summary = localise_log("run.csv", "tank.map.npz", "out/")  # doctest: +SKIP
>>> summary["map"]["position_rms_m"] < 1.5 * summary["map"]["crb_position_rms_m"]  # doctest: +SKIP
True
"""
from __future__ import annotations

import json
import time
from pathlib import Path

import numpy as np

from electrosense.validation.localisation.smoother import (
    DEFAULT_MOTION,
    ROTATION_GAUGE_SIGMA_RAD,
    ROUND_TANK_FIRST_VELOCITY_SIGMA,
    MotionModel,
    expected_error,
    posterior_crb,
    smooth_track,
)
from electrosense.validation.localisation.track import (
    cramer_rao,
    emitter_and_receivers,
    heading_error,
    map_currents,
    psm_currents,
    track,
)

__all__ = ["localise_log", "localise_observations", "model_summary"]

METHOD_SMOOTHER = ("maximum a posteriori track over each pass under the motion model (Gauss-Newton on all poses, each "
                   "step by a Kalman filter and Rauch-Tung-Striebel smoother of the linearised problem, started from "
                   "an iterated extended Kalman filter from the first logged pose, stiffer priors solved first), "
                   "currents whitened by the noise; Cramer-Rao bound: the posterior bound (Fisher information of "
                   "the currents at the logged poses plus the motion prior's); the per-sample bound (J^T S^-1 J)^-1 "
                   "beside it; with a map, tracked again with each current weighted by the noise and the map's "
                   "estimated error at the first track's poses in quadrature (the bounds of the noise alone)")
OBJECT_METHOD = ("one sphere at a given height (default the log's) fitted to the currents whitened by the noise, "
                 "the sensor at the logged poses: the map's currents plus the sphere's change of K from the BEM's "
                 "field (dipole and quadrupole, walls' first reflections), or the PSM with the sphere; started from "
                 "a scan of the dipole term over a 2 cm grid around the path; detected where the scan's statistic "
                 "exceeds its Monte Carlo null quantile at the false-alarm rate; the map's own estimated error in "
                 "the currents' covariance, correlated along the pass as between the map's nodes; the statistic "
                 "and the bound scaled by the residuals' variance factor where they exceed it; Cramer-Rao bound "
                 "from the fit's Jacobian (horizontal position, strength as nuisance)")
METHOD_PER_SAMPLE = ("per-sample maximum likelihood (Levenberg-Marquardt on the currents whitened by the noise), each "
                     "sample started from the previous estimate, the first from the logged first pose; Cramer-Rao "
                     "bound (J^T S^-1 J)^-1 of each model at the logged poses")


def _rms(x) -> float:
    return float(np.sqrt(np.mean(np.square(x)))) if len(x) else float("nan")


def _position_rms(C) -> float:
    return float(np.sqrt(np.nanmean(C[:, 0, 0] + C[:, 1, 1])))


#: in a round tank the heading against the radius is scored where the sensor's centre is this far from the axis
OFF_AXIS_M = 0.02


def model_summary(name, model, currents, poses, noise_rel, t_s=None, motion: MotionModel | None = None,
                  passes=None, model_error=None, round_tank: bool = False) -> tuple[dict, np.ndarray]:
    """Track ``currents`` (P, m, per volt) with ``model`` from the first logged pose: under ``motion`` over the
    whole log (:func:`smooth_track`, ``t_s`` (P,) s and ``passes`` index arrays), or each sample alone
    (``motion=None``, :func:`track`); errors against ``poses`` (P, 4) and the Cramer-Rao bounds at them;
    (summary, estimated (P, 3)).

    ``model_error``: ``q (P, 3) -> (P, m)`` the model's own estimated relative error (a tank map's). The track is
    then solved twice: with the noise alone, then with each current weighted by the noise and the model's error at
    the first track's poses in quadrature (weighted least squares: a receiver the model knows less well counts
    less). The bounds stay those of the noise alone (``crb_position_rms_m``, what the currents can tell with a
    perfect model); ``crb_position_rms_m_model_error`` is the bound under the weighted noise model.

    ``round_tank``: the model is the same at every rotation about the tank's axis (a round tank without objects):
    the first logged pose gives the angle about it (:func:`~.smoother.first_state_prior`), and the errors of what
    the currents do fix, the distance from the axis and the heading against the radius, are reported beside."""
    t0 = time.perf_counter()
    q_true = poses[:, [0, 1, 3]]
    t_s = np.arange(len(poses), dtype=float) if t_s is None else np.asarray(t_s, float)

    def solve(spread):
        if motion is None:
            t = track(model, currents, q_true[0], spread)
            return t.poses, int(t.converged.sum()), {"chi2": t.chi2}
        t = smooth_track(model, currents, t_s, q_true[0], motion, spread, passes, round_tank=round_tank)
        return t.poses, int(len(poses) if t.converged else 0), {"chi2": t.chi2}

    est, n_conv, fit = solve(noise_rel)
    spread = noise_rel
    if model_error is not None and np.isfinite(est).all():
        spread = np.hypot(noise_rel, model_error(est))
        est, n_conv, fit = solve(spread)
    seconds = time.perf_counter() - t0
    ok = np.isfinite(est[:, 0])
    d_pos = np.linalg.norm(est[ok, :2] - q_true[ok, :2], axis=1)
    d_yaw = heading_error(est[ok, 2], q_true[ok, 2])
    at = model(q_true)
    crb = None
    if at is not None:
        C1 = cramer_rao(at[1], currents, noise_rel)
        gauge = q_true if round_tank else None
        C = C1 if motion is None else posterior_crb(at[1], currents, t_s, motion, noise_rel, passes, gauge)
        if motion is not None:
            bias, scatter = expected_error(at[1], currents, t_s, motion, noise_rel, q_true, passes,
                                           round_tank=round_tank)
            expected = float(np.sqrt(np.nanmean(np.sum(bias[:, :2] ** 2 + scatter[:, :2] ** 2, axis=1))))
        crb = {"crb_position_rms_m": _position_rms(C), "crb_position_median_m": float(np.median(
               np.sqrt(C[:, 0, 0] + C[:, 1, 1]))), "crb_heading_rms_rad": float(np.sqrt(np.mean(C[:, 2, 2]))),
               "crb_per_sample_position_rms_m": _position_rms(C1), "crb_position_m": np.sqrt(C[:, 0, 0] + C[:, 1, 1]),
               "crb_per_sample_position_m": np.sqrt(C1[:, 0, 0] + C1[:, 1, 1])}
        if np.ndim(spread):
            Cw = (cramer_rao(at[1], currents, spread) if motion is None
                  else posterior_crb(at[1], currents, t_s, motion, spread, passes, gauge))
            crb["crb_position_rms_m_model_error"] = _position_rms(Cw)
    chi2 = fit["chi2"][np.isfinite(fit["chi2"])]
    out = {"model": name, "samples": int(len(poses)), "estimated": int(ok.sum()), "converged": n_conv,
           "position_rms_m": _rms(d_pos),
           "position_max_m": float(d_pos.max()) if len(d_pos) else float("nan"),
           "position_median_m": float(np.median(d_pos)) if len(d_pos) else float("nan"),
           "heading_rms_rad": _rms(d_yaw), "seconds": seconds,
           "chi2_per_current": float(chi2.sum() / (chi2.size * currents.shape[1])) if chi2.size else None}
    if round_tank:   # what the currents fix in a round tank, whatever the angle about the axis
        radius = lambda q: np.hypot(q[:, 0], q[:, 1])  # noqa: E731
        against_radius = lambda q: q[:, 2] - np.arctan2(q[:, 1], q[:, 0])  # noqa: E731
        out["distance_from_axis_rms_m"] = _rms(radius(est[ok]) - radius(q_true[ok]))
        off_axis = ok & (radius(q_true) > OFF_AXIS_M)    # the radius has a direction
        out["heading_against_radius_rms_rad"] = _rms(heading_error(against_radius(est[off_axis]),
                                                                   against_radius(q_true[off_axis])))
        out["round_tank"] = ("the currents are the same at every rotation about the tank's axis: the first logged "
                             f"pose gives the angle about it (to {1e3 * ROTATION_GAUGE_SIGMA_RAD:g} mrad; the first "
                             f"velocity's prior {ROUND_TANK_FIRST_VELOCITY_SIGMA[0]:g} m/s, "
                             f"{ROUND_TANK_FIRST_VELOCITY_SIGMA[2]:g} rad/s)"
                             + (", the motion prior carries it" if motion else "; each sample alone leaves it open"))
    for k in ("crb_position_rms_m", "crb_heading_rms_rad", "crb_position_median_m", "crb_per_sample_position_rms_m"):
        out[k] = None if crb is None else crb[k]
    out["position_error_over_crb"] = None if crb is None else out["position_rms_m"] / crb["crb_position_rms_m"]
    if np.ndim(spread):
        out["noise_model"] = "the noise and the map's estimated error at the first track's poses, in quadrature"
        out["crb_position_rms_m_model_error"] = None if crb is None else crb["crb_position_rms_m_model_error"]
    if motion is not None:
        out["expected_position_rms_m"] = None if crb is None else expected
        out["position_error_over_expected"] = None if crb is None else out["position_rms_m"] / expected
    if crb is None:
        out["note"] = f"the {name} does not cover every logged pose: no bound"
    if not ok.all():
        out["note"] = (f"the {name} lost the track at sample {int(np.argmin(ok))} of {len(ok)} (a pose it does not "
                       "cover)")
    elif out["chi2_per_current"] is not None and out["chi2_per_current"] > 4.0:
        out["note"] = (f"the residuals are {np.sqrt(out['chi2_per_current']):.1f} times the noise model: the {name}'s "
                       "error" + ("" if motion is None else " or a motion prior too stiff for this robot's path")
                       + " dominates")
    out["_crb_position_m"] = None if crb is None else crb["crb_position_m"]
    out["_crb_per_sample_position_m"] = None if crb is None else crb["crb_per_sample_position_m"]
    return out, est


def localise_observations(obs, tank_map, psm=None, noise_rel: float | None = None,
                          motion: MotionModel | None = DEFAULT_MOTION, progress=None, with_psm: bool = True,
                          find_object: bool = False, object_z_m: float | None = None, true_object_m=None) -> dict:
    """Track one run (:class:`~electrosense.validation.diagnosis.observations.Observations`) with the map and
    (``with_psm``) the PSM, under ``motion`` (``None``: each sample alone); a dict of summaries, estimated tracks
    and the noise used; with ``find_object``, an object the run passes (:func:`object_summary`) under
    ``"object"``."""
    from electrosense.psm.images import has_images as psm_has_images
    from electrosense.validation.comparison.metrics import noise_level
    from electrosense.validation.diagnosis.forward import effect_objects
    from electrosense.validation.simulation.models import calibrated_psm, poses_reached
    from electrosense.validation.simulation.tank_map import log_in_map_scene

    say = progress or (lambda s: None)
    obs = log_in_map_scene(tank_map, obs)
    if obs.n_receivers < 3:
        raise ValueError(f"{obs.n_receivers} receiver current(s) per sample cannot fix (x, y, heading): localisation "
                         "needs a sensor with at least 3 receivers")
    source = obs.source or "the log"
    z = np.unique(np.round(obs.poses[:, 2], 6))
    if len(z) > 1:
        raise ValueError(f"{source}: its poses lie at {len(z)} depths; localisation is in the plane of one depth")
    z_m = float(obs.poses[0, 2])
    # the logged poses score the track and place the bounds: each must put the sensor in the map's water
    in_water, why = poses_reached(None, obs.sensor, obs.tank, tuple(obs.objects), obs.poses)
    if not in_water.all():
        raise ValueError(f"{source}: {np.count_nonzero(~in_water)} of {obs.n_poses} logged poses put the sensor "
                         f"where the map's scene has no water ({why.replace('pose ', 'sample ', 1)})")
    currents = obs.currents_A / obs.U_V[:, None]
    zero = np.argwhere(currents == 0)
    if len(zero):   # the tracks fit log |I| (each current's relative noise)
        i, k = zero[0]
        raise ValueError(f"{source}: sample {i}: receiver current {k + 1} of the log is 0 ({len(zero)} zero "
                         "reading(s)); a track fits the currents' logarithm: leave such samples out")
    measured = noise_rel is None
    if measured:
        try:
            noise_rel = noise_level(np.log(np.abs(currents)), obs.pass_indices())
        except ValueError as exc:   # no pass of three samples: nothing to measure it on
            lengths = ", ".join(str(len(i)) for i in obs.pass_indices())
            raise ValueError(f"{obs.source or 'the log'}: {exc} (its passes have {lengths} samples); --noise "
                             "gives it") from None
    say(f"{obs.n_poses} samples, {'measured' if measured else 'given'} noise {100 * noise_rel:.4f} %"
        + ("" if motion is None else f"; motion prior: acceleration {motion.acceleration_psd_m2_per_s3:g} m^2/s^3, "
                                     f"turn {motion.turn_psd_rad2_per_s3:g} rad^2/s^3"))
    models = {"map": map_currents(tank_map, z_m, obs.sigma_S_per_m)}
    result = {"noise_rel": float(noise_rel), "z_m": z_m, "tracks": {}, "motion": motion}
    not_balls = [o.label for o in obs.objects if o not in effect_objects(obs.objects)]   # the PSM's: balls only
    if with_psm and not psm_has_images(obs.tank):
        with_psm = False
        result["psm_left_out"] = f"the PSM's images are a box's: it has no model of a {type(obs.tank).__name__}"
        say(result["psm_left_out"])
    elif with_psm and not_balls:
        with_psm = False
        result["psm_left_out"] = f"the PSM's object term is a ball's: it has no model of the {', '.join(not_balls)}"
        say(result["psm_left_out"])
    if with_psm:
        psm = calibrated_psm(obs.sensor) if psm is None else psm
        models["psm"] = psm_currents(psm, obs.sensor, obs.tank, z_m, obs.sigma_S_per_m, tuple(obs.objects))
    for name, model in models.items():
        say(f"tracking with the {name}")
        error = None
        if name == "map":
            def error(q):
                return tank_map.estimated_error(np.c_[q[:, :2], np.full(len(q), z_m), q[:, 2]])
        summary, est = model_summary(name, model, currents, obs.poses, noise_rel, obs.t_s, motion,
                                     obs.pass_indices(), model_error=error,
                                     round_tank=name == "map" and tank_map.frame.cylinder and tank_map.frame.symmetric)
        result[name] = summary
        result["tracks"][name] = est
    if find_object:
        result["object"] = object_summary(obs, tank_map, psm if with_psm else None, currents, noise_rel,
                                          object_z_m, true_object_m, say)
    return result


#: poses per block of the map's error covariance in the object search: the correlation falls over the nodes'
#: spacing (centimetres), so a long log's blocks are independent and its memory grows with its length, not its square
ERROR_BLOCK_POSES = 500


def _error_blocks(tank_map, poses) -> list:
    """The map's error covariance at ``poses`` as blocks of :data:`ERROR_BLOCK_POSES` consecutive poses."""
    return [tank_map.error_covariance(poses[i:i + ERROR_BLOCK_POSES])
            for i in range(0, len(poses), ERROR_BLOCK_POSES)]


def object_summary(obs, tank_map, psm, currents, noise_rel: float, z_m: float | None = None, true_centre_m=None,
                   progress=None) -> dict:
    """An object the log passes, by the map (and the PSM where given): :func:`~electrosense.validation.
    localisation.object_position.locate_object` at the logged poses, scored against ``true_centre_m`` where
    known."""
    from electrosense.psm.conductance import PlacementError
    from electrosense.validation.diagnosis.object_field import sensor_object_field
    from electrosense.validation.localisation.object_position import (
        FALSE_ALARM,
        field_model,
        locate_object,
        psm_model,
        score_against,
    )

    say = progress or (lambda s: None)
    e, rec = emitter_and_receivers(obs.sensor)
    field = sensor_object_field(obs.sensor, obs.sigma_S_per_m)
    base = -tank_map.conductance(obs.poses, obs.sigma_S_per_m)[:, rec, e]
    models = {"map": field_model(base, field, obs.poses, obs.tank, obs.sensor)}
    if psm is not None:
        models["psm"] = psm_model(psm, obs.sensor, obs.tank, obs.poses, obs.sigma_S_per_m, tuple(obs.objects))
    out = {"method": OBJECT_METHOD, "false_alarm": FALSE_ALARM,
           "z_m": float(np.median(obs.poses[:, 2])) if z_m is None else float(z_m),
           "true_centre_m": None if true_centre_m is None else [float(v) for v in true_centre_m]}
    if hasattr(obs.tank, "radius_m"):
        out["note"] = ("the object's field takes the curved wall's reflection in its tangent plane where the "
                       "object's radius meets it (first reflections only, as a box's walls)")
    for name, model in models.items():
        say(f"looking for an object with the {name}")
        try:
            fit = locate_object(model, currents, noise_rel, obs.poses, obs.tank, obs.sensor, field, z_m,
                                model_error_cov=_error_blocks(tank_map, obs.poses) if name == "map" else None)
        except PlacementError as exc:   # the PSM's spheres through a wall at a logged pose: its search left out,
            out[f"{name}_left_out"] = f"the {name.upper()} refuses a logged pose: {exc}"   # the map's kept
            say(out[f"{name}_left_out"])
            continue
        out[name] = fit if true_centre_m is None else score_against(fit, true_centre_m)
    return out


def localise_log(log_path, map_path, outdir, psm=None, figure: bool = True, motion: MotionModel | None = DEFAULT_MOTION,
                 noise_rel: float | None = None, progress=None, find_object: bool = True,
                 object_z_m: float | None = None, true_object_m=None) -> dict:
    """Read a bench log and a map, track (under ``motion``; ``None``: each sample alone), look for an object the
    log passes (``find_object``; at height ``object_z_m``, scored against ``true_object_m`` where given), write
    ``localise.json`` (and ``localise.png``); the summary."""
    from electrosense.validation.bench.log import read_bench_log
    from electrosense.validation.diagnosis.observations import from_bench_logs
    from electrosense.validation.simulation.tank_map import load_tank_map

    obs = from_bench_logs([read_bench_log(log_path)], *((3, "to measure the noise on the log; --noise gives it")
                                                        if noise_rel is None else (1, "")))
    tank_map = load_tank_map(map_path)
    res = localise_observations(obs, tank_map, psm, noise_rel, motion, progress, find_object=find_object,
                                object_z_m=object_z_m, true_object_m=true_object_m)
    outdir = Path(outdir)
    outdir.mkdir(parents=True, exist_ok=True)
    summary = {"log": Path(log_path).name, "map_file": Path(map_path).name, "noise_rel": res["noise_rel"],
               "map": {k: v for k, v in res["map"].items() if not k.startswith("_")},
               "psm": ({k: v for k, v in res["psm"].items() if not k.startswith("_")} if "psm" in res
                       else {"left_out": res["psm_left_out"]}),
               "noise_measured": noise_rel is None,
               "method": METHOD_PER_SAMPLE if motion is None else METHOD_SMOOTHER,
               "motion_model": None if motion is None else motion.record(),
               "map_estimated_error_rms": float(np.sqrt(np.mean(tank_map.estimated_error(obs.poses) ** 2)))}
    if "object" in res:
        summary["object"] = res["object"]
    (outdir / "localise.json").write_text(json.dumps(summary, indent=2))
    np.savez(outdir / "localise_tracks.npz", logged=obs.poses, **res["tracks"])
    if figure:
        from electrosense.validation.localisation.figure import track_figure

        track_figure(obs, res, outdir / "localise.png")
    return summary
