"""Options shared by `crane-train fit` and `crane-train sweep`, and their parsing into settings."""

from __future__ import annotations

import os
from pathlib import Path
from typing import TYPE_CHECKING

import click

from crane_io.errors import ConfigError
from crane_io.toml_config import from_table, read_toml

if TYPE_CHECKING:
    from ..data.preprocess import PreprocessConfig

DEFAULT_CONFIG = Path(__file__).parents[1] / "config" / "train.toml"


def config_sections() -> dict:
    """Section name -> settings class. Imported when a configuration is read, not for --help (the
    settings modules bring numpy and torch)."""
    from ..data.preprocess import PreprocessConfig
    from ..data.splits import SplitConfig
    from ..models.batched import MLPSettings

    return {"preprocess": PreprocessConfig, "splits": SplitConfig, "mlp": MLPSettings}


def load_config(path=None) -> dict:
    """{'preprocess': PreprocessConfig, 'splits': SplitConfig, 'mlp': MLPSettings} from the defaults
    file overlaid with `path` (TOML, sections as in train/config/train.toml); each value checked against
    the settings' field types (crane_io.toml_config.from_table)."""
    sections = config_sections()
    data: dict[str, dict] = {}
    out = {section: cls() for section, cls in sections.items()}
    for p in [DEFAULT_CONFIG] + ([Path(path)] if path else []):
        for section, values in read_toml(p).items():
            if section not in sections or not isinstance(values, dict):
                raise ConfigError(f"{p}: unknown section [{section}] (known: {', '.join(sections)})")
            data[section] = {**data.get(section, {}), **values}
            out[section] = from_table(sections[section], data[section], str(p), f"[{section}]")
    return out


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
    func = click.option("--alpha", default=None, type=float,
                        help="Dead-zone threshold: a joint moves when |dq| > alpha * std(dq) [0.1].")(func)
    func = click.option("--joints", default=None,
                        help="Comma-separated learning joints, or 'all' (every arm joint the sessions "
                             "record) [joint1,joint2,joint4].")(func)
    func = click.option("--config", "config_path", default=None, type=click.Path(dir_okay=False),
                        help="TOML overriding train/config/train.toml.")(func)
    return func


def load_dataset(sessions, joints: str | None, alpha: float | None, zero_phase: bool,
                 config: PreprocessConfig | None = None, arm: str | None = None):
    """Read `arm`'s group (default: the config's, "follower") and preprocess; explicit options win over
    `config` (default: PreprocessConfig()). A session whose arm the operator's hand moved is refused with
    train.data.session.HandOnArmError (see `hand_on_hint`)."""
    from ..data.preprocess import PreprocessConfig, read_preprocessed

    config = config or PreprocessConfig()
    values = config.to_dict()
    if joints:
        values["joints"] = tuple(j.strip() for j in joints.split(",") if j.strip())
    if alpha is not None:
        values["alpha"] = alpha
    if zero_phase:
        values["zero_phase"] = True
    if arm:
        values["arm"] = arm
    return read_preprocessed(sessions, PreprocessConfig.from_dict(values))


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


def writable_output(path, kind: str) -> Path:
    """Check, before any work, that the output `path` (kind "dir" or "file") can be written; nothing is
    created. A path under a file, an existing one of the other kind or a read-only place -> ConfigError."""
    path = Path(path)
    if path.exists() and path.is_dir() != (kind == "dir"):
        what = "a folder" if path.is_dir() else "a file"
        raise ConfigError(f"cannot write {path}: it is {what} already")
    existing = next(p for p in [path.parent if kind == "file" else path, *path.parents]
                    if p.exists() or p == Path(p.anchor or "."))
    if existing.exists() and not existing.is_dir():
        raise ConfigError(f"cannot write {path}: {existing} is a file, not a folder")
    if not os.access(existing if existing.exists() else Path("."), os.W_OK):
        raise ConfigError(f"cannot write {path}: the folder {existing} is not writable")
    return path
