"""`crane-collect selftest`: a first contact with one arm that checks its wiring and conventions before
any bilateral run puts torque on it in current mode (where a wrong sign turns force feedback into
positive feedback).

    result = run_selftest(port, arm, calibration=cal)     # a SelftestResult: findings, passed
    result = run_selftest(sim.url, arm, period_s=0.005, paced=False)   # a simulated arm in lockstep

The arm is driven in position mode only, slowly, with low Current Limits and Velocity Limit / Profile
Velocity (torque is off while they are written), and its torque goes off at the end whatever happened:
  1. identity: every servo's ID, model number and firmware (registers only, torque off);
  2. encoder: every joint's calibrated angle at rest (torque off) within its limits or calibrated range;
  3. the arm goes to the test poses; at each it is nudged up and down so that static friction cancels,
     and the current it holds there is compared with the model's gravity torque (sign and size);
  4. at the first pose each joint is moved a few degrees up and back, then down and back: position,
     velocity and current must go the way of the command.
Identity or encoder failures end the test before torque goes on. A joint that falls more than
RUNAWAY_RAD behind its goal, a hardware error or a link that stops answering ends it at once (torque off)
with a failing finding. The conclusions are collect/selftest_checks.py's; the record,
collect/selftest_record.py's.
"""

from __future__ import annotations

import math
import time
from dataclasses import dataclass, field, replace

import numpy as np

from crane_io.errors import CraneError, HardwareError

from .selftest_checks import (
    FAIL,
    Finding,
    JointMove,
    direction_finding,
    encoder_findings,
    gravity_findings,
    identity_findings,
    passed,
)

DEG = math.pi / 180.0
# Test poses, calibrated degrees in the arm's joint order (joint1..joint7, gripper): the shoulder and the
# elbow loaded both ways, the rolls turned so that a reversed or swapped joint changes where the arm hangs.
POSES_DEG = (
    (0.0, 30.0, 0.0, -60.0, 0.0, 30.0, 0.0, 10.0),
    (0.0, -25.0, 40.0, -90.0, 30.0, -45.0, 20.0, 10.0),
    (0.0, 45.0, -35.0, -40.0, -40.0, 60.0, -20.0, 10.0),
)
SPEED_RADS = 20 * DEG  # how fast the goal moves between poses
NUDGE_RAD, NUDGE_SPEED = 2 * DEG, 20 * DEG  # the nudge at each pose
STEP_RAD, STEP_SPEED = 4 * DEG, 12 * DEG  # each joint's own move at the first pose
SETTLE_S, HOLD_S, REST_S = 0.6, 0.25, 0.2  # after a pose; averaging a hold; a rest between move legs
VELOCITY_LIMIT_RADS = 40 * DEG  # Velocity Limit and Profile Velocity of every servo during the test
RUNAWAY_RAD = 15 * DEG  # a joint this far from its goal ends the test
WATCHDOG_S = 0.5  # the servos' Bus Watchdog: a host that stops sending goals leaves no torque on
CURRENT_MARGIN_A = 0.4  # Current Limit: twice the largest gravity current of the poses plus this


class SelftestAborted(CraneError):
    """The arm did something the test does not go on from (a joint ran away, a hardware error)."""


@dataclass
class SelftestResult:
    findings: list[Finding]
    duration_s: float  # the arm's seconds under torque (simulated time on a lockstep simulator)
    poses_rad: list = field(default_factory=list)

    @property
    def passed(self) -> bool:
        return passed(self.findings)


def selftest_arm(arm):
    """The arm as the self-test drives it: every joint in position mode."""
    return replace(arm, bilateral_joints=())


def gravity_model(arm):
    """g(q) of the arm's joints joint1..joint7 (crane_io.physics.dynamics): a function of (n,) angles."""
    from crane_io.physics.dynamics import ArmDynamics

    names = [n for n in arm.joint_names if n != "gripper"]
    dyn = ArmDynamics(joints=tuple(names))
    return len(names), lambda q: dyn.gravity_torque(np.asarray(q[:len(names)], dtype=float))


def current_limits(arm, gravity) -> np.ndarray:
    """Per joint (A): twice the largest gravity current over the test poses plus a margin, at most the
    servo's own limit."""
    m, g = gravity
    worst = np.zeros(len(arm.joints))
    for pose in POSES_DEG:
        worst[:m] = np.maximum(worst[:m], np.abs(g(np.array(pose) * DEG)))
    kt = np.array([j.torque_constant for j in arm.joints])
    top = np.array([j.current_limit for j in arm.joints])
    return np.minimum(2 * worst / kt + CURRENT_MARGIN_A, top)


class _Driver:
    """Goal positions (calibrated) to a bus in position mode, one per period, and what came back."""

    def __init__(self, bus, offsets: np.ndarray, period_s: float, paced: bool):
        self.bus, self.offsets, self.period_s, self.paced = bus, offsets, period_s, paced
        self.goal = self.read().position
        self.cycles = 0
        self._next = time.monotonic()

    def read(self):
        s = self.bus.read_state()
        return replace(s, position=s.position - self.offsets)

    def cycle(self, goal: np.ndarray):
        """Send `goal` (clamped to the joints' limits), wait a period, read the arm; a runaway aborts."""
        sent = self.bus.write_goal_position(np.asarray(goal) + self.offsets) - self.offsets
        self.goal = sent
        self.cycles += 1
        if self.paced:
            self._next += self.period_s
            delay = self._next - time.monotonic()
            if delay > 0:
                time.sleep(delay)
            else:
                self._next = time.monotonic()
        s = self.read()
        off = np.abs(s.position - sent)
        if off.max() > RUNAWAY_RAD:
            k = int(np.argmax(off))
            name = self.bus.arm.joints[k].name
            raise SelftestAborted(f"{name} ended {math.degrees(off[k]):.0f} deg away from its goal (it runs "
                                  "away or is blocked); torque went off")
        return s

    def ramp(self, target: np.ndarray, speed: float) -> list:
        """The goal moved in a straight line to `target` at `speed` rad/s (the joint furthest away)."""
        start = self.goal.copy()
        steps = max(1, math.ceil(np.max(np.abs(target - start)) / (speed * self.period_s)))
        return [self.cycle(start + (target - start) * (k / steps)) for k in range(1, steps + 1)]

    def hold(self, seconds: float) -> list:
        return [self.cycle(self.goal) for _ in range(max(1, round(seconds / self.period_s)))]


def _mean(states: list, what: str) -> np.ndarray:
    return np.mean([getattr(s, what) for s in states], axis=0)


def _held(d: _Driver, pose: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(angles, held current) at `pose`: the mean of resting there after a nudge up and a nudge down."""
    rests = []
    for sign in (1.0, -1.0):
        d.ramp(pose + sign * NUDGE_RAD, NUDGE_SPEED)
        d.ramp(pose, NUDGE_SPEED)
        d.hold(SETTLE_S)
        rests += d.hold(HOLD_S)
    return _mean(rests, "position"), _mean(rests, "current")


def _joint_move(d: _Driver, i: int, name: str, lower: float, upper: float) -> JointMove:
    """Joint i moved STEP_RAD up and back, then down and back (the others held)."""
    base = d.goal.copy()
    step = min(STEP_RAD, upper - base[i], base[i] - lower)
    legs, rests = [], [_mean(d.hold(REST_S), "position")[i]]
    for target in (step, 0.0, -step, 0.0):
        goal = base.copy()
        goal[i] += target
        legs.append(d.ramp(goal, STEP_SPEED))
        rests.append(_mean(d.hold(REST_S), "position")[i])
    cur = [_mean(leg, "current")[i] for leg in legs]
    vel = [_mean(leg, "velocity")[i] for leg in legs]
    return JointMove(name, step, up=rests[1] - rests[0], down=rests[3] - rests[2],
                     velocity_up=vel[0], velocity_down=vel[2],
                     current_up=(cur[0] + cur[3]) / 2, current_down=(cur[1] + cur[2]) / 2)


def _motion(d: _Driver, arm, gravity, findings: list) -> list:
    """Steps 3 and 4 (see the module docstring); the findings appended; the poses' angles returned."""
    m, g = gravity
    n_poses = len(POSES_DEG)
    q = np.zeros((n_poses, len(arm.joints)))
    held = np.zeros_like(q)
    for p, pose in enumerate(POSES_DEG):
        target = np.array(pose) * DEG
        d.ramp(target, SPEED_RADS)
        d.hold(SETTLE_S)
        q[p], held[p] = _held(d, target)
        if p == 0:
            for i, joint in enumerate(arm.joints):
                findings.append(direction_finding(_joint_move(d, i, joint.name, joint.lower, joint.upper)))
    gnm = np.array([g(q[p]) for p in range(n_poses)])
    findings += gravity_findings(arm, q, held, gnm)
    return q.tolist()


def run_selftest(port: str, arm, calibration=None, *, period_s: float = 0.01, paced: bool = True,
                 name: str = "arm") -> SelftestResult:
    """The self-test of the arm on `port` (see the module docstring). `period_s`: one goal per period,
    waited for on the wall clock when `paced` (hardware, a served link), not when the arm is a lockstep
    simulator whose time is the goals sent. Bus errors before torque on propagate (one sentence)."""
    from crane_io.dynamixel.bus import DynamixelBus

    arm = selftest_arm(arm)
    offsets = calibration.offsets(arm.joint_names) if calibration is not None else np.zeros(len(arm.joints))
    with DynamixelBus(port, arm, name=name) as bus:
        report = bus.servo_report()
        findings = identity_findings(report)
        if any(f.failed for f in findings):
            return SelftestResult(findings, 0.0)
        findings += encoder_findings(arm, bus.read_state(check_faults=False).position - offsets, calibration)
        if any(f.failed for f in findings):
            return SelftestResult(findings, 0.0)
        gravity = gravity_model(arm)
        kept_limits = np.array([r["current_limit_a"] for r in report])
        bus.configure(watchdog_s=WATCHDOG_S, current_limits=current_limits(arm, gravity))
        kept_velocities = bus.limit_motion(VELOCITY_LIMIT_RADS, VELOCITY_LIMIT_RADS)
        poses, t0, d = [], time.monotonic(), None
        try:
            bus.torque_on()
            d = _Driver(bus, offsets, period_s, paced)
            poses = _motion(d, arm, gravity, findings)
        except (SelftestAborted, HardwareError) as exc:  # a runaway, a servo fault, a link that fails
            findings.append(Finding("motion", "arm", FAIL, f"{str(exc).rstrip('.')}."))
        finally:
            bus.safe_stop()
            try:  # the servos' own limits back (Current Limit and Velocity Limit survive a power cycle)
                bus.configure(watchdog_s=None, current_limits=kept_limits)
                bus.limit_motion(*kept_velocities)
            except HardwareError as exc:
                why = str(exc).rstrip(".")
                findings.append(Finding("motion", "arm", FAIL, "the servos' Current Limit and Velocity Limit "
                                        f"could not be restored ({why}); run the test again"))
    # paced: the wall clock's seconds (a busy host stretches the plan); else the simulated arm's time
    cycles = d.cycles if d is not None else 0
    return SelftestResult(findings, time.monotonic() - t0 if paced else cycles * period_s, poses)
