"""``esense validate`` / ``esense diagnose`` on transfer logs: the real-tank comparison of :mod:`validation.studies.real_tank`.

The log's meta names its scene (relative to the log's folder); the scene's
``[protocol]`` table says which set-up is the reference and where the balls are.
``validate`` runs the comparison (noise floor, empty tank held out, balls);
``diagnose`` adds the diagnosis candidates (electrode positions, water depth,
channel gains...).
"""
from __future__ import annotations

from pathlib import Path

__all__ = ["all_transfer_logs", "run_transfer_logs"]


def all_transfer_logs(paths) -> bool:
    """True when every path is a transfer log (and there is at least one)."""
    from .log import is_transfer_log

    paths = list(paths)
    return bool(paths) and all(is_transfer_log(p) for p in paths)


def run_transfer_logs(paths, outdir, positions: bool = True) -> None:
    """Compare each transfer log with the BEM of its scene; one sub-folder of ``outdir`` per log.

    ``positions``: also run the diagnosis (electrode positions from one
    solve's sensitivities, water depth, channel gains...); False: the
    comparison only.
    """
    from validation.studies.real_tank import main

    from .log import read_transfer_log

    paths = list(paths)
    for p in paths:
        log = read_transfer_log(p)
        sub = Path(outdir) / Path(p).stem if len(paths) > 1 else Path(outdir)
        args = ["--data", str(p), "--scene", str(log.scene_path()), "-o", str(sub)]
        main(args + ([] if positions else ["--no-diagnosis"]))
