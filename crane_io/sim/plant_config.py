"""Configuration of the simulated CRANE-X7 arm plant (crane_io.sim.arm_plant.ArmPlant), in TOML.

    cfg = load_plant_config("crane-x7")            # a named preset from crane_io/sim/plants/*.toml
    cfg = load_plant_config("my_plant.toml")       # or a file of your own

Keys (every one optional; crane_io/sim/plants/crane-x7.toml documents each with its default):

    name, description          what the preset is
    base = "PRESET"            start from another preset, then apply this file's keys
    seed = 0                   seed of the sensor noise (ArmPlant(seed=...) overrides it)
    joints = [...]             the joints the plant integrates with the full rigid-body dynamics, any
                               of joint1..joint7 (arm order, at least one); default the paper's three
                               ["joint1", "joint2", "joint4"] (BILATERAL_JOINTS). The others (and the
                               gripper) are held servos: locked in the dynamics at [locked], simple
                               position followers. ArmPlant(joints=...) overrides it; every joint
                               effect and joint wall must be on an integrated joint
    substep_s = 0.00025        integration substep (s); stick-slip is resolved every substep
    arm_model = "PATH"         an identified arm model (arm_model.toml of `crane-train identify`, data
                               only; a path relative to this file): the plant's rigid bodies are its
                               bodies, and its viscous and Coulomb friction (where it has them) join
                               [[effects]] as `viscous` and `coulomb` effects. Its free joints must be
                               the plant's `joints` and its locked angles the plant's [locked] ones; a
                               `payload` effect, or friction of the plant's own on a joint the model
                               gives friction for, is refused (the model holds them already)
    effect_specs = [...]       effect-spec files (JSON, crane_io/physics/effects/spec.py; paths relative
                               to this file): effects as data (sums of basis terms) that [[effects]]
                               and [hidden] can name. Loading a plant never runs code: the former
                               `effect_files` (Python files) is refused
    [torque_constant]          TRUE N m/A per joint (the recorder uses crane_io.description's values)
    [locked]                   angle (rad) at which each held joint is locked in the dynamics; an
                               entry for an integrated joint is not used (PlantConfig.locked holds
                               only the held joints'; a joint left out is locked at 0)
    [initial]                  initial angle (rad) per joint
    [sensor]                   position_noise_probability, current_noise_lsb, velocity_noise_lsb
    [overload]                 enabled, time_s, current_fraction, still_velocity: overload bit after
                               time_s at the Current Limit without moving (crane_io.sim.servo_health)
    [thermal]                  enabled, ambient_c, time_constant_s, thermal_resistance: winding
                               temperature from I^2 R; overheating bit above the Temperature Limit
    [supply]                   enabled, voltage, resistance_ohm: the servos' supply; input voltage bit
                               outside the Min/Max Voltage Limit
    [limits]                   stiffness (N m/rad), damping (N m s/rad) of the hard end stops
    [[effects]]                the plant's truth: effect = NAME, joint = JOINT (an integrated joint;
                               none for arm effects),
                               then the effect's parameters by name (defaults from the library)
    [known]                    effects = [{effect = NAME, joint = JOINT}, ...]: what a baseline model
                               is told (the truth minus the hidden effect, minus what a fitted
                               rigid-body model absorbs anyway)
    [hidden]                   one planted effect (effect, joint, parameters), simulated like the rest
    [[environment]]            objects the arm can touch (crane_io.sim.environment; none by default):
        kind = "joint-wall"    joint = JOINT (an integrated joint), angle = RAD, side = "above" or
                               "below" (the wall stops motion above / below angle), stiffness = 50.0
                               N m/rad, damping = 0.5 N m s/rad (damping acts only while penetrating;
                               the wall never pulls)
        kind = "plane"         point = [x, y, z] m and normal = [nx, ny, nz] (into free space,
                               normalised here) in the arm's base frame; frame = "tool" (the point
                               on the arm checked against the plane: a frame of the arm model,
                               default the tool frame 0.08 m beyond the gripper base, roughly between
                               the fingertips), stiffness = 2000.0 N/m, damping = 20.0 N s/m,
                               friction = 0.3 (Coulomb mu, tangential force <= mu x normal force),
                               friction_velocity = 0.01 m/s (the tanh smoothing of friction)

The truth (effects and parameters) is only written on request (`write_truth`), never into a session.
"""

from __future__ import annotations

import copy
import json
import math
from dataclasses import dataclass, field, fields, replace
from importlib import resources
from pathlib import Path
from typing import TYPE_CHECKING, Literal

from crane_io.description import default_arm
from crane_io.errors import ConfigError
from crane_io.sim.servo_health import OverloadConfig, SupplyConfig, ThermalConfig, check_configs
from crane_io.toml_config import check_keys, check_seed, expect, from_table, is_number, read_toml

if TYPE_CHECKING:
    from crane_io.physics.identified_model import IdentifiedArm

BILATERAL_JOINTS = ("joint1", "joint2", "joint4")  # the paper's joints: the default integrated set
# the joints a plant can integrate (the gripper is always a held servo)
ARM_JOINTS = ("joint1", "joint2", "joint3", "joint4", "joint5", "joint6", "joint7")
_TOP_KEYS = {"name", "description", "base", "seed", "joints", "substep_s", "effect_files", "effect_specs",
             "torque_constant", "locked", "initial", "sensor", "overload", "thermal", "supply", "limits",
             "effects", "known", "hidden", "environment", "arm_model"}
ENVIRONMENT_KINDS = ("joint-wall", "plane")


@dataclass
class EffectSpec:
    effect: str  # library name, or the name of an effect of one of the plant's effect_specs files
    joint: str | None  # joint name (None for arm-scope effects)
    values: dict[str, float] = field(default_factory=dict)
    definition: dict | None = None  # the effect as data when it comes from an effect-spec file

    def as_dict(self) -> dict:
        return {"effect": self.effect, "joint": self.joint, **self.values}

    def build(self):
        """A fresh instance of the effect (from its definition when it has one; nothing is run)."""
        if self.definition is not None:
            from crane_io.physics.effects.spec import rebuild

            return rebuild(self.definition, f"the plant's effect {self.effect!r}")
        from crane_io.physics.effects import get_effect

        return get_effect(self.effect)


@dataclass(frozen=True)
class JointWallSpec:
    """A wall in one joint's angle (see crane_io.sim.environment.JointWall)."""

    joint: str  # an integrated joint
    angle: float  # rad
    side: Literal["above", "below"]  # "above": stops motion above `angle`; "below": below it
    stiffness: float = 50.0  # N m/rad
    damping: float = 0.5  # N m s/rad, only while penetrating
    kind: str = "joint-wall"

    def as_dict(self) -> dict:
        return {"kind": self.kind, "joint": self.joint, "angle": self.angle, "side": self.side,
                "stiffness": self.stiffness, "damping": self.damping}


@dataclass(frozen=True)
class PlaneSpec:
    """A plane in the arm's base frame checked against one frame of the arm
    (crane_io.sim.environment.Plane)."""

    point: tuple[float, float, float]  # m, a point of the plane
    normal: tuple[float, float, float]  # unit vector into free space
    frame: str = "tool"  # the point on the arm: a frame of the arm model
    stiffness: float = 2000.0  # N/m
    damping: float = 20.0  # N s/m, only while penetrating
    friction: float = 0.3  # Coulomb coefficient mu
    friction_velocity: float = 0.01  # m/s: friction = mu F_n tanh(|v_t| / friction_velocity)
    kind: str = "plane"

    def as_dict(self) -> dict:
        return {"kind": self.kind, "point": list(self.point), "normal": list(self.normal),
                "frame": self.frame, "stiffness": self.stiffness, "damping": self.damping,
                "friction": self.friction, "friction_velocity": self.friction_velocity}


EnvironmentSpec = JointWallSpec | PlaneSpec


@dataclass
class SensorConfig:
    position_noise_probability: float = 0.05  # chance per read that a joint reads one count off
    current_noise_lsb: float = 1.5  # std of Present Current noise, in 2.69 mA steps
    velocity_noise_lsb: float = 0.3  # std of Present Velocity noise, in 0.229 rpm steps


@dataclass
class LimitsConfig:
    stiffness: float = 200.0  # N m/rad of the end-stop spring beyond a joint limit
    damping: float = 2.0  # N m s/rad of the end stop


@dataclass
class PlantConfig:
    name: str = "custom"
    description: str = ""
    seed: int = 0
    joints: tuple[str, ...] = BILATERAL_JOINTS  # integrated joints when ArmPlant(joints=None)
    substep_s: float = 0.00025
    torque_constant: dict[str, float] = field(default_factory=dict)
    locked: dict[str, float] = field(default_factory=dict)
    initial: dict[str, float] = field(default_factory=dict)
    sensor: SensorConfig = field(default_factory=SensorConfig)
    overload: OverloadConfig = field(default_factory=OverloadConfig)  # crane_io.sim.servo_health
    thermal: ThermalConfig = field(default_factory=ThermalConfig)
    supply: SupplyConfig = field(default_factory=SupplyConfig)
    limits: LimitsConfig = field(default_factory=LimitsConfig)
    effects: list[EffectSpec] = field(default_factory=list)
    known: list[tuple[str, str | None, dict | None]] = field(default_factory=list)
    hidden: EffectSpec | None = None
    environment: list[EnvironmentSpec] = field(default_factory=list)  # objects the arm can touch
    source: str = ""  # preset name or file path it was loaded from
    arm_model: IdentifiedArm | None = None  # identified bodies (and friction) the plant is built from
    arm_model_path: str = ""  # where arm_model was read from

    @property
    def all_effects(self) -> list[EffectSpec]:
        """Every effect the plant simulates (truth), the hidden one included."""
        return list(self.effects) + ([self.hidden] if self.hidden else [])

    def truth(self) -> dict:
        """The plant's hidden truth as plain data (for write_truth and tests); the environment only
        when there is one."""
        out = {
            "plant": self.name, "source": self.source, "torque_constant": dict(self.torque_constant),
            "effects": [e.as_dict() for e in self.effects],
            "hidden": self.hidden.as_dict() if self.hidden else None,
            "known": [{"effect": n, "joint": j} for n, j, _ in self.known],
        }
        if self.environment:
            out["environment"] = [e.as_dict() for e in self.environment]
        if self.arm_model is not None:
            out["arm_model"] = self.arm_model_path
        return out

    def restricted_to(self, joints) -> PlantConfig:
        """A copy that integrates `joints` (arm order as given) and simulates only the effects, the
        hidden effect, the [known] entries and the joint walls on those joints (arm-scope effects and
        planes stay). For running a preset's arm with some of its joints held: a held joint is a servo
        in position mode, so its friction has no part in the physics the run records. The copy's
        `description` says what was left out."""
        joints = tuple(joints)
        keep = set(joints)
        cfg = copy.copy(self)
        cfg.joints = joints
        cfg.effects = [e for e in self.effects if e.joint is None or e.joint in keep]
        cfg.hidden = self.hidden if self.hidden is None or self.hidden.joint in (None, *joints) else None
        cfg.known = [k for k in self.known if k[1] is None or k[1] in keep]
        cfg.environment = [e for e in self.environment if not isinstance(e, JointWallSpec) or e.joint in keep]
        dropped = sorted({e.joint for e in self.all_effects if e.joint is not None and e.joint not in keep})
        if dropped:
            cfg.description = (f"{self.description} Restricted to {', '.join(joints)}: the effects on "
                               f"{', '.join(dropped)} (held) are not simulated.").strip()
        return cfg

    def without_environment(self) -> PlantConfig:
        """A copy with no [[environment]] objects (e.g. for the leader arm, which touches nothing)."""
        cfg = copy.copy(self)
        cfg.environment = []
        return cfg


def presets() -> list[str]:
    """Names of the shipped presets (crane_io/sim/plants/*.toml)."""
    folder = resources.files("crane_io.sim") / "plants"
    return sorted(p.name[:-5] for p in folder.iterdir() if p.name.endswith(".toml"))


def _raw(preset_or_path: str | Path, depth: int = 0) -> tuple[dict, str]:
    if depth > 5:
        raise ConfigError(f"plant configuration {preset_or_path}: 'base' presets nest too deeply")
    key = str(preset_or_path)
    path = Path(key)
    if key in presets():
        where = f"preset {key!r}"
        text = (resources.files("crane_io.sim") / "plants" / f"{key}.toml").read_text()
        data = read_toml(text=text, what="plant configuration", where=where)
    elif key.endswith(".toml") or path.exists():
        where = str(path)
        data = read_toml(path, what="plant configuration file")
    else:
        raise ConfigError(f"unknown plant preset {key!r}; presets: {', '.join(presets())} "
                          f"(or give a .toml path)")
    check_keys(data, _TOP_KEYS, where)
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
    expect(isinstance(table, dict), f"{where}: [{key}]", "a table of joint = number", table)
    names = set(joints or default_arm().joint_names)
    for name, value in table.items():
        if name not in names:
            raise ConfigError(f"{where}: [{key}] names unknown joint {name!r}")
        expect(is_number(value), f"{where}: [{key}] {name}", "a finite number", value)
    return {name: float(value) for name, value in table.items()}


def _within_limits(angles: dict[str, float], key: str, where: str) -> None:
    """ConfigError for the first angle (rad) outside its joint's limits (crane_io.description)."""
    arm = default_arm()
    for name, value in angles.items():
        j = arm.joint(name)
        expect(j.lower <= value <= j.upper, f"{where}: [{key}] {name}",
               f"within the joint's limits, {j.lower:.4g} to {j.upper:.4g} rad", value)


def _dataclass_table(cls, data, key: str, where: str):
    obj = from_table(cls, data.get(key), where, f"[{key}]")
    numbers = [f.name for f in fields(cls) if not isinstance(getattr(obj, f.name), bool)]
    _signs(obj, f"{where}: [{key}]", nonneg=numbers)
    if getattr(obj, "position_noise_probability", 0.0) > 1:
        raise ConfigError(f"{where}: [{key}] position_noise_probability must be at most 1, "
                          f"got {obj.position_noise_probability}")
    return obj


def check_joints(joints, where: str = "the plant") -> tuple[str, ...]:
    """The integrated joint set as a tuple in arm order: any of joint1..joint7, at least one, each once.
    Anything else -> ConfigError."""
    if isinstance(joints, (str, bytes)) or not hasattr(joints, "__iter__"):
        raise ConfigError(f"{where}: joints must be a list of joint names (any of {', '.join(ARM_JOINTS)}), "
                          f"got {joints!r}")
    joints = list(joints)
    bad = [j for j in joints if j not in ARM_JOINTS]
    if bad:
        raise ConfigError(f"{where}: joints names {bad[0]!r}, which the plant cannot integrate (any of "
                          f"{', '.join(ARM_JOINTS)}; the gripper is always a held servo)")
    if len(set(joints)) != len(joints) or not joints:
        raise ConfigError(f"{where}: joints must name at least one joint, each once, got {list(joints)!r}")
    return tuple(j for j in ARM_JOINTS if j in joints)


def _effect_spec(entry, where: str, joints=BILATERAL_JOINTS, defined: dict | None = None) -> EffectSpec:
    if not isinstance(entry, dict) or "effect" not in entry:
        raise ConfigError(f"{where}: every effect entry needs an 'effect' name")
    entry = dict(entry)
    name = entry.pop("effect")
    joint = entry.pop("joint", None)
    if not isinstance(name, str):
        raise ConfigError(f"{where}: an effect name must be a text, got {name!r}")
    spec = EffectSpec(name, joint, definition=(defined or {}).get(name))
    eff = spec.build()
    if eff.scope == "joint":
        if joint not in joints:
            fix = (f" (to simulate it there, add {joint} to the plant's joints)" if joint in ARM_JOINTS
                   else "")
            raise ConfigError(f"{where}: effect {name!r} needs joint = one of the integrated joints "
                              f"{', '.join(joints)}, got {joint!r}{fix}")
    elif joint is not None:
        raise ConfigError(f"{where}: effect {name!r} acts on the whole arm; remove its joint")
    values = eff.check_values(entry)
    spec.values = {k: values[k] for k in values}
    return spec


def _defined_effects(data: dict, where: str) -> dict[str, dict]:
    """name -> terms spec of every effect in the plant's effect_specs files (read as data). A plant that
    lists Python `effect_files` is refused: loading a plant never runs code."""
    from crane_io.physics.effects.spec import read_spec_file

    files = data.get("effect_files") or []
    files = files if isinstance(files, list) else [files]
    if files:
        raise ConfigError(f"{where}: effect_files names Python files ({', '.join(map(str, files))}), which "
                          f"loading a plant never runs; write the effects as data in an effect-spec file and "
                          f"list it in effect_specs")
    paths = data.get("effect_specs") or []
    if not isinstance(paths, list) or not all(isinstance(p, str) and p for p in paths):
        raise ConfigError(f"{where}: effect_specs must be a list of effect-spec file paths")
    base_dir = Path(where).parent if Path(where).is_file() else Path.cwd()
    out: dict[str, dict] = {}
    for f in paths:
        p = Path(f) if Path(f).is_absolute() else base_dir / f
        for spec in read_spec_file(p):
            if spec["name"] in out and out[spec["name"]] != spec:
                raise ConfigError(f"{where}: two effect-spec files define different effects named "
                                  f"{spec['name']!r}")
            out[spec["name"]] = spec
    return out


def load_plant_config(preset_or_path: str | Path = "crane-x7") -> PlantConfig:
    """A PlantConfig from a preset name (see presets()) or a TOML path. Bad input -> ConfigError. Nothing
    it names is run: effects come from the library or, as data, from its effect_specs files."""
    data, where = _raw(preset_or_path)
    cfg = PlantConfig(source=str(preset_or_path))
    cfg.name = str(data.get("name", Path(str(preset_or_path)).stem))
    cfg.description = str(data.get("description", ""))
    seed, substep = data.get("seed", 0), data.get("substep_s", cfg.substep_s)
    check_seed(seed, f"{where}: seed")
    expect(is_number(substep), f"{where}: substep_s", "a number", substep)
    cfg.seed, cfg.substep_s = seed, float(substep)
    cfg.joints = check_joints(data.get("joints", list(BILATERAL_JOINTS)), where)
    if not 1e-5 <= cfg.substep_s <= 0.002:
        raise ConfigError(f"{where}: substep_s must be between 1e-05 and 0.002 s, got {cfg.substep_s}")
    defined = _defined_effects(data, where)
    arm = default_arm()
    cfg.torque_constant = {j.name: j.torque_constant for j in arm.joints}
    cfg.torque_constant.update(_float_table(data, "torque_constant", where))
    if any(v <= 0 for v in cfg.torque_constant.values()):
        raise ConfigError(f"{where}: every torque constant must be positive")
    # an integrated joint is free: its [locked] entry (e.g. inherited from a base preset) is not used
    cfg.locked = {n: v for n, v in _float_table(data, "locked", where).items() if n not in cfg.joints}
    cfg.initial = _float_table(data, "initial", where)
    _within_limits(cfg.locked, "locked", where)
    _within_limits(cfg.initial, "initial", where)
    cfg.sensor = _dataclass_table(SensorConfig, data, "sensor", where)
    cfg.overload = _dataclass_table(OverloadConfig, data, "overload", where)
    cfg.thermal = _dataclass_table(ThermalConfig, data, "thermal", where)
    cfg.supply = _dataclass_table(SupplyConfig, data, "supply", where)
    problem = check_configs(cfg.overload, cfg.thermal, cfg.supply, where)
    if problem:
        raise ConfigError(problem)
    cfg.limits = _dataclass_table(LimitsConfig, data, "limits", where)
    effects = data.get("effects", []) or []
    if not isinstance(effects, list):
        raise ConfigError(f"{where}: effects must be a list of [[effects]] tables")
    cfg.effects = [_effect_spec(e, where, cfg.joints, defined) for e in effects]
    if data.get("hidden"):
        cfg.hidden = _effect_spec(data["hidden"], where + " [hidden]", cfg.joints, defined)
    known_table = data.get("known") or {}
    if not isinstance(known_table, dict):
        raise ConfigError(f"{where}: known must be a table ([known] with effects = [...])")
    known = known_table.get("effects", [])
    if not isinstance(known, list):
        raise ConfigError(f"{where}: [known] effects must be a list of tables with an 'effect' name")
    from crane_io.physics.effects import get_effect

    for k in known:
        if not isinstance(k, dict) or "effect" not in k:
            raise ConfigError(f"{where}: [known] effects must be tables with an 'effect' name")
        if k["effect"] not in defined:
            get_effect(k["effect"])
        cfg.known.append((str(k["effect"]), k.get("joint"), k.get("shape")))
    cfg.environment = _environment(data.get("environment", []), where, cfg.joints)
    if "arm_model" in data:
        _use_arm_model(cfg, data["arm_model"], where)
    return cfg


# ---- arm_model ---------------------------------------------------------------------------------------

def _use_arm_model(cfg: PlantConfig, path, where: str) -> None:
    """Read the identified arm model `path` (relative to the plant file), check that it fits the plant,
    and add its friction to the plant's effects."""
    from crane_io.physics.identified_model import IdentifiedArm

    if not isinstance(path, str) or not path:
        raise ConfigError(f"{where}: arm_model must be the path of an identified arm model (arm_model.toml)")
    base_dir = Path(where).parent if Path(where).is_file() else Path.cwd()
    full = Path(path) if Path(path).is_absolute() else base_dir / path
    model = IdentifiedArm.from_toml(full)
    try:
        model.check_configuration(cfg.joints, cfg.locked)
    except ConfigError as exc:
        raise ConfigError(f"{where}: {str(exc).split('; ')[0]}; set the plant's joints and [locked] to the "
                          f"model's, or identify the arm again") from None
    for spec in cfg.all_effects:
        if spec.effect == "payload":
            raise ConfigError(f"{where}: arm_model {model.source} holds the identified payload in its "
                              f"bodies; remove the plant's payload effect")
        eff = spec.build()
        if spec.joint in model.friction and (eff.friction or spec.effect == "viscous"):
            raise ConfigError(f"{where}: arm_model {model.source} gives the friction of {spec.joint}, and "
                              f"so does the plant's effect {spec.effect!r}; remove one of them")
    for joint in cfg.joints:
        for name, value in sorted(model.friction.get(joint, {}).items(), reverse=True):
            cfg.effects.append(EffectSpec(name, joint, {name: value}))
    cfg.arm_model, cfg.arm_model_path = model, str(full)


# ---- [[environment]] -------------------------------------------------------------------------------

def _environment(entries, where: str, joints=BILATERAL_JOINTS) -> list[EnvironmentSpec]:
    if not isinstance(entries, list):
        raise ConfigError(f"{where}: environment must be a list of [[environment]] tables")
    out = []
    for n, entry in enumerate(entries, start=1):
        at = f"{where}: [[environment]] entry {n}"
        if not isinstance(entry, dict):
            raise ConfigError(f"{at} must be a table with a kind")
        kind = entry.get("kind")
        if kind not in ENVIRONMENT_KINDS:
            raise ConfigError(f"{at} needs kind = one of {', '.join(map(repr, ENVIRONMENT_KINDS))}, "
                              f"got {kind!r}")
        out.append(_joint_wall(entry, at, joints) if kind == "joint-wall" else _plane(entry, at))
    return out


def _signs(spec, prefix: str, positive=(), nonneg=()) -> None:
    """ConfigError "<prefix> <key> must be positive / zero or more" for the first field out of range."""
    for key in positive:
        expect(getattr(spec, key) > 0, f"{prefix} {key}", "positive", getattr(spec, key))
    for key in nonneg:
        expect(getattr(spec, key) >= 0, f"{prefix} {key}", "zero or more", getattr(spec, key))


def _joint_wall(entry: dict, at: str, joints=BILATERAL_JOINTS) -> JointWallSpec:
    wall = from_table(JointWallSpec, entry, at)
    if wall.joint not in joints:
        fix = f" (add {wall.joint} to the plant's joints to integrate it)" if wall.joint in ARM_JOINTS else ""
        raise ConfigError(f"{at}: joint must be one of the integrated joints {', '.join(joints)}, "
                          f"got {wall.joint!r}{fix}")
    _signs(wall, f"{at}:", positive=("stiffness",), nonneg=("damping",))
    return wall


def _frame_names() -> list[str]:
    from crane_io.physics.arm_model import JOINTS, TOOL_FRAME

    return [j[0] for j in JOINTS] + [j[4] for j in JOINTS] + [TOOL_FRAME]


def _plane(entry: dict, at: str) -> PlaneSpec:
    plane = from_table(PlaneSpec, entry, at)
    length = math.sqrt(sum(v * v for v in plane.normal))
    if length < 1e-9:
        raise ConfigError(f"{at}: normal must not be the zero vector")
    if plane.frame not in _frame_names():
        raise ConfigError(f"{at}: frame must be a frame of the arm model ({', '.join(_frame_names())}), "
                          f"got {plane.frame!r}")
    _signs(plane, f"{at}:", positive=("stiffness", "friction_velocity"), nonneg=("damping", "friction"))
    return replace(plane, normal=tuple(v / length for v in plane.normal))


def write_truth(config: PlantConfig, path: str | Path) -> Path:
    """Write the plant's truth (effects, parameters, hidden effect, true torque constants) as JSON."""
    path = Path(path)
    path.write_text(json.dumps(config.truth(), indent=2) + "\n")
    return path
