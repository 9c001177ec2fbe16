"""The chosen explanation evaluated by the BEM itself: is the effect model's answer the reference's?

Geometric effects (walls, depth, an object, the robot's frame) are fitted with
a fast effect model, and a contact impedance through effective areas (a
lumped series network). Once an explanation is chosen, its fitted scene is
solved by the BEM at a few of the baseline's BEM poses (where the baseline
*is* the BEM, so that the two predictions differ only by the effect's model):
a new tank, the object meshed, the contact impedance as the BEM's boundary
condition. The gap of the bench against both predictions is reported there;
where the BEM leaves more than the noise floor that the effect model claimed
to reach, the diagnosis says that its effect model, not the data, made the
answer.

Where the BEM leaves more than both the effect model's own gap and what the
noise leaves at these poses (the floor, plus two standard deviations of an RMS
of that many samples), the parameters are then refined on the BEM itself, a defect correction
(Gauss-Newton on the BEM's residual with the effect model's Jacobian: each
step one BEM solve of the changed scene; it converges while the effect model's
sensitivities are within a factor of two of the BEM's, and a step that does
not lower the BEM's residual is not taken): a wall 3 cm in that the effect
model put 2.3 cm in is found where the BEM puts it.

Example
-------
>>> from electrosense.validation.diagnosis.bem_check import needs_bem_check
>>> from electrosense.validation.diagnosis.effects import library
>>> lib = library()
>>> needs_bem_check([lib["conductivity"][0]]), needs_bem_check([lib["tank_size"][0]])
(False, True)
"""
from __future__ import annotations

import numpy as np

from electrosense.validation.diagnosis.fitting import _split

__all__ = ["needs_bem_check", "bem_check", "taylor_remainder_bound", "check_pose_count", "CHECK_RESIDUALS"]


#: residuals (poses x receivers) a BEM check compares: an effect model as exact as the BEM leaves an RMS of them
#: above 1.5x the noise floor (the check's refusal) with probability P(chi2_30 / 30 > 2.25) = 1e-4, and a model error
#: e shows as sqrt(floor^2 + e^2) whatever their number; more poses only sharpen the decision near its threshold
CHECK_RESIDUALS = 30

#: the fewest poses of a check: a refinement on the BEM at one or two would fit their noise
MIN_CHECK_POSES = 4


def check_pose_count(n_receivers: int) -> int:
    """BEM poses of a check: enough for :data:`CHECK_RESIDUALS` residuals, at least :data:`MIN_CHECK_POSES`.

    >>> check_pose_count(5), check_pose_count(2), check_pose_count(12)
    (6, 15, 4)
    """
    return max(MIN_CHECK_POSES, -(-CHECK_RESIDUALS // max(int(n_receivers), 1)))


def needs_bem_check(effects) -> bool:
    """Whether the explanation goes through an approximate model: a geometric effect or a contact impedance."""
    return any(e.geometric or e.name == "contact_impedance" for e in effects)


def taylor_remainder_bound(problem, candidate, anchors: np.ndarray) -> np.ndarray | None:
    """How far a BEM check of a pose or heading offset could move from what the baseline already says, per pose.

    A pose offset is predicted from the BEM's own derivatives (:mod:`.pose_gradient`): at the baseline's BEM
    poses ``anchors``, where the check is made, the gradient *is* the BEM's, and the step's only approximation is
    its Taylor remainder. The whole second-order term there (the diagonal second derivatives, as the prediction
    has them), doubled for the cross derivatives that it leaves out and for those second derivatives' own error,
    bounds it: where that moves no receiver current by a third of the noise, a BEM solve at the moved pose cannot
    differ from the prediction by what the noise could show, and only the other poses need solving.

    Returns the doubled second-order term at each anchor (relative, the largest over the receivers), or None for
    any candidate other than a pose offset (or a baseline without pose derivatives).
    """
    from electrosense.validation.diagnosis.anchored import _receiver_entries
    from electrosense.validation.diagnosis.fitting import scenario
    from electrosense.validation.diagnosis.pose_gradient import POSE_AXES

    pg = problem.pose_gradient
    if pg is None or not len(anchors) or any(e.name != "pose_offset" for e in candidate.effects):
        return None
    idx = np.asarray(anchors)
    obs = problem.obs
    moved = scenario(problem, candidate.effects, np.asarray(candidate.fit.theta, float), np.arange(obs.n_poses))
    d = moved.poses[idx][:, POSE_AXES] - obs.poses[idx][:, POSE_AXES]
    d[:, 2] = np.angle(np.exp(1j * d[:, 2]))
    second = 0.5 * np.einsum("pk,pkq->pq", d**2, pg.H[idx])[:, _receiver_entries(obs.sensor)]
    return 2.0 * np.max(np.abs(second), axis=1) if second.size else np.zeros(len(idx))


def _jacobian(fun, theta: np.ndarray, steps: np.ndarray) -> np.ndarray:
    """Central differences of ``fun`` at ``theta``, one-sided where the model refuses one side."""
    columns = []
    for j in range(theta.size):
        h = np.zeros_like(theta)
        h[j] = steps[j]
        sides = []
        for sign in (1.0, -1.0):
            try:
                sides.append((sign, fun(theta + sign * h)))
            except ValueError:
                continue
        if not sides:
            raise ValueError(f"the effect model refuses parameter {j} on both sides")
        if len(sides) == 2:
            columns.append((sides[0][1] - sides[1][1]) / (2 * steps[j]))
        else:
            sign, f = sides[0]
            columns.append(sign * (f - fun(theta)) / steps[j])
    return np.column_stack(columns)


def check_from_secant(candidate, secant: dict, floor: float) -> dict | None:
    """The :func:`bem_check` of ``candidate`` from the BEM solve its secant already made (:mod:`.bem_secant`), when
    that solve was at the candidate's final parameters (within a third of their size): the same scene solved
    again would say nothing new. None otherwise."""
    from electrosense.validation.diagnosis.effects import combined_scales

    if len(candidate.effects) != 1 or secant.get("label") != candidate.effects[0].label:
        return None
    scales = combined_scales(candidate.effects)
    theta, solved = np.asarray(candidate.fit.theta, float), np.asarray(secant["theta"], float)
    if np.linalg.norm((theta - solved) / scales) > np.linalg.norm(solved / scales) / 3:
        return None
    gap_model, gap_bem = secant["gap_effect_model"], secant["gap_bem"]
    return {"effect": candidate.name, "poses": secant["poses"], "gap_before": secant["gap_before"],
            "gap_effect_model": gap_model, "gap_bem": gap_bem,
            "confirmed": bool(gap_bem <= max(1.5 * floor, 1.25 * gap_model + floor)),
            "params_bem": {p: float(v) for p, v in zip(candidate.effects[0].param_names, theta)},
            "gap_bem_refined": gap_bem,
            "how": "the fitted scene solved by the BEM (the anchors' tank mesh stretched to it, the object meshed) at "
                   "the logged poses where the change is largest, by the secant that then corrected the candidate's "
                   "fit; gaps are RMS relative residuals there, in-sample"}


def bem_check(problem, candidate, anchors: np.ndarray, floor: float, bem_options: dict | None = None,
              n_poses: int | None = None, refine_steps: int = 2, progress=None, anchor_sweep=None) -> dict | None:
    """The bench against ``candidate`` evaluated by its effect model and by the BEM, at up to ``n_poses`` of the
    baseline's BEM poses ``anchors`` (sample indices; default :func:`check_pose_count`), then its parameters
    refined on the BEM (module doc);
    None when nothing in it needs the check.

    Returns a dict: the poses, the RMS relative gaps there of the baseline, the effect model's prediction and
    the BEM's at the effect model's parameters (``gap_before``, ``gap_effect_model``, ``gap_bem``), and
    ``confirmed``: the BEM reaches what the effect model claimed (within 1.5 times the noise floor, or within 25 %
    of the effect model's gap plus one floor); after the refinement ``params_bem`` and ``gap_bem_refined``.

    ``anchor_sweep``: a callable returning the anchors' own :class:`~electrosense.bem.PoseSweep` (1 S/m, their
    tank mesh). A scene that keeps the believed tank and objects (a pose or heading offset, a contact impedance)
    is solved on it (with its contact impedance: :meth:`~electrosense.bem.PoseSweep.with_contact_impedance`): the
    same mesh as the baseline, so that the two differ by the effect alone, and no tank to assemble.
    """
    from electrosense.meshes.scene_mesh import trajectory_focus_m
    from electrosense.validation.diagnosis.anchored import default_bem_options
    from electrosense.validation.diagnosis.effects import combined_bounds, combined_scales
    from electrosense.validation.diagnosis.fitting import predict, scenario
    from electrosense.validation.simulation.models import pose_evaluator

    effects = candidate.effects
    if not needs_bem_check(effects) or not len(anchors):
        return None
    say = progress or (lambda s: None)
    obs = problem.obs
    n_poses = check_pose_count(obs.n_receivers) if n_poses is None else n_poses
    idx = np.asarray(anchors)[np.unique(np.linspace(0, len(anchors) - 1, min(n_poses, len(anchors))).round()
                                        .astype(int))]
    rows = np.arange(obs.n_poses)
    options = default_bem_options(obs.sensor, bem_options)

    def by_bem(theta):
        sc = scenario(problem, effects, theta, rows)
        z = None if sc.contact_ohm_m2 is None else np.asarray(sc.contact_ohm_m2, float)
        if anchor_sweep is not None and sc.tank == obs.tank and tuple(sc.objects) == tuple(obs.objects):
            sweep = anchor_sweep()      # 1 S/m: a contact impedance z at sigma is z * sigma at 1 S/m
            if z is not None:
                sweep = sweep.with_contact_impedance(z * obs.sigma_S_per_m)
            K = sweep.conductance(sc.poses[idx]).K_S * obs.sigma_S_per_m
            return problem.currents(K, sc, idx, idx, contact=False)
        opts = dict(options)
        if sc.tank is not None:
            opts.setdefault("focus_m", trajectory_focus_m(obs.sensor, sc.poses))
        ev = pose_evaluator("bem", obs.sensor, sc.tank, obs.sigma_S_per_m, tuple(sc.objects),
                            contact_impedance_ohm_m2=z, prepare=False, **opts)
        return problem.currents(ev.conductance(sc.poses[idx]).K_S, sc, idx, idx, contact=False)

    residual = lambda I: problem.relative_residual(I, idx)  # noqa: E731
    rms = lambda I: float(np.sqrt(np.mean(residual(I) ** 2)))  # noqa: E731
    theta = np.asarray(candidate.fit.theta, float)
    say(f"BEM check of {candidate.name} at {len(idx)} poses")
    I_model, I_bem = predict(problem, effects, theta, idx), by_bem(theta)
    gap_before, gap_model, gap_bem = rms(problem.I_base[idx]), rms(I_model), rms(I_bem)
    out = {"effect": candidate.name, "poses": idx.tolist(), "gap_before": gap_before,
           "gap_effect_model": gap_model, "gap_bem": gap_bem,
           "confirmed": bool(gap_bem <= max(1.5 * floor, 1.25 * gap_model + floor)),
           "how": "the fitted scene solved by the BEM (a new tank, the object meshed, the contact impedance as its "
                  "boundary condition) at the baseline's BEM poses; gaps are RMS relative residuals there, in-sample; "
                  "the parameters then refined on the BEM (Gauss-Newton with the effect model's Jacobian)"}
    scales = combined_scales(effects)
    lower, upper = combined_bounds(effects)
    best, best_gap = theta, gap_bem
    r = residual(I_bem).ravel()
    # what the noise alone leaves at these few poses: the floor, plus two standard deviations of an RMS of r.size
    # samples (1 / sqrt(2 N) of it, relative)
    noise_reach = floor * (1.0 + 2.0 / np.sqrt(2.0 * max(r.size, 1)))
    out["noise_reach"] = noise_reach
    for step in range(refine_steps):
        if best_gap <= max(noise_reach, gap_model):  # the BEM already reaches what the model claimed, or the noise
            break                                    # of these poses: a step would fit that noise
        try:
            J = _jacobian(lambda t: residual(predict(problem, effects, t, idx)).ravel(), best, 0.05 * scales)
        except ValueError as exc:  # the effect model refuses both sides of a parameter (a sphere through a wall)
            if step == 0:
                out["refinement_stopped"] = f"{type(exc).__name__}: {exc}"
                break
            # the last step's Jacobian serves (a Broyden-like step: the sensitivities change little)
        trial = np.clip(best - np.linalg.lstsq(J, r, rcond=None)[0], lower, upper)
        say(f"BEM refinement of {candidate.name}, step {step + 1}")
        try:
            I_trial = by_bem(trial)
        except (ValueError, np.linalg.LinAlgError) as exc:  # the BEM refuses the scene (a pose out of the water)
            out["refinement_stopped"] = f"{type(exc).__name__}: {exc}"
            break
        gap_trial = rms(I_trial)
        if gap_trial >= best_gap:
            break
        best, best_gap, r = trial, gap_trial, residual(I_trial).ravel()
    out["params_bem"] = {f"{e.name}.{p}" if len(effects) > 1 else p: float(v) for e, ps in zip(effects, _split(
        effects, best)) for p, v in zip(e.param_names, ps)}
    out["gap_bem_refined"] = best_gap
    return out
