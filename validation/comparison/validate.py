"""Validate models against a bench log: simulate every logged pose, compare receiver by receiver.

For each model (``"bem"``, ``"psm"``) the log's poses are simulated in the
log's scene (sensor, tank and conductivity of its meta line, plus any known
objects) through :func:`electrosense.validation.simulation.models.pose_evaluator`; the receiver
currents at the logged voltage ``I_k = -K[k, e] U`` are compared with the
bench's (:mod:`.metrics`), overall, per receiver and per region of the path
(:mod:`.regions`). With two models their difference on the same poses
(PSM against BEM) is reported beside. Optionally the paper's conductivity
correction (:mod:`.correction`) is fitted per model and every metric is given
again after it.

Example
-------
>>> from electrosense.validation.bench.log import read_bench_log
>>> result = validate_log(read_bench_log("run.csv"), models=("psm",))   # doctest: +SKIP
>>> result.comparisons["psm"].overall["mean_abs"]                        # doctest: +SKIP
0.0206
"""
from __future__ import annotations

import time
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from electrosense.validation.bench.log.header import tank_meta
from electrosense.validation.comparison.correction import fit_conductivity_scale
from electrosense.validation.comparison.metrics import Comparison, compare_currents
from electrosense.validation.comparison.regions import NEAR_OBJECT_M, NEAR_WALL_M, path_regions
from electrosense.validation.simulation.models import EvaluatorCache

__all__ = ["LogValidation", "validate_log", "validation_summary_rows", "MODEL_ORDER"]

MODEL_ORDER = ("bem", "psm", "map")


@dataclass
class LogValidation:
    """What :func:`validate_log` found for one log.

    Attributes
    ----------
    label : str
        The log's name (file stem).
    log : validation.bench.log.BenchLog
    regions : (P,) array of str
    model_currents_A : dict
        Model name -> (P, m) simulated receiver currents at the logged U.
    seconds : dict
        Model name -> wall-clock seconds of its simulation.
    comparisons : dict
        Model name -> :class:`Comparison` against the bench.
    model_difference : Comparison or None
        PSM against BEM on the same poses (when both were run).
    corrections : dict
        Model name -> :class:`ConductivityCorrection` (empty when not asked).
    corrected : dict
        Model name -> :class:`Comparison` after its correction.
    objects : tuple
        Known objects used for the simulation and the regions.
    thresholds_m : dict
        The region thresholds (``near_wall_m``, ``near_object_m``).
    """

    label: str
    log: object
    regions: np.ndarray
    model_currents_A: dict
    seconds: dict
    comparisons: dict
    model_difference: Comparison | None
    corrections: dict = field(default_factory=dict)
    corrected: dict = field(default_factory=dict)
    objects: tuple = ()
    thresholds_m: dict = field(default_factory=dict)

    @property
    def receivers(self) -> tuple[int, ...]:
        return tuple(self.log.sensor.receivers)

    @property
    def models(self) -> tuple[str, ...]:
        return tuple(self.model_currents_A)

    def corrected_bench_A(self, model: str | None = None) -> np.ndarray | None:
        """The bench brought back to the nominal conductivity with ``model``'s factor (default: the first model)."""
        if not self.corrections:
            return None
        model = model or next(iter(self.corrections))
        return self.corrections[model].corrected_bench(self.log.currents_A)

    def to_dict(self) -> dict:
        """JSON-ready summaries (metrics.json)."""
        log = self.log
        d = {
            "log": self.label,
            "files": [str(Path(p).name) for p in (log.paths or (log.path,)) if p is not None],
            "sensor": log.sensor.name,
            "emitter": log.emitter,
            "receivers": list(self.receivers),
            "water_depth_m": None,
            **tank_meta(log.tank),
            "sigma_S_per_m": log.sigma_S_per_m,
            "n_poses": int(len(log.poses)),
            "n_passes": int(len(log.pass_numbers)),
            "objects": [repr(o) for o in self.objects],
            "region_thresholds_m": self.thresholds_m,
            "region_counts": {str(r): int(np.sum(self.regions == r)) for r in dict.fromkeys(self.regions)},
            "models": {},
        }
        for name in self.models:
            entry = {"seconds": self.seconds.get(name), "vs_bench": self.comparisons[name].to_dict()}
            if name in self.corrections:
                entry["conductivity_correction"] = self.corrections[name].to_dict()
                entry["vs_bench_corrected"] = self.corrected[name].to_dict()
            d["models"][name] = entry
        if self.model_difference is not None:
            d["psm_vs_bem"] = self.model_difference.to_dict()
        return d


def validate_log(
    log,
    models=MODEL_ORDER,
    psm_model=None,
    conductivity_correction: bool = False,
    objects=(),
    near_wall_m: float = NEAR_WALL_M,
    near_object_m: float = NEAR_OBJECT_M,
    evaluators: EvaluatorCache | None = None,
    progress: bool = False,
    label: str | None = None,
    **bem_options,
) -> LogValidation:
    """Simulate the log's poses with each model and compare with the bench.

    Parameters
    ----------
    log : validation.bench.log.BenchLog
    models : sequence of {"bem", "psm", "map"}
        ``"map"``: a tank map, given to ``evaluators`` (:class:`EvaluatorCache` ``tank_map=``).
    psm_model : PolySphericalModel or path to its JSON, optional
        ``None``: a PSM calibrated on the sensor's free-space BEM (cached).
    conductivity_correction : bool
        Fit the paper's one-factor conductivity correction per model and
        compare again after it.
    objects : sequence of meshes.objects objects
        Known objects in the tank (simulated, and used for the regions).
    near_wall_m, near_object_m : float
        Region thresholds (m), see :func:`electrosense.validation.comparison.regions.path_regions`.
    evaluators : EvaluatorCache, optional
        Shared between logs of the same scene (built here when not given).
    progress : bool
        Progress bars of the BEM pose sweeps.
    **bem_options
        Passed to the BEM pose sweep (e.g. ``edge_length_m``).
    """
    models = tuple(dict.fromkeys(m.strip().lower() for m in models))
    unknown = [m for m in models if m not in MODEL_ORDER]
    if unknown or not models:
        raise ValueError(f"unknown model(s) {', '.join(unknown) or '(none given)'}; known: {', '.join(MODEL_ORDER)}")
    evaluators = evaluators or EvaluatorCache(psm_model=psm_model, **bem_options)
    poses = log.poses
    U = log.U_V
    bench = log.currents_A
    receivers = tuple(log.sensor.receivers)
    zero = np.argwhere(bench == 0)
    if len(zero):   # the comparison is relative to the bench: a zero reading has none; before any model runs
        i, k = zero[0]
        raise ValueError(f"{getattr(log, 'path', '') or 'the log'}: sample {i}: receiver current {k + 1} is 0 "
                         f"({len(zero)} zero reading(s)): the comparison is relative to the bench's currents")
    objects = tuple(objects)
    regions = path_regions(poses, log.tank, objects, log.sensor, near_wall_m, near_object_m)
    currents, seconds, comparisons = {}, {}, {}
    for name in models:
        t0 = time.perf_counter()
        evaluator = evaluators.get(name, log.sensor, log.tank, log.sigma_S_per_m, objects)
        C = evaluator.conductance(poses, progress=progress)
        currents[name] = C.receiver_currents_A(U)
        seconds[name] = time.perf_counter() - t0
        comparisons[name] = compare_currents(currents[name], bench, receivers, regions, model=name, reference="bench")
    difference = None
    if "bem" in currents and "psm" in currents:
        difference = compare_currents(currents["psm"], currents["bem"], receivers, regions, model="psm", reference="bem")
    corrections, corrected = {}, {}
    if conductivity_correction:
        for name in models:
            fit = fit_conductivity_scale(currents[name], bench, log.sigma_S_per_m)
            corrections[name] = fit
            corrected[name] = compare_currents(fit.apply_to_model(currents[name]), bench, receivers, regions,
                                               model=f"{name} (sigma corrected)", reference="bench")
    return LogValidation(
        label=label or (Path(log.path).stem if log.path is not None else "log"),
        log=log,
        regions=regions,
        model_currents_A=currents,
        seconds=seconds,
        comparisons=comparisons,
        model_difference=difference,
        corrections=corrections,
        corrected=corrected,
        objects=objects,
        thresholds_m={"near_wall_m": near_wall_m, "near_object_m": near_object_m},
    )


def validation_summary_rows(results) -> list[list]:
    """One row per log and comparison: mean/max/RMS/bias in percent (for tables and the terminal)."""
    rows = []
    for r in results:
        entries = [(f"{m.upper()} vs bench", r.comparisons[m]) for m in r.models]
        entries += [(f"{m.upper()} vs bench, sigma corrected", r.corrected[m]) for m in r.corrected]
        if r.model_difference is not None:
            entries.append(("PSM vs BEM", r.model_difference))
        for name, c in entries:
            s = c.overall
            rows.append([r.label, name, 100 * s["mean_abs"], 100 * s["max_abs"], 100 * s["rms"], 100 * s["bias"], s["n"]])
    return rows
