"""Reader of the EIT phantom .mat layout (EIDORS sample data, Viasys / Goettingen system) into a transfer log.

Layout: per set-up ``X`` three arrays ``vvX`` (n*n: n adjacent drive patterns
times n adjacent measurements, drive-major), ``voltsX`` (n) and ``currX`` (n),
and a ``description`` string. Conventions established from physics (see
docs/transfer-log.md):

* drive k drives electrodes (k, k+1), measurement m reads the pair (m, m+1)
  (1-based, cyclic); the 3 measurements that touch a drive electrode are
  stored as exact zeros: they are NOT measured and are left out of the log;
* the entries are magnitudes; the BEM gives ``V(m) - V(m+1) < 0`` for every
  other measurement with the current into k and out of k+1, so a stored
  value is ``V(m+1) - V(m)``: the log has ``meas_plus = m+1, meas_minus = m``;
* of ``volts*`` and ``curr*``, the one that is constant over the drives is
  the current source's (the names are swapped in the sample file: ``volts``
  ~4.6e-3 constant, ``curr`` 2.9..3.9 varying with the drive pair's contact
  impedances); the reader decides by that test and records it in the meta.
  The varying one is the drive pair's voltage, logged as the row whose
  measurement pair is the drive pair.

Example
-------
>>> import tempfile, pathlib, numpy as np, scipy.io
>>> n = 4
>>> vv = np.ones((n, n)); vv[[0, 0, 0], [3, 0, 1]] = 0; vv[[1, 1, 1], [0, 1, 2]] = 0
>>> vv[[2, 2, 2], [1, 2, 3]] = 0; vv[[3, 3, 3], [2, 3, 0]] = 0
>>> p = pathlib.Path(tempfile.mkdtemp()) / "x.mat"
>>> scipy.io.savemat(p, {"vvRef": vv.reshape(-1, 1), "voltsRef": np.full((n, 1), 1e-3), "currRef": np.full((n, 1), 2.0) + np.arange(n)[:, None]})
>>> rows, meta = read_eit_mat(p)
>>> len(rows), meta["current_field"]["Ref"], rows[1]
(8, 'voltsRef', ('Ref', 1, 2, 4, 3, 1.0, 0.001))
"""
from __future__ import annotations

from pathlib import Path

import numpy as np

from electrosense.validation.bench.log.errors import BenchLogError

__all__ = ["read_eit_mat", "eit_mat_to_transfer_log"]


#: accepted spellings (any letter case) of each array's prefix: ``vvRef``, ``voltRef``, ``CURRENTRef``...
FIELD_PREFIXES = {"vv": ("vv",), "volts": ("volts", "volt", "voltage", "voltages"),
                  "curr": ("curr", "cur", "current", "currents")}


def _setup_arrays(d: dict) -> dict:
    """``{setup: {"vv": key, "volts": key or None, "curr": key or None}}`` from a loaded .mat's keys.

    The set-ups are named by their ``vv`` arrays; the other two prefixes are
    matched in any letter case and any of :data:`FIELD_PREFIXES`' spellings.

    >>> _setup_arrays({"vvRef": 0, "voltRef": 0, "currRef": 0, "VVAvg1": 0, "CURRENTAvg1": 0})
    {'Ref': {'vv': 'vvRef', 'volts': 'voltRef', 'curr': 'currRef'}, 'Avg1': {'vv': 'VVAvg1', 'volts': None, 'curr': 'CURRENTAvg1'}}
    """
    keys = [k for k in d if not k.startswith("__")]
    setups = {k[2:]: {"vv": k} for k in keys if k[:2].lower() == "vv" and len(k) > 2}
    for s, found in setups.items():
        for field, spellings in FIELD_PREFIXES.items():
            if field == "vv":
                continue
            names = {(p + s).lower() for p in spellings}
            matches = [k for k in keys if k.lower() in names]
            found[field] = matches[0] if len(matches) == 1 else (None if not matches else tuple(matches))
    return setups


def _drive_major(a: np.ndarray, path: str, key: str) -> tuple[np.ndarray, int, int]:
    """The ``vv`` array as (frames, n*n) drive-major rows, with ``n`` and the frame count.

    A vector of n*n is one frame; an (n*n, F) array holds F frames (one a
    column, as EIDORS stores them); an (n, n) matrix is MATLAB's
    ``reshape(vv, n, n)`` of one frame (a column a drive).
    """
    a = np.asarray(a)
    if a.dtype.kind not in "iufc" or a.size == 0:
        raise BenchLogError(path, None, f"{key}: expected a numeric array, got {a.dtype} of shape {a.shape}")
    if np.iscomplexobj(a):
        a = np.abs(a)
    a = a.astype(float)
    if a.ndim > 2:
        raise BenchLogError(path, None, f"{key}: a {a.ndim}-D array of shape {a.shape}; expected n*n values "
                            "(one frame) or (n*n, frames)")
    rows, cols = (a.shape + (1,))[:2] if a.ndim == 1 else a.shape
    if a.ndim == 2 and rows == cols and rows * cols >= 16 and int(round(np.sqrt(rows))) ** 2 != rows:
        n = rows                                     # an n x n matrix, a column a drive (MATLAB's reshape)
        return a.ravel(order="F")[None, :], n, 1
    if min(rows, cols) == 1:
        frames = a.reshape(1, -1)
    else:
        frames = a.T if int(round(np.sqrt(rows))) ** 2 == rows else a    # (n*n, F) as EIDORS, or (F, n*n)
    n = int(round(np.sqrt(frames.shape[1])))
    if n * n != frames.shape[1] or n < 4:
        raise BenchLogError(path, None, f"{key} has shape {a.shape}: not n*n values (adjacent drives x adjacent "
                            "measurements) for n >= 4 electrodes")
    return frames, n, frames.shape[0]


def _positive_vector(d, key, n, path, what):
    a = np.asarray(d[key])
    if a.dtype.kind not in "iuf" or a.size == 0:
        raise BenchLogError(path, None, f"{key}: expected numbers ({what}), got {a.dtype} of shape {a.shape}")
    a = a.astype(float)
    if a.ndim == 2 and min(a.shape) > 1 and n in a.shape:      # several frames: their mean, a value a drive
        a = a.mean(axis=1 if a.shape[0] == n else 0)
    a = a.ravel()
    if a.size != n:
        raise BenchLogError(path, None, f"{key}: {a.size} values, expected {n} (one per drive pattern)")
    bad = np.flatnonzero(~(np.isfinite(a) & (a > 0)))
    if bad.size:
        raise BenchLogError(path, None, f"{key}: drive {bad[0] + 1} holds {a[bad[0]]}; {what} must be positive "
                            "and finite")
    return a


def read_eit_mat(path) -> tuple[list[tuple], dict]:
    """Rows of a transfer log and its meta (without the scene) from a .mat of this layout.

    Accepted variants (the meta says which were met): the arrays' prefixes in
    any letter case and spelling of :data:`FIELD_PREFIXES`; a drive-voltage
    or drive-current array missing (no current: ``I_A`` is 1 and the meta's
    ``current_unit`` says the impedances are per unit of an unknown current,
    which the tools' fitted scale absorbs; no drive voltage: no drive-pair
    rows); several frames (their mean, with the frame count); any electrode
    count n >= 4; measurements touching a drive electrode stored as values
    rather than zeros (left out, counted); all values of one sign (negative:
    the opposite measurement polarity, turned round and said). Refused, with
    the file, the array and the reason: no ``vv`` array, a size that is not
    n*n, non-finite values, a zero or sign change among the measured entries,
    two arrays of the same meaning for one set-up.
    """
    import scipy.io

    path = str(path)
    try:
        d = scipy.io.loadmat(path)
    except NotImplementedError as exc:        # MATLAB v7.3 files are HDF5
        raise BenchLogError(path, None, f"a MATLAB v7.3 (HDF5) file, which this reader does not open ({exc}); "
                            "save it with -v7 in MATLAB or Octave") from None
    except Exception as exc:  # scipy raises several types for bad files
        raise BenchLogError(path, None, f"not a readable .mat file: {exc}") from None
    setups = _setup_arrays(d)
    if not setups:
        raise BenchLogError(path, None, "no vv<setup> array: not the EIT phantom layout (arrays: "
                            f"{', '.join(k for k in d if not k.startswith('__')) or 'none'})")
    rows = []
    meta = {"source": Path(path).name, "layout": "eit-phantom-mat", "current_field": {}, "voltage_field": {},
            "protocol": "adjacent drive k=(k,k+1), measurement m=(m+1)-(m), 1-based cyclic",
            "not_measured": "pairs touching a drive electrode (stored as 0 in the .mat) are left out"}
    notes = []
    description = next((k for k in d if k.lower() == "description"), None)
    if description is not None:
        meta["description"] = " ".join(str(x) for x in np.ravel(d[description]))
    for s, keys in setups.items():
        for field in ("volts", "curr"):
            if isinstance(keys[field], tuple):
                raise BenchLogError(path, None, f"set-up {s}: arrays {', '.join(keys[field])} all name the same "
                                    f"quantity ({field}); keep one")
        frames, n, n_frames = _drive_major(d[keys["vv"]], path, keys["vv"])
        if not np.all(np.isfinite(frames)):
            raise BenchLogError(path, None, f"{keys['vv']} holds non-finite values")
        if n_frames > 1:
            notes.append(f"{keys['vv']}: the mean of {n_frames} frames")
        vv = frames.mean(axis=0).reshape(n, n)
        fields = {keys[f]: _positive_vector(d, keys[f], n, path, "drive voltages or currents")
                  for f in ("volts", "curr") if keys[f] is not None}
        I, Vd = _current_and_drive_voltage(fields, path, s)
        if I is None:
            I = np.ones(n)
            meta["current_unit"] = "unknown: the file has no drive current; I_A = 1, so V_V / I_A is in volts"
        cur_name = next((k for k, v in fields.items() if v is I), None)
        volt_name = next((k for k, v in fields.items() if v is Vd), None)
        meta["current_field"][s], meta["voltage_field"][s] = cur_name, volt_name
        drive = np.arange(n)
        a, b = drive + 1, (drive + 1) % n + 1                                     # drive k: electrodes (a, b)
        p, q = (drive + 1) % n + 1, drive + 1                                     # measurement m: (m+1) - (m)
        touches = np.zeros((n, n), bool)                                           # (drive, measurement)
        for e in (a, b):
            touches |= (p[None, :] == e[:, None]) | (q[None, :] == e[:, None])
        measured = vv[~touches]
        if np.count_nonzero(vv[touches]):
            notes.append(f"{keys['vv']}: {np.count_nonzero(vv[touches])} values on measurements touching a drive "
                         "electrode (their contact impedances enter): left out")
        zero = np.argwhere((vv == 0) & ~touches)
        if zero.size:
            k, m = zero[0]
            raise BenchLogError(path, None, f"{keys['vv']}: drive {k + 1}, measurement {m + 1} is 0 but does not "
                                f"touch a drive electrode ({len(zero)} such): not the adjacent protocol, or a dead "
                                "channel")
        if np.all(measured < 0):
            vv = -vv
            notes.append(f"{keys['vv']}: all measured values negative, the opposite polarity: turned round")
        elif np.any(measured < 0):
            k, m = np.argwhere((vv < 0) & ~touches)[0]
            raise BenchLogError(path, None, f"{keys['vv']}: drive {k + 1}, measurement {m + 1} is {vv[k, m]} while "
                                f"{np.count_nonzero(measured > 0)} others are positive: magnitudes of one sign "
                                "expected")
        for k in range(n):
            if Vd is not None:
                rows.append((s, int(a[k]), int(b[k]), int(a[k]), int(b[k]), float(Vd[k]), float(I[k])))
            rows += [(s, int(a[k]), int(b[k]), int(p[m]), int(q[m]), float(vv[k, m]), float(I[k]))
                     for m in range(n) if not touches[k, m]]
    if notes:
        meta["reader_notes"] = notes
    return rows, meta


def _current_and_drive_voltage(fields: dict, path: str, setup: str):
    """Which of the (up to two) per-drive arrays is the source current, which the drive pair's voltage.

    A current source drives the same current whatever the pair's contact
    impedances, so the current is the array that is constant over the drives:
    with two arrays, the one of smaller relative spread (the other at least
    3x as spread); with one, it is the current if it varies by less than 1 %
    (a source's own stability), else the drive voltage. Returns
    ``(I or None, V_drive or None)``.
    """
    spread = {k: float(np.std(v) / np.mean(v)) for k, v in fields.items()}
    if len(fields) == 2:
        cur_name, volt_name = sorted(spread, key=spread.get)
        if spread[volt_name] < 3 * spread[cur_name]:
            raise BenchLogError(path, None, f"set-up {setup}: cannot tell the drive current from the drive voltage "
                                f"(relative spreads {spread}); the constant one is the current source's")
        return fields[cur_name], fields[volt_name]
    if len(fields) == 1:
        (name, v), = fields.items()
        return (v, None) if spread[name] < 0.01 else (None, v)
    return None, None


def eit_mat_to_transfer_log(mat_path, out_path, scene: str, ring=None) -> Path:
    """Convert a .mat of this layout to a transfer log naming ``scene`` (relative to the log's folder).

    ``ring``: the scene's electrode numbers of the file's electrodes 1..n in
    ring order (the scene's ``[protocol]`` ring); None: the scene numbers
    them 1..n. A ring of another length than the file's is refused.
    """
    from electrosense.validation.bench.transfer.log import write_transfer_log

    rows, meta = read_eit_mat(mat_path)
    if ring is not None:
        ring = [int(e) for e in ring]
        n = max(max(r[1:5]) for r in rows)
        if len(ring) != n:
            raise BenchLogError(str(mat_path), None, f"the file's ring has {n} electrodes, the scene's [protocol] "
                                f"ring {len(ring)}: not this scene's data")
        rows = [(r[0], *(ring[e - 1] for e in r[1:5]), *r[5:]) for r in rows]
        if ring != list(range(1, n + 1)):
            meta["electrodes_mapped_to_scene_ring"] = ring
    return write_transfer_log(out_path, {"scene": scene, **meta}, rows)
