"""``esense study``: run the slow studies and benchmarks (outside the test run)."""
from __future__ import annotations

import importlib
import pkgutil

import click


def _available() -> dict[str, str]:
    import validation.studies as studies

    out = {}
    for info in pkgutil.iter_modules(studies.__path__):
        if info.name.startswith("_"):
            continue
        mod = importlib.import_module(f"validation.studies.{info.name}")
        if hasattr(mod, "main"):
            out[info.name] = (mod.__doc__ or "").strip().splitlines()[0] if mod.__doc__ else ""
    return out


@click.command("study", context_settings={"ignore_unknown_options": True, "allow_interspersed_args": False})
@click.argument("name", required=False)
@click.argument("args", nargs=-1, type=click.UNPROCESSED)
@click.option("--list", "list_", is_flag=True, help="List the studies and benchmarks and exit.")
def study(name, args, list_):
    """Run the study or benchmark NAME (extra ARGS go to it); ``all`` runs every one in turn.

    Example: ``esense study bem_speed``.
    """
    available = _available()
    if list_ or not name:
        for key, doc in sorted(available.items()):
            click.echo(f"{key:28s} {doc}")
        return
    names = sorted(available) if name == "all" else [name]
    for n in names:
        if n not in available:
            raise click.BadParameter(f"unknown study {n!r}; known: {', '.join(sorted(available))}", param_hint="NAME")
        click.echo(f"== {n}")
        importlib.import_module(f"validation.studies.{n}").main(list(args))
