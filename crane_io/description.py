"""The CRANE-X7 as the software sees it: joints, servo IDs, servo models, limits, torque constants.

Numbers from shared/crane_x7_facts.md (sections 1, 3 and 4). Torque constants are configurable
per joint because public sources disagree by up to 50 % (facts section 3 and 9.1): the default is
RT's own tuned ROS 2 value (2.20 N m/A for XM430-W350, 3.60 N m/A for XM540-W270).

An arm description can be loaded from TOML (see crane_io/config/crane_x7.toml for every key and
its default); anything left out keeps the default below.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, replace
from pathlib import Path

from crane_io.dynamixel.control_table import MODELS, ServoModel
from crane_io.errors import ConfigError
from crane_io.toml_config import from_table, is_number, read_toml

DEG = math.pi / 180.0


class DescriptionError(ConfigError):
    """A configuration that does not describe a usable arm."""


@dataclass(frozen=True)
class Joint:
    name: str
    servo_id: int
    model: str  # key into control_table.MODELS
    lower: float  # rad, software limit
    upper: float  # rad
    velocity_limit: float  # rad/s
    effort_limit: float  # N m
    torque_constant: float  # N m per A of goal current (configurable)

    @property
    def servo_model(self) -> ServoModel:
        return MODELS[self.model]

    @property
    def current_limit(self) -> float:
        """Largest current the servo accepts (its Current Limit register default), in A."""
        return self.servo_model.current_limit_default * 2.69e-3


@dataclass(frozen=True)
class ArmDescription:
    joints: tuple[Joint, ...]
    bilateral_joints: tuple[str, ...] = ("joint1", "joint2", "joint4")
    baudrate: int = 3_000_000
    name: str = "crane-x7"

    # ---- lookups -------------------------------------------------------------------------------
    @property
    def joint_names(self) -> tuple[str, ...]:
        return tuple(j.name for j in self.joints)

    @property
    def servo_ids(self) -> tuple[int, ...]:
        return tuple(j.servo_id for j in self.joints)

    @property
    def held_joints(self) -> tuple[str, ...]:
        return tuple(j.name for j in self.joints if j.name not in self.bilateral_joints)

    def joint(self, name: str) -> Joint:
        for j in self.joints:
            if j.name == name:
                return j
        raise DescriptionError(f"the arm has no joint named {name!r} (joints: {', '.join(self.joint_names)})")

    def index(self, name: str) -> int:
        return self.joint_names.index(self.joint(name).name)

    def by_id(self, servo_id: int) -> Joint:
        for j in self.joints:
            if j.servo_id == servo_id:
                return j
        raise DescriptionError(f"no joint uses servo ID {servo_id}")

    def with_torque_constants(self, constants: dict[str, float]) -> ArmDescription:
        new = []
        for j in self.joints:
            if j.name in constants:
                kt = float(constants[j.name])
                if not kt > 0:
                    raise DescriptionError(f"torque constant of {j.name} must be positive, got {kt}")
                j = replace(j, torque_constant=kt)
            new.append(j)
        return replace(self, joints=tuple(new))

    # ---- loading -------------------------------------------------------------------------------
    @classmethod
    def from_toml(cls, path: str | Path) -> ArmDescription:
        try:
            data = read_toml(path, what="arm description")
        except ConfigError as exc:
            raise DescriptionError(str(exc)) from None
        return cls.from_dict(data.get("arm", data), where=f"arm description {path}")

    @classmethod
    def from_dict(cls, data: dict, where: str = "arm description") -> ArmDescription:
        """The default arm with the keys of `data` (the [arm] table: joints.NAME tables of Joint fields,
        lower_deg/upper_deg in degrees; bilateral_joints; baudrate) applied; each value type-checked."""
        base = default_arm()
        joints = {j.name: j for j in base.joints}
        for name, over in (data.get("joints") or {}).items():
            if name not in joints:
                raise DescriptionError(f"unknown joint {name!r} in arm description")
            joints[name] = _joint_with(joints[name], over, where)
        desc = replace(base, joints=tuple(joints.values()))
        if "bilateral_joints" in data:
            desc = replace(desc, bilateral_joints=tuple(data["bilateral_joints"]))
            for n in desc.bilateral_joints:
                desc.joint(n)
        if "baudrate" in data:
            desc = replace(desc, baudrate=_checked_baudrate(data["baudrate"], where))
        return desc


def _joint_with(joint: Joint, over: dict, where: str) -> Joint:
    """`joint` with the fields of its description table `over` (angles in degrees as lower_deg and
    upper_deg), each checked."""
    name = joint.name
    fields = dict(over)
    for key in [k for k in ("lower_deg", "upper_deg") if k in fields]:
        value = fields.pop(key)
        if not is_number(value):
            raise DescriptionError(f"{where}: joint {name} {key} must be a finite number, "
                                   f"got {value!r}")
        fields[key[:-4]] = value * DEG
    unknown = set(fields) - set(Joint.__dataclass_fields__)
    if unknown:
        raise DescriptionError(f"unknown keys for joint {name}: {', '.join(sorted(unknown))}")
    if "model" in fields and fields["model"] not in MODELS:
        raise DescriptionError(f"joint {name}: unknown servo model {fields['model']!r}")
    try:
        return from_table(Joint, fields, where, f"joint {name}", base=joint)
    except ConfigError as exc:
        raise DescriptionError(str(exc)) from None


def _checked_baudrate(baudrate, where: str) -> int:
    ok = isinstance(baudrate, int) and not isinstance(baudrate, bool) and baudrate > 0
    if not ok:
        raise DescriptionError(f"{where}: baudrate must be a positive integer, got {baudrate!r}")
    return baudrate


_KT_XM430 = 2.20  # RT ROS 2 current_to_effort (facts section 3)
_KT_XM540 = 3.60
_VMAX = 4.81710873  # URDF velocity limit, rad/s


def default_arm() -> ArmDescription:
    """The CRANE-X7 with URDF (ROS 2) limits and RT's tuned torque constants."""
    J = Joint
    joints = (
        J("joint1", 2, "XM430-W350", -157 * DEG, 157 * DEG, _VMAX, 10.0, _KT_XM430),
        J("joint2", 3, "XM540-W270", -90 * DEG, 90 * DEG, _VMAX, 10.0, _KT_XM540),
        J("joint3", 4, "XM430-W350", -157 * DEG, 157 * DEG, _VMAX, 4.0, _KT_XM430),
        J("joint4", 5, "XM430-W350", -159 * DEG, 0.001 * DEG, _VMAX, 4.0, _KT_XM430),
        J("joint5", 6, "XM430-W350", -157 * DEG, 157 * DEG, _VMAX, 4.0, _KT_XM430),
        J("joint6", 7, "XM430-W350", -90 * DEG, 90 * DEG, _VMAX, 4.0, _KT_XM430),
        J("joint7", 8, "XM430-W350", -167 * DEG, 167 * DEG, _VMAX, 4.0, _KT_XM430),
        J("gripper", 9, "XM430-W350", -5 * DEG, 90 * DEG, _VMAX, 4.0, _KT_XM430),
    )
    return ArmDescription(joints=joints)

