"""Arm calibration: `crane-collect calibrate` against a simulated arm whose encoders are off finds the
offsets and the ranges, stores them per adapter, and `run` and `check` use them: the recorded angles
shift by exactly the offsets."""

import io
import json
import math
import threading
from types import SimpleNamespace

import h5py
import numpy as np
import pytest
from click.testing import CliRunner

from collect.cli import main as collect_main
from collect.runner import RunOptions, run_session
from collect.sim_lab import OffsetPlant, SimulatedLab, parse_offsets
from crane_io.description import default_arm
from crane_io.dynamixel import calibration as cal_mod
from crane_io.dynamixel.calibration import (
    Calibration,
    CalibrationError,
    JointCalibration,
    adapter_key,
    find_calibration,
    load_calibration,
    save_calibration,
)
from crane_io.dynamixel.units import RAD_PER_PULSE
from crane_io.errors import ConfigError
from crane_io.sim.chain import SimulatedChain
from crane_io.sim.simple_plant import SimplePlant
from crane_io.sim.transport import PtyServer

ARM = default_arm()
NAMES = ARM.joint_names
# whole pulses, so that the quantised readings of an offset arm are exactly the true ones shifted
OFFSETS = np.array([7, -12, 0, 25, -4, 9, 0, 3]) * RAD_PER_PULSE


def test_a_calibration_round_trips_through_its_file(tmp_path):
    joints = {"joint1": JointCalibration(0.0123, -2.5, 2.4), "joint2": JointCalibration(-0.004)}
    cal = Calibration("left arm", "FT6Z5Q1I", joints, created="2026-11-24T08:00:00Z")
    path = save_calibration(cal, tmp_path / "c.toml")
    back = load_calibration(path)
    assert back.name == "left arm" and back.key == "FT6Z5Q1I" and back.created == cal.created
    assert back.joints == cal.joints and back.path == str(path)
    assert back.offsets(["joint2", "joint1", "joint3"]).tolist() == [-0.004, 0.0123, 0.0]


@pytest.mark.parametrize("text, words", [
    ("[arm]\nname = 'x'\n", "names no joint"),
    ("[joints.joint1]\noffset_rad = 0.9\n", "not within ±20 deg"),
    ("[joints.joint1]\nmin_rad = 0.1\n", "needs a number offset_rad"),
    ("not = [toml", "not valid TOML"),
])
def test_a_bad_calibration_file_is_refused_in_one_sentence(tmp_path, text, words):
    path = tmp_path / "bad.toml"
    path.write_text(text)
    with pytest.raises(CalibrationError, match=words):
        load_calibration(path)


def test_the_key_is_the_adapters_usb_serial_or_the_ports_name(tmp_path):
    dev = tmp_path / "ttyUSB3"
    dev.write_text("")
    link = tmp_path / "crane_x7_leader"
    link.symlink_to(dev)
    infos = [SimpleNamespace(device=str(dev), serial_number="FT6Z5Q1I")]
    assert adapter_key(str(link), infos) == "FT6Z5Q1I"  # through the udev-style link, the adapter's serial
    assert adapter_key("/tmp/sim/leader", []) == "port-leader"


def test_encoder_offsets_for_sim_serve_are_parsed_or_refused():
    out = parse_offsets(["leader:joint2=0.05", "follower:joint1=-0.1"], ARM)
    assert out["leader"][NAMES.index("joint2")] == 0.05 and out["follower"][0] == -0.1
    assert parse_offsets(["joint4=0.2"], ARM, arms=("arm",))["arm"][NAMES.index("joint4")] == 0.2
    for bad in ("joint2=0.05", "leader:joint9=0.1", "leader:joint2=abc"):
        with pytest.raises(ConfigError, match="`encoder_offsets`"):
            parse_offsets([bad], ARM)


class _Person(io.RawIOBase):
    """stdin of the calibrate command: Enter at the marks; before the second Enter, moves the arm's
    joints through a range while the command samples it."""

    def __init__(self, plant, sweeps):
        self.plant, self.sweeps, self.presses = plant, sweeps, 0

    def readable(self):
        return True

    def _put(self, s: float) -> None:
        q = self.plant.q.copy()
        for j, (lo, hi) in self.sweeps.items():
            q[j] = lo + (hi - lo) * s
        self.plant.q = q  # one reference swap (the server thread steps the plant meanwhile)

    def readinto(self, buffer):
        if self.presses == 1:  # step 2: the person moves every joint in `sweeps` end to end
            # rests a moment at each end
            for s in np.concatenate([np.zeros(15), np.linspace(0.0, 1.0, 40), np.ones(15)]):
                self._put(s)
                threading.Event().wait(0.02)
        self.presses += 1
        buffer[:1] = b"\n"
        return 1


@pytest.fixture
def offset_arm(tmp_path):
    plant = SimplePlant.from_arm(ARM)  # at rest at the marks (all zero), no sensor noise, no gravity
    # the wall clock: torque off, a person moves the arm and the servos see it (lockstep servos would
    # only look at the plant when a goal current is written)
    chain = SimulatedChain.for_arm(ARM, OffsetPlant(plant, OFFSETS), clock="wall", return_delay_time=0)
    server = PtyServer(chain, tmp_path / "arm").start()
    yield plant, str(tmp_path / "arm")
    server.stop()


def test_calibrate_finds_the_offsets_and_the_ranges_and_check_uses_them(offset_arm):
    plant, port = offset_arm
    # joint1 and joint4, true angles. Both ranges hold the marks (0): the sampler starts at step 2 with
    # the arm still on its marks, and whether it reads once before the person's first move is a race
    # (a clean-clone CI run met it: joint4's max came out 0, not the sweep's end)
    sweeps = {0: (-1.0, 1.2), 3: (-2.0, 0.0)}
    person = io.BufferedReader(_Person(plant, sweeps), buffer_size=1)
    out = CliRunner().invoke(collect_main, ["calibrate", "--port", port, "--arm", "left"], input=person)
    assert out.exit_code == 0, out.output
    assert "Torque is off" in out.output and "calibration written to" in out.output
    cal = find_calibration(port)
    assert cal is not None and cal.key == "port-arm" and cal.name == "left"
    assert np.allclose(cal.offsets(NAMES), OFFSETS, atol=1e-9)
    for j, (lo, hi) in sweeps.items():  # ranges in calibrated (true) angles, to a pulse
        joint = cal.joints[NAMES[j]]
        assert abs(joint.min_rad - lo) < 1.5 * RAD_PER_PULSE and abs(joint.max_rad - hi) < 1.5 * RAD_PER_PULSE
    assert cal.joints["joint2"].min_rad is None  # never moved: no range claimed
    # check names the calibration and shows the calibrated angle beside the servo's
    plant.q = np.zeros(len(NAMES))
    threading.Event().wait(0.1)
    out = CliRunner().invoke(collect_main, ["check", "--port", port])
    assert "calibration 'left' of adapter port-arm" in out.output
    row = next(line for line in out.output.splitlines() if " joint4 " in line)
    assert f"at {math.degrees(OFFSETS[3]):7.1f} deg (calibrated     0.0)" in row


def test_calibrate_refuses_a_joint_far_from_its_mark(offset_arm):
    plant, port = offset_arm
    plant.q = np.where(np.arange(len(NAMES)) == 1, 0.6, 0.0)  # joint2 not on its mark
    threading.Event().wait(0.1)
    out = CliRunner().invoke(collect_main, ["calibrate", "--port", port, "--arm", "a", "--no-range"],
                             input="\n")
    assert out.exit_code != 0 and "joint2 reads" in out.output and "Traceback" not in out.output
    assert find_calibration(port) is None


def _record(tmp_path, name: str, offsets: dict | None, calibrations: dict | None):
    """A 1.5 s session over two lockstep sim links (the crane-x7 plant; the hand on the leader takes hold
    1 s of the arm's time after its torque came on, i.e. well into the recording)."""
    lab = SimulatedLab.build(plant="crane-x7", seed=5, clock="lockstep", encoder_offsets=offsets,
                             hand_delay_s=1.0, return_delay_time=0)
    links = {"leader": tmp_path / f"{name}-L", "follower": tmp_path / f"{name}-F"}
    lab.serve(links)
    try:
        files = {}
        for arm, cal in (calibrations or {}).items():
            files[arm] = save_calibration(cal, tmp_path / f"{name}-{arm}.toml")
        out = io.StringIO()
        run_session(RunOptions(output=tmp_path / f"{name}.h5", leader_port=str(links["leader"]),
                               follower_port=str(links["follower"]), duration=1.5, status=True, stream=out,
                               leader_calibration=files.get("leader"),
                               follower_calibration=files.get("follower"), skip_selftest=True))
    finally:
        lab.stop()
    with h5py.File(tmp_path / f"{name}.h5") as f:
        return {arm: f[f"{arm}/q"][()] for arm in ("leader", "follower")}, dict(f.attrs), out.getvalue()


def _calibration(name, offsets):
    return Calibration(name, f"sim-{name}", {n: JointCalibration(float(o)) for n, o in zip(NAMES, offsets)})


@pytest.mark.slow
def test_run_uses_the_calibration_and_the_session_records_it(tmp_path):
    off = {"leader": OFFSETS, "follower": -0.5 * OFFSETS}
    off["follower"] = np.round(off["follower"] / RAD_PER_PULSE) * RAD_PER_PULSE
    truth, attrs_truth, said_truth = _record(tmp_path, "truth", None, None)
    raw, _, _ = _record(tmp_path, "raw", off, None)
    cal, attrs, said = _record(tmp_path, "cal", off, {a: _calibration(a, o) for a, o in off.items()})
    bil = [NAMES.index(n) for n in ARM.bilateral_joints]
    still = slice(0, 100)  # the first 0.2 s: the arms rest where the alignment left them, no hand yet
    # uncalibrated, the leader (held where it rests by the alignment) reads its true angles plus the
    # offsets (the median over the rows, to a pulse: the sensor's noise, and the hold under gravity ends a
    # pulse apart from run to run, the wall clock pacing both); the follower and the held joints are then
    # aligned to the wrong readings
    shift = np.median(raw["leader"][still][:, bil] - truth["leader"][still][:, bil], axis=0)
    assert np.abs(shift - off["leader"][bil]).max() <= 1.5 * RAD_PER_PULSE
    for arm in ("leader", "follower"):
        # calibrated, the session holds the true angles, as from arms without offsets (to the sensor's
        # noise and the follower's alignment, within a pulse or two of the leader)
        assert np.median(np.abs(cal[arm][still] - truth[arm][still])) < 0.5 * RAD_PER_PULSE
        assert np.abs(cal[arm][still] - truth[arm][still]).max() < 3.5 * RAD_PER_PULSE
    assert "leader: calibration 'leader' of adapter sim-leader" in said
    assert "no calibration" in said_truth
    recorded = json.loads(attrs["leader_calibration"])
    assert recorded["key"] == "sim-leader" and np.isclose(recorded["offsets_rad"]["joint4"], OFFSETS[3])
    assert attrs_truth["leader_calibration"] == ""


def test_a_run_refuses_a_missing_calibration_file_before_torque_on(tmp_path):
    out = CliRunner().invoke(collect_main, ["run", "--sim", "--duration", "1", "-o", str(tmp_path / "s.h5"),
                                            "--leader-calibration", str(tmp_path / "none.toml")])
    assert out.exit_code != 0 and "cannot read the calibration" in out.output
    assert not (tmp_path / "s.h5").exists()


def test_the_calibration_folder_follows_the_environment(tmp_path, monkeypatch):
    monkeypatch.setenv(cal_mod.CONFIG_ENV, str(tmp_path / "cfg"))
    assert cal_mod.config_dir() == tmp_path / "cfg" / "calibration"
