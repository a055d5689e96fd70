"""The `crane-train` command line, the edge of train: one module per subcommand (info, fit, identify, sweep,
report,
diagnose, compare, effects, export, fidelity, view, importing) and the options fit and sweep share
(options); each is a thin wrapper over the library (train.api and the subpackages). This file only wires
them into one click group. Bad input ends with one sentence on stderr and a non-zero exit."""

from __future__ import annotations

from crane_io.shutdown import interrupt_until_main

interrupt_until_main("crane-train")  # a Ctrl+C among the imports: one line, 130

import click  # noqa: E402

from crane_io.cli_support import LazyGroup, one_blas_thread  # noqa: E402

one_blas_thread()  # before numpy is imported (the subcommands import it)

# (module, attribute) of every subcommand; imported lazily so `--help` stays fast.
COMMANDS = {
    "info": ("train.cli.info", "info"),
    "fit": ("train.cli.fit", "fit"),
    "identify": ("train.cli.identify", "identify"),
    "sweep": ("train.cli.sweep", "sweep"),
    "report": ("train.cli.report", "report"),
    "diagnose": ("train.cli.diagnose", "diagnose"),
    "compare": ("train.cli.compare", "compare"),
    "effects": ("train.cli.effects", "effects"),
    "export": ("train.cli.export", "export"),
    "fidelity": ("train.cli.fidelity", "fidelity"),
    "view": ("train.cli.view", "view"),
    "import": ("train.cli.importing", "import_session"),
}


@click.group(cls=LazyGroup, commands=COMMANDS)
@click.version_option(package_name="crane-x7")
def main():
    """Turn CRANE-X7 session files into inverse-dynamics models, compare and diagnose them."""
    import warnings

    warnings.showwarning = _one_line(warnings.showwarning)


def _one_line(default):
    """A showwarning that writes the data checks' findings (train.data.data_checks.DataCheckWarning) as one
    line on stderr, "Warning: <sentence>", and leaves other warnings to `default`."""
    from crane_io.cli_support import shown

    def show(message, category, filename, lineno, file=None, line=None):
        if category.__name__ != "DataCheckWarning":
            return default(message, category, filename, lineno, file, line)
        click.echo(f"Warning: {shown(message)}", err=True)

    return show
