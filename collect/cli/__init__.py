"""The `crane-collect` command line. Each subcommand lives in its own module of this package
(collect/cli/run.py, check.py, ...); this file only wires them into one click group. Bad input ends
with one sentence on stderr and a non-zero exit."""

from __future__ import annotations

from crane_io.shutdown import interrupt_until_main

interrupt_until_main("crane-collect", "no torque was on")  # a Ctrl+C among the imports: one line, 130

import click  # noqa: E402

from crane_io.cli_support import LazyGroup, one_blas_thread  # noqa: E402

one_blas_thread()  # before numpy is imported (the subcommands import it)

# (module, attribute) of every subcommand; imported lazily so `--help` stays fast.
COMMANDS = {
    "run": ("collect.cli.run", "run"),
    "excite": ("collect.cli.excite", "excite"),
    "check": ("collect.cli.check", "check"),
    "ports": ("collect.cli.ports", "ports"),
    "calibrate": ("collect.cli.calibrate", "calibrate"),
    "selftest": ("collect.cli.selftest", "selftest"),
    "sim-serve": ("collect.cli.sim_serve", "sim_serve"),
    "recover": ("collect.cli.recover", "recover"),
}


@click.group(cls=LazyGroup, commands=COMMANDS, interrupt_note="no torque was on",
             prompt_exit=("run", "excite"))
@click.version_option(package_name="crane-x7")
def main():
    """Drive a leader and a follower CRANE-X7 (or two simulated ones) and record sessions."""
