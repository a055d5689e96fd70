"""Seven joints end to end: `crane-collect excite --sim --joints all` records an exciting trajectory of the
whole arm, and `crane-train identify --joints all` identifies every joint's parameters from it (a short
lockstep session at 100 Hz)."""

from __future__ import annotations

import json

from click.testing import CliRunner

from collect.cli import main as collect_main
from crane_io.physics.arm_model import JOINT_NAMES
from crane_io.sim.plant_config import load_plant_config
from train.cli import main as train_main

ARM = tuple(n for n in JOINT_NAMES if n != "gripper")


def test_excite_and_identify_all_seven_joints(tmp_path):
    session = tmp_path / "ex7.h5"
    r = CliRunner().invoke(collect_main, ["excite", "--sim", "--joints", "all", "--duration", "20",
                                          "--budget", "20", "--rate", "100", "--quiet", "-o", str(session)])
    assert r.exit_code == 0, r.output
    out = tmp_path / "id7"
    r = CliRunner().invoke(train_main, ["identify", str(session), "--joints", "all", "--scale-to-data",
                                        "--json", "-o", str(out)])
    assert r.exit_code in (0, 1), r.output  # 1: a check of the verdict failed; the model is written
    doc = json.loads(r.output)
    assert doc["joints"] == list(ARM) and (out / "model.json").exists()
    truth = {e.joint: e.values["coulomb"] for e in load_plant_config("crane-x7-7dof").effects
             if e.effect == "stiction"}
    coulomb = {p["name"].split("@")[1]: p["estimate"] for p in doc["parameters"]
               if p["name"].startswith("coulomb.")}
    assert sorted(coulomb) == sorted(ARM)
    for joint in ARM:
        assert 0.5 * truth[joint] < coulomb[joint] < 1.5 * truth[joint], (joint, coulomb[joint], truth[joint])
    # the arm model written beside it loads: the simulator and the controller accept it
    from crane_io.physics.identified_model import IdentifiedArm

    arm = IdentifiedArm.from_toml(out / "arm_model.toml")
    assert arm.free == ARM
