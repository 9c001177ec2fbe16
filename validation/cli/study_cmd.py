"""``esense study``: run the slow studies and benchmarks (outside the test run)."""
from __future__ import annotations

import importlib
import pkgutil

import click

from electrosense.validation.cli._extras import require_extra


def _names() -> list[str]:
    import electrosense.validation.studies as studies

    return sorted(info.name for info in pkgutil.iter_modules(studies.__path__) if not info.name.startswith("_"))


def _summary(name: str) -> str:
    """First line of a study's docstring, read without importing it (a study may set up numba threads)."""
    import ast

    import electrosense.validation.studies as studies

    path = f"{studies.__path__[0]}/{name}.py"
    with open(path, encoding="utf-8") as f:
        doc = ast.get_docstring(ast.parse(f.read())) or ""
    return doc.strip().splitlines()[0] if doc.strip() else ""


@click.command("study", context_settings={"ignore_unknown_options": True, "allow_interspersed_args": False})
@click.argument("name", required=False)
@click.argument("args", nargs=-1, type=click.UNPROCESSED)
@click.option("--list", "list_", is_flag=True, help="List the studies and benchmarks and exit.")
def study(name, args, list_):
    """Run the study or benchmark NAME (extra ARGS go to it); ``all`` runs every one in turn.

    Example: ``esense study bem_speed``.
    """
    available = _names()
    if list_ or not name:
        for key in available:
            click.echo(f"{key:28s} {_summary(key)}")
        return
    names = available if name == "all" else [name]
    for n in names:
        if n not in available:
            raise click.BadParameter(f"unknown study {n!r}; known: {', '.join(available)}", param_hint="NAME")
        module = importlib.import_module(f"electrosense.validation.studies.{n}")
        for extra in getattr(module, "NEEDS_EXTRAS", ()):   # checked before any work, not where first used
            require_extra(extra, f"esense study {n}")
        click.echo(f"== {n}")
        module.main(list(args))
