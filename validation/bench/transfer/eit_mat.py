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


def read_eit_mat(path) -> tuple[list[tuple], dict]:
    """Rows of a transfer log and its meta (without the scene) from a .mat of this layout."""
    import scipy.io

    path = str(path)
    try:
        d = scipy.io.loadmat(path)
    except Exception as exc:  # scipy raises several types for bad files
        raise BenchLogError(path, None, f"not a readable .mat file: {exc}") from None
    setups = [k[2:] for k in d if k.startswith("vv") and not k.startswith("__")]
    if not setups:
        raise BenchLogError(path, None, "no vv<setup> array: not the EIT phantom layout")
    rows, meta = [], {"source": Path(path).name, "layout": "eit-phantom-mat", "current_field": {}, "voltage_field": {},
                      "protocol": "adjacent drive k=(k,k+1), measurement m=(m+1)-(m), 1-based cyclic",
                      "not_measured": "pairs touching a drive electrode (stored as 0 in the .mat) are left out"}
    if "description" in d:
        meta["description"] = " ".join(str(x) for x in np.ravel(d["description"]))
    for s in setups:
        vv = np.asarray(d["vv" + s], float).ravel()
        n = int(round(np.sqrt(vv.size)))
        if n * n != vv.size or n < 4:
            raise BenchLogError(path, None, f"vv{s} has {vv.size} entries, not n*n for n >= 4 electrodes")
        fields = {}
        for f in ("volts", "curr"):
            if f + s not in d:
                raise BenchLogError(path, None, f"set-up {s}: array {f + s} missing")
            a = np.asarray(d[f + s], float).ravel()
            if a.size != n or not np.all(np.isfinite(a)) or np.any(a <= 0):
                raise BenchLogError(path, None, f"{f + s} must hold {n} positive finite values")
            fields[f + s] = a
        spread = {k: np.std(v) / np.mean(v) for k, v in fields.items()}
        cur_name = min(spread, key=spread.get)
        volt_name = max(spread, key=spread.get)
        if spread[volt_name] < 3 * spread[cur_name]:
            raise BenchLogError(path, None, f"set-up {s}: cannot tell the drive current from the drive voltage "
                                f"(relative spreads {spread}); the constant one is the current source's")
        I, Vd = fields[cur_name], fields[volt_name]
        meta["current_field"][s], meta["voltage_field"][s] = cur_name, volt_name
        vv = vv.reshape(n, n)
        if not np.all(np.isfinite(vv)):
            raise BenchLogError(path, None, f"vv{s} holds non-finite values")
        for k in range(n):
            a, b = k + 1, (k + 1) % n + 1
            rows.append((s, a, b, a, b, float(Vd[k]), float(I[k])))
            for m in range(n):
                p, q = (m + 1) % n + 1, m + 1
                touches = bool({p, q} & {a, b})
                if touches:
                    if vv[k, m] != 0:
                        raise BenchLogError(path, None, f"vv{s}: drive {k + 1}, measurement {m + 1} touches a drive "
                                            f"electrode but is {vv[k, m]}, not 0: not the adjacent protocol")
                    continue
                if not vv[k, m] > 0:
                    raise BenchLogError(path, None, f"vv{s}: drive {k + 1}, measurement {m + 1} is {vv[k, m]}: "
                                        "expected a positive magnitude")
                rows.append((s, a, b, p, q, float(vv[k, m]), float(I[k])))
    return rows, meta


def eit_mat_to_transfer_log(mat_path, out_path, scene: str) -> Path:
    """Convert a .mat of this layout to a transfer log naming ``scene`` (relative to the log's folder)."""
    from electrosense.validation.bench.transfer.log import write_transfer_log

    rows, meta = read_eit_mat(mat_path)
    return write_transfer_log(out_path, {"scene": scene, **meta}, rows)
