"""The `crane-train` command line. Each subcommand lives in its own module; this file only wires
them into one click group. Bad input ends with one sentence on stderr and a non-zero exit."""

from __future__ import annotations

import importlib
import importlib.util

import click

# (module, attribute) of every subcommand; imported lazily so `--help` stays fast.
_COMMANDS = {
    "info": ("train.cmd_info", "info"),
    "fit": ("train.cmd_fit", "fit"),
    "sweep": ("train.cmd_sweep", "sweep"),
    "report": ("train.cmd_report", "report"),
    "diagnose": ("train.cmd_diagnose", "diagnose"),
    "compare": ("train.cmd_compare", "compare"),
    "effects": ("train.cmd_effects", "effects"),
}


class _LazyGroup(click.Group):
    def list_commands(self, ctx):
        return sorted(n for n, (mod, _) in _COMMANDS.items() if importlib.util.find_spec(mod))

    def get_command(self, ctx, name):
        if name not in _COMMANDS:
            return None
        module, attr = _COMMANDS[name]
        return getattr(importlib.import_module(module), attr)


@click.group(cls=_LazyGroup)
@click.version_option(package_name="crane-x7")
def main():
    """Turn CRANE-X7 session files into inverse-dynamics models, compare and diagnose them."""
