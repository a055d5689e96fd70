"""Pieces shared by the two command lines (crane-collect, crane-train)."""

from __future__ import annotations

import functools
import importlib
import importlib.util
import sys

import click

from crane_io.errors import CraneError


class LazyGroup(click.Group):
    """A click group whose subcommands live in their own modules and are imported only when used,
    so `--help` and every command start fast. `commands` maps a command name to (module, attribute)."""

    def __init__(self, *args, commands: dict[str, tuple[str, str]], **kwargs):
        super().__init__(*args, **kwargs)
        self.lazy_commands = dict(commands)

    def list_commands(self, ctx):
        return sorted(n for n, (mod, _) in self.lazy_commands.items() if importlib.util.find_spec(mod))

    def get_command(self, ctx, name):
        if name not in self.lazy_commands:
            return None
        module, attr = self.lazy_commands[name]
        return getattr(importlib.import_module(module), attr)


def plant_presets() -> list[str]:
    """Names of the shipped plant presets (crane_io/sim/plants/*.toml), read from the folder without importing
    the simulator, so that a command's --help can list them."""
    from importlib import resources

    folder = resources.files("crane_io.sim") / "plants"
    return sorted(p.name[:-5] for p in folder.iterdir() if p.name.endswith(".toml"))


def cli_errors(func):
    """Decorator for click commands: CraneError -> 'Error: <sentence>' on stderr and its exit code."""

    @functools.wraps(func)
    def wrapper(*args, **kwargs):
        try:
            return func(*args, **kwargs)
        except CraneError as exc:
            click.echo(f"Error: {exc}", err=True)
            sys.exit(exc.exit_code)

    return wrapper
