"""The optional extras of the distribution (``pip install 'electrosense[EXTRA]'``) and what each must import.

One check for every command and study that needs an extra, made before any work: a study that needs the
sweep's modules used to run nine minutes and then end in an internal error, its figures lost.

>>> EXTRA_MODULES["sweep"]
('dask', 'distributed', 'xarray', 'zarr')
"""
from __future__ import annotations

import importlib.util

import click

__all__ = ["EXTRA_MODULES", "missing_modules", "require_extra"]

#: extra -> the top-level modules it installs (pyproject.toml's [project.optional-dependencies])
EXTRA_MODULES = {
    "sweep": ("dask", "distributed", "xarray", "zarr"),
    "html": ("trame",),
}


def missing_modules(extra: str) -> list[str]:
    """The modules of ``extra`` that cannot be imported here."""
    return [m for m in EXTRA_MODULES[extra] if importlib.util.find_spec(m) is None]


def require_extra(extra: str, what: str) -> None:
    """Refuse, in one line naming the install command, ``what`` (e.g. "esense sweep") without ``extra``'s modules."""
    missing = missing_modules(extra)
    if missing:
        raise click.ClickException(f"{what} needs {', '.join(missing)}: pip install 'electrosense[{extra}]'")
