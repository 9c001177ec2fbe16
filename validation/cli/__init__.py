"""The ``esense`` command.

Each subcommand lives in its own module of this package and is registered on
the ``main`` group below; heavy imports happen inside the commands so that
``esense --help`` stays fast.
"""
from __future__ import annotations

import importlib

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
}


@click.group(context_settings={"help_option_names": ["-h", "--help"]})
@click.version_option(package_name="electrosense")
def main():
    """electrosense: electric-sense sensors in water, simulated (BEM, PSM) and checked against the bench.

    Units are SI (m, rad, S/m, V, A, ohm); electrodes are numbered from the
    head (1) to the tail; the emitter is the last electrode unless told
    otherwise; receiver currents are positive into the receiver.
    """


for _module, _attr in _COMMANDS.items():
    try:
        _mod = importlib.import_module(f"{__name__}.{_module}")
    except ModuleNotFoundError as _exc:  # a command not written yet
        if _exc.name != f"{__name__}.{_module}":
            raise
        continue
    main.add_command(getattr(_mod, _attr))
