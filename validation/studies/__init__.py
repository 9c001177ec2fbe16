"""Studies and benchmarks: slow scripts outside the default test run.

Each module has ``main(argv=None)`` and prints its figures side by side with
the reference (the paper, a closed form, or an issue's target). Run one with
``esense study NAME`` or ``python -m electrosense.validation.studies.NAME``; ``esense study
--list`` lists them.
"""


def positive_numbers(parser, option: str, text: str) -> tuple[float, ...]:
    """A study option's comma-separated positive numbers (``--gaps 0.005,0.01``), or ``parser.error`` naming
    the option and what it got.

    Example
    -------
    >>> import argparse
    >>> positive_numbers(argparse.ArgumentParser(), "--gaps", "0.005,0.01")
    (0.005, 0.01)
    """
    try:
        values = tuple(float(v) for v in text.split(","))
    except ValueError:
        parser.error(f"{option}: expected positive numbers separated by commas, got {text!r}")
    if not all(v > 0 for v in values):
        parser.error(f"{option}: every value must be positive, got {text!r}")
    return values
