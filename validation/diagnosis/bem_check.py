"""The chosen explanation evaluated by the BEM itself: is the effect model's answer the reference's?

Geometric effects (walls, depth, an object, the robot's frame) are fitted with
a fast effect model, and a contact impedance through effective areas (a
lumped series network). Once an explanation is chosen, its fitted scene is
solved by the BEM at a few of the baseline's BEM poses (where the baseline
*is* the BEM, so that the two predictions differ only by the effect's model):
a new tank, the object meshed, the contact impedance as the BEM's boundary
condition. The held-out-free gap of the bench against both predictions is
reported; where the BEM leaves more than the noise floor that the effect
model claimed to reach, the diagnosis says that its effect model, not the
data, made the answer.

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

__all__ = ["needs_bem_check", "bem_check"]


def needs_bem_check(effects) -> bool:
    """Whether the explanation goes through an approximate model: a geometric effect or a contact impedance."""
    return any(e.geometric or e.name == "contact_impedance" for e in effects)


def bem_check(problem, candidate, anchors: np.ndarray, floor: float, bem_options: dict | None = None,
              n_poses: int = 12, progress=None) -> dict | None:
    """The bench against ``candidate`` evaluated by its effect model and by the BEM, at up to ``n_poses`` of the
    baseline's BEM poses ``anchors`` (sample indices); None when nothing in it needs the check.

    Returns a dict: the poses, the RMS relative gaps there of the baseline, the effect model's prediction and
    the BEM's (``gap_before``, ``gap_effect_model``, ``gap_bem``), and ``confirmed``: the BEM reaches what the
    effect model claimed (within 1.5 times the noise floor, or within 25 % of the effect model's gap plus one
    floor).
    """
    from electrosense.meshes.scene_mesh import trajectory_focus_m
    from electrosense.validation.diagnosis.anchored import default_bem_options
    from electrosense.validation.simulation.models import pose_evaluator

    effects = candidate.effects
    if not needs_bem_check(effects) or not len(anchors):
        return None
    obs = problem.obs
    idx = np.asarray(anchors)[np.unique(np.linspace(0, len(anchors) - 1, min(n_poses, len(anchors))).round()
                                        .astype(int))]
    rows = np.arange(obs.n_poses)
    sc = problem.nominal(rows)
    parts = _split(effects, candidate.fit.theta)
    for k in sorted(range(len(effects)), key=lambda j: effects[j].order):
        sc = effects[k].apply(parts[k], sc, problem, rows)
    I_model = problem.predict(sc, idx)
    options = default_bem_options(obs.sensor, bem_options)
    z = None if sc.contact_ohm_m2 is None else np.asarray(sc.contact_ohm_m2, float)
    (progress or (lambda s: None))(f"BEM check of {candidate.name} at {len(idx)} poses")
    if sc.tank is not None:
        options.setdefault("focus_m", trajectory_focus_m(obs.sensor, sc.poses))
    ev = pose_evaluator("bem", obs.sensor, sc.tank, obs.sigma_S_per_m, tuple(sc.objects),
                        contact_impedance_ohm_m2=z, prepare=False, **options)
    K_bem = ev.conductance(sc.poses[idx]).K_S
    I_bem = problem.currents(K_bem, sc, idx, idx, contact=False)
    rms = lambda I: float(np.sqrt(np.mean(problem.relative_residual(I, idx) ** 2)))  # noqa: E731
    gap_before, gap_model, gap_bem = rms(problem.I_base[idx]), rms(I_model), rms(I_bem)
    confirmed = bool(gap_bem <= max(1.5 * floor, 1.25 * gap_model + floor))
    return {"effect": candidate.name, "poses": idx.tolist(), "gap_before": gap_before,
            "gap_effect_model": gap_model, "gap_bem": gap_bem, "confirmed": confirmed,
            "how": "the fitted scene solved by the BEM (a new tank, the object meshed, the contact impedance as its "
                   "boundary condition) at the baseline's BEM poses; gaps are RMS relative residuals there, in-sample"}
