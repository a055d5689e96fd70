"""crane-train's settings and inputs as the library takes them: the TOML settings (train/config/train.toml
overlaid with a user file), a session's preprocessed data for a joint set, an effect named in text, and a
check that an output can be written. The command line (train/cli/) and the Python front door (train.api)
both call these; nothing here knows a command-line flag."""

from __future__ import annotations

import os
from collections.abc import Sequence
from pathlib import Path
from typing import TYPE_CHECKING

from crane_io.errors import ConfigError
from crane_io.toml_config import from_table, read_toml

if TYPE_CHECKING:
    from .data.dataset import Dataset
    from .data.preprocess import PreprocessConfig

DEFAULT_CONFIG = Path(__file__).parent / "config" / "train.toml"



def config_sections() -> dict:
    """Section name -> settings class. Imported when a configuration is read, not for --help (the
    settings modules bring numpy and torch)."""
    from .data.preprocess import PreprocessConfig
    from .data.splits import SplitConfig
    from .models.mlp_settings import MLPSettings

    return {"preprocess": PreprocessConfig, "splits": SplitConfig, "mlp": MLPSettings}


def load_config(path: Path | str | None = None) -> dict:
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


def load_dataset(sessions: str | os.PathLike | Sequence[str | os.PathLike],
                 joints: str | Sequence[str] | None = None, alpha: float | None = None,
                 zero_phase: bool = False, config: PreprocessConfig | None = None,
                 arm: str | None = None) -> Dataset:
    """Read `arm`'s group of the sessions (default: the config's, "follower") and preprocess them.

    `joints`: the learning joints, a sequence of names or one comma-separated string ("all": every arm
    joint the sessions record); `alpha`: the dead-zone threshold (a joint moves when |dq| > alpha
    std(dq)); `zero_phase`: filter forward and backward instead of the paper's causal filters. Given
    values win over `config` (default: PreprocessConfig()). A session whose arm the operator's hand moved
    is refused with train.data.session.HandOnArmError."""
    from .data.preprocess import PreprocessConfig, read_preprocessed

    config = config or PreprocessConfig()
    values = config.to_dict()
    if isinstance(sessions, (str, os.PathLike)):
        sessions = [sessions]
    if isinstance(joints, str):
        joints = joints.split(",")
    if joints:
        values["joints"] = tuple(j.strip() for j in joints if j.strip())
    if alpha is not None:
        values["alpha"] = alpha
    if zero_phase:
        values["zero_phase"] = True
    if arm:
        values["arm"] = arm
    return read_preprocessed(list(sessions), PreprocessConfig.from_dict(values))


def parse_effect(text: str) -> tuple[str, str | None, dict | None]:
    """'NAME', 'NAME:joint=joint2' or 'NAME:joint=joint2,stribeck_velocity=0.05' -> (name, joint, shape)."""
    name, _, rest = text.partition(":")
    name = name.strip()
    if not name:
        raise ConfigError(f"`effects` {text!r} has no effect name")
    joint, shape = None, {}
    for item in filter(None, (p.strip() for p in rest.split(","))):
        key, eq, value = item.partition("=")
        if not eq:
            raise ConfigError(f"`effects` {text!r}: expected key=value after the name, got {item!r}")
        if key.strip() == "joint":
            joint = value.strip()
        else:
            try:
                shape[key.strip()] = float(value)
            except ValueError:
                raise ConfigError(f"`effects` {text!r}: {key.strip()} must be a number, "
                                  f"got {value!r}") from None
    return name, joint, shape or None
