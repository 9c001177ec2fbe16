"""Real saline tank: the BEM against a measured EIT phantom (noise floor, empty tank held out, balls, diagnosis).

Run: ``esense study real_tank --data FILE.mat|LOG.csv --scene pail.toml -o DIR``.

* The data are read into a transfer log (:mod:`electrosense.validation.bench.transfer`), written
  to ``DIR/transfer_log.csv`` beside a copy of the scene file.
* Noise floor: reciprocity (drive (a,b)/measure (c,d) against drive
  (c,d)/measure (a,b)) of the reference set-up.
* Empty tank: one BEM solve of the scene gives K of all electrodes and every
  transfer impedance (:mod:`electrosense.bem.protocol`). What a user cannot know (the
  saline's conductivity times the system's gain: one scale, the two are
  indistinguishable in V/I) is fitted on the even drive patterns and scored
  on the odd ones: ``empty_heldout_rms_rel`` = RMS of (model - measured) /
  measured over the held-out measurements.
* Each ball set-up: difference signal (with ball / without - 1), measured vs
  BEM with the balls where the scene's ``[protocol]`` table says.
* Diagnosis (left out with ``--no-diagnosis``, as ``esense validate`` does):
  candidate effects fitted on the even drives and scored on the odd ones,
  each linear about the BEM: per-channel gains or offsets of the measurement
  system, electrode positions along the wall (one solve's sensitivities, by
  reciprocity), water depth, the tank's shape at the ring (radius; taper of
  the wall; one solve each), current returning through electrodes off the
  ring; contact impedances from the drive pairs' voltages (they cannot
  change a four-electrode transfer impedance). ``diagnosis.chosen`` and
  ``diagnosis.verdict`` come from the pose diagnosis's engine
  (:mod:`electrosense.validation.diagnosis.transfer_engine`: held-out drive
  patterns, a detection test at a stated false-alarm rate, forward
  selection, geometric candidates made exact on the BEM where they were
  fitted). ``diagnosis.one_geometry``
  asks whether one tank shape explains both the empty tank and the balls:
  the ring radius the empty tank's fit wants against the one at which each
  ball's measured/simulated amplitude is 1.
* Scene fit (left out with ``--no-scene-fit``): the scene's unknowns (the
  tank's radius and taper at the ring, the water depth, the ring's height,
  the electrodes' effective size, the balls' radius, height and frame) and
  the instrument's (scale, multiplexer classes, channel gains, common mode,
  ground current) fitted on the BEM to the reference's training drives and
  one ball set-up (``--fit-setup``), scored on the held-out drives and the
  other set-ups, with standard errors and what the data cannot separate
  (:mod:`electrosense.validation.diagnosis.tank_scene_fit`).

The logic lives in the package along the data's path: the comparison in
:mod:`electrosense.validation.comparison.transfer`, the diagnosis in
:mod:`electrosense.validation.diagnosis.transfer`, figures and report in
:mod:`electrosense.validation.comparison.transfer_report`, the run in
:func:`electrosense.validation.cli.transfer_logs.run_transfer_comparison` (what ``esense
validate`` / ``esense diagnose`` call on transfer logs). This study is its
command line, printing the figures beside the goals.

Nothing is tuned to one file: the ring, the set-ups and the balls come from
the scene's ``[protocol]`` table, the electrodes from its geometry.
"""
from __future__ import annotations

import argparse
from pathlib import Path

from electrosense.validation.cli.transfer_logs import run_transfer_comparison
from electrosense.validation.comparison.transfer import TransferMismatchError
from electrosense.validation.comparison.transfer_report import summary_text


def main(argv=None) -> None:
    ap = argparse.ArgumentParser(prog="esense study real_tank", description=__doc__.splitlines()[0])
    ap.add_argument("--data", type=Path, required=True, help="the phantom's .mat file, or a transfer log .csv")
    ap.add_argument("--scene", type=Path, required=True, help="the tank's scene file (TOML) with a [protocol] table")
    ap.add_argument("-o", "--out", type=Path, required=True)
    ap.add_argument("--no-diagnosis", dest="diagnosis", action="store_false",
                    help="only the comparison (noise floor, empty tank, balls): no diagnosis candidates")
    ap.add_argument("--no-scene-fit", dest="scene_fit", action="store_false",
                    help="no fit of the scene's unknowns across set-ups (the slowest part: about 40 BEM solves)")
    ap.add_argument("--fit-setup", default=None,
                    help="the ball set-up fitted with the reference (default: the first the protocol places); "
                         "the others are held out")
    args = ap.parse_args(argv)
    try:
        metrics = run_transfer_comparison(args.data, args.scene, args.out, diagnose=args.diagnosis,
                                          scene_fit=args.scene_fit, fit_setup=args.fit_setup)
    except TransferMismatchError as exc:
        raise SystemExit(str(exc)) from None
    print(summary_text(metrics))


if __name__ == "__main__":
    main()
