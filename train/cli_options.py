"""Options shared by `crane-train fit` and `crane-train sweep`, and their parsing into settings."""

from __future__ import annotations

import click

from crane_io.errors import ConfigError

from .preprocess import PreprocessConfig, preprocess
from .session import read_sessions


def data_options(func):
    """--joints, --alpha, --zero-phase, --scale-to-data (applied bottom-up by click)."""
    func = click.option("--scale-to-data", is_flag=True,
                        help="Shrink the split sizes (pool 6000, validation 500, test 500) to fit short data "
                             "instead of stopping with an error.")(func)
    func = click.option("--zero-phase", is_flag=True,
                        help="Filter forward and backward (no delay), not the paper's causal filters.")(func)
    func = click.option("--alpha", default=0.1, show_default=True, type=float,
                        help="Dead-zone threshold: a joint moves when |dq| > alpha * std(dq).")(func)
    func = click.option("--joints", default="joint1,joint2,joint4", show_default=True,
                        help="Comma-separated learning joints.")(func)
    return func


def load_dataset(sessions, joints: str, alpha: float, zero_phase: bool):
    names = tuple(j.strip() for j in joints.split(",") if j.strip())
    config = PreprocessConfig(joints=names, alpha=alpha, zero_phase=zero_phase)
    return preprocess(read_sessions(sessions), config)


def parse_sizes(text: str) -> list[int]:
    """'300:3000:300' (start:stop:step, stop included) or '300,600,1200'."""
    try:
        if ":" in text:
            parts = [int(p) for p in text.split(":")]
            if len(parts) != 3 or parts[2] <= 0 or parts[0] <= 0 or parts[1] < parts[0]:
                raise ValueError
            return list(range(parts[0], parts[1] + 1, parts[2]))
        sizes = [int(p) for p in text.split(",") if p.strip()]
        if not sizes or min(sizes) <= 0:
            raise ValueError
        return sizes
    except ValueError:
        raise ConfigError(f"--sizes {text!r} is not START:STOP:STEP or a comma list of positive "
                          f"integers") from None


def parse_effect(text: str) -> tuple[str, str | None, dict | None]:
    """'NAME', 'NAME:joint=joint2' or 'NAME:joint=joint2,stribeck_velocity=0.05' -> (name, joint, shape)."""
    name, _, rest = text.partition(":")
    name = name.strip()
    if not name:
        raise ConfigError(f"--effect {text!r} has no effect name")
    joint, shape = None, {}
    for item in filter(None, (p.strip() for p in rest.split(","))):
        key, eq, value = item.partition("=")
        if not eq:
            raise ConfigError(f"--effect {text!r}: expected key=value after the name, got {item!r}")
        if key.strip() == "joint":
            joint = value.strip()
        else:
            try:
                shape[key.strip()] = float(value)
            except ValueError:
                raise ConfigError(f"--effect {text!r}: {key.strip()} must be a number, "
                                  f"got {value!r}") from None
    return name, joint, shape or None
