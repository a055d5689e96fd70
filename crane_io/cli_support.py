"""Pieces shared by the two command lines (crane-collect, crane-train)."""

from __future__ import annotations

import functools
import importlib
import importlib.util
import math
import os
import re
import sys

import click

from crane_io.errors import CraneError
from crane_io.toml_config import SEED_MAX


def one_blas_thread() -> None:
    """Ask numpy's OpenBLAS for one thread unless the user set OPENBLAS_NUM_THREADS; call before numpy is
    imported. The commands' matrix products are small (tens of columns): a second thread gains little on
    an idle machine, and on a busy one OpenBLAS's spinning threads made `crane-train diagnose` 4x slower
    in CPU (a 30 000 x 32 Gram matrix: 26 ms on one thread against 397 ms on the default two at load 6)."""
    os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")


class LazyGroup(click.Group):
    """A click group whose subcommands live in their own modules and are imported only when used,
    so `--help` and every command start fast. `commands` maps a command name to (module, attribute).

    A stop signal that ends a command by raising (Ctrl+C: KeyboardInterrupt; crane_io.shutdown's
    Terminated) is one line on stderr, "<prog>: interrupted while <what the program was doing>[; <note>]"
    (crane_io.shutdown.set_activity says what), and the exit status 128 + the signal number (130 for
    Ctrl+C), instead of click's "Aborted!" and 1. `interrupt_note`: what the line adds ("no torque was
    on"). `prompt_exit`: the commands whose start-up ends within a moment of a stop signal even inside C
    code (crane_io.shutdown.arm_prompt_exit, until the command disarms it, e.g. before torque goes on)."""

    def __init__(self, *args, commands: dict[str, tuple[str, str]], interrupt_note: str | None = None,
                 prompt_exit: tuple[str, ...] = (), **kwargs):
        super().__init__(*args, **kwargs)
        self.lazy_commands = dict(commands)
        self.interrupt_note = interrupt_note
        self.prompt_exit = tuple(prompt_exit)

    def invoke(self, ctx):
        from crane_io import shutdown

        try:
            with shutdown.resurface_lost_interrupts():
                return super().invoke(ctx)
        except KeyboardInterrupt as exc:
            shutdown.disarm_prompt_exit()
            _ignore_further_stop_signals()
            line, code = shutdown.interrupted_line(exc, self.interrupt_note)
            try:  # on a terminal on a line of its own (after the echoed ^C); in a pipe exactly one line
                sys.stdout.flush()
                tty = sys.stderr.isatty()
                sys.stderr.write(f"{chr(10) if tty else ''}{ctx.find_root().info_name}: {line}\n")
                sys.stderr.flush()
            except (OSError, ValueError):
                pass
            if ctx.invoked_subcommand in self.prompt_exit and shutdown.is_program(ctx.find_root().info_name):
                # everything was closed on the way here; the interpreter's own teardown (numba, LLVM)
                # can take a second on a busy machine, and the person asked to stop now
                os._exit(code)
            sys.exit(code)
        finally:
            shutdown.disarm_prompt_exit()

    def main(self, *args, **kwargs):
        from crane_io.shutdown import set_activity

        if self.prompt_exit:
            set_activity("starting up")
        return super().main(*args, **kwargs)

    def resolve_command(self, ctx, args):
        from crane_io.shutdown import arm_prompt_exit, restore_interrupt, set_activity

        # the subcommand's module is imported here, still under the start-up's Ctrl+C handler (one line,
        # 130, at once): a KeyboardInterrupt raised inside the import machinery's own callbacks is lost
        name, cmd, rest = super().resolve_command(ctx, args)
        if name in self.prompt_exit:
            set_activity("loading the toolkit's modules")
            arm_prompt_exit(ctx.find_root().info_name, self.interrupt_note)
        restore_interrupt()
        return name, cmd, rest

    def list_commands(self, ctx):
        return sorted(n for n, (mod, _) in self.lazy_commands.items() if importlib.util.find_spec(mod))

    def get_command(self, ctx, name):
        if name not in self.lazy_commands:
            return None
        module, attr = self.lazy_commands[name]
        return getattr(importlib.import_module(module), attr)


def _ignore_further_stop_signals() -> None:
    """While the program says why it ends: a second Ctrl+C must not print a traceback over it."""
    import signal
    import threading

    if threading.current_thread() is threading.main_thread():
        for name in ("SIGINT", "SIGTERM", "SIGHUP"):
            if hasattr(signal, name):
                signal.signal(getattr(signal, name), signal.SIG_IGN)


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
    options the sentence names (`name`) shown as this command's flags, control characters escaped."""

    @functools.wraps(func)
    def wrapper(*args, **kwargs):
        try:
            return func(*args, **kwargs)
        except CraneError as exc:
            message = with_flags(str(exc), command_flags(click.get_current_context(silent=True)))
            click.echo(f"Error: {shown(message)}", err=True)  # a name with escape codes stays one line
            sys.exit(exc.exit_code)

    return wrapper


def interval_format(value: float, half: float, least: int = 3, most: int = 8) -> str:
    """The format spec that prints a value and its interval value +- `half` with the interval's width
    visible to two digits, so that a bound never rounds onto the value or onto a round number it stops
    short of: "{least}g" for a wide interval; for a narrow one more significant digits (up to `most`),
    trailing zeros kept ("#.5g": 0.25000, not 0.25)."""
    if not (math.isfinite(value) and math.isfinite(half)) or half <= 0 or value == 0:
        return f".{least}g"
    digits = int(min(most, max(least, math.ceil(math.log10(abs(value) / half)) + 2)))
    return f".{least}g" if digits == least else f"#.{digits}g"


def shown(value) -> str:
    """`value` as text safe to print on a terminal: control characters (escape codes, newlines) are shown
    as Python escapes (\\x1b, \\n), everything else as it is."""
    text = str(value)
    if all(c.isprintable() for c in text):
        return text
    return "".join(c if c.isprintable() else repr(c)[1:-1] for c in text)


class OptionValueError(click.BadParameter):
    """A bad option value, said in one line ("Error: --rate must be between 100 and 2000 Hz, got 50")
    without click's usage lines; exit 2."""

    def show(self, file=None) -> None:
        click.echo(f"Error: {self.message}", file=file, err=file is None)


def _flag(param) -> str:
    if param is None:
        return "the value"
    opts = [o for o in getattr(param, "opts", ()) if o.startswith("--")] or list(getattr(param, "opts", ()))
    return max(opts, key=len) if opts else (param.name or "the value").upper()


class Number(click.ParamType):
    """A finite number (`kind` float or int) within a documented range, for every numeric option of both
    command lines: NaN, infinities and out-of-range values are one sentence naming the option and its
    range, exit 2.

        type=Number(float, 100, 2000, unit="Hz")      # --rate must be between 100 and 2000 Hz, got 50
        type=Number(float, 0, low_open=True, what="a positive number of seconds")
        type=Number(int, 0, 2**32 - 1)                 # a seed
    """

    def __init__(self, kind=float, low=None, high=None, *, unit: str = "", low_open: bool = False,
                 what: str | None = None):
        self.kind, self.low, self.high, self.unit, self.low_open = kind, low, high, unit, low_open
        self.name = "integer" if kind is int else "number"
        self.what = what or self.describe()

    def describe(self) -> str:
        unit = f" {self.unit}" if self.unit else ""
        low, high = (None if v is None else f"{v:g}" if isinstance(v, float) else str(v)
                     for v in (self.low, self.high))
        a = "an integer" if self.kind is int else "a number"
        if low is not None and high is not None:
            return (a + " " if self.kind is int else "") + f"between {low} and {high}{unit}"
        if low is not None:
            return f"{a} {'greater than' if self.low_open else 'of at least'} {low}{unit}"
        if high is not None:
            return f"{a} of at most {high}{unit}"
        return "an integer" if self.kind is int else "a finite number"

    def convert(self, value, param, ctx):
        try:
            if isinstance(value, bool):
                raise ValueError
            number = self.kind(value if isinstance(value, (int, float)) else str(value).strip())
        except (TypeError, ValueError, OverflowError):
            number = None
        ok = number is not None and math.isfinite(number)
        if ok and self.low is not None:
            ok = number > self.low if self.low_open else number >= self.low
        if ok and self.high is not None:
            ok = number <= self.high
        if not ok:
            raise OptionValueError(f"{_flag(param)} must be {self.what}, got {shown(value)}", ctx, param)
        return number


SEED = Number(int, 0, SEED_MAX)  # every --seed
