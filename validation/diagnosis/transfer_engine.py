"""A transfer log's candidates in the pose diagnosis's engine: one fit, detection, selection and verdict for both.

A transfer log (electrodes on the tank, rows of drive pattern and measurement
pair: :mod:`electrosense.validation.comparison.transfer`) and a pose log differ
in how the model's prediction is made, not in the statistics that decide
between causes. This module states a transfer log as the engine's problem,
:class:`TransferProblem`, with the interface that
:func:`~electrosense.validation.diagnosis.fitting.fit`,
:func:`~electrosense.validation.diagnosis.fitting.cross_validate`,
:func:`~electrosense.validation.diagnosis.select.rank_candidates`,
:func:`~electrosense.validation.diagnosis.detection.diagnose_detection` and
:func:`~electrosense.validation.diagnosis.select.forward_selection` use, and
its candidates as the engine's :class:`~electrosense.validation.diagnosis.effects.Effect`:

* **samples**: one row a sample (``m = 1``); the rows of one drive pattern
  are a *pass*. Held out as whole drive patterns (every fifth one in a fold:
  both parities in each, so a multiplexer class is always seen by the
  training set), or as segments of every drive pattern where a candidate's
  parameters are seen by the held-out drives alone
  (:func:`~electrosense.validation.diagnosis.fitting.folds_determining`).
* **noise model**: white, relative, one variance: the log's own reciprocity
  floor per measurement (:func:`electrosense.validation.comparison.transfer.noise_floor`),
  measured before any model is fitted. The BEM's own error is not in it (the
  scene fit of :mod:`.tank_scene_fit` measures it on a finer mesh).
* **the units' scale**: a transfer log's units are the instrument's, so the
  model is first scaled to the measured magnitudes (their mean ratio over
  every row, so that the relative residual has zero mean) and every candidate's columns are made orthogonal to the model in the
  relative residual's metric: a fit of a block is then the fit of the block
  and the scale together (Frisch-Waugh-Lovell), in every fold alike. The one
  number fitted on all rows makes each held-out gap optimistic by one
  parameter among the rows, the same for every candidate.
* **candidates**: the column blocks of :mod:`electrosense.validation.diagnosis.transfer`
  (linear about the one solve: per-channel gains and offsets, a multiplexer's
  classes, a ground's share of the current, the electrodes moved along the
  ring and up the wall, the water depth, the ring's radius, the wall's taper),
  each with its physical units and bounds, and the common-mode error of a
  magnitude demodulator (:mod:`electrosense.validation.diagnosis.common_mode`:
  ``g |Z + (c' + i c'') V_cm|``, fitted in ``c''^2 >= 0`` so that no
  quadrature is not a saddle point). Blocks whose columns change nothing
  along one direction (a rigid rotation of the ring, the channels' mean gain
  that the scale carries) are parametrised with that direction removed: the
  last parameter is minus the sum of the others.

Combinations come from the engine's greedy forward selection, the verdict from
its detection test (a stated false-alarm rate, the null drawn under the noise
model) and its goodness of fit, every parameter with its standard error and
95 % interval.

Example
-------
Per-channel gains of 1 % and -1 % in a synthetic log (two channels, eight drive patterns), named by the engine:

>>> rng = np.random.default_rng(0)
>>> drive_index = np.repeat(np.arange(8), 6); channel = np.tile([0, 1], 24)
>>> Zm = rng.uniform(1.0, 2.0, 48); Zd = 3.0 * Zm * np.where(channel == 0, 1.01, 0.99)
>>> Zd = Zd * (1 + 1e-3 * rng.standard_normal(48))
>>> blocks = [Block("channel_gains", np.c_[Zm * (channel == 0), Zm * (channel == 1)], ("gain_1", "gain_2"), "1",
...                 0.5, gauge=True)]
>>> out, _, _ = diagnose_rows(TransferProblem.scaled(drive_index, Zm, Zd, np.ones(48), blocks), noise=1e-3)
>>> out["verdict"], out["chosen"], [round(g, 3) for g in out["parameters"]["channel_gains"].values()]
('explained', 'channel_gains', [0.01, -0.01])
"""
from __future__ import annotations

from dataclasses import dataclass, field, replace

import numpy as np

from electrosense.validation.diagnosis.bem_secant import SecantCorrection
from electrosense.validation.diagnosis.detection import ALPHA, diagnose_detection
from electrosense.validation.diagnosis.effects import Effect
from electrosense.validation.diagnosis.fitting import make_folds, predict
from electrosense.validation.diagnosis.select import (
    SelectionRules,
    confusable_pairs,
    forward_selection,
    rank_candidates,
    score_candidate,
)

__all__ = ["TransferRows", "TransferScenario", "Block", "TransferProblem", "transfer_library", "bem_secants",
           "diagnose_rows"]

#: a parameter's typical size: the change that moves the rows it touches by this much (relative RMS)
TYPICAL_CHANGE_REL = 0.01


@dataclass(frozen=True)
class TransferRows:
    """The rows of a transfer log as the engine's samples: ``drive_index`` (R,) the drive pattern of each row."""

    drive_index: np.ndarray

    @property
    def n_poses(self) -> int:
        return int(len(self.drive_index))

    @property
    def n_receivers(self) -> int:
        return 1

    def pass_indices(self) -> list[np.ndarray]:
        """The rows of each drive pattern, in the order of the patterns."""
        return [np.flatnonzero(self.drive_index == d) for d in np.unique(self.drive_index)]


@dataclass
class TransferScenario:
    """What is predicted for the rows ``rows`` (sorted): the model plus ``added`` (measured units), then the
    common-mode reading ``common_mode`` = (log gain, c', c''^2) where a candidate sets it."""

    rows: np.ndarray
    added: np.ndarray
    common_mode: np.ndarray | None = None


@dataclass(frozen=True)
class Block:
    """One linear candidate: ``columns`` (R, k), the change of each row (measured units) per unit of each parameter.

    ``units``: the parameters' unit; ``bound``: the largest plausible magnitude of a parameter (physical units);
    ``gauge``: the columns' sum changes nothing (a rigid motion, the scale's share): the last parameter is minus
    the sum of the others.
    """

    name: str
    columns: np.ndarray = field(repr=False)
    param_names: tuple
    units: str
    bound: float
    gauge: bool = False
    describe: str = ""


@dataclass
class TransferProblem:
    """A transfer log's diagnosis problem (the interface of :class:`~.effects.Problem` that the engine uses).

    ``Z_model`` (R,): the model's values in the measured units (the scale applied); ``Z_measured`` (R,);
    ``norm`` (R,): what each row's residual is divided by. Without it the rows are magnitudes (an instrument that
    demodulates |Z|) and each is relative to the model's own: ``norm = |Z_model|``. With it, signed values (a
    voltage that changes sign across the ring) relative to a common size, e.g. the model's RMS. ``sign`` (R,):
    the signed transfer's sign (magnitudes); ``V_cm`` (R,): the common-mode voltage per unit current in the
    measured units (None: no common-mode candidate); ``columns``: the blocks' columns as the effects apply them
    (orthogonal to the model, gauge removed); ``blocks``: the :class:`Block` of each.
    """

    obs: TransferRows
    Z_model: np.ndarray
    Z_measured: np.ndarray
    sign: np.ndarray | None = None
    V_cm: np.ndarray | None = None
    blocks: dict = field(default_factory=dict)
    columns: dict = field(default_factory=dict)
    scale: float = 1.0
    norm: np.ndarray | None = None
    baseline_name: str = "BEM"
    secants: dict = field(default_factory=dict)
    object_field: object = None
    weight: np.ndarray = field(init=False)
    I_base: np.ndarray = field(init=False)

    def __post_init__(self):
        self.Z_model, self.Z_measured = np.asarray(self.Z_model, float), np.asarray(self.Z_measured, float)
        if self.norm is None:
            self.Z_model, self.Z_measured = np.abs(self.Z_model), np.abs(self.Z_measured)
            self.norm = self.Z_model
        self.norm = np.broadcast_to(np.asarray(self.norm, float), self.Z_model.shape)
        if np.any(self.norm == 0):
            raise ValueError("a row's residual would be divided by zero (a zero model magnitude or norm)")
        self.I_base = self.Z_model[:, None]
        self.weight = np.ones_like(self.I_base)
        for b in self.blocks.values():
            self.columns[b.name] = self.effect_columns(b)

    @classmethod
    def scaled(cls, drive_index, Z_model, Z_measured, sign=None, blocks=(), V_cm=None,
               norm=None) -> "TransferProblem":
        """The problem with the model scaled to the measured units and the blocks' and the common mode's columns
        scaled alike (they are given in the model's units). The scale is the least squares of the residual in
        its metric (``norm`` in the model's units, see the class; for magnitudes the mean ratio, so that the
        relative residual has zero mean)."""
        Zm, Zd = np.asarray(Z_model, float), np.asarray(Z_measured, float)
        if norm is None:
            Zm, Zd = np.abs(Zm), np.abs(Zd)
        n = Zm if norm is None else np.broadcast_to(np.asarray(norm, float), Zm.shape)
        s = float(np.sum(Zd * Zm / n**2) / np.sum(Zm**2 / n**2))
        blocks = {b.name: replace(b, columns=s * np.asarray(b.columns, float).reshape(len(Zm), -1)) for b in blocks}
        return cls(TransferRows(np.asarray(drive_index)), s * Zm, Zd, None if sign is None else np.asarray(sign, float),
                   None if V_cm is None else s * np.asarray(V_cm, float), blocks, scale=s,
                   norm=None if norm is None else s * n)

    def effect_columns(self, b: Block) -> np.ndarray:
        """``b``'s columns orthogonal to the model in the residual's metric (the scale refitted with them), the
        gauge direction removed."""
        X = np.asarray(b.columns, float).reshape(self.obs.n_poses, -1)
        z = self.Z_model / self.norm                # the model's column in the residual's metric
        Xr = X / self.norm[:, None]
        Xr = Xr - z[:, None] * (z @ Xr) / (z @ z)
        X = Xr * self.norm[:, None]
        return X[:, :-1] - X[:, -1:] if b.gauge and X.shape[1] > 1 else X

    def physical(self, name: str, theta) -> np.ndarray:
        """Every parameter of block ``name`` from the fitted ones (the gauge's last one restored)."""
        theta = np.asarray(theta, float)
        return np.r_[theta, -theta.sum()] if self.blocks[name].gauge and len(self.blocks[name].param_names) > 1 \
            else theta

    # the engine's interface -------------------------------------------------------------------------------
    def nominal(self, idx) -> TransferScenario:
        idx = np.asarray(idx)
        return TransferScenario(rows=idx, added=np.zeros(len(idx)))

    def predict(self, scenario: TransferScenario, idx) -> np.ndarray:
        """Predicted magnitudes (p, 1) of ``scenario`` at the rows ``idx``."""
        idx = np.asarray(idx)
        at = np.searchsorted(scenario.rows, idx)
        Z = self.Z_model[idx] + scenario.added[at]
        if scenario.common_mode is not None:
            log_gain, c_in, c_quad_sq = scenario.common_mode
            X = self.V_cm[idx]
            Z = np.exp(log_gain) * np.hypot(self.sign[idx] * Z + c_in * X, np.sqrt(max(c_quad_sq, 0.0)) * X)
        return Z[:, None]

    def relative_residual(self, I_pred: np.ndarray, idx) -> np.ndarray:
        """(measured - predicted) / norm at the rows ``idx``: (p, 1)."""
        idx = np.asarray(idx)
        return (self.Z_measured[idx, None] - I_pred) / self.norm[idx, None]


def _typical(col_rel: np.ndarray) -> float:
    rms = float(np.sqrt(np.mean(col_rel**2)))
    return TYPICAL_CHANGE_REL / rms if rms > 0 else 1.0


def _block_effect(problem: TransferProblem, b: Block) -> Effect:
    X = problem.columns[b.name]
    names = tuple(b.param_names[:X.shape[1]])

    def apply(theta, sc, pb, idx):
        return replace(sc, added=sc.added + pb.columns[b.name][sc.rows] @ np.asarray(theta, float))

    scales = tuple(_typical(X[:, j] / problem.norm) for j in range(X.shape[1]))
    return Effect(b.name, "", names, (b.units,) * len(names), scales, (-b.bound,) * len(names),
                  (b.bound,) * len(names), apply, describe=b.describe)


def _common_mode(theta, sc, pb, idx):
    return replace(sc, common_mode=np.asarray(theta, float))


def transfer_library(problem: TransferProblem) -> dict[str, list[Effect]]:
    """The candidates of ``problem``: one per block, the common mode where ``V_cm`` is given, and ``none``."""
    lib = {name: [_block_effect(problem, b)] for name, b in problem.blocks.items()}
    if problem.V_cm is not None and problem.sign is not None:
        x = float(np.sqrt(np.mean((problem.V_cm / problem.norm) ** 2)))
        lib["common_mode"] = [Effect(
            "common_mode", "", ("log_gain", "c_in_phase", "c_quadrature_sq"), ("1", "1", "1"),
            (TYPICAL_CHANGE_REL, TYPICAL_CHANGE_REL / max(x, 1e-12), (TYPICAL_CHANGE_REL / max(x, 1e-12)) ** 2),
            (-0.5, -1.0, 0.0), (0.5, 1.0, 1.0), _common_mode,
            describe="the instrument reads g |Z + (c' + i c'') V_cm|: a fraction of each pair's common-mode voltage "
                     "against its ground, demodulated as a magnitude (c''^2 fitted: its sign is not determined)")]
    lib["none"] = [Effect("none", "", (), (), (), (), (), lambda theta, sc, pb, idx: sc,
                          describe="nothing beyond the units' scale: the gap is noise")]
    return lib


def _named_parameters(problem: TransferProblem, c) -> tuple[dict, dict]:
    """``{effect: {param: value}}`` and their standard errors, physical (a gauge's last parameter restored, its
    standard error from the covariance of the sum)."""
    values, errors, i = {}, {}, 0
    cov = c.fit.cov
    for e in c.effects:
        k = e.n_params
        th = c.fit.theta[i:i + k]
        C = cov[i:i + k, i:i + k] if cov.size else np.zeros((k, k))
        names = list(e.param_names)
        if e.name in problem.blocks:
            th = problem.physical(e.name, th)
            if len(th) > k:
                names = list(problem.blocks[e.name].param_names)
                T = np.vstack([np.eye(k), -np.ones((1, k))])
                C = T @ C @ T.T
        sd = np.sqrt(np.clip(np.diag(C), 0, None))
        if e.name == "common_mode" and e.name not in problem.blocks:      # |c''| from c''^2 (delta method; at zero its se is that of sqrt)
            q, sq = max(float(th[2]), 0.0), float(sd[2])
            th, sd = np.r_[th[:2], np.sqrt(q)], np.r_[sd[:2], sq / (2 * np.sqrt(q)) if q > 0 else np.sqrt(sq)]
            names = ["log_gain", "c_in_phase", "c_quadrature_abs"]
        if e.name != "none":
            values[e.name] = {n: float(v) for n, v in zip(names, th)}
            errors[e.name] = {n: float(v) for n, v in zip(names, sd)}
        i += k
    return values, errors


def _interval(values: dict, errors: dict) -> dict:
    z = 1.959963984540054
    return {e: {p: [v - z * errors[e][p], v + z * errors[e][p]] for p, v in ps.items()} for e, ps in values.items()}


def _restore(problem, label, name, kept) -> None:
    """Put back a block's previous secant correction (or none) and columns, ``kept`` = (secant, columns)."""
    problem.secants.pop(label, None)
    if kept[0] is not None:
        problem.secants[label] = kept[0]
    problem.columns[name] = kept[1]


def bem_secants(problem: TransferProblem, ranking: list, lib: dict, solve_at, names, folds, noise: float, r0,
                iterations: int = 4) -> tuple[list, list[dict]]:
    """Geometric candidates made exact on the BEM where they were fitted (:mod:`.bem_secant`'s correction).

    A block is the BEM's first order about the stated scene; a move of a few millimetres leaves its second order
    in the held-out gap. For each candidate in ``names``, the scene at its fitted parameters is solved
    (``solve_at``, see :func:`diagnose_rows`), and ``c = log(|Z_BEM| / Z_block)`` at every row (its mean, a change
    of scale, removed: the scale is refitted with every candidate) is added to the block's prediction in
    proportion to the parameters' projection on the fitted ones
    (:class:`~.bem_secant.SecantCorrection`): exact at no change and at the fitted one. Where the solve also
    gives the block's columns there (an electrode's move: the BEM's sensitivities at the moved scene), the block
    takes them: its derivative at the fitted parameters is then the BEM's too (a Newton step; the secant alone
    converges about linearly, halving the excess gap a solve on a synthetic phantom). The candidate is then
    fitted and scored again, and the scene at its new parameters solved again, ``iterations`` times at most, as
    long as the penalised held-out score falls. Returns the ranking (re-sorted) and, per candidate, what each
    solve gave and its final parameters with their standard errors.
    """
    if np.any(problem.Z_model <= 0):
        raise ValueError("the BEM's steps correct magnitudes by their log-ratio: this problem's rows are signed")
    everything = np.arange(problem.obs.n_poses)
    by_name = {c.name: c for c in ranking}
    infos = []
    for name in names:
        best = by_name[name]
        effect = best.effects[0]
        info = {"effect": name, "heldout_rms_rel_linear": best.heldout_gap, "solves": []}
        for _ in range(iterations):
            theta = np.asarray(best.fit.theta, float)
            try:
                Z, fraction, note, columns = solve_at(name, problem.physical(name, theta))
            except (ValueError, MemoryError, np.linalg.LinAlgError) as exc:   # said, the linear candidate stands
                info["solves"].append({"refused": f"{type(exc).__name__}: {exc}"})
                break
            kept = problem.secants.pop(effect.label, None), problem.columns[name]
            if columns is not None:     # the BEM's own sensitivities where it was solved: a Newton step
                problem.columns[name] = problem.effect_columns(
                    replace(problem.blocks[name], columns=problem.scale * np.asarray(columns, float)))
            theta_hat = fraction * theta
            Z_block = predict(problem, [effect], theta_hat, everything)[:, 0]
            if np.any(Z_block <= 0):        # the linear block far outside its range: no ratio to correct by
                info["solves"].append({"refused": f"the linear block predicts a magnitude <= 0 on "
                                                  f"{int(np.sum(Z_block <= 0))} of {len(Z_block)} rows at its "
                                                  "fit: far outside the range where it is linear"})
                _restore(problem, effect.label, name, kept)
                break
            c = np.log(problem.scale * np.abs(Z) / Z_block)
            c = c - c.mean()
            problem.secants[effect.label] = SecantCorrection(theta_hat / np.asarray(effect.scales, float), c[:, None])
            again = score_candidate(problem, lib[name], folds, noise, r0)
            step = {"fraction_solved": float(fraction), "block_vs_bem_rms_rel": float(np.sqrt(np.mean(c**2))),
                    "heldout_rms_rel": again.heldout_gap, **({"note": note} if note else {})}
            info["solves"].append(step)
            if again.score >= best.score:        # no better: the previous correction (or none) stays
                _restore(problem, effect.label, name, kept)
                break
            best = by_name[name] = again
        info["heldout_rms_rel"] = best.heldout_gap
        values, errors = _named_parameters(problem, best)
        info["parameters"], info["standard_errors"] = values.get(name, {}), errors.get(name, {})
        infos.append(info)
    return sorted(by_name.values(), key=lambda c: c.score), infos


def diagnose_rows(problem: TransferProblem, noise: float, folds=None, rules: SelectionRules = SelectionRules(),
                  alpha: float = ALPHA, lib: dict | None = None, solve_at=None, solvable=(),
                  noise_source: str = "the log's reciprocity floor") -> tuple[dict, np.ndarray, np.ndarray]:
    """The engine's diagnosis of a transfer problem: ranking, detection, selection, verdict.

    ``noise``: the relative noise per row (``noise_source`` says where it comes from); ``folds`` default to whole drive patterns,
    every fifth in a fold (:func:`~.fitting.make_folds`). ``solve_at(name, theta) -> (|Z| (R,) model units,
    fraction of theta solved, note, the block's columns there or None)``: the BEM at a geometric candidate's fitted parameters (physical, every one,
    :meth:`TransferProblem.physical`), for the candidates named in ``solvable`` whose held-out improvement alone
    passes the detection test (:func:`bem_secants`). Returns a JSON-ready dict and the held-out relative
    residuals (R,) of the baseline and of the selection's last combination (the baseline's where the verdict is
    ``none``). The dict: ``verdict``, ``chosen``
    (``a+b``, ``none`` or ``""`` when unexplained), ``combination`` (the selection's last, named or not),
    ``gap_before`` / ``gap_after`` (held-out RMS, relative),
    ``parameters`` / ``standard_errors`` / ``interval_95`` of the chosen combination, ``ranking`` (every
    candidate alone), ``detection``, ``confusable`` (pairs of candidates whose sensitivities on these rows are
    nearly parallel: what the data cannot separate) and ``steps``.
    """
    lib = transfer_library(problem) if lib is None else lib
    folds = make_folds(problem.obs) if folds is None else folds
    everything = np.arange(problem.obs.n_poses)
    r0 = problem.relative_residual(problem.I_base, everything)
    ranking = rank_candidates(problem, lib, folds, noise, r0)
    detection = diagnose_detection(problem, ranking, folds, noise, alpha=alpha)
    secants = []
    if solve_at is not None:
        significant = [c.name for c in ranking if c.name in problem.blocks and c.name in solvable
                       and detection["p_by_candidate"].get(c.name, 1.0) < alpha]
        if significant:
            ranking, secants = bem_secants(problem, ranking, lib, solve_at, significant, folds, noise, r0)
            detection = diagnose_detection(problem, ranking, folds, noise, alpha=alpha)
    selection = forward_selection(problem, ranking, folds, noise, rules, floor=noise, detection=detection)
    base = next(c for c in ranking if c.name == "none")
    final = selection.chosen[-1] if selection.chosen and selection.verdict != "none" else base
    chosen = {"none": "none", "unexplained": ""}.get(selection.verdict, final.name)
    values, errors = _named_parameters(problem, final)

    def row(c):
        v, s = _named_parameters(problem, c)
        return {"effect": c.name, "n_params": c.n_params, "heldout_rms_rel": c.heldout_gap,
                "score": c.score, "delta_score_vs_none": c.score - base.score, "at_bound": c.at_bound,
                "heldout_by": "whole drive patterns" if c.folds is folds or not c.folds
                else "segments of every drive pattern", "parameters": v, "standard_errors": s}

    return {
        "engine": "the pose diagnosis's: held-out likelihood with a BIC charge per parameter, a detection test at a "
                  f"false-alarm rate of {alpha:.0%} (null drawn under the noise model), greedy forward selection",
        "noise_rel": float(noise),
        "noise_model": f"white relative noise of {100 * noise:.3g} % per measurement ({noise_source})",
        "verdict": selection.verdict,
        "chosen": chosen,
        "combination": final.name,      # the selection's last combination: the nearest where nothing is named
        "gap_before": base.heldout_gap,
        "gap_after": final.heldout_gap,
        "shrink": 1 - final.heldout_gap / base.heldout_gap if base.heldout_gap > 0 else 0.0,
        "units_scale": problem.scale,
        "parameters": values,
        "standard_errors": errors,
        "interval_95": _interval(values, errors),
        "ranking": [row(c) for c in ranking],
        "detection": {k: v for k, v in detection.items() if k not in ("null_sse",)},
        "confusable": [{k: v for k, v in c.items() if k != "separate_by"} for c in confusable_pairs(ranking, rules)],
        "bem_secants": secants,
        "steps": selection.steps,
        "folds": "whole drive patterns, every fifth in a fold; segments of every pattern where the held-out patterns "
                 "alone see a parameter",
    }, base.heldout[:, 0], final.heldout[:, 0]
