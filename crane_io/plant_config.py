"""Configuration of the simulated CRANE-X7 arm plant (crane_io.arm_plant.ArmPlant), in TOML.

    cfg = load_plant_config("crane-x7")            # a named preset from crane_io/plants/*.toml
    cfg = load_plant_config("my_plant.toml")       # or a file of your own

Keys (every one optional; crane_io/plants/crane-x7.toml documents each with its default):

    name, description          what the preset is
    base = "PRESET"            start from another preset, then apply this file's keys
    seed = 0                   seed of the sensor noise (ArmPlant(seed=...) overrides it)
    substep_s = 0.00025        integration substep (s); stick-slip is resolved every substep
    effect_files = []          user Python files with Effect subclasses to load first
    [torque_constant]          TRUE N m/A per joint (the recorder uses crane_io.description's values)
    [locked]                   angle (rad) at which each held joint is locked in the 3-DOF dynamics
    [initial]                  initial angle (rad) per joint
    [sensor]                   position_noise_probability, current_noise_lsb, velocity_noise_lsb
    [overload]                 enabled, time_s: overload bit after time_s saturated at the limit
    [limits]                   stiffness (N m/rad), damping (N m s/rad) of the hard end stops
    [[effects]]                the plant's truth: effect = NAME, joint = JOINT (none for arm effects),
                               then the effect's parameters by name (defaults from the library)
    [known]                    effects = [{effect = NAME, joint = JOINT}, ...]: what a baseline model
                               is told (the truth minus the hidden effect, minus what a fitted
                               rigid-body model absorbs anyway)
    [hidden]                   one planted effect (effect, joint, parameters), simulated like the rest

The truth (effects and parameters) is only written on request (`write_truth`), never into a session.
"""

from __future__ import annotations

import copy
import json
import math
import sys
from dataclasses import dataclass, field
from importlib import resources
from pathlib import Path

from .description import default_arm
from .errors import ConfigError

if sys.version_info >= (3, 11):
    import tomllib
else:  # pragma: no cover
    import tomli as tomllib

BILATERAL_JOINTS = ("joint1", "joint2", "joint4")
_TOP_KEYS = {"name", "description", "base", "seed", "substep_s", "effect_files", "torque_constant", "locked",
             "initial", "sensor", "overload", "limits", "effects", "known", "hidden"}


@dataclass
class EffectSpec:
    effect: str  # library name
    joint: str | None  # joint name (None for arm-scope effects)
    values: dict[str, float] = field(default_factory=dict)

    def as_dict(self) -> dict:
        return {"effect": self.effect, "joint": self.joint, **self.values}


@dataclass
class SensorConfig:
    position_noise_probability: float = 0.05  # chance per read that a joint reads one count off
    current_noise_lsb: float = 1.5  # std of Present Current noise, in 2.69 mA steps
    velocity_noise_lsb: float = 0.3  # std of Present Velocity noise, in 0.229 rpm steps


@dataclass
class OverloadConfig:
    enabled: bool = False
    time_s: float = 1.0  # seconds at the current limit before the overload bit is set


@dataclass
class LimitsConfig:
    stiffness: float = 200.0  # N m/rad of the end-stop spring beyond a joint limit
    damping: float = 2.0  # N m s/rad of the end stop


@dataclass
class PlantConfig:
    name: str = "custom"
    description: str = ""
    seed: int = 0
    substep_s: float = 0.00025
    effect_files: list[str] = field(default_factory=list)
    torque_constant: dict[str, float] = field(default_factory=dict)
    locked: dict[str, float] = field(default_factory=dict)
    initial: dict[str, float] = field(default_factory=dict)
    sensor: SensorConfig = field(default_factory=SensorConfig)
    overload: OverloadConfig = field(default_factory=OverloadConfig)
    limits: LimitsConfig = field(default_factory=LimitsConfig)
    effects: list[EffectSpec] = field(default_factory=list)
    known: list[tuple[str, str | None, dict | None]] = field(default_factory=list)
    hidden: EffectSpec | None = None
    source: str = ""  # preset name or file path it was loaded from

    @property
    def all_effects(self) -> list[EffectSpec]:
        """Every effect the plant simulates (truth), the hidden one included."""
        return list(self.effects) + ([self.hidden] if self.hidden else [])

    def truth(self) -> dict:
        """The plant's hidden truth as plain data (for write_truth and tests)."""
        return {
            "plant": self.name, "source": self.source, "torque_constant": dict(self.torque_constant),
            "effects": [e.as_dict() for e in self.effects],
            "hidden": self.hidden.as_dict() if self.hidden else None,
            "known": [{"effect": n, "joint": j} for n, j, _ in self.known],
        }


def presets() -> list[str]:
    """Names of the shipped presets (crane_io/plants/*.toml)."""
    folder = resources.files("crane_io") / "plants"
    return sorted(p.name[:-5] for p in folder.iterdir() if p.name.endswith(".toml"))


def _read_toml(text: str, where: str) -> dict:
    try:
        return tomllib.loads(text)
    except tomllib.TOMLDecodeError as exc:
        raise ConfigError(f"plant configuration {where} is not valid TOML: {exc}") from None


def _raw(preset_or_path: str | Path, depth: int = 0) -> tuple[dict, str]:
    if depth > 5:
        raise ConfigError(f"plant configuration {preset_or_path}: 'base' presets nest too deeply")
    key = str(preset_or_path)
    path = Path(key)
    if key in presets():
        text = (resources.files("crane_io") / "plants" / f"{key}.toml").read_text()
        where = f"preset {key!r}"
    elif key.endswith(".toml") or path.exists():
        if not path.exists():
            raise ConfigError(f"plant configuration file {path} does not exist")
        if not path.is_file():
            raise ConfigError(f"plant configuration {path} is not a file")
        try:
            text = path.read_text(encoding="utf-8")
        except (OSError, UnicodeDecodeError) as exc:
            why = "not UTF-8 text" if isinstance(exc, UnicodeDecodeError) else (exc.strerror or str(exc))
            raise ConfigError(f"plant configuration file {path} cannot be read ({why})") from None
        where = str(path)
    else:
        raise ConfigError(f"unknown plant preset {key!r}; presets: {', '.join(presets())} "
                          f"(or give a .toml path)")
    data = _read_toml(text, where)
    unknown = sorted(set(data) - _TOP_KEYS)
    if unknown:
        raise ConfigError(f"plant configuration {where} has unknown key(s) {', '.join(unknown)}")
    if "base" in data:
        base, _ = _raw(data["base"], depth + 1)
        merged = copy.deepcopy(base)
        for k, v in data.items():
            if k == "base":
                continue
            if isinstance(v, dict) and isinstance(merged.get(k), dict) and k not in ("hidden", "known"):
                merged[k] = {**merged[k], **v}
            else:
                merged[k] = v
        merged.pop("base", None)
        if "name" not in data:
            merged.pop("name", None)
        data = merged
    return data, where


def _float_table(data, key: str, where: str, joints=None) -> dict[str, float]:
    table = data.get(key, {}) or {}
    if not isinstance(table, dict):
        raise ConfigError(f"{where}: [{key}] must be a table of joint = number")
    names = set(joints or default_arm().joint_names)
    out = {}
    for name, value in table.items():
        if name not in names:
            raise ConfigError(f"{where}: [{key}] names unknown joint {name!r}")
        if isinstance(value, bool) or not isinstance(value, (int, float)) or not math.isfinite(value):
            raise ConfigError(f"{where}: [{key}] {name} must be a finite number, got {value!r}")
        out[name] = float(value)
    return out


def _dataclass_table(cls, data, key: str, where: str):
    table = data.get(key, {}) or {}
    if not isinstance(table, dict):
        raise ConfigError(f"{where}: {key} must be a table ([{key}]), got {table!r}")
    fields = cls.__dataclass_fields__
    unknown = sorted(set(table) - set(fields))
    if unknown:
        raise ConfigError(f"{where}: [{key}] has unknown key(s) {', '.join(unknown)}")
    defaults = cls()
    values = {}
    for k, v in table.items():
        if isinstance(getattr(defaults, k), bool):
            if not isinstance(v, bool):
                raise ConfigError(f"{where}: [{key}] {k} must be true or false, got {v!r}")
        elif isinstance(v, bool) or not isinstance(v, (int, float)) or not math.isfinite(v) or v < 0:
            raise ConfigError(f"{where}: [{key}] {k} must be a finite number, zero or more, got {v!r}")
        else:
            v = float(v)
        values[k] = v
    obj = cls(**values)
    if getattr(obj, "position_noise_probability", 0.0) > 1:
        raise ConfigError(f"{where}: [{key}] position_noise_probability must be at most 1, "
                          f"got {obj.position_noise_probability}")
    return obj


def _effect_spec(entry, where: str) -> EffectSpec:
    from .effects import get_effect

    if not isinstance(entry, dict) or "effect" not in entry:
        raise ConfigError(f"{where}: every effect entry needs an 'effect' name")
    entry = dict(entry)
    name = entry.pop("effect")
    joint = entry.pop("joint", None)
    eff = get_effect(name)
    if eff.scope == "joint":
        if joint not in BILATERAL_JOINTS:
            raise ConfigError(f"{where}: effect {name!r} needs joint = one of {', '.join(BILATERAL_JOINTS)}, "
                              f"got {joint!r}")
    elif joint is not None:
        raise ConfigError(f"{where}: effect {name!r} acts on the whole arm; remove its joint")
    values = eff.check_values(entry)
    return EffectSpec(name, joint, {k: values[k] for k in values})


def load_plant_config(preset_or_path: str | Path = "crane-x7") -> PlantConfig:
    """A PlantConfig from a preset name (see presets()) or a TOML path. Bad input -> ConfigError."""
    from .effects import load_effect_file

    data, where = _raw(preset_or_path)
    cfg = PlantConfig(source=str(preset_or_path))
    cfg.name = str(data.get("name", Path(str(preset_or_path)).stem))
    cfg.description = str(data.get("description", ""))
    seed, substep = data.get("seed", 0), data.get("substep_s", cfg.substep_s)
    if isinstance(seed, bool) or not isinstance(seed, int):
        raise ConfigError(f"{where}: seed must be an integer, got {seed!r}")
    if isinstance(substep, bool) or not isinstance(substep, (int, float)):
        raise ConfigError(f"{where}: substep_s must be a number, got {substep!r}")
    cfg.seed, cfg.substep_s = seed, float(substep)
    if not 1e-5 <= cfg.substep_s <= 0.002:
        raise ConfigError(f"{where}: substep_s must be between 1e-05 and 0.002 s, got {cfg.substep_s}")
    files = data.get("effect_files", []) or []
    base_dir = Path(where).parent if Path(where).is_file() else Path.cwd()
    for f in files:
        p = Path(f)
        p = p if p.is_absolute() else base_dir / p
        load_effect_file(p)
        cfg.effect_files.append(str(p))
    arm = default_arm()
    cfg.torque_constant = {j.name: j.torque_constant for j in arm.joints}
    cfg.torque_constant.update(_float_table(data, "torque_constant", where))
    if any(v <= 0 for v in cfg.torque_constant.values()):
        raise ConfigError(f"{where}: every torque constant must be positive")
    cfg.locked = _float_table(data, "locked", where)
    clash = [n for n in cfg.locked if n in BILATERAL_JOINTS]
    if clash:
        raise ConfigError(f"{where}: [locked] cannot lock the simulated joint(s) {', '.join(clash)}")
    cfg.initial = _float_table(data, "initial", where)
    cfg.sensor = _dataclass_table(SensorConfig, data, "sensor", where)
    cfg.overload = _dataclass_table(OverloadConfig, data, "overload", where)
    cfg.limits = _dataclass_table(LimitsConfig, data, "limits", where)
    effects = data.get("effects", []) or []
    if not isinstance(effects, list):
        raise ConfigError(f"{where}: effects must be a list of [[effects]] tables")
    cfg.effects = [_effect_spec(e, where) for e in effects]
    if data.get("hidden"):
        cfg.hidden = _effect_spec(data["hidden"], where + " [hidden]")
    known_table = data.get("known") or {}
    if not isinstance(known_table, dict):
        raise ConfigError(f"{where}: known must be a table ([known] with effects = [...])")
    known = known_table.get("effects", [])
    if not isinstance(known, list):
        raise ConfigError(f"{where}: [known] effects must be a list of tables with an 'effect' name")
    from .effects import get_effect

    for k in known:
        if not isinstance(k, dict) or "effect" not in k:
            raise ConfigError(f"{where}: [known] effects must be tables with an 'effect' name")
        get_effect(k["effect"])
        cfg.known.append((str(k["effect"]), k.get("joint"), k.get("shape")))
    return cfg


def write_truth(config: PlantConfig, path: str | Path) -> Path:
    """Write the plant's truth (effects, parameters, hidden effect, true torque constants) as JSON."""
    path = Path(path)
    path.write_text(json.dumps(config.truth(), indent=2) + "\n")
    return path
