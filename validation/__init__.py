"""validation: bench logs, serial acquisition, model-vs-bench comparison, gap diagnosis, plots and reports.

This package sits on top of :mod:`meshes`, :mod:`bem` and :mod:`psm`; they never import it.
"""
