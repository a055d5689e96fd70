"""The CRANE-X7 description: defaults, TOML loading and its errors."""

import math

import pytest

from crane_io.description import ArmDescription, DescriptionError, default_arm
from crane_io.errors import CraneError


def test_default_arm_matches_the_hardware():
    arm = default_arm()
    assert arm.servo_ids == (2, 3, 4, 5, 6, 7, 8, 9)
    assert arm.joint("joint2").model == "XM540-W270"
    assert all(j.model == "XM430-W350" for j in arm.joints if j.name != "joint2")
    assert arm.bilateral_joints == ("joint1", "joint2", "joint4")
    assert arm.held_joints == ("joint3", "joint5", "joint6", "joint7", "gripper")
    assert arm.baudrate == 3_000_000
    assert arm.joint("joint4").lower == pytest.approx(-159 * math.pi / 180)
    assert arm.by_id(5).name == "joint4"
    assert arm.index("joint4") == 3


def test_shipped_toml_loads_to_the_default():
    from importlib.resources import files

    path = files("crane_io") / "config" / "crane_x7.toml"
    assert ArmDescription.from_toml(path) == default_arm()


def test_toml_overrides_only_what_it_names(tmp_path):
    p = tmp_path / "arm.toml"
    p.write_text('[arm]\nbilateral_joints = ["joint1", "joint4"]\n'
                 "[arm.joints.joint2]\ntorque_constant = 2.409\nupper_deg = 45.0\n")
    arm = ArmDescription.from_toml(p)
    assert arm.joint("joint2").torque_constant == 2.409
    assert arm.joint("joint2").upper == pytest.approx(math.pi / 4)
    assert arm.joint("joint2").lower == default_arm().joint("joint2").lower
    assert arm.bilateral_joints == ("joint1", "joint4")


@pytest.mark.parametrize("text,match", [
    ("[arm.joints.joint9]\nservo_id = 10\n", "unknown joint 'joint9'"),
    ("[arm.joints.joint1]\nspeed = 1\n", "unknown keys for joint joint1: speed"),
    ('[arm.joints.joint1]\nmodel = "XL330"\n', "unknown servo model 'XL330'"),
    ('[arm]\nbilateral_joints = ["elbow"]\n', "no joint named 'elbow'"),
    ("[arm\n", "not valid TOML"),
    ('[arm.joints.joint1]\nservo_id = "2"\n', "servo_id must be an integer, got '2'"),  # was accepted
    ('[arm.joints.joint1]\nlower_deg = "-90"\n', "lower_deg must be a finite number"),  # was a TypeError
])
def test_bad_description_is_one_clear_sentence(tmp_path, text, match):
    p = tmp_path / "arm.toml"
    p.write_text(text)
    with pytest.raises(DescriptionError, match=match) as info:
        ArmDescription.from_toml(p)
    assert isinstance(info.value, CraneError)


def test_missing_description_file(tmp_path):
    with pytest.raises(DescriptionError, match="does not exist"):
        ArmDescription.from_toml(tmp_path / "nope.toml")


def test_torque_constants_must_be_positive():
    arm = default_arm().with_torque_constants({"joint1": 1.783})
    assert arm.joint("joint1").torque_constant == 1.783
    with pytest.raises(DescriptionError, match="must be positive"):
        default_arm().with_torque_constants({"joint1": 0.0})
