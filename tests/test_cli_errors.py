"""Library sentences name options by their parameter names (`duration`); the command line shows its own
flags in their place (crane_io.cli_support.cli_errors), and Python sees the parameter names."""

import click
from click.testing import CliRunner

from crane_io.cli_support import cli_errors, command_flags, with_flags
from crane_io.errors import ConfigError, HardwareError


def _library(duration, force=False):
    if duration <= 0:
        raise ConfigError(f"`duration` must be a positive number of seconds, got {duration:g}")
    if not force:
        raise ConfigError("out.h5 already exists; pass `force` to overwrite it (see `with`)")
    raise HardwareError("`leader_port` and `follower_port` must be different ports")


@click.group()
@click.option("--verbose/--quiet", "verbose", default=False)
def group(verbose):
    pass


@group.command()
@click.option("--duration", type=float)
@click.option("-f", "--force", is_flag=True)
@click.option("--leader-port", "leader_port")
@cli_errors
def run(duration, force, leader_port):
    _library(duration, force)


def test_the_command_line_shows_its_flags_in_place_of_the_parameter_names():
    out = CliRunner().invoke(group, ["run", "--duration", "-1"])
    assert out.exit_code == 2
    assert out.output.strip() == "Error: --duration must be a positive number of seconds, got -1"
    out = CliRunner().invoke(group, ["run", "--duration", "1"])
    # a backquoted word that is no option of the command (`with`) stays as it is
    assert out.output.strip() == "Error: out.h5 already exists; pass --force to overwrite it (see `with`)"
    out = CliRunner().invoke(group, ["run", "--duration", "1", "--force"])
    assert out.exit_code == 3
    assert out.output.strip() == "Error: --leader-port and `follower_port` must be different ports"


def test_python_sees_the_parameter_names():
    try:
        _library(-2.0)
    except ConfigError as exc:
        assert str(exc) == "`duration` must be a positive number of seconds, got -2"


def test_the_flags_come_from_the_command_and_the_groups_above_it():
    with click.Context(group) as parent, click.Context(run, parent=parent) as ctx:
        flags = command_flags(ctx)
    assert flags == {"duration": "--duration", "force": "--force", "leader_port": "--leader-port",
                     "verbose": "--verbose"}
    assert with_flags("`force` or `nothing`", flags) == "--force or `nothing`"


def test_an_interval_is_printed_with_the_digits_that_show_its_width():
    from crane_io.cli_support import interval_format

    def text(value, half):
        f = interval_format(value, half)
        return f"{value:{f}} ({value - half:{f}} to {value + half:{f}})"

    # a narrow interval that stops short of a round number is not printed as reaching it
    assert text(0.249331, 0.000643) == "0.24933 (0.24869 to 0.24997)"
    assert text(0.248213, 0.0018) == "0.24821 (0.24641 to 0.25001)"  # trailing zeros kept
    assert text(0.2, 0.05) == "0.2 (0.15 to 0.25)"  # a wide one keeps three digits
    assert interval_format(0.0, 1e-3) == ".3g" and interval_format(1.0, 0.0) == ".3g"
    assert interval_format(1.0, 1e-12) == "#.8g" and interval_format(float("nan"), 1.0) == ".3g"
