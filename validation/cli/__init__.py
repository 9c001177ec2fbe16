"""The ``esense`` command.

Each subcommand lives in its own module of this package and is registered on
the ``main`` group below; heavy imports happen inside the commands so that
``esense --help`` stays fast. A command's module is imported only when that
command runs (or when the list of commands is shown): ``esense sweep`` does
not pay for the diagnosis's imports.
"""
from __future__ import annotations

import importlib
import os
import traceback
from pathlib import Path

import click

#: subcommand module (validation.cli.<module>) -> click command attribute name
_COMMANDS = {
    "mesh_cmd": "mesh",
    "view_cmd": "view",
    "conductance_cmd": "conductance",
    "sweep_cmd": "sweep",
    "calibrate_cmd": "calibrate",
    "acquire_cmd": "acquire",
    "bench_sim_cmd": "bench_sim",
    "validate_cmd": "validate",
    "diagnose_cmd": "diagnose",
    "demo_cmd": "demo",
    "study_cmd": "study",
    "map_cmd": "map_group",
    "localise_cmd": "localise",
}


class _Esense(click.Group):
    """The command group, with one last word on errors: no input makes ``esense`` print a traceback.

    Refused input (a ``ValueError`` from any layer: bench logs, scene files,
    meshes, the BEM's boundary conditions...) and files that cannot be read or
    written (``OSError``) end in one line that says what and where, exit 2.
    Anything else is a bug of ours: one line naming the exception and the
    place it was raised, exit 1; ``ESENSE_TRACEBACK=1`` shows the traceback.
    """

    def _load(self, module: str):
        try:
            mod = importlib.import_module(f"{__name__}.{module}")
        except ModuleNotFoundError as exc:  # a command not written yet
            if exc.name != f"{__name__}.{module}":
                raise
            return
        self.add_command(getattr(mod, _COMMANDS[module]))

    def _load_all(self):
        for module in _COMMANDS:
            self._load(module)

    def list_commands(self, ctx):
        self._load_all()
        return super().list_commands(ctx)

    def get_command(self, ctx, name):
        if name not in self.commands:   # the module named after the command first ("bench-sim": bench_sim_cmd)
            guess = f"{name.replace('-', '_')}_cmd"
            if guess in _COMMANDS:
                self._load(guess)
            if name not in self.commands:
                self._load_all()
        return super().get_command(ctx, name)

    def invoke(self, ctx):
        try:
            return super().invoke(ctx)
        except (click.exceptions.ClickException, click.exceptions.Exit, click.exceptions.Abort, SystemExit,
                KeyboardInterrupt):
            raise
        except Exception as exc:
            if os.environ.get("ESENSE_TRACEBACK"):
                raise
            raise SystemExit(error_line(exc)) from None


def error_line(exc: BaseException) -> str:
    """The one line ``esense`` prints for an exception that ends a command.

    >>> error_line(ValueError("pail.toml: [tank] radius_m must be positive"))
    'esense: error: pail.toml: [tank] radius_m must be positive'
    >>> error_line(FileNotFoundError(2, "No such file or directory", "run.csv"))
    "esense: error: [Errno 2] No such file or directory: 'run.csv'"
    >>> try:
    ...     [][1]
    ... except IndexError as exc:
    ...     print(error_line(exc))   # doctest: +ELLIPSIS
    esense: internal error: IndexError: list index out of range (at <doctest ...>:2); ESENSE_TRACEBACK=1 ...
    """
    if isinstance(exc, (ValueError, OSError)):
        return f"esense: error: {exc}"
    tb = traceback.extract_tb(exc.__traceback__)
    where = f" (at {Path(tb[-1].filename).name}:{tb[-1].lineno})" if tb else ""
    return (f"esense: internal error: {type(exc).__name__}: {exc}{where}; ESENSE_TRACEBACK=1 shows the traceback, "
            "please report it with the command that raised it")


@click.group(cls=_Esense, context_settings={"help_option_names": ["-h", "--help"]})
@click.version_option(package_name="electrosense")
def main():
    """electrosense: electric-sense sensors in water, simulated (BEM, PSM) and checked against the bench.

    Units are SI (m, rad, S/m, V, A, ohm); electrodes are numbered from the
    head (1) to the tail; the emitter is the last electrode unless told
    otherwise; receiver currents are positive into the receiver.
    """
