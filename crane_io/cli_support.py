"""Pieces shared by the two command lines (crane-collect, crane-train)."""

from __future__ import annotations

import functools
import importlib
import importlib.util
import os
import re
import sys

import click

from crane_io.errors import CraneError


def one_blas_thread() -> None:
    """Ask numpy's OpenBLAS for one thread unless the user set OPENBLAS_NUM_THREADS; call before numpy is
    imported. The commands' matrix products are small (tens of columns): a second thread gains little on
    an idle machine, and on a busy one OpenBLAS's spinning threads made `crane-train diagnose` 4x slower
    in CPU (a 30 000 x 32 Gram matrix: 26 ms on one thread against 397 ms on the default two at load 6)."""
    os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")


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


_NAMED_OPTION = re.compile(r"`([A-Za-z_][A-Za-z0-9_]*)`")


def command_flags(ctx: click.Context | None) -> dict[str, str]:
    """Parameter name -> the flag that sets it (`force` -> `--force`), for the command being run and the
    groups above it (the longest `--` spelling of each option)."""
    flags: dict[str, str] = {}
    while ctx is not None:
        for param in ctx.command.params:
            if isinstance(param, click.Option) and param.name and param.name not in flags:
                long = [o for o in param.opts if o.startswith("--")] or list(param.opts)
                flags[param.name] = max(long, key=len)
        ctx = ctx.parent
    return flags


def with_flags(message: str, flags: dict[str, str]) -> str:
    """A library sentence as the command line says it: each backquoted parameter name the command has an
    option for becomes that option's flag; other backquoted words stay as they are."""
    return _NAMED_OPTION.sub(lambda m: flags.get(m.group(1), m.group(0)), message)


def cli_errors(func):
    """Decorator for click commands: CraneError -> 'Error: <sentence>' on stderr and its exit code, the
    options the sentence names (`name`) shown as this command's flags."""

    @functools.wraps(func)
    def wrapper(*args, **kwargs):
        try:
            return func(*args, **kwargs)
        except CraneError as exc:
            message = with_flags(str(exc), command_flags(click.get_current_context(silent=True)))
            click.echo(f"Error: {message}", err=True)
            sys.exit(exc.exit_code)

    return wrapper
