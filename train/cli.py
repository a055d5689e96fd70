"""The `crane-train` command line. Each subcommand lives in its own module; this file only wires
them into one click group. Bad input ends with one sentence on stderr and a non-zero exit."""

from __future__ import annotations

import click

from crane_io.cli_support import LazyGroup

# (module, attribute) of every subcommand; imported lazily so `--help` stays fast.
COMMANDS = {
    "info": ("train.cmd_info", "info"),
    "fit": ("train.cmd_fit", "fit"),
    "sweep": ("train.cmd_sweep", "sweep"),
    "report": ("train.cmd_report", "report"),
    "diagnose": ("train.cmd_diagnose", "diagnose"),
    "compare": ("train.cmd_compare", "compare"),
    "effects": ("train.cmd_effects", "effects"),
    "export": ("train.cmd_export", "export"),
    "fidelity": ("train.cmd_fidelity", "fidelity"),
    "view": ("train.cmd_view", "view"),
    "import": ("train.cmd_import", "import_session"),
}


@click.group(cls=LazyGroup, commands=COMMANDS)
@click.version_option(package_name="crane-x7")
def main():
    """Turn CRANE-X7 session files into inverse-dynamics models, compare and diagnose them."""
