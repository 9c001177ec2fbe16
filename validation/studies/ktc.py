"""KTC2023 tanks: the scene's unknowns fitted on one folder, every tank of other folders predicted from its truth.

Run: ``esense study ktc --fit DIR --predict DIR [--predict DIR ...] -o OUT``.

``--fit`` is a folder of the series (``ref.mat``, ``dataN.mat``, ``trueN.mat``;
the Kuopio Tomography Challenge 2023 training set, Rasanen et al., Zenodo,
doi:10.5281/zenodo.8252370, CC BY 4.0). The study fits the scene's unknowns on
its empty tank and its tanks with objects, then predicts every ``dataN.mat``
of each ``--predict`` folder from its ``trueN.mat`` and that folder's
``ref.mat``, with no further fitting, and writes ``OUT/metrics.json``,
``OUT/report.md`` and the figures (the tanks with their objects, measured
against predicted change by pattern, the gap by electrode, the diagnosis's
candidates). The model: :mod:`electrosense.validation.comparison.ktc` (the
scene in 3-D, solved by cosine modes in depth, :mod:`electrosense.bem.prism_modes`);
the diagnosis: :mod:`electrosense.validation.diagnosis.ktc_gap`.

Bad input (a folder without ``ref.mat``, a file that is not of this layout) ends
in one line naming the file and the reason; electrodes out of use (NaN data)
carry no current, and their measurements and the patterns that drive them are
left out of every score.
"""
from __future__ import annotations

import argparse
import json
import os
import resource
import sys
import time
from pathlib import Path

import numpy as np


def _cpu_s() -> float:
    r = resource.getrusage(resource.RUSAGE_SELF)
    c = resource.getrusage(resource.RUSAGE_CHILDREN)
    return r.ru_utime + r.ru_stime + c.ru_utime + c.ru_stime


def main(argv=None) -> dict:
    ap = argparse.ArgumentParser(prog="esense study ktc", description=__doc__.splitlines()[0])
    ap.add_argument("--fit", type=Path, required=True, help="folder with ref.mat, dataN.mat, trueN.mat to fit on")
    ap.add_argument("--predict", type=Path, action="append", default=[],
                    help="folder whose every dataN.mat is predicted from its trueN.mat and ref.mat (repeatable)")
    ap.add_argument("-o", "--out", type=Path, required=True)
    ap.add_argument("--modes", type=int, default=30, help="cosine modes in depth (default 30)")
    ap.add_argument("--no-figures", dest="figures", action="store_false")
    ap.add_argument("--no-diagnosis", dest="diagnosis", action="store_false")
    args = ap.parse_args(argv)
    from electrosense.validation.bench.log.errors import BenchLogError
    from electrosense.validation.bench.transfer.ktc_mat import read_ktc_folder

    try:
        fit_folder = read_ktc_folder(args.fit)
        predict = [read_ktc_folder(p) for p in args.predict]
    except BenchLogError as exc:
        raise SystemExit(f"esense study ktc: {exc}") from None
    if not 1 <= args.modes <= 400:
        raise SystemExit(f"esense study ktc: --modes {args.modes}: give 1 to 400")
    try:
        args.out.mkdir(parents=True, exist_ok=True)
    except OSError as exc:
        raise SystemExit(f"esense study ktc: cannot write {args.out}: {exc.strerror}") from None
    from electrosense.validation.comparison.ktc_run import run_ktc

    t0, c0 = time.perf_counter(), _cpu_s()
    metrics = run_ktc(fit_folder, predict, args.out, n_modes=args.modes, figures=args.figures,
                      diagnosis=args.diagnosis, progress=lambda s: print(f"  {s}", flush=True))
    metrics["seconds"] = {**metrics.get("seconds", {}), "wall_s": time.perf_counter() - t0,
                          "cpu_s": _cpu_s() - c0, "threads": os.environ.get("NUMBA_NUM_THREADS", "default")}
    (args.out / "metrics.json").write_text(json.dumps(_finite(metrics), indent=1, default=_json_default))
    from electrosense.validation.comparison.ktc_report import summary_text

    print(summary_text(metrics))
    sys.stdout.flush()
    return metrics


def _finite(o):
    """The metrics with every non-finite number as null (strict JSON)."""
    if isinstance(o, dict):
        return {k: _finite(v) for k, v in o.items()}
    if isinstance(o, (list, tuple)):
        return [_finite(v) for v in o]
    if isinstance(o, np.ndarray):
        return _finite(o.tolist())
    if isinstance(o, (float, np.floating)) and not np.isfinite(o):
        return None
    return o


def _json_default(o):
    if isinstance(o, (np.floating, np.integer)):
        return o.item()
    if isinstance(o, np.ndarray):
        return o.tolist()
    raise TypeError(type(o).__name__)


if __name__ == "__main__":
    main()
