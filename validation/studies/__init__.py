"""Studies and benchmarks: slow scripts outside the default test run.

Each module has ``main(argv=None)`` and prints its figures side by side with
the reference (the paper, a closed form, or an issue's target). Run one with
``esense study NAME`` or ``python -m electrosense.validation.studies.NAME``; ``esense study
--list`` lists them.
"""
