"""Options shared by `crane-train fit` and `crane-train sweep` (the settings they fill are read by
train.settings)."""

from __future__ import annotations

import click

from crane_io.cli_support import Number
from crane_io.errors import ConfigError


def data_options(func):
    """--joints, --alpha, --zero-phase, --scale-to-data, --eval-set (applied bottom-up by click)."""
    func = click.option("--eval-set", type=click.Choice(["auto", "all-moving", "per-joint"]), default=None,
                        help="Validation and test sets: the paper's samples with every joint moving, or "
                             "per joint (each joint scored where it moves); auto: all-moving up to 3 "
                             "learning joints, per-joint from 4 [auto].")(func)
    func = click.option("--scale-to-data", is_flag=True,
                        help="Shrink the split sizes (pool 6000, validation 500, test 500) to fit short data "
                             "instead of stopping with an error.")(func)
    func = click.option("--zero-phase", is_flag=True,
                        help="Filter forward and backward (no delay), not the paper's causal filters.")(func)
    func = click.option("--alpha", default=None, type=Number(float, 0),
                        help="Dead-zone threshold: a joint moves when |dq| > alpha * std(dq) [0.1].")(func)
    func = click.option("--joints", default=None,
                        help="Comma-separated learning joints, or 'all' (every arm joint the sessions "
                             "record) [joint1,joint2,joint4].")(func)
    func = click.option("--config", "config_path", default=None, type=click.Path(dir_okay=False),
                        help="TOML overriding train/config/train.toml.")(func)
    return func


def force_option(what: str):
    """--force: replace the command's existing output(s); `what` says which, for the help."""
    return click.option("--force", is_flag=True,
                        help=f"Replace {what} if it exists (without it an existing output is refused). An "
                             "output is never one of the command's inputs, and is written whole or not "
                             "at all.")


def arm_option(func):
    """--arm leader|follower: which arm's data a model is fitted on."""
    return click.option("--arm", type=click.Choice(["leader", "follower"]), default=None,
                        help="The arm whose data to fit: the follower, or the leader of a session recorded "
                             "with the hand on the follower (hand_on = follower) [follower].")(func)


def hand_on_hint(exc) -> str:
    """A HandOnArmError's sentence with how to record usable data of that arm (the CLI's hint)."""
    other = "follower" if exc.arm == "leader" else "leader"
    return (f"{exc}; record {exc.arm} data with `crane-collect run --hand-on {other}` (the hand on the "
            f"{other}, the {exc.arm} moving on its own)")


MAX_SIZES = 1000  # training sizes in one sweep
MAX_SIZE = 10**8  # samples in one training set


def parse_sizes(text: str) -> list[int]:
    """'300:3000:300' (start:stop:step, stop included) or '300,600,1200': at most MAX_SIZES sizes, each
    1 .. MAX_SIZE."""
    try:
        if ":" in text:
            parts = [int(p) for p in text.split(":")]
            if len(parts) != 3 or parts[2] <= 0 or parts[0] <= 0 or parts[1] < parts[0]:
                raise ValueError
            if parts[1] > MAX_SIZE or (parts[1] - parts[0]) // parts[2] >= MAX_SIZES:
                raise ValueError
            return list(range(parts[0], parts[1] + 1, parts[2]))
        sizes = [int(p) for p in text.split(",") if p.strip()]
        if not sizes or min(sizes) <= 0 or max(sizes) > MAX_SIZE or len(sizes) > MAX_SIZES:
            raise ValueError
        return sizes
    except ValueError:
        raise ConfigError(f"--sizes {text!r} is not START:STOP:STEP or a comma list of positive "
                          f"integers (at most {MAX_SIZES} sizes of at most {MAX_SIZE})") from None
