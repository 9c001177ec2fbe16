"""Gap diagnosis: where the sim-to-real gap lies, which unmodelled effect causes it, how far it shrinks.

Modules, one idea each:

* :mod:`.observations`: what the logs say (poses, currents, times, passes, meta);
* :mod:`.anchored`: the default baseline, the BEM at adaptive anchor poses
  (cached per sensor and tank) interpolated over pose against the PSM or the
  free-space K, with its estimated error;
* :mod:`.contact`: contact impedance through areas fitted to the BEM's
  contact boundary condition;
* :mod:`.forward`: forward models ``(poses, tank, objects) -> K`` (the PSM
  as effect model, the project's models, a point-electrode stand-in);
* :mod:`.effects`: the candidate library, physical parametrised additions;
* :mod:`.where`: the residual broken down by receiver, place, time, heading;
* :mod:`.fitting`: noise level, held-out folds, fits with uncertainties;
* :mod:`.select`: ranking, forward selection, confusable pairs;
* :mod:`.bem_check`: the chosen effect's fitted scene solved by the BEM, its
  parameters refined there;
* :mod:`.pipeline`: :func:`diagnose`, the whole chain;
* :mod:`.report`: ``diagnosis.json`` and ``index.html``;
* :mod:`.blind`: worlds with withheld effects, for tests and studies;
* :mod:`.unseen`: random sensors, tanks and passes for blind checks.

Example
-------
>>> from electrosense.validation.diagnosis import EFFECT_NAMES
>>> EFFECT_NAMES[-1]
'none'
"""
from electrosense.validation.diagnosis.effects import EFFECT_NAMES, library
from electrosense.validation.diagnosis.observations import DiagnosisInputError, Observations, from_bench_logs
from electrosense.validation.diagnosis.pipeline import Diagnosis, diagnose

__all__ = ["EFFECT_NAMES", "library", "Observations", "DiagnosisInputError", "from_bench_logs", "Diagnosis", "diagnose"]
