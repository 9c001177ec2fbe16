"""Ranking the candidates and choosing the effect(s): held-out scores, greedy forward selection.

Every candidate is fitted on training samples and scored on held-out ones
(:func:`electrosense.validation.diagnosis.fitting.cross_validate`). Its penalised score is
a Bayesian information criterion with the noise variance s^2 estimated from
the data::

    score = SSE_heldout / s^2 + k ln N

(k parameters, N held-out residuals; the residuals weighted by how far the
effect model can be trusted at each sample, see
:func:`electrosense.validation.diagnosis.effects.model_trust_weights`). A combination grows one effect at a
time (at most three), taking the effect that lowers the score most; it stops
when

* the gap before any effect is within the noise (RMS <= ``start_noise`` x s), or
* no effect lowers the score (an effect whose fit pins a parameter at its
  plausibility bound is not taken: it is bending itself to mimic something
  else), or
* the best one removes less than ``min_gain`` of the remaining excess
  (held-out mean square above s^2): what is left is not worth a cause, or
* after an effect, the held-out gap is within the noise (RMS <= ``at_noise`` x s).

Parsimony among nested candidates: when a candidate with one common
parameter (a uniform scale such as the conductivity) lies within the
sensitivity span of the best, per-receiver or per-electrode one (largest principal angle
below ``nested_deg``: a common change is one of the per-receiver changes) and
leaves a held-out mean square within ``nested_excess`` x s^2 of the best
one's, the simpler one is taken: the richer one's extra parameters remove
less than a noise variance per sample, which the models' own approximation
(PSM against BEM, mesh against mesh) cannot vouch for, although over many
samples the information criterion would count it as significant.

After two or more effects, each is offered a replacement by every other
candidate (a gain per receiver may have soaked up part of another effect's
signature before that effect was in); the penalised score decides.

``none`` is answered when no effect is accepted and the gap is within the
noise floor (RMS <= ``none_ceiling`` x floor, the floor being the noise and
the baseline's own error in quadrature): nothing is invented; a gap above
the bench noise but within the floor is noted as the model's own limit.
When the gap is above the floor and no candidate removes it, nothing is
chosen and the verdict says "unexplained".

Example
-------
>>> SelectionRules().none_ceiling
1.5
"""
from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
from scipy.linalg import subspace_angles

from electrosense.validation.diagnosis.effects import Effect, Problem
from electrosense.validation.diagnosis.fitting import (
    FitResult,
    cross_validate,
    fit,
    folds_determining,
    object_starts,
    predict,
    segment_folds,
    subspace_angle_deg,
)

__all__ = ["SelectionRules", "CandidateScore", "Selection", "score_candidate", "rank_candidates", "forward_selection",
           "confusable_pairs"]


@dataclass(frozen=True)
class SelectionRules:
    """Thresholds of the selection, in units of the estimated noise."""

    start_noise: float = 1.2  # before any effect: held-out RMS <= start_noise * s is noise, nothing is tried
    at_noise: float = 1.5  # after an effect: held-out RMS <= at_noise * s, nothing more to explain
    none_ceiling: float = 1.5  # nothing accepted and gap <= none_ceiling * s: the gap is noise
    min_gain: float = 0.30  # an added effect must remove >= this share of the excess mean square
    max_effects: int = 3
    confusable_deg: float = 15.0  # sensitivity subspaces closer than this: cannot be told apart
    nested_deg: float = 2.0  # a simpler candidate whose sensitivities lie within this angle of the best's span ...
    nested_excess: float = 1.0  # ... and whose held-out mean square is within this many s^2 of it is preferred
    named_shrink: float = 0.8  # a combination that misses the floor is still named if it removes this share of the gap


def _rms(x: np.ndarray, mask=None) -> float:
    x = x if mask is None else x[mask]
    x = x[np.isfinite(x)]
    return float(np.sqrt(np.mean(x**2))) if x.size else float("nan")


@dataclass
class CandidateScore:
    """One candidate (or combination) fitted on all data and cross-validated."""

    effects: tuple
    fit: FitResult
    heldout: np.ndarray  # (P, m) pooled held-out relative residual
    score: float
    heldout_gap: float
    region_gap: float | None = None
    fold_thetas: list = field(default_factory=list, repr=False)
    folds: list = field(default_factory=list, repr=False)  # the held-out sets it was scored on
    other_forms: list = field(default_factory=list, repr=False)  # the candidate's other forms, scored alike

    @property
    def name(self) -> str:
        names = [e.name for e in self.effects if e.name != "none"]
        return "+".join(names) if names else "none"

    @property
    def n_params(self) -> int:
        return self.fit.n_params

    @property
    def at_bound(self) -> list[str]:
        """Well-determined parameters pinned at a plausibility bound (the effect is then bending itself
        to mimic something else).

        A parameter counts when the bound lies more than 3 standard deviations from zero (a poorly
        determined parameter wandering to its bound says nothing); the zero lower bound of a contact
        impedance is physical, not a plausibility limit.
        """
        out, i = [], 0
        sd = np.sqrt(np.clip(np.diag(self.fit.cov), 0, None)) if self.fit.cov.size else np.zeros(0)
        for e in self.effects:
            for j, name in enumerate(e.param_names):
                lo, hi, v = e.lower[j], e.upper[j], self.fit.theta[i + j]
                tol = 1e-3 * (hi - lo)
                at_lo = v - lo < tol and not (e.name == "contact_impedance" and lo == 0.0)
                at_hi = hi - v < tol
                if (at_lo or at_hi) and abs(v) > 3 * sd[i + j]:
                    out.append(f"{e.name}.{name}")
            i += e.n_params
        return out


def _score(heldout: np.ndarray, k: int, noise: float) -> float:
    r = heldout[np.isfinite(heldout)]
    return float(r @ r / noise**2 + k * np.log(r.size))


def _evaluate(problem, effects, folds, noise, starts, region_mask) -> CandidateScore:
    everything = np.arange(problem.obs.n_poses)
    best = None
    for s in starts:
        f = fit(problem, effects, everything, theta0=s, noise=noise)
        if best is None or f.train_rms < best.train_rms:
            best = f
    if any(e.local for e in effects):   # what one pass alone sees cannot be predicted from the other passes
        folds = segment_folds(problem.obs)
    else:                               # nor a parameter that only the held-out pass determines
        folds = folds_determining(best.jac, problem.obs, folds)
    weighted, thetas = cross_validate(problem, effects, folds, full=best, noise=noise)
    heldout = weighted / problem.weight
    return CandidateScore(
        tuple(effects), best, heldout, _score(weighted, best.n_params, noise), _rms(heldout),
        _rms(heldout, region_mask) if region_mask is not None else None, thetas, folds=folds,
    )


def _starts(problem: Problem, effect: Effect, r0: np.ndarray):
    if effect.name == "unmodelled_object":
        return object_starts(problem, np.arange(problem.obs.n_poses), r0) or [None]
    return [None]


def _combo_starts(problem: Problem, current: CandidateScore, single: CandidateScore) -> list:
    """Starts for the new effect's parameters in a combination: its own fit, and for the object a fresh
    scan of what the current combination leaves unexplained."""
    starts = [single.fit.theta]
    if single.effects[0].name == "unmodelled_object":
        everything = np.arange(problem.obs.n_poses)
        r = problem.relative_residual(predict(problem, current.effects, current.fit.theta, everything), everything)
        starts += object_starts(problem, everything, r, n_best=2)
    return starts


def score_candidate(problem: Problem, forms, folds, noise: float, r0: np.ndarray, region_mask=None) -> CandidateScore:
    """The best form of one candidate (lowest penalised held-out score), the others in its ``other_forms``."""
    scored = sorted((_evaluate(problem, [effect], folds, noise, _starts(problem, effect, r0), region_mask)
                     for effect in forms), key=lambda c: c.score)
    best = scored[0]
    best.other_forms = scored[1:]
    return best


def rank_candidates(problem, lib: dict, folds, noise, r0, region_mask=None, progress=None) -> list[CandidateScore]:
    """Every candidate alone, best first (by penalised held-out score)."""
    out = []
    for name, forms in lib.items():
        if progress:
            progress(name)
        out.append(score_candidate(problem, forms, folds, noise, r0, region_mask))
    return sorted(out, key=lambda c: c.score)


@dataclass
class Selection:
    chosen: list  # list of CandidateScore steps (cumulative combinations)
    verdict: str
    steps: list = field(default_factory=list)  # dicts: what was tried at each step and why it stopped


def forward_selection(problem, ranking: list[CandidateScore], folds, noise, rules: SelectionRules = SelectionRules(),
                      region_mask=None, floor: float | None = None,
                      model_error_by_place: dict | None = None, detection: dict | None = None) -> Selection:
    """Greedy forward selection over the single-candidate fits of ``ranking``.

    ``floor`` (default ``noise``) is the noise floor: the bench noise and the
    baseline's own estimated error in quadrature. Every threshold of
    :class:`SelectionRules` is in units of it: what the model itself cannot
    vouch for is never named as a cause: with no effect accepted, a baseline
    gap within ``none_ceiling`` x floor is answered ``none`` (with a note,
    when it is above the bench noise, that the model's own error is the
    limit, and where: ``model_error_by_place`` maps a place to the
    baseline's estimated RMS error there); ``unexplained`` only when it is
    above that.
    """
    fl = noise if floor is None else max(float(floor), noise)
    baseline = next(c for c in ranking if c.name == "none")
    singles = {c.name: c for c in ranking if c.name != "none"}
    current = baseline
    in_current = lambda c: [e.name for e in c.effects if e.name != "none"]  # noqa: E731
    path: list[CandidateScore] = []
    steps = []
    if detection is not None and not detection["detected"]:
        # no candidate improves the held-out fit beyond what the noise model gives at the false-alarm rate
        stop = (f"no candidate's held-out improvement ({detection['improvement']:.1f} s^2) exceeds the "
                f"{1 - detection['alpha']:.0%} quantile of its distribution under the noise model "
                f"({detection['improvement_threshold']:.1f} s^2; p = {detection['p_detection']:.3g})")
        if detection["p_fit_before"] < detection["alpha"]:
            return Selection([], "unexplained", [{"stop": stop + f"; yet the gap is beyond the noise model "
                                                          f"(p = {detection['p_fit_before']:.3g}): nothing in the "
                                                          "library explains it"}])
        return Selection([], "none", [{"stop": stop}])
    if detection is None and baseline.heldout_gap <= rules.start_noise * fl:
        return Selection([], "none", [{"stop": "the gap before any effect is within the noise floor"}])
    while len(path) < rules.max_effects:
        if path and detection is not None and \
                _fits_noise_model(current, problem, detection)["p_fit_after"] >= detection["alpha"]:
            steps.append({"stop": "the held-out residual is within the noise model (goodness of fit at the "
                                  "false-alarm rate)"})
            break
        if path and current.heldout_gap <= rules.at_noise * fl:
            steps.append({"stop": "the held-out gap is within the noise"})
            break
        tried = []
        for name, single in singles.items():
            if name in in_current(current):
                continue
            if any(_refines(single, singles.get(e), baseline, rules, fl) for e in in_current(current)):
                continue  # a richer variant of an effect already in: its extra parameters are refused (module doc)
            if not in_current(current):
                tried.append(single)
                continue
            effects = list(current.effects) + [single.effects[0]]
            starts = [np.concatenate([current.fit.theta, s]) for s in _combo_starts(problem, current, single)]
            tried.append(_evaluate(problem, effects, folds, noise, starts, region_mask))
        pinned = {c.name: c.at_bound for c in tried if c.at_bound}
        tried = [c for c in tried if not c.at_bound]
        if not tried:
            break
        best = _parsimonious(min(tried, key=lambda c: c.score), tried, current, rules, fl)
        if detection is None:
            best = _fewest_reaching_floor(best, tried, current, rules, fl)
        excess = current.heldout_gap**2 - fl**2
        gain = current.heldout_gap**2 - best.heldout_gap**2
        step = {"tried": {c.name: {"score": c.score, "heldout_gap": c.heldout_gap} for c in tried}, "best": best.name,
                "refused_at_bounds": pinned}
        if best.score >= current.score:
            step["stop"] = "no effect lowers the penalised held-out score"
            steps.append(step)
            break
        if gain < rules.min_gain * excess:
            step["stop"] = f"the best effect removes less than {rules.min_gain:.0%} of the excess over the noise"
            steps.append(step)
            break
        steps.append(step)
        path.append(best)
        current = best
    if len(path) >= 2:
        current = _swap_pass(problem, current, singles, folds, noise, region_mask, steps, rules, baseline)
        path[-1] = current
    if detection is not None and path:
        fits = _fits_noise_model(path[-1], problem, detection)
        steps.append({"fit_after": fits})
        if fits["p_fit_after"] >= detection["alpha"]:
            return Selection(path, "explained", steps)
    if not path:
        if detection is not None:
            verdict = "unexplained" if detection["p_fit_before"] < detection["alpha"] else "none"
        elif baseline.heldout_gap <= rules.none_ceiling * fl:
            verdict = "none"
            if baseline.heldout_gap > rules.none_ceiling * noise:
                steps.append({"stop": _model_limit_note(baseline.heldout_gap, noise, fl, model_error_by_place)})
        else:
            verdict = "unexplained"
    elif path[-1].heldout_gap <= rules.none_ceiling * fl:
        verdict = "explained"
    elif path[-1].heldout_gap <= (1 - rules.named_shrink) * baseline.heldout_gap:
        verdict = "partly explained"
    else:
        verdict = "unexplained"
        steps.append({"stop": f"no combination brings the held-out gap within {rules.none_ceiling}x the noise floor "
                              f"({100 * fl:.3g} %) nor removes {rules.named_shrink:.0%} of it: nothing is named "
                              f"(nearest: {path[-1].name}, {100 * path[-1].heldout_gap:.3g} %)"})
    return Selection(path, verdict, steps)


def _fits_noise_model(c: CandidateScore, problem, detection: dict) -> dict:
    """Goodness of fit of ``c``'s held-out residual against the noise model's distribution of SSE / s^2."""
    from electrosense.validation.diagnosis.detection import p_value

    r = c.heldout * problem.weight
    sse = float(np.nansum(r**2) / detection["noise"] ** 2)
    return {"sse_after": sse, "p_fit_after": p_value(sse, detection["null_sse"])}


def _model_limit_note(gap: float, noise: float, floor: float, by_place: dict | None) -> str:
    """Why a gap above the bench noise is still answered ``none``: it is within the model's own error.

    Example
    -------
    >>> print(_model_limit_note(0.002, 0.0005, 0.0015, {"centre": 0.0003, "wall_x-": 0.002}))
    the gap (0.2 %) is above the bench noise (0.05 %) but within the model's own error (noise floor 0.15 %): nothing is named; the model is the limit at wall_x- (0.2 %)
    """
    note = (f"the gap ({100 * gap:.3g} %) is above the bench noise ({100 * noise:.3g} %) but within the model's own "
            f"error (noise floor {100 * floor:.3g} %): nothing is named")
    worst = sorted(((e, g) for g, e in (by_place or {}).items() if e is not None and e > noise), reverse=True)
    if worst:
        note += "; the model is the limit at " + ", ".join(f"{g} ({100 * e:.3g} %)" for e, g in worst)
    return note


def _fewest_reaching_floor(best: CandidateScore, tried: list, current: CandidateScore, rules: SelectionRules,
                           floor: float) -> CandidateScore:
    """One parameter that explains the gap to the floor beats several: a one-parameter candidate whose held-out gap
    is within ``at_noise`` x floor and within one floor^2 (in mean square) of the best's is taken instead (the
    lowest score among such). Between richer candidates the score decides; the others that explain the data as
    well are reported as the ambiguity set."""
    if best.n_params <= 1 or best.heldout_gap > rules.at_noise * floor:
        return best
    # every form counts: a common contact impedance (one parameter) that reaches the floor beats per-channel gains
    # even where its per-electrode form scored better
    pool = [f for c in tried for f in (c, *c.other_forms) if not f.at_bound]
    reach = [c for c in pool if c.n_params == 1 and c.heldout_gap <= rules.at_noise * floor
             and c.score < current.score and c.heldout_gap**2 - best.heldout_gap**2 < floor**2]
    return min(reach, key=lambda c: c.score) if reach else best


def nested_angle_deg(J_simple: np.ndarray, J_rich: np.ndarray) -> float:
    """Largest principal angle (deg) between span(J_simple) and span(J_rich): 0 when the first lies in the second."""
    keep_a = np.linalg.norm(J_simple, axis=0) > 0 if J_simple.size else np.zeros(0, bool)
    keep_b = np.linalg.norm(J_rich, axis=0) > 0 if J_rich.size else np.zeros(0, bool)
    if not keep_a.any() or not keep_b.any() or keep_a.sum() > keep_b.sum():
        return 90.0
    return float(np.degrees(np.max(subspace_angles(J_simple[:, keep_a], J_rich[:, keep_b]))))


def _parsimonious(best: CandidateScore, tried: list, current: CandidateScore, rules: SelectionRules,
                  noise: float) -> CandidateScore:
    """A one-parameter candidate nested in ``best`` that does nearly as well, else ``best`` (see module doc)."""
    simpler = [c for c in tried if c.n_params == 1 < best.n_params and c.score < current.score
               and c.heldout_gap**2 - best.heldout_gap**2 < rules.nested_excess * noise**2
               and nested_angle_deg(c.fit.jac, best.fit.jac) < rules.nested_deg]
    return min(simpler, key=lambda c: (c.n_params, c.score)) if simpler else best


def _refines(rich: CandidateScore, simple: CandidateScore | None, baseline: CandidateScore,
             rules: SelectionRules, noise: float) -> bool:
    """Whether ``rich`` (alone) is a richer variant of ``simple`` (alone) that parsimony refuses."""
    return simple is not None and _parsimonious(rich, [simple], baseline, rules, noise) is simple


def _swap_pass(problem, current: CandidateScore, singles: dict, folds, noise, region_mask, steps,
               rules: SelectionRules = SelectionRules(), baseline: CandidateScore | None = None) -> CandidateScore:
    """Try replacing each chosen effect by each other candidate; keep a replacement that lowers the score.

    Greedy selection can take a broad effect first (a gain per receiver soaks
    up part of an object's signature as well as a conductivity change); once
    the rest is in the combination, the simpler, physical one may do better.
    """
    for i in range(len(current.effects)):
        best = current
        for name, single in singles.items():
            names = [e.name for e in current.effects]
            if name in names:
                continue
            effects = list(current.effects)
            parts = _split_theta(current)
            effects[i] = single.effects[0]
            parts[i] = single.fit.theta
            cand = _evaluate(problem, effects, folds, noise, [np.concatenate(parts)], region_mask)
            if cand.score < best.score and not cand.at_bound and not (
                    baseline is not None and _refines(singles[name], singles.get(current.effects[i].name), baseline,
                                                      rules, noise)):
                best = cand
        if best is not current:
            steps.append({"swap": f"{current.effects[i].name} -> {best.effects[i].name}", "score": best.score,
                          "heldout_gap": best.heldout_gap})
            current = best
    return current


def _split_theta(c: CandidateScore) -> list:
    out, i = [], 0
    for e in c.effects:
        out.append(c.fit.theta[i:i + e.n_params])
        i += e.n_params
    return out


# ------------------------------------------------------------------ confusability
#: what measurement separates two candidates (order-free keys)
SEPARATING_MEASUREMENT = {
    frozenset({"conductivity", "channel_gain"}): "log the water's conductivity with a conductimeter (the sigma_S_per_m column), or swap the receivers' channels",
    frozenset({"conductivity", "temperature_drift"}): "log the water temperature (temp_C) during the run, or repeat a pass at its start and end",
    frozenset({"conductivity", "contact_impedance"}): "a pass where the water resistance changes much (close to a wall), or a second drive frequency (z_c depends on frequency, sigma hardly)",
    frozenset({"channel_gain", "contact_impedance"}): "a pass close to a wall (the contact share changes with the water resistance), or a calibration with a known resistor",
    frozenset({"pose_offset", "tank_size"}): "passes along both axes, reaching both walls of each",
    frozenset({"water_depth", "conductivity"}): "passes at another depth z (closer to the floor or the surface)",
    frozenset({"water_depth", "tank_size"}): "passes at another depth z, and close to the walls",
    frozenset({"unmodelled_object", "tank_size"}): "a pass across the tank (another y) to locate the disturbance",
    frozenset({"unmodelled_object", "pose_offset"}): "a pass with the sensor turned (another heading) or along another line",
}


def _hint(a: str, b: str) -> str:
    return SEPARATING_MEASUREMENT.get(
        frozenset({a, b}), "poses where their sensitivities differ: other lines across the tank, other headings and depths"
    )


def confusable_pairs(ranking: list[CandidateScore], rules: SelectionRules = SelectionRules()) -> list[dict]:
    """Pairs of candidates whose sensitivity columns (on these poses) are nearly parallel."""
    singles = [c for c in ranking if c.n_params > 0]
    out = []
    for i, a in enumerate(singles):
        for b in singles[i + 1:]:
            angle = subspace_angle_deg(a.fit.jac, b.fit.jac)
            if angle < rules.confusable_deg:
                out.append({
                    "pair": [a.name, b.name],
                    "angle_deg": angle,
                    "reason": f"on these poses the sensitivities of {a.name} and {b.name} are {angle:.1f} deg apart "
                              "(a change of one is nearly a change of the other)",
                    "separate_by": _hint(a.name, b.name),
                })
    return sorted(out, key=lambda d: d["angle_deg"])
