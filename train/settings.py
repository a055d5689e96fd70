"""crane-train's settings and inputs as the library takes them: the TOML settings (train/config/train.toml
overlaid with a user file), a session's preprocessed data for a joint set, an effect named in text, and a
check that an output can be written. The command line (train/cli/) and the Python front door (train.api)
both call these; nothing here knows a command-line flag."""

from __future__ import annotations

import math
import os
from collections.abc import Sequence
from pathlib import Path
from typing import TYPE_CHECKING

from crane_io.errors import ConfigError
from crane_io.toml_config import expect, from_table, read_toml

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
            _check_ranges(out[section], section, str(p))
    return out


# section -> setting -> (lowest, highest, lowest excluded): the documented range of each number
# (train/config/train.toml); None: no bound on that side. Types and finiteness are from_table's.
RANGES = {
    "preprocess": {"cutoff_rad_s": (0, None, True), "pseudo_diff_rad_s": (0, None, True),
                   "downsample_hz": (0, None, True), "alpha": (0, None, False), "settle_s": (0, None, False),
                   "split_gap_s": (0, None, True)},
    "splits": {"n_pool": (1, None, False), "n_val": (1, None, False), "n_test": (1, None, False),
               "window_s": (0, None, True), "block_s": (0, None, True), "gap_s": (0, None, False)},
    "mlp": {"hidden": (1, 100_000, False), "lr": (0, 10, True), "epochs": (1, 1_000_000, False),
            "batch_size": (1, None, False), "eps": (0, 1, True)},
}


def _check_ranges(settings, section: str, where: str) -> None:
    """ConfigError naming the first setting of `section` outside its range (RANGES)."""
    for name, (low, high, low_open) in RANGES.get(section, {}).items():
        value = getattr(settings, name)
        ok = (value > low if low_open else value >= low) and (high is None or value <= high)
        if not ok:
            above = f"greater than {low}" if low_open else f"at least {low}"
            expect(False, f"{where}: [{section}] {name}", above + (f" and at most {high}" if high else ""),
                   value)
    if section == "mlp":
        betas = settings.betas
        expect(all(0 <= b < 1 for b in betas), f"{where}: [mlp] betas", "two numbers in [0, 1)", list(betas))


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
                shape[key.strip()] = math.nan
            if not math.isfinite(shape[key.strip()]):
                raise ConfigError(f"`effects` {text!r}: {key.strip()} must be a finite number, "
                                  f"got {value!r}")
    return name, joint, shape or None
