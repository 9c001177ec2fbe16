"""How far a model's receiver currents are from a reference's (the bench, or the BEM).

The relative error of receiver k at pose p is

    e[p, k] = (I_model[p, k] - I_ref[p, k]) / I_ref[p, k],

positive when the model predicts more current than the reference. Its
summaries, per receiver, over all receivers, and per region of the path:

* ``mean_abs``: mean of |e|, the paper's "mean relative error";
* ``max_abs``: max of |e|;
* ``rms``: sqrt(mean e^2);
* ``bias``: mean of e (signed: a conductivity error shows as a bias);
* ``n``: number of samples.

All values are plain fractions (multiply by 100 for percent).

Example
-------
>>> import numpy as np
>>> bench = np.array([[1.0, 2.0], [1.0, 2.0]])
>>> summary = error_summary(relative_error(1.01 * bench, bench))
>>> round(summary["bias"], 12), round(summary["max_abs"], 12)
(0.01, 0.01)
"""
from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

__all__ = ["noise_level",
    "relative_error",
    "error_summary",
    "Comparison",
    "compare_currents",
    "SUMMARY_KEYS",
]

SUMMARY_KEYS = ("mean_abs", "max_abs", "rms", "bias", "n")


def relative_error(model_A, reference_A) -> np.ndarray:
    """(model - reference) / reference, element by element.

    Raises
    ------
    ValueError
        When the shapes differ, or a reference current is zero or not finite
        (the relative error would be meaningless there), naming the first
        offending index.
    """
    model = np.asarray(model_A, dtype=float)
    ref = np.asarray(reference_A, dtype=float)
    if model.shape != ref.shape:
        raise ValueError(f"model currents {model.shape} and reference currents {ref.shape} differ in shape")
    for name, a in (("reference", ref), ("model", model)):
        bad = ~np.isfinite(a)
        if bad.any():
            raise ValueError(f"{name} currents are not finite at index {tuple(int(i) for i in np.argwhere(bad)[0])}")
    zero = ref == 0
    if zero.any():
        raise ValueError(
            f"reference current is zero at index {tuple(int(i) for i in np.argwhere(zero)[0])}: "
            "no relative error there"
        )
    return (model - ref) / ref


def error_summary(e) -> dict:
    """mean |e|, max |e|, RMS, bias (mean e) and count of an array of relative errors."""
    e = np.asarray(e, dtype=float).ravel()
    if e.size == 0:
        return {"mean_abs": None, "max_abs": None, "rms": None, "bias": None, "n": 0}
    a = np.abs(e)
    return {
        "mean_abs": float(a.mean()),
        "max_abs": float(a.max()),
        "rms": float(np.sqrt(np.mean(e**2))),
        "bias": float(e.mean()),
        "n": int(e.size),
    }


@dataclass
class Comparison:
    """A model's currents beside a reference's, with the summaries.

    Attributes
    ----------
    model, reference : str
        Names (``"bem"``, ``"psm"``, ``"bench"``...).
    receivers : tuple of int
        1-based receiver numbers, the columns of the current arrays.
    model_A, reference_A : (P, m) arrays
        Currents into the receivers (A).
    regions : (P,) array of str
        Region label of each pose (:func:`electrosense.validation.comparison.regions.path_regions`).
    error : (P, m) array
        Relative error (model - reference) / reference.
    """

    model: str
    reference: str
    receivers: tuple[int, ...]
    model_A: np.ndarray
    reference_A: np.ndarray
    regions: np.ndarray
    error: np.ndarray = field(init=False)

    def __post_init__(self):
        self.model_A = np.atleast_2d(np.asarray(self.model_A, dtype=float))
        self.reference_A = np.atleast_2d(np.asarray(self.reference_A, dtype=float))
        self.error = relative_error(self.model_A, self.reference_A)
        P, m = self.error.shape
        if len(self.receivers) != m:
            raise ValueError(f"{m} current columns but {len(self.receivers)} receiver numbers {self.receivers}")
        self.regions = np.asarray(self.regions, dtype=str).ravel()
        if self.regions.shape != (P,):
            raise ValueError(f"{P} poses but {self.regions.size} region labels")

    @property
    def overall(self) -> dict:
        return error_summary(self.error)

    @property
    def by_receiver(self) -> dict:
        return {str(k): error_summary(self.error[:, j]) for j, k in enumerate(self.receivers)}

    @property
    def by_region(self) -> dict:
        """Region -> {"all": summary, "receivers": {k: summary}} in order of first appearance."""
        out = {}
        for region in dict.fromkeys(self.regions):
            rows = self.regions == region
            out[str(region)] = {
                "all": error_summary(self.error[rows]),
                "receivers": {str(k): error_summary(self.error[rows, j]) for j, k in enumerate(self.receivers)},
            }
        return out

    def to_dict(self) -> dict:
        """The JSON-ready summaries (no per-pose arrays)."""
        return {
            "model": self.model,
            "reference": self.reference,
            "error_definition": f"({self.model} - {self.reference}) / {self.reference}, receiver currents",
            "all": self.overall,
            "receivers": self.by_receiver,
            "regions": self.by_region,
        }


def compare_currents(model_A, reference_A, receivers, regions=None, model="model", reference="bench") -> Comparison:
    """Build a :class:`Comparison`; ``regions`` default to one region ``"all"``.

    Example
    -------
    >>> import numpy as np
    >>> c = compare_currents(np.array([[1.0], [2.2]]), np.array([[1.0], [2.0]]), receivers=(1,))
    >>> round(c.overall["max_abs"], 12)
    0.1
    """
    model_A = np.atleast_2d(np.asarray(model_A, dtype=float))
    if regions is None:
        regions = np.full(model_A.shape[0], "all")
    return Comparison(model, reference, tuple(int(k) for k in receivers), model_A, reference_A, regions)


def noise_level(r: np.ndarray, groups) -> float:
    """Relative noise (1 sigma) from the second differences of ``r`` (P, m) along each group (time-ordered indices).

    White noise of spread s gives second differences of spread sqrt(6) s; a
    smooth gap gives almost none. A robust first estimate (median absolute
    deviation) sets a 3-sigma cut against the few large differences where the
    gap bends sharply; the RMS of the rest, corrected for the cut, is the
    estimate (more precise than the MAD alone on Gaussian noise).
    """
    d = []
    for g in groups:
        if len(g) >= 3:
            x = r[g]
            d.append((x[:-2] - 2 * x[1:-1] + x[2:]).ravel())
    if not d:
        raise ValueError("need at least 3 samples in a pass to estimate the noise")
    d = np.concatenate(d)
    spread = 1.4826 * np.median(np.abs(d - np.median(d)))
    if spread == 0:
        return 0.0
    kept = d[np.abs(d - np.median(d)) < 3 * spread]
    # variance of a unit Gaussian truncated at +-3: 1 - 6 phi(3) / (2 Phi(3) - 1) = 0.97334
    return float(np.sqrt(np.mean((kept - np.median(d)) ** 2) / 0.97334) / np.sqrt(6.0))
