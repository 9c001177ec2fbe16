"""The gap diagnosis from observations to a result: where, which effect, how far it shrinks.

:func:`diagnose` runs the whole chain:

1. the baseline at the logged poses, in the believed tank, at the believed
   conductivity: by default (``"anchored"``) the BEM at an adaptive set of
   poses, interpolated over pose (as a ratio to the PSM or to the free-space
   K, whichever cross-validates better), until its estimated error is below a
   third of the noise
   (:mod:`.anchored`, cached on disk per sensor and tank); or the bare
   ``"bem"`` or ``"psm"``; with ``"psm"`` and ``bem_correction_poses``,
   corrected by the BEM on that many poses (:mod:`.multifidelity`);
   the *model-error budget*: the baseline's estimated error by region, beside
   the bench noise; their quadrature sum is the *noise floor* below which no
   effect is named;
2. the residual r = (bench - baseline) / |baseline|, the noise level s
   estimated from the data, and where r lies (:mod:`.where`);
3. every candidate of :mod:`.effects` fitted and cross-validated on held-out
   passes or segments (:mod:`.fitting`), ranked by penalised held-out score;
4. greedy forward selection (:mod:`.select`) against the noise floor, or
   ``none`` when the gap is within it, ``unexplained`` when no candidate
   brings it there (nor removes 80 % of it); the candidates that these poses
   cannot tell from the chosen one (the ambiguity set) with the measurement
   that would separate them.

Geometric effects are evaluated by an *effect model*, as a relative change
of the baseline. With the PSM as baseline it is that PSM itself (the gap is
explained in the PSM's own physics). With the BEM as baseline (the default)
every geometric change comes from the BEM's own solutions at the anchors:

* the sensor's pose (a robot-frame or mounting offset): the BEM's exact pose
  derivatives at every anchor (:mod:`electrosense.bem.shape_derivative`: moving the
  sensor is moving every wall the other way), the departure from the fast
  model's interpolated along each pass (:mod:`.pose_gradient`);
* walls, floor and free surface: the BEM's shape derivatives at every anchor
  correct the fast model's change to the BEM's first order (:mod:`.wall_gradient`);
* an unmodelled object: the BEM's field of the sensor where the sphere sits,
  its dipole and quadrupole (:mod:`.object_field`);

the fast model (the PSM with its radii calibrated and its spheres at the
electrodes' centres, :func:`electrosense.validation.diagnosis.forward.geometric_psm`,
with Kelvin images for spheres: :class:`electrosense.validation.diagnosis.forward.CompositeEffectModel`)
gives only the shape between anchors and the higher orders of a wall's move.

Example
-------
>>> from electrosense.validation.diagnosis.pipeline import diagnose  # doctest: +SKIP
>>> d = diagnose(obs, model="psm")  # doctest: +SKIP
>>> d.chosen, d.gap_before, d.gap_after  # doctest: +SKIP
(['conductivity'], 0.0203, 0.0006)
"""
from __future__ import annotations

import time
import warnings
from dataclasses import dataclass, field

import numpy as np

from electrosense.meshes.tank import Tank
from electrosense.validation.diagnosis.effects import EFFECT_NAMES, Problem, library, model_trust_weights
from electrosense.validation.diagnosis.fitting import make_folds, noise_level
from electrosense.validation.diagnosis.forward import ModelSimulator, PointElectrodeSimulator, PSMEffectModel
from electrosense.validation.diagnosis.observations import DiagnosisInputError, Observations
from electrosense.validation.diagnosis.select import (
    CandidateScore,
    Selection,
    SelectionRules,
    confusable_pairs,
    forward_selection,
    rank_candidates,
)
from electrosense.validation.diagnosis.where import breakdown, region_mask

__all__ = ["Diagnosis", "diagnose", "parse_effects", "default_effect_model"]


def parse_effects(spec: str | None) -> list[str]:
    """``"all"`` or ``"NAME,NAME"`` -> list of candidate names (``none`` always included)."""
    if spec is None or spec.strip().lower() == "all":
        return list(EFFECT_NAMES)
    names = [s.strip() for s in spec.split(",") if s.strip()]
    unknown = [n for n in names if n not in EFFECT_NAMES]
    if unknown:
        raise ValueError(f"unknown effect(s) {', '.join(unknown)}; known: {', '.join(EFFECT_NAMES)}")
    if "none" not in names:
        names.append("none")
    return names


def default_effect_model(obs: Observations, psm_model=None):
    """The calibrated PSM (or ``psm_model``) as effect model, or the point-electrode stand-in if the PSM cannot be used."""
    try:
        from electrosense.validation.diagnosis.forward import geometric_psm

        calibrated = None
        if psm_model is not None:
            from electrosense.validation.simulation.models import _load_psm

            calibrated = _load_psm(psm_model)
        return default_effect_model_from(obs.sensor, obs.sigma_S_per_m, geometric_psm(obs.sensor, calibrated),
                                         obs), "psm+kelvin"
    except Exception as exc:  # the PSM is missing or broken: say so and go on with the stand-in
        warnings.warn(f"PSM unavailable as effect model ({exc}); using the point-electrode stand-in", stacklevel=2)
        return PointElectrodeSimulator(obs.sensor, obs.sigma_S_per_m), "point-electrodes"


def default_effect_model_from(sensor, sigma_S_per_m, psm_model, obs=None):
    """The geometric PSM with Kelvin spheres (:class:`CompositeEffectModel`)."""
    from electrosense.validation.diagnosis.forward import CompositeEffectModel

    psm = PSMEffectModel(sensor, sigma_S_per_m, psm_model)
    if obs is not None:
        psm(obs.poses, obs.tank, tuple(obs.objects))  # fails early if the PSM is not usable; fixes the image shells
    points = PointElectrodeSimulator(sensor, sigma_S_per_m, radii_m=np.asarray(psm.model.radii_m), kelvin=True)
    return CompositeEffectModel(psm, points)


@dataclass
class Diagnosis:
    """Everything the report needs."""

    obs: Observations
    model: str
    effect_model: str
    noise: float
    r0: np.ndarray
    where: dict
    region: np.ndarray
    folds: list
    ranking: list
    selection: Selection
    confusable: list
    seconds: float
    model_split: dict | None = None
    notes: list = field(default_factory=list)
    I_base: np.ndarray | None = None
    model_error: dict = field(default_factory=dict)
    ambiguity: list = field(default_factory=list)
    bem_check: dict | None = None
    detection: dict | None = None

    @property
    def noise_floor(self) -> float:
        """sqrt(noise^2 + baseline error^2): the gap no effect can be asked to explain."""
        return float(self.model_error.get("noise_floor", self.noise))

    @property
    def baseline(self) -> CandidateScore:
        return next(c for c in self.ranking if c.name == "none")

    @property
    def chosen(self) -> list[str]:
        if self.selection.verdict == "none":
            return ["none"]
        if self.selection.verdict == "unexplained":
            return []
        return [e.name for e in self.selection.chosen[-1].effects] if self.selection.chosen else []

    @property
    def final(self) -> CandidateScore:
        return self.selection.chosen[-1] if self.selection.chosen else self.baseline

    @property
    def gap_before(self) -> float:
        return self.baseline.heldout_gap

    @property
    def gap_after(self) -> float:
        return self.final.heldout_gap


def _model_split(obs, model_K_psm, n_poses: int, bem_options: dict) -> dict:
    """PSM vs BEM on a subsample of the poses, and BEM vs bench there."""
    from electrosense.validation.diagnosis.forward import receiver_currents

    idx = np.unique(np.linspace(0, obs.n_poses - 1, min(n_poses, obs.n_poses)).round().astype(int))
    bem = ModelSimulator("bem", obs.sensor, obs.sigma_S_per_m, dict(bem_options))
    K_bem = bem(obs.poses[idx], obs.tank, tuple(obs.objects))
    I_bem = receiver_currents(K_bem, obs.emitter) * obs.U_V[idx, None]
    I_psm = receiver_currents(model_K_psm[idx], obs.emitter) * obs.U_V[idx, None]
    psm_vs_bem = (I_psm - I_bem) / np.abs(I_bem)
    bench_vs_bem = (obs.currents_A[idx] - I_bem) / np.abs(I_bem)
    bench_vs_psm = (obs.currents_A[idx] - I_psm) / np.abs(I_psm)
    rms = lambda x: float(np.sqrt(np.mean(x**2)))  # noqa: E731
    total = rms(bench_vs_psm) ** 2
    return {
        "poses": idx.tolist(),
        "psm_vs_bem_rms": rms(psm_vs_bem),
        "bench_vs_bem_rms": rms(bench_vs_bem),
        "bench_vs_psm_rms": rms(bench_vs_psm),
        "share_psm_approximation": rms(psm_vs_bem) ** 2 / total if total > 0 else 0.0,
        "share_missing_physics": rms(bench_vs_bem) ** 2 / total if total > 0 else 0.0,
        "note": "shares of the squared gap; they need not add to 1 when the two parts correlate",
    }


def diagnose(
    obs: Observations,
    model: str = "anchored",
    effects: str | list | None = "all",
    effect_model=None,
    K_base: np.ndarray | None = None,
    rules: SelectionRules = SelectionRules(),
    model_options: dict | None = None,
    split_with_bem: int = 0,
    psm_model=None,
    model_error: float = 0.0,
    bem_correction_poses: int = 0,
    bem_check_poses: int | None = None,
    statistical: bool = True,
    progress=None,
    baseline=None,
) -> Diagnosis:
    """Diagnose the gap between ``obs`` and ``model``.

    Parameters
    ----------
    obs : Observations
    model : {"anchored", "bem", "psm"}
        The baseline simulation: ``"anchored"`` (default) the BEM at adaptive
        anchor poses, interpolated, until its estimated error is below a third of the noise
        (:func:`electrosense.validation.diagnosis.anchored.anchored_baseline`); ``"bem"``
        the BEM at every pose; ``"psm"`` the calibrated PSM (its own error is
        then not known: a note says so).
    effects : "all", "NAME,NAME" or list of names
        Candidates to consider (``none`` is always considered).
    effect_model : callable, optional
        ``(poses, tank, objects) -> K`` for geometric effects (default: the
        baseline PSM with ``model="psm"``; the geometric PSM with Kelvin
        spheres otherwise; the stand-in when the PSM cannot be used).
    K_base : (P, n, n), optional
        The baseline's K at the logged poses, if already computed.
    rules : SelectionRules
    model_options : dict
        Options of :func:`electrosense.validation.simulation.models.simulate` for the baseline.
    psm_model : PolySphericalModel or path, optional
        The PSM for the effects (and the baseline with ``model="psm"``).
    split_with_bem : int
        With ``model="psm"``: run the BEM on this many poses to split the gap
        into the PSM's approximation and the missing physics (0: skip).
    model_error : float
        Relative error of the effect model on what the tank does (weights the
        samples near the walls down, where models disagree; 0: equal weights).
    bem_correction_poses : int
        With ``model="psm"``: run the BEM on about this many poses (dense where
        the tank's effect changes fastest) and correct the PSM baseline by the
        BEM/PSM ratio interpolated along the path
        (:mod:`electrosense.validation.diagnosis.multifidelity`); samples weighted by the
        estimated error of that correction. The diagnosis then explains the
        gap between the bench and the BEM's physics, not the PSM's
        approximation (0: the bare PSM).
    statistical : bool
        The verdict by the tests of :mod:`electrosense.validation.diagnosis.detection` (held-out
        improvement and goodness of fit against the noise model, false-alarm rate
        :data:`~electrosense.validation.diagnosis.detection.ALPHA`); False: the thresholds of
        :class:`SelectionRules` in units of the noise floor.
    bem_check_poses : int, optional
        With the anchored baseline: solve the chosen explanation's fitted scene with the BEM at this many of
        the baseline's BEM poses, when it holds a geometric effect or a contact impedance
        (:mod:`electrosense.validation.diagnosis.bem_check`; 0: skip; default: enough poses for
        :data:`~electrosense.validation.diagnosis.bem_check.CHECK_RESIDUALS` residuals,
        :func:`~electrosense.validation.diagnosis.bem_check.check_pose_count`).
    progress : callable(str), optional
    baseline : AnchoredBaseline, optional
        A baseline computed elsewhere with its estimated error, used as the anchored one (a tank map's:
        :func:`electrosense.validation.diagnosis.map_baseline.map_baseline`).
    """
    if obs.tank is not None and not isinstance(obs.tank, Tank):
        raise DiagnosisInputError(
            f"{obs.source or 'observations'}: the diagnosis knows box tanks (its wall candidates move walls, floor "
            f"and free surface of a box; its effect model, the PSM, images in a box's walls), not a "
            f"{type(obs.tank).__name__}; compare such a log with the BEM or its tank map instead (esense validate "
            f"--models bem, or --map FILE), or fit a scene to a tank with electrodes of its own (the real-tank "
            f"studies, esense study real_tank)")
    t0 = time.perf_counter()
    say = progress or (lambda s: None)
    notes = []
    names = parse_effects(effects) if isinstance(effects, (str, type(None))) else list(effects) + (["none"] if "none" not in effects else [])
    anchored = None
    effect_name = getattr(effect_model, "name", type(effect_model).__name__) if effect_model is not None else None
    if baseline is not None:   # a tank map's (or any precomputed) baseline, with its estimated error
        anchored, K_base, noise0 = baseline, baseline.K, _prior_noise(obs, psm_model)
        notes.append(f"baseline: a tank map ({baseline.n_cached} BEM poses, no new BEM); estimated error "
                     f"{100 * baseline.rms_error:.4f} % RMS at the logged poses")
    if K_base is None and model == "anchored":
        from electrosense.validation.diagnosis.anchored import anchored_baseline

        noise0 = _prior_noise(obs, psm_model)
        say(f"baseline: BEM anchors interpolated over {obs.n_poses} poses (noise about {100 * noise0:.3f} %)")
        if effect_model is None:
            effect_model, effect_name = default_effect_model(obs, psm_model)
        anchored = anchored_baseline(obs, noise0, psm_model=_load(psm_model),
                                     bem_options={k: v for k, v in (model_options or {}).items() if k != "psm_model"},
                                     pose_reference=effect_model, progress=say)
        K_base = anchored.K
        notes.append(f"baseline: the BEM at {len(anchored.anchors)} of {obs.n_poses} poses, interpolated as a ratio "
                     f"to the {'PSM' if anchored.base == 'psm' else 'free-space K'} "
                     f"({anchored.n_bem_new} run now, {anchored.n_cached} from the cache, {len(anchored.refused)} "
                     f"refused by the PSM); estimated error {100 * anchored.rms_error:.4f} % RMS against a target of "
                     f"{100 * anchored.target:.4f} % ({anchored.seconds:.1f} s)")
    elif K_base is None:
        say(f"baseline: {model} at {obs.n_poses} poses")
        options = dict(model_options or {})
        if model == "psm" and psm_model is not None:
            options["psm_model"] = psm_model
        base_sim = ModelSimulator(model, obs.sensor, obs.sigma_S_per_m, options)
        K_base = base_sim(obs.poses, obs.tank, tuple(obs.objects))
    else:
        base_sim = None
    if effect_model is None and model == "psm":
        # the baseline's own physics: effects as the (calibrated) PSM would show them
        try:
            from electrosense.validation.simulation.models import _load_psm, calibrated_psm

            own = _load_psm(psm_model) if psm_model is not None else calibrated_psm(obs.sensor)
            effect_model, effect_name = PSMEffectModel(obs.sensor, obs.sigma_S_per_m, own), "psm"
        except Exception as exc:  # fall back on the default below, and say so
            notes.append(f"the baseline PSM could not serve as effect model ({exc})")
    if effect_model is None:
        effect_model, effect_name = default_effect_model(obs, psm_model)
    if effect_name == "point-electrodes":
        notes.append("geometric effects evaluated with the point-electrode stand-in (the PSM was not usable)")
    if obs.sigma_logged_S_per_m is not None:
        logged = float(np.nanmean(obs.sigma_logged_S_per_m))
        notes.append(f"the log holds conductimeter readings: mean {logged:.5g} S/m against {obs.sigma_S_per_m:.5g} S/m "
                     f"in the meta line ({100 * (logged / obs.sigma_S_per_m - 1):+.2f} %); the simulation uses the "
                     "meta line's value, compare with the conductivity candidate")
    simulated = simulated_by(obs)
    if simulated is not None:
        notes.append(f"these data were made by the virtual bench with the {simulated.upper()} as physics"
                     + (": the PSM's own error (not physics) will show as a gap against this baseline; make bench "
                        "data with the BEM physics (the virtual bench's default), or diagnose with model 'psm' to "
                        "check the bench's plumbing only" if simulated == "psm" and model != "psm" else
                        ": baseline and data share one model; the diagnosis then checks the plumbing, not the physics"
                        if simulated == model else ""))
    correction = None
    if model == "psm" and bem_correction_poses > 0:
        from electrosense.validation.diagnosis.forward import receiver_currents
        from electrosense.validation.diagnosis.multifidelity import bem_correction, choose_bem_poses

        free = receiver_currents(effect_model(obs.poses, None, tuple(obs.objects)), obs.emitter)
        in_tank = receiver_currents(effect_model(obs.poses, obs.tank, tuple(obs.objects)), obs.emitter)
        tank_effect = np.max(np.abs(in_tank / free - 1.0), axis=1) if obs.tank is not None else np.zeros(obs.n_poses)
        idx = choose_bem_poses(tank_effect, obs.pass_indices(), bem_correction_poses)
        say(f"BEM on {len(idx)} poses to correct the PSM baseline")
        try:
            bem = ModelSimulator("bem", obs.sensor, obs.sigma_S_per_m,
                                 {k: v for k, v in (model_options or {}).items() if k != "psm_model"})
            K_bem = bem(obs.poses[idx], obs.tank, tuple(obs.objects))
            correction = bem_correction(obs, np.asarray(K_base, float), K_bem, idx)
            K_base = correction.corrected(np.asarray(K_base, float))
            notes.append(f"PSM baseline corrected by the BEM on {len(idx)} poses (BEM/PSM ratio interpolated along "
                         f"the path): bare PSM vs BEM there {100 * np.sqrt(np.mean(correction.psm_vs_bem**2)):.3f} % "
                         f"RMS, leave-one-out error of the correction "
                         f"{100 * np.sqrt(np.mean(correction.leave_one_out**2)):.3f} % RMS")
        except Exception as exc:  # the diagnosis still runs on the bare PSM; say so
            notes.append(f"BEM correction of the PSM baseline not computed ({type(exc).__name__}: {exc})")
    problem = Problem(obs, K_base, effect_model, baseline_name=model,
                      pose_gradient=anchored.pose_gradient if anchored is not None else None)
    if anchored is not None and anchored.pose_gradient is not None and len(anchored.pose_gradient.nodes):
        notes.append(f"pose offsets through the BEM's own pose gradient at {len(anchored.pose_gradient.nodes)} BEM "
                     f"poses ({anchored.pose_gradient.how}), not through the effect model")
    if anchored is not None and "unmodelled_object" in names and (obs.tank is None or isinstance(obs.tank, Tank)):
        from electrosense.validation.diagnosis.object_field import sensor_object_field

        try:
            problem.object_field = sensor_object_field(obs.sensor, obs.sigma_S_per_m)
            notes.append("an unmodelled object's change of K from the BEM's own field where it sits (the sensor's "
                         "unit solutions in unbounded water, tabulated; the walls' first reflections; dipole and "
                         "quadrupole of the sphere), not through the effect model")
        except (ValueError, np.linalg.LinAlgError) as exc:   # the object stays with the effect model; say so
            notes.append(f"the object's BEM field not computed ({type(exc).__name__}: {exc}); the object through "
                         "the effect model")
    if anchored is not None and anchored.wall_derivatives is not None:
        from electrosense.validation.diagnosis.wall_gradient import wall_gradient

        try:
            problem.wall_gradient = wall_gradient(problem, anchored.wall_derivatives, anchored.wall_regions,
                                                  anchored.K)
        except (ValueError, np.linalg.LinAlgError) as exc:   # the wall effects stay with the effect model; say so
            notes.append(f"the walls' BEM derivatives not used ({type(exc).__name__}: {exc})")
        if problem.wall_gradient is not None:
            notes.append(f"walls, floor and free surface through the BEM's shape derivative at "
                         f"{len(problem.wall_gradient.nodes)} BEM poses (the effect model's change corrected to "
                         "the BEM's first order)")
    everything = np.arange(obs.n_poses)
    r0 = problem.relative_residual(problem.I_base, everything)
    noise = noise_level(r0, obs.pass_indices())
    if anchored is not None and noise0 < noise:
        # the interpolated correction's own wiggles enter second differences; the bare PSM's error is smooth
        notes.append(f"noise from bench / PSM ({100 * noise0:.4f} %), not from bench / corrected baseline "
                     f"({100 * noise:.4f} %), whose interpolation adds roughness of its own")
        noise = noise0
    if not noise > 0:
        noise = max(1e-6, 1e-3 * float(np.sqrt(np.mean(r0**2))))
        notes.append("the noise estimate was zero (noise-free data?); a floor of 1e-6 relative is used")
    problem.weight = model_trust_weights(problem, noise, model_error)
    if correction is not None:  # the correction's own uncertainty, as a model error of each sample
        problem.weight = problem.weight / np.sqrt(1.0 + (correction.error / noise) ** 2)
    if anchored is not None:
        problem.weight = problem.weight / np.sqrt(1.0 + (anchored.total_error / noise) ** 2)
    budget = model_error_budget(obs, model, noise, anchored, correction)
    if problem.wall_gradient is not None:
        from electrosense.validation.diagnosis.anchored import _receiver_entries

        budget["wall_gradient"] = problem.wall_gradient.summary(_receiver_entries(obs.sensor))
    floor = budget["noise_floor"]
    where = breakdown(obs, r0)
    mask = region_mask(where)
    folds = make_folds(obs)
    lib = {k: v for k, v in library(obs).items() if k in names}
    skipped = [n for n in names if n not in lib]
    if skipped:
        notes.append(f"candidates not applicable to these data: {', '.join(skipped)}")
    ranking = rank_candidates(problem, lib, folds, noise, r0, mask, progress=lambda n: say(f"fitting {n}"))
    detection = None
    if statistical:
        from electrosense.validation.diagnosis.detection import diagnose_detection

        say("detection test against the noise model")
        detection = diagnose_detection(problem, ranking, folds, noise,
                                       anchored.total_error if anchored is not None else None)
        if anchored is not None and anchored.focus_m is not None:
            secants = refine_on_bem(problem, ranking, lib, detection, anchored,
                                    {k: v for k, v in (model_options or {}).items() if k != "psm_model"},
                                    folds, noise, r0, mask, say)
            solved = [i for i in secants if not i.get("skipped")]
            if solved:
                notes.append("solved by the BEM at their fitted scenes, and scored again: " + "; ".join(
                    f"{i['effect']} (the model {100 * i['model_vs_bem_rms']:.3f} % RMS off the BEM there, of a "
                    f"{100 * i['change_rms']:.3f} % change)" for i in solved))
            skipped_secants = [i for i in secants if i.get("skipped")]
            if skipped_secants:
                notes.append("not solved by the BEM, since no re-solve could bring its score below the best's "
                             f"({skipped_secants[0]['best_score']:.0f}): " + "; ".join(
                                 f"{i['effect']} (score at least {i['score_lower_bound']:.0f} with each current "
                                 f"changed by up to {i['reach']:.0%} of its own change of it)" for i in skipped_secants))
            if solved:
                ranking = sorted(ranking, key=lambda c: c.score)
                detection = diagnose_detection(problem, ranking, folds, noise, anchored.total_error)
            if secants:
                budget["bem_secants"] = secants
    selection = forward_selection(problem, ranking, folds, noise, rules, mask, floor=floor,
                                  model_error_by_place=budget.get("baseline_by_place"), detection=detection)
    confusable = confusable_pairs(ranking, rules)
    ambiguity = ambiguity_set(selection, ranking, rules, floor)
    notes += [s["stop"] for s in selection.steps if "within the model's own error" in s.get("stop", "")]
    check = None
    if bem_check_poses is None:
        from electrosense.validation.diagnosis.bem_check import check_pose_count

        bem_check_poses = check_pose_count(obs.n_receivers)
    if anchored is not None and selection.verdict in ("explained", "partly explained") and selection.chosen \
            and bem_check_poses > 0:
        from electrosense.validation.diagnosis.bem_check import (
            MIN_CHECK_POSES,
            bem_check,
            check_from_secant,
            taylor_remainder_bound,
        )

        for secant in reversed(budget.get("bem_secants") or []):   # the chosen scene already solved by the BEM
            check = check or check_from_secant(selection.chosen[-1], secant, floor)
        anchors = np.asarray(anchored.anchors)
        remainder = None if check is not None else \
            taylor_remainder_bound(problem, selection.chosen[-1], anchors)
        if remainder is not None:       # solve only where the Taylor step could differ from the BEM by noise/3
            needed = int(np.sum(remainder >= noise / 3.0))
            order = np.argsort(-remainder)
            # at least a few poses once any is needed: a refinement on one or two would fit their noise
            take = 0 if needed == 0 else min(len(anchors), bem_check_poses, max(needed, MIN_CHECK_POSES))
            below = remainder[remainder < noise / 3.0]
            if len(below):
                solved = "not checked by new BEM solves" if take == 0 else (
                    f"checked by new BEM solves at {take} of its {len(anchors)} BEM poses"
                    + (f" (the {take} largest of the {needed} where the Taylor step's remainder could reach a third "
                       "of the noise)" if take < needed else ""))
                notes.append(f"{selection.chosen[-1].name} {solved}: at {len(below)} of its BEM poses it is the BEM's "
                             "own pose derivatives, whose Taylor step's second-order term (doubled for the cross terms "
                             f"and its own error) moves no current by more than {100 * float(below.max()):.4f} %, a "
                             f"third of the noise being {100 * noise / 3:.4f} %")
            anchors = np.sort(anchors[order[:take]])
        if check is None and len(anchors):
            try:
                check = bem_check(problem, selection.chosen[-1], anchors, floor,
                                  {k: v for k, v in (model_options or {}).items() if k != "psm_model"},
                                  n_poses=bem_check_poses, progress=say, anchor_sweep=anchored.bem_sweep)
            except Exception as exc:  # the check is extra evidence; its failure is said, the diagnosis stands
                notes.append(f"BEM check of the chosen effect not computed ({type(exc).__name__}: {exc})")
        if check is not None and "params_bem" in check and check["gap_bem_refined"] < check["gap_bem"]:
            params = ", ".join(f"{k} = {v:.4g}" for k, v in check["params_bem"].items())
            notes.append(f"{check['effect']} refined on the BEM at its {len(check['poses'])} poses: {params}; the BEM "
                         f"then leaves {100 * check['gap_bem_refined']:.3f} % there (noise floor {100 * floor:.3f} %)")
        if check is not None and not check["confirmed"]:
            notes.append(f"the BEM does not confirm {check['effect']}: with its fitted parameters the BEM leaves "
                         f"{100 * check['gap_bem']:.3f} % at {len(check['poses'])} BEM poses where the effect model "
                         f"left {100 * check['gap_effect_model']:.3f} % (noise floor {100 * floor:.3f} %): the effect "
                         "model, not the data, made this answer")
    split = None
    if model == "psm" and split_with_bem > 0:
        try:
            say(f"PSM vs BEM on {split_with_bem} poses")
            split = _model_split(obs, problem.K_base, split_with_bem, model_options or {})
        except Exception as exc:  # report, do not fail the diagnosis
            notes.append(f"PSM/BEM split not computed: {exc}")
    return Diagnosis(obs, model, effect_name, noise, r0, where, mask, folds, ranking, selection, confusable,
                     time.perf_counter() - t0, split, notes, problem.I_base, budget, ambiguity, check, detection)


#: geometric candidates whose fitted scene is solved by the BEM when their held-out improvement is significant
SECANT_CANDIDATES = ("tank_size", "water_depth", "unmodelled_object")

#: the largest share of a geometric candidate's own fitted change of a current that its BEM re-solve may alter
#: there, by candidate. Walls and depth are already the BEM's to first order (:mod:`.wall_gradient`): a re-solve
#: changes their second order, measured at fitted scenes on blind logs as 2-3 % of the change (RMS over the
#: re-solved poses; 1-4 % for the shape derivative against moved-mesh solves): a quarter is 6-10x that. An object
#: through the BEM field of the sensor: 10 % near a pass, 35-57 % when fitted far from where the effect is (a
#: proxy for another effect): the whole of it.
SECANT_REACH = {"tank_size": 0.25, "water_depth": 0.25, "unmodelled_object": 1.0}


def secant_reach(name: str) -> float:
    """:data:`SECANT_REACH` of a candidate (1, the whole of its change, for one not listed)."""
    return SECANT_REACH.get(name, 1.0)


def secant_cannot_overtake(problem, candidate, best_score: float, noise: float,
                           reach: float | None = None) -> tuple[bool, float]:
    """Whether a BEM re-solve of ``candidate``'s fitted scene cannot bring its score below ``best_score``.

    The re-solve changes each sample's prediction by at most ``reach`` times
    the candidate's own fitted change there, ``delta_i`` (weighted), so each
    held-out residual ``r_i`` keeps at least ``|r_i| - reach |delta_i|``::

        score >= sum_i max(0, |r_i| - reach |delta_i|)^2 / s^2 + k ln N.

    Returns ``(cannot, that lower bound)``.

    Example
    -------
    An object fitted where it changes a few samples cannot remove the gap
    that every other sample keeps:

    >>> import numpy as np
    >>> r, delta = np.full(100, 3.0), np.r_[np.full(10, 5.0), np.zeros(90)]
    >>> float(np.sum(np.maximum(0.0, np.abs(r) - delta) ** 2))
    810.0
    """
    from electrosense.validation.diagnosis.fitting import predict

    reach = secant_reach(candidate.name) if reach is None else reach
    every = np.arange(problem.obs.n_poses)
    effects = list(candidate.effects)
    theta = np.asarray(candidate.fit.theta, float)
    changed = predict(problem, effects, theta, every)
    base = predict(problem, effects, np.zeros_like(theta), every)
    delta = (problem.relative_residual(base, every) - problem.relative_residual(changed, every)) * problem.weight
    r = candidate.heldout * problem.weight
    finite = np.isfinite(r)
    kept = np.maximum(0.0, np.abs(r[finite]) - reach * np.abs(delta[finite]))
    bound = float(kept @ kept) / noise**2 + candidate.n_params * np.log(int(finite.sum()))
    return bound > best_score, bound


def refine_on_bem(problem, ranking: list, lib: dict, detection: dict, anchored, bem_options: dict, folds, noise,
                  r0, mask, say, rounds: int = 2, at_most: int = 3) -> list[dict]:
    """The geometric candidates that improve the held-out fit beyond the noise model's (p below the false-alarm
    rate each) solved by the BEM at their fitted scenes (:mod:`electrosense.validation.diagnosis.bem_secant`) and
    scored again, in place in ``ranking``; a second round where the refit moved the parameters by more than a
    third. Returns what each solve found."""
    from electrosense.meshes.scene_mesh import DEFAULT_TANK_GRADING, default_tank_edge_length_m
    from electrosense.meshes.tank_mesh import mesh_tank
    from electrosense.validation.diagnosis.anchored import default_bem_options
    from electrosense.validation.diagnosis.bem_secant import SECANT_ENOUGH, bem_secant
    from electrosense.validation.diagnosis.detection import ALPHA
    from electrosense.validation.diagnosis.effects import combined_scales
    from electrosense.validation.diagnosis.select import score_candidate

    obs = problem.obs
    p = detection.get("p_by_candidate", {})
    todo = [c for c in ranking if c.name in SECANT_CANDIDATES and p.get(c.name, 1.0) < ALPHA][:at_most]
    if not todo:
        return []
    options = default_bem_options(obs.sensor, bem_options)
    mesh = None
    if isinstance(obs.tank, Tank):
        h = options.get("tank_edge_length_m") or default_tank_edge_length_m(obs.sensor)
        mesh = mesh_tank(obs.tank, h, anchored.focus_m, grading=DEFAULT_TANK_GRADING)
    elif obs.tank is not None:
        return []   # a cylinder's stretch is not built
    found = []
    for c in todo:
        best_score = min(x.score for x in ranking)
        if c.score > best_score:
            cannot, bound = secant_cannot_overtake(problem, c, best_score, noise)
            if cannot:
                say(f"{c.name}: not solved by the BEM (its score cannot fall below {bound:.0f} by a re-solve; "
                    f"the best is {best_score:.0f})")
                found.append({"effect": c.name, "skipped": True, "score_lower_bound": bound,
                              "best_score": best_score, "reach": secant_reach(c.name)})
                continue
        current = c
        for _ in range(rounds):
            effect = current.effects[0]
            try:
                correction, info = bem_secant(problem, current, mesh, options, progress=say,
                                              negligible=noise / (3 * secant_reach(current.name)),
                                              enough=SECANT_ENOUGH * noise)
            except (ValueError, np.linalg.LinAlgError) as exc:   # the scene cannot be solved: the candidate stays
                say(f"{current.name}: its fitted scene not solved by the BEM ({type(exc).__name__}: {exc})")
                break
            problem.secants[effect.label] = correction
            found.append(info)
            again = score_candidate(problem, lib[current.name], folds, noise, r0, mask)
            scales = combined_scales(again.effects)
            moved = np.linalg.norm((again.fit.theta - np.asarray(info["theta"])) / scales) if \
                again.effects[0].label == effect.label else np.inf
            current = again
            if moved <= np.linalg.norm(np.asarray(info["theta"]) / scales) / 3:
                break
        ranking[ranking.index(c)] = current
    return found


def simulated_by(obs: Observations) -> str | None:
    """``"psm"`` or ``"bem"`` when the log says it was made by the virtual bench (its meta or description), else None.

    >>> from electrosense.validation.bench.virtual.bench import SIMULATOR_LABEL
    >>> simulated_by(type("O", (), {"meta": {"notes": SIMULATOR_LABEL + "; model psm; sensor x"}})())
    'psm'
    """
    from electrosense.validation.bench.virtual.bench import SIMULATOR_LABEL

    texts = [v for v in (obs.meta or {}).values() if isinstance(v, str)]
    for t in texts:
        if SIMULATOR_LABEL in t:
            import re

            m = re.search(r"model (\w+)", t)
            return m.group(1).lower() if m else "unknown"
    return None


def _load(psm_model):
    if psm_model is None:
        return None
    from electrosense.validation.simulation.models import _load_psm

    return _load_psm(psm_model)


def _prior_noise(obs: Observations, psm_model=None) -> float:
    """The bench noise from the second differences of bench / PSM - 1 along each pass (PSM-usable poses).

    The PSM's own error is smooth along a pass and hardly enters second
    differences; where the PSM refuses every pose, the log of the currents is used.
    """
    from electrosense.validation.diagnosis.anchored import psm_usable
    from electrosense.validation.diagnosis.forward import effect_objects, geometric_psm, receiver_currents
    from electrosense.validation.simulation.models import calibrated_psm, pose_evaluator

    model = _load(psm_model) or calibrated_psm(obs.sensor)
    ok = psm_usable(model, obs.poses, obs.tank)
    if ok.sum() < 8:  # the calibrated spheres do not fit (or the calibration degenerated): spheres at the electrodes
        model = geometric_psm(obs.sensor, model)
        ok = psm_usable(model, obs.poses, obs.tank)
    if ok.sum() >= 8:
        # the balls only (effect_objects): a pole or a box left out changes the PSM smoothly along a pass
        K = pose_evaluator("psm", obs.sensor, obs.tank, obs.sigma_S_per_m, effect_objects(obs.objects), psm_model=model,
                           poses=obs.poses[ok]).conductance(obs.poses[ok]).K_S
        r = np.zeros_like(obs.currents_A)
        r[ok] = obs.currents_A[ok] / (receiver_currents(K, obs.emitter) * obs.U_V[ok, None]) - 1.0
        groups = [g[ok[g]] for g in obs.pass_indices()]
    else:
        r = np.log(np.abs(obs.currents_A / obs.U_V[:, None]))
        groups = obs.pass_indices()
    s = noise_level(r, groups)
    return s if s > 0 else 1e-6


def model_error_budget(obs: Observations, model: str, noise: float, anchored=None, correction=None) -> dict:
    """The baseline's estimated error (RMS, by place) beside the bench noise, and the noise floor they make."""
    from electrosense.validation.diagnosis.where import place_labels

    rms = lambda x: float(np.sqrt(np.mean(np.square(x)))) if np.size(x) else 0.0  # noqa: E731
    out = {"noise": noise, "baseline": model}
    if anchored is not None:
        labels = place_labels(obs)
        by_place = lambda err: {g: rms(err[labels == g]) for g in dict.fromkeys(labels.tolist())}  # noqa: E731
        out.update({
            "baseline_rms": anchored.rms_error,
            "baseline_by_place": by_place(anchored.total_error),
            "interpolation_rms": anchored.interpolation_rms,
            "interpolation_by_place": by_place(anchored.error),
            "base": anchored.base,
            "how": "the BEM at anchor poses, its ratio to the base (the PSM, or the free-space K: whichever predicts "
                   "the BEM better at the anchors) interpolated over pose; interpolation error = leave-one-out "
                   "error at the nearest BEM poses scaled by the distance from them (an upper estimate, zero at the "
                   "BEM poses), in quadrature with the "
                   "BEM's own discretisation error",
            "bem_poses": int(len(anchored.anchors)), "bem_poses_new": int(anchored.n_bem_new),
            "bem_poses_cached": int(anchored.n_cached), "psm_refused_poses": int(len(anchored.refused)),
            "target": anchored.target, "rounds": anchored.rounds, "stopped": anchored.stopped or None,
            "bare_psm_vs_bem_rms": anchored.psm_vs_bem_rms,
        })
        if anchored.pose_gradient is not None and len(anchored.pose_gradient.nodes):
            from electrosense.validation.diagnosis.anchored import _receiver_entries

            out["pose_gradient"] = {**anchored.pose_gradient.error_per_step(_receiver_entries(obs.sensor)),
                                    "how": anchored.pose_gradient.how + "; leave-one-out error beside the change "
                                                                        "itself"}
        if anchored.bem_error is not None:
            out["bem_discretisation_rms"] = rms(anchored.bem_error)
            out["bem_discretisation_by_place"] = by_place(anchored.bem_error)
    elif correction is not None:
        out.update({"baseline_rms": rms(correction.error),
                    "how": "leave-one-out error of the BEM/PSM ratio interpolated along each pass"})
    elif model == "bem":
        out.update({"baseline_rms": 0.0, "how": "the BEM at every pose"})
    elif model == "psm":
        out.update({"baseline_rms": None, "how": "not estimated: the bare PSM (its error near walls is several "
                                                  "percent); use the default baseline to know it"})
    else:
        out.update({"baseline_rms": None, "how": "not estimated: the baseline was given by the caller"})
    out["bem_discretisation"] = {
        "free_space": "the sensor mesh's electrode-edge error in unbounded water is corrected against the converged "
                      "ring-element BEM (bem.edge_correction)",
        "in_the_tank": ("measured at a few anchor poses: the change of the receiver currents on a 1.5x finer "
                        "sensor and tank mesh, extrapolated to the converged limit (first order: three times the "
                        "change); each sample takes the estimate of the nearest such pose"
                        if "bem_discretisation_rms" in out else "not estimated"),
    }
    base = out["baseline_rms"] or 0.0
    out["noise_floor"] = float(np.hypot(noise, base))
    out["rule"] = ("an effect is named only when its held-out gap is within 1.5x the noise floor, or it removes "
                   "80 % of the gap and its gain exceeds the noise floor")
    return out


def ambiguity_set(selection: Selection, ranking: list, rules: SelectionRules, floor: float) -> list[dict]:
    """Candidates that explain the data about as well as the first chosen one (held-out mean squares within one
    floor^2), with the measurement that would separate each from it."""
    from electrosense.validation.diagnosis.select import _hint

    if not selection.chosen:
        return []
    first = selection.chosen[0]
    out = []
    for c in ranking:
        if c.name in ("none", first.name) or c.at_bound:
            continue
        if c.heldout_gap**2 - first.heldout_gap**2 < floor**2:
            out.append({"effect": c.name, "heldout_gap": c.heldout_gap, "separate_by": _hint(first.name, c.name)})
    return out
