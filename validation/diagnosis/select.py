"""Ranking the candidates and choosing the effect(s): held-out scores, greedy forward selection.

Every candidate is fitted on training samples and scored on held-out ones
(:func:`validation.diagnosis.fitting.cross_validate`). Its penalised score is
a Bayesian information criterion with the noise variance s^2 estimated from
the data::

    score = SSE_heldout / s^2 + k ln N

(k parameters, N held-out residuals). A combination grows one effect at a
time (at most three), taking the effect that lowers the score most; it stops
when

* the held-out gap is already within the noise (RMS <= ``at_noise`` x s), or
* no effect lowers the score, or
* the best one removes less than ``min_gain`` of the remaining excess
  (held-out mean square above s^2): what is left is not worth a cause.

``none`` is answered when the gap before any effect is within the noise:
nothing is invented. When the gap is above the noise and no candidate removes
it, nothing is chosen and the verdict says "unexplained".

Example
-------
>>> SelectionRules().at_noise
1.25
"""
from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from .effects import Effect, Problem
from .fitting import FitResult, cross_validate, fit, object_starts, subspace_angle_deg

__all__ = ["SelectionRules", "CandidateScore", "Selection", "score_candidate", "rank_candidates", "forward_selection",
           "confusable_pairs"]


@dataclass(frozen=True)
class SelectionRules:
    """Thresholds of the selection, in units of the estimated noise."""

    at_noise: float = 1.25  # held-out RMS <= at_noise * s: the gap is noise
    min_gain: float = 0.10  # an added effect must remove >= this share of the excess mean square
    max_effects: int = 3
    confusable_deg: float = 15.0  # sensitivity subspaces closer than this: cannot be told apart


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

    @property
    def name(self) -> str:
        names = [e.name for e in self.effects if e.name != "none"]
        return "+".join(names) if names else "none"

    @property
    def n_params(self) -> int:
        return self.fit.n_params


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
    heldout, thetas = cross_validate(problem, effects, folds, full=best, noise=noise)
    return CandidateScore(
        tuple(effects), best, heldout, _score(heldout, best.n_params, noise), _rms(heldout),
        _rms(heldout, region_mask) if region_mask is not None else None, thetas,
    )


def _starts(problem: Problem, effect: Effect, r0: np.ndarray):
    if effect.name == "unmodelled_object":
        return object_starts(problem, np.arange(problem.obs.n_poses), r0) or [None]
    return [None]


def score_candidate(problem: Problem, forms, folds, noise: float, r0: np.ndarray, region_mask=None) -> CandidateScore:
    """The best form of one candidate (lowest penalised held-out score)."""
    best = None
    for effect in forms:
        cs = _evaluate(problem, [effect], folds, noise, _starts(problem, effect, r0), region_mask)
        if best is None or cs.score < best.score:
            best = cs
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
                      region_mask=None) -> Selection:
    """Greedy forward selection over the single-candidate fits of ``ranking``."""
    baseline = next(c for c in ranking if c.name == "none")
    singles = {c.name: c for c in ranking if c.name != "none"}
    current = baseline
    in_current = lambda c: [e.name for e in c.effects if e.name != "none"]  # noqa: E731
    path: list[CandidateScore] = []
    steps = []
    if current.heldout_gap <= rules.at_noise * noise:
        return Selection([], "none", [{"stop": "the gap before any effect is within the noise"}])
    while len(path) < rules.max_effects:
        if current.heldout_gap <= rules.at_noise * noise:
            steps.append({"stop": "the held-out gap is within the noise"})
            break
        tried = []
        for name, single in singles.items():
            if name in in_current(current):
                continue
            if not in_current(current):
                tried.append(single)
                continue
            effects = list(current.effects) + [single.effects[0]]
            theta0 = np.concatenate([current.fit.theta, single.fit.theta])
            tried.append(_evaluate(problem, effects, folds, noise, [theta0], region_mask))
        if not tried:
            break
        best = min(tried, key=lambda c: c.score)
        excess = current.heldout_gap**2 - noise**2
        gain = current.heldout_gap**2 - best.heldout_gap**2
        step = {"tried": {c.name: {"score": c.score, "heldout_gap": c.heldout_gap} for c in tried}, "best": best.name}
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
    verdict = "explained" if path else "unexplained"
    if path and path[-1].heldout_gap > 2 * rules.at_noise * noise:
        verdict = "partly explained"
    return Selection(path, verdict, steps)


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
