"""Reader of the KTC2023 tank layout (Kuopio Tomography Challenge 2023): current patterns, measurement pattern,
voltages, and the truth masks of the objects; and the data's own linear floor.

Layout (one file a tank state): ``Inj`` (``Injref`` in ``ref.mat``), (E, P): the current on each electrode in
each pattern; ``Mpat``, (E, M): measurement m reads ``Mpat[:, m] @ U`` (electrode m minus m+1 in the series);
``Uel`` (``Uelref``), (P*M, 1): the voltages, pattern after pattern, NaN where an electrode was out of use.
``trueN.mat``: ``truth``, an (N, N) uint8 mask, 0 water, 1 resistive (plastic), 2 conductive (metal), pixels
of ``side / N`` over ``[-side/2, side/2]^2``, column j at ``x = -side/2 + (j + 1/2) w``, row i at
``y = +side/2 - (i + 1/2) w``.

The linear floor: a linear medium (any conductivity, any contact impedances, any geometry) makes the
voltages of a pattern the same linear map of its currents, ``U[p, m] = Inj[:, p] @ B[:, m]``. Where the
patterns are linearly dependent (KTC: 76 patterns spanning 15 dimensions), the data must obey the same
dependencies; how far they miss them is what the instrument adds and no model of the medium can remove
(:func:`linear_floor`).

Example
-------
>>> rng = np.random.default_rng(0)
>>> inj = rng.standard_normal((8, 3)) @ rng.standard_normal((3, 10))     # 10 patterns spanning 3 dimensions
>>> B = rng.standard_normal((8, 7))
>>> U = inj.T @ B
>>> round(linear_floor(inj, U)["floor_rms_rel"], 12), linear_floor(inj, U + 0.01 * rng.standard_normal(U.shape))["rank"]
(0.0, 3)
"""
from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np

from electrosense.validation.bench.log.errors import BenchLogError

__all__ = ["KtcMeasurement", "KtcTruth", "KtcFolder", "linear_floor", "read_ktc_mat", "read_ktc_truth",
           "read_ktc_folder", "usable", "ktc_patterns"]


@dataclass(frozen=True)
class KtcMeasurement:
    """One tank state: ``injection`` (E, P) in the file's current units, ``measurement_pattern`` (E, M),
    ``voltages_V`` (P, M) with NaN where not measured, and the file it came from."""

    injection: np.ndarray
    measurement_pattern: np.ndarray
    voltages_V: np.ndarray
    source: str

    @property
    def electrodes_out_of_use(self) -> list[int]:
        """1-based electrodes that no finite voltage reads (every measurement that touches them is NaN)."""
        read = np.isfinite(self.voltages_V).any(axis=0)                 # measurements finite somewhere
        used = np.abs(self.measurement_pattern[:, read]).sum(axis=1) > 0
        return [int(e) + 1 for e in np.flatnonzero(~used)]


@dataclass(frozen=True)
class KtcTruth:
    """An object mask (N, N): 0 water, 1 resistive, 2 conductive; pixel ``w_m`` wide, row 0 at ``y = +side/2``."""

    mask: np.ndarray
    side_m: float

    @property
    def pixel_m(self) -> float:
        return self.side_m / self.mask.shape[0]

    def centres_m(self) -> tuple[np.ndarray, np.ndarray]:
        """(x, y) of the pixel centres, each (N,): x by column, y by row."""
        n, w = self.mask.shape[0], self.pixel_m
        c = -0.5 * self.side_m + (np.arange(n) + 0.5) * w
        return c, -c


@dataclass(frozen=True)
class KtcFolder:
    """A folder of the series: its empty tank (``ref.mat``) and each tank with objects, ``{name: (measurement,
    truth)}`` (``name`` ``data1``, ...); ``notes``: files left out and why."""

    path: str
    ref: KtcMeasurement
    tanks: dict
    notes: tuple = ()


def usable(meas: KtcMeasurement) -> tuple[np.ndarray, list[int], list[int]]:
    """Which voltages can be scored: (P, M) mask, the electrodes out of use (1-based), the patterns left out.

    An electrode is out of use where no finite voltage reads it; it carries no
    current, so a pattern that puts current on it is left out whole (its
    voltages were not made by the currents the file states), and every
    measurement that touches it is NaN already.

    >>> inj = np.array([[1.0, 0.0], [-1.0, 1.0], [0.0, -1.0], [0.0, 0.0]])
    >>> mp = np.array([[1.0, 0, 0], [-1, 1, 0], [0, -1, 1], [0, 0, -1]])
    >>> U = np.array([[0.5, np.nan, np.nan], [0.1, np.nan, np.nan]])
    >>> ok, out, left = usable(KtcMeasurement(inj, mp, U, "x.mat"))
    >>> out, left, int(ok.sum())
    ([3, 4], [2], 1)
    """
    out = meas.electrodes_out_of_use
    ok = np.isfinite(meas.voltages_V)
    left = []
    if out:
        drives = np.abs(meas.injection[np.array(out) - 1]).max(axis=0) > 0
        left = [int(p) + 1 for p in np.flatnonzero(drives)]
        ok[drives] = False
    return ok, out, left


def read_ktc_folder(path) -> KtcFolder:
    """``ref.mat`` and every ``dataN.mat`` with its ``trueN.mat`` of a folder; a ``dataN.mat`` without its truth,
    or of another layout than the reference's, is left out with a note (no file outside the folder is read)."""
    import re

    folder = Path(path)
    if not folder.is_dir():
        raise BenchLogError(str(folder), None, "not a folder (a KTC folder holds ref.mat, dataN.mat, trueN.mat)")
    ref_path = folder / "ref.mat"
    if not ref_path.is_file():
        raise BenchLogError(str(folder), None, "no ref.mat (the empty tank) in this folder")
    ref = read_ktc_mat(ref_path)
    tanks, notes = {}, []
    numbered = sorted((int(m.group(1)), f) for f in folder.iterdir()
                      if f.is_file() and (m := re.fullmatch(r"data(\d+)\.mat", f.name)))
    for n, f in numbered:
        truth = folder / f"true{n}.mat"
        if not truth.is_file():
            notes.append(f"{f.name}: no true{n}.mat beside it, left out")
            continue
        d = read_ktc_mat(f)
        if d.injection.shape != ref.injection.shape or d.measurement_pattern.shape != ref.measurement_pattern.shape:
            notes.append(f"{f.name}: {d.injection.shape[1]} patterns x {d.measurement_pattern.shape[1]} measurements, "
                         f"not the reference's {ref.injection.shape[1]} x {ref.measurement_pattern.shape[1]}: left out")
            continue
        tanks[f"data{n}"] = (d, read_ktc_truth(truth))
    return KtcFolder(str(folder), ref, tanks, tuple(notes))


def ktc_patterns(n_electrodes: int = 32, amplitude: float = 1.5) -> tuple[np.ndarray, np.ndarray]:
    """The series' current patterns (E, P) and measurement pattern (E, E - 1): currents on the odd electrodes only,
    first each to the next odd one (adjacent), then each against every fourth odd electrode (1, 9, 17, 25 of 32);
    measurement m is electrode m minus m + 1.

    >>> inj, mp = ktc_patterns(32)
    >>> inj.shape, mp.shape, int(np.linalg.matrix_rank(inj))
    ((32, 76), (32, 31), 15)
    """
    E = int(n_electrodes)
    odd = np.arange(0, E, 2)
    cols = []
    for a, b in zip(odd, np.roll(odd, -1)):
        cols.append((a, b))
    for ref in odd[::4]:
        cols += [(b, ref) for b in odd if b != ref]
    inj = np.zeros((E, len(cols)))
    for p, (a, b) in enumerate(cols):
        inj[a, p], inj[b, p] = amplitude, -amplitude
    mp = np.zeros((E, E - 1))
    mp[np.arange(E - 1), np.arange(E - 1)], mp[np.arange(1, E), np.arange(E - 1)] = 1, -1
    return inj, mp


def _load(path: str) -> dict:
    import scipy.io

    try:
        return scipy.io.loadmat(path)
    except NotImplementedError as exc:
        raise BenchLogError(path, None, f"a MATLAB v7.3 (HDF5) file, which this reader does not open ({exc})") from None
    except Exception as exc:  # scipy raises several types for bad files
        raise BenchLogError(path, None, f"not a readable .mat file: {exc}") from None


def _field(d: dict, path: str, names: tuple[str, ...]) -> tuple[str, np.ndarray]:
    keys = {k.lower(): k for k in d if not k.startswith("__")}
    for n in names:
        if n.lower() in keys:
            k = keys[n.lower()]
            a = np.asarray(d[k])
            if a.dtype.kind not in "iuf" or a.size == 0:
                raise BenchLogError(path, None, f"{k}: expected numbers, got {a.dtype} of shape {a.shape}")
            return k, a.astype(float)
    raise BenchLogError(path, None, f"no array {' or '.join(names)} (arrays: {', '.join(keys.values()) or 'none'}): "
                        "not the KTC layout")


def read_ktc_mat(path) -> KtcMeasurement:
    """Read ``ref.mat`` or ``dataN.mat`` of the KTC layout; :class:`BenchLogError` (file, array, reason) otherwise."""
    path = str(path)
    d = _load(path)
    k_inj, inj = _field(d, path, ("Inj", "Injref"))
    k_m, mpat = _field(d, path, ("Mpat",))
    k_u, u = _field(d, path, ("Uel", "Uelref"))
    if inj.ndim != 2 or mpat.ndim != 2 or inj.shape[0] != mpat.shape[0]:
        raise BenchLogError(path, None, f"{k_inj} {inj.shape} and {k_m} {mpat.shape} must both be (electrodes, ...) "
                            "with the same number of electrodes")
    E, P = inj.shape
    M = mpat.shape[1]
    if u.size != P * M:
        raise BenchLogError(path, None, f"{k_u} holds {u.size} values, not {P} patterns x {M} measurements = {P * M}")
    if not np.all(np.isfinite(inj)):
        raise BenchLogError(path, None, f"{k_inj} holds non-finite currents")
    sums = np.abs(inj.sum(axis=0))
    if np.any(sums > 1e-6 * np.abs(inj).max(axis=0).clip(1e-300)):
        p = int(np.argmax(sums))
        raise BenchLogError(path, None, f"{k_inj}: pattern {p + 1}'s currents sum to {inj[:, p].sum():.3g}, not 0")
    if np.any(np.abs(mpat.sum(axis=0)) > 1e-9):
        raise BenchLogError(path, None, f"{k_m}: a measurement's weights must sum to 0 (a voltage difference)")
    U = u.reshape(P, M)
    if np.isinf(U).any():
        raise BenchLogError(path, None, f"{k_u} holds infinite values (NaN marks data not measured)")
    if not np.isfinite(U).any():
        raise BenchLogError(path, None, f"{k_u} holds no finite voltage")
    return KtcMeasurement(inj, mpat, U, Path(path).name)


def read_ktc_truth(path, side_m: float = 0.23) -> KtcTruth:
    """Read ``trueN.mat`` (``truth``: a square mask of 0, 1, 2); ``side_m`` the pixels' square's side."""
    path = str(path)
    d = _load(path)
    k, mask = _field(d, path, ("truth",))
    if mask.ndim != 2 or mask.shape[0] != mask.shape[1]:
        raise BenchLogError(path, None, f"{k}: a square mask expected, got shape {mask.shape}")
    if not np.all(np.isin(mask, (0, 1, 2))):
        raise BenchLogError(path, None, f"{k}: values other than 0 (water), 1 (resistive), 2 (conductive): "
                            f"{sorted(set(np.unique(mask).tolist()) - {0, 1, 2})[:5]}")
    return KtcTruth(mask.astype(np.uint8), float(side_m))


def linear_floor(injection, voltages, rtol: float = 1e-8) -> dict:
    """How far the voltages miss the linear relations among the patterns: what no medium can explain.

    Each measurement's column of voltages is fitted, over its finite entries,
    by the span of the patterns' currents (least squares, ``rank`` the span's
    dimension); the residual is the floor. ``floor_rms_rel`` = RMS residual /
    RMS voltage (over the finite entries); ``noise_rms`` (and ``_rel``) = the
    residual's RMS scaled by its degrees of freedom (the per-voltage noise,
    were the instrument's error independent from voltage to voltage);
    ``relations``: how many linear relations the data had to obey;
    ``residual`` (P, M), NaN where not measured.
    """
    A = np.asarray(injection, float).T                                   # (P, E)
    U = np.asarray(voltages, float)
    R = np.full(U.shape, np.nan)
    dof = 0
    rank = 0
    for m in range(U.shape[1]):
        ok = np.isfinite(U[:, m])
        if not ok.any():
            continue
        coef, _, r, _ = np.linalg.lstsq(A[ok], U[ok, m], rcond=rtol)
        R[ok, m] = U[ok, m] - A[ok] @ coef
        dof += int(ok.sum()) - int(r)
        rank = max(rank, int(r))
    fin = np.isfinite(R)
    rms_u = float(np.sqrt(np.mean(U[fin] ** 2)))
    rms_r = float(np.sqrt(np.mean(R[fin] ** 2)))
    noise = float(np.sqrt(np.sum(R[fin] ** 2) / max(dof, 1)))
    return {"floor_rms_rel": rms_r / rms_u if rms_u > 0 else float("nan"), "floor_rms": rms_r,
            "noise_rms": noise, "noise_rms_rel": noise / rms_u if rms_u > 0 else float("nan"), "rank": rank,
            "relations": dof, "residual": R}
