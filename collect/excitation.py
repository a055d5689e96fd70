"""`crane-collect excite`: one arm runs an exciting trajectory on its own, recorded as a session.

    result = run_excitation(RunOptions(output="excite.h5", sim=True, duration=20),
                            ExcitationOptions(arm="follower", evaluations=400))

It is a collection run (collect/runner.py `BilateralRun`: the same start-up, ports, observers, safety,
recorder and endings) whose recording drives the arm along a trajectory instead of the bilateral law:

1. the trajectory is designed (crane_io/physics/excitation_design.py: the regressor's condition number
   minimised within the limits below, clear of the table and the arm's links) or read from a file and
   checked against the same limits; it is saved (JSON) and its condition number said, all before any
   torque is on;
2. the alignment holds each arm at its own pose (the held joints go to [held]; in simulation both arms
   first go to operator.start, as in a bilateral run);
3. recording: collect/excitation_motion.py (approach, whole periods of the trajectory, rest), the other
   arm held still. The session carries the excitation attributes of crane_io/session_format.py
   (`EXCITATION_ROOT`) and `hand_on` names the arm that was not driven (no hand moved the driven one).

The speed schedule: a run long enough for SPEED_CYCLE's periods at about NOMINAL_PERIOD_S each at full
speed (113 s) plays the designed period at the speed scales SPEED_CYCLE in turn (a whole number of
cycles; the period is the duration over the cycles' total in full-speed periods); a shorter run plays
whole periods of about NOMINAL_PERIOD_S at full speed (crane_io/physics/excitation_trajectory.py, `play`).

The limits of the trajectory, for the run's bilateral joints: the software joint limits shrunk by
`safety.limit_margin` plus LIMIT_CLEARANCE (out of the soft zone, with room for the tracking error);
speed VELOCITY_FRACTION of the safety guard ([safety.velocity_limit]) and at most the URDF limit;
acceleration MAX_ACCELERATION (the MoveIt limit of shared/crane_x7_facts.md section 1). The joints not
bilateral stay at [held] in the dynamics and the clearance model.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from crane_io import session_format as sf
from crane_io.errors import ConfigError
from crane_io.physics.excitation_trajectory import FourierTrajectory

from .alignment import checked
from .arm_pair import ARMS
from .excitation_motion import ExcitationMotion
from .run_options import RunOptions, RunResult
from .runner import BilateralRun

LIMIT_CLEARANCE = math.radians(10.0)  # rad inside the soft zone's edge
VELOCITY_FRACTION = 0.5  # of each joint's safety guard
MAX_ACCELERATION = 4.4  # rad/s^2 (facts section 1: ROS 2 joint_limits.yaml, every joint)
DEFAULT_DURATION_S = 20.0  # s of trajectory when none is given
NOMINAL_PERIOD_S = 10.0  # s: a designed trajectory's period is the duration over round(duration / this)
HARMONICS = 5
SPEED_CYCLE = (1.0, 0.7, 0.5, 0.35, 0.25)  # speed scales of the periods of a long run, in turn


@dataclass
class ExcitationOptions:
    arm: str = "follower"  # the arm that runs the trajectory
    trajectory: str | Path | None = None  # a saved trajectory to replay (None: design one)
    save: str | Path | None = None  # where the trajectory's JSON goes (None: next to the session)
    evaluations: int = 1000  # the optimiser's budget in cost evaluations
    seconds: float | None = None  # ... and in seconds (None: no time limit)
    normalised: bool = False  # optimise the unit-column-norm condition number (excitation_design.optimise)
    speeds: tuple[float, ...] = SPEED_CYCLE  # a long run's speed cycle ((1.0,): every period at full speed)
    say: object = None  # where the design's progress lines go (None: the run's status stream)


def trajectory_path(opts: RunOptions, ex: ExcitationOptions) -> Path:
    """Where the trajectory is saved: `save`, or the session file's name with .trajectory.json."""
    if ex.save is not None:
        return Path(ex.save)
    out = Path(opts.output)
    return out.with_name(out.stem + ".trajectory.json")


def speed_schedule(duration: float, cycle: tuple[float, ...] = SPEED_CYCLE
                   ) -> tuple[float, tuple[float, ...], int]:
    """(period s, speed cycle, periods) of a designed trajectory played for `duration` s (the module
    docstring's schedule, with the speed cycle `cycle`)."""
    if not cycle or any(not 0.0 < s <= 1.0 for s in cycle):
        raise ConfigError("every speed of the speed cycle must lie above 0 and at most 1")
    slow = float(sum(1.0 / s for s in cycle))  # a cycle's length in full-speed periods
    if len(cycle) > 1 and duration >= NOMINAL_PERIOD_S * slow:
        cycles = max(1, round(duration / (NOMINAL_PERIOD_S * slow)))
        return duration / (cycles * slow), tuple(float(s) for s in cycle), cycles * len(cycle)
    periods = max(1, round(duration / NOMINAL_PERIOD_S))
    return duration / periods, (1.0,), periods


def design_space(config, arm, joints, duration: float, cycle: tuple[float, ...] = SPEED_CYCLE):
    """The DesignSpace of the module docstring for `joints` and a trajectory played for `duration` s (speed
    cycle `cycle`), and the number of periods played."""
    from crane_io.physics.excitation_design import DesignSpace

    s = config.safety
    margin = s.limit_margin + LIMIT_CLEARANCE
    lower = np.array([arm.joint(n).lower for n in joints]) + margin
    upper = np.array([arm.joint(n).upper for n in joints]) - margin
    vmax = np.array([min(VELOCITY_FRACTION * s.velocity_limit[n], arm.joint(n).velocity_limit)
                     for n in joints])
    period, _, periods = speed_schedule(duration, cycle)
    return DesignSpace(tuple(joints), lower, upper, vmax, np.full(len(joints), MAX_ACCELERATION),
                       period=period, harmonics=HARMONICS), periods


def models(config, joints):
    """(ArmDynamics, ArmClearance) over `joints`, the other arm joints at [held]."""
    from crane_io.physics.arm_clearance import ArmClearance
    from crane_io.physics.arm_model import JOINT_NAMES
    from crane_io.physics.dynamics import ArmDynamics

    locked = {n: config.held.get(n, 0.0) for n in JOINT_NAMES if n not in joints and n != "gripper"}
    return ArmDynamics(joints, locked=locked), ArmClearance(joints, locked=locked)


def check_trajectory(traj: FourierTrajectory, space, clearance, where: str) -> None:
    """A replayed trajectory within the run's limits and clear of the table and the links (sampled
    finely), or ConfigError naming what it breaks."""
    from crane_io.physics.excitation_design import GRID

    if tuple(traj.joints) != tuple(space.joints):
        raise ConfigError(f"{where} moves {', '.join(traj.joints)} but this run's joints are "
                          f"{', '.join(space.joints)} (`joints`)")
    if not traj.at_rest(1e-6):
        raise ConfigError(f"{where} does not start at rest (dq and ddq must be 0 at t = 0)")
    t = np.linspace(0.0, traj.period, 4 * GRID, endpoint=False)
    q, dq, ddq = traj.evaluate(t)
    checks = ((q < space.lower) | (q > space.upper), np.abs(dq) > space.vmax, np.abs(ddq) > space.amax)
    for bad, what in zip(checks, ("joint limits", "speed limits", "acceleration limits")):
        if bad.any():
            j = space.joints[int(np.flatnonzero(bad.any(axis=0))[0])]
            raise ConfigError(f"{where} leaves this run's {what} on {j}")
    if float(np.min(clearance.clearance(q[::4]))) < 0.0:
        raise ConfigError(f"{where} comes closer to the table or the arm's own links than allowed")


class ExcitationRun(BilateralRun):
    """A BilateralRun whose recording runs an exciting trajectory (the module docstring)."""

    def __init__(self, options: RunOptions, excitation: ExcitationOptions):
        if excitation.arm not in ARMS:
            raise ConfigError(f"the excited arm is the leader or the follower, not {excitation.arm!r}")
        other = ARMS[1 - ARMS.index(excitation.arm)]
        options.hand_on = other  # no hand moved the driven arm; train reads it as hand-free data
        super().__init__(options)
        self.excitation = excitation
        self.trajectory: FourierTrajectory | None = None
        self.motion: ExcitationMotion | None = None
        self.saved = trajectory_path(options, excitation)
        from crane_io.output_files import check_output

        inputs = [p for p in (options.output, excitation.trajectory, options.config) if p is not None]
        check_output(self.saved, inputs=inputs, force=options.force, what="trajectory file")

    def _say(self, line: str) -> None:
        say = self.excitation.say
        if say is not None:
            say(line)
        elif self.options.status and self.out is not None:
            print(line, file=self.out, flush=True)

    def plan(self) -> FourierTrajectory:
        """Design (or read and check) the trajectory, save it, say its condition number."""
        from crane_io.physics import excitation_trajectory as et
        from crane_io.physics.excitation_design import optimise

        ex, joints = self.excitation, tuple(self.arm.bilateral_joints)
        given = et.load(ex.trajectory) if ex.trajectory is not None else None
        duration = self.options.duration
        if duration is None:
            duration = given.duration if given is not None else DEFAULT_DURATION_S
        space, periods = design_space(self.config, self.arm, joints,
                                      given.period if given is not None else duration, ex.speeds)
        dynamics, clearance = models(self.config, joints)
        if given is not None:
            check_trajectory(given, space, clearance, f"trajectory file {ex.trajectory}")
            q, dq, ddq = given.evaluate(np.linspace(0.0, given.period, 60, endpoint=False))
            traj = given.with_condition(et.regressor_condition(dynamics, q, dq, ddq))
            traj = traj.with_periods(traj.periods_within(duration))
        else:
            speeds = speed_schedule(duration, ex.speeds)[1]
            self._say(f"designing an exciting trajectory for {', '.join(joints)}: {periods} periods of "
                      f"{space.period:.1f} s at full speed"
                      + (f" played at speeds {', '.join(f'{s:g}' for s in speeds)} in turn"
                         if len(speeds) > 1 else "")
                      + f", {HARMONICS} harmonics, budget {ex.evaluations} evaluations"
                      + (f" or {ex.seconds:g} s" if ex.seconds is not None else ""))
            result = optimise(space, dynamics, clearance, seed=self.options.seed, evaluations=ex.evaluations,
                              seconds=ex.seconds, progress=self._say, normalised=ex.normalised)
            traj = result.trajectory.with_periods(periods, speeds)
            self._say(f"condition number {result.initial_condition:.1f} at the start, "
                      f"{traj.condition_number:.1f} optimised ({result.evaluations} evaluations, "
                      f"{result.seconds:.0f} s; clearance {100 * result.clearance:.1f} cm)")
        et.save(traj, self.saved)
        self._say(f"trajectory ({traj.duration:g} s, condition number {traj.condition_number:.1f}) saved "
                  f"to {self.saved}")
        self.trajectory = traj
        return traj

    def start(self) -> None:
        if self.trajectory is None:
            self.plan()
            self.stop.check()
        super().start()

    def align(self) -> None:
        self.align_message = self.loop.align(own_pose=not self.options.sim)

    def start_motion(self) -> float:
        loop = self.loop
        states = checked(loop.pair.read_both(), "reading the arms before recording")
        self.motion = ExcitationMotion(self.trajectory, self.arm, self.excitation.arm,
                                       self.config.safety.homing_speed)
        duration = self.motion.start(states[0].position, states[1].position)
        loop.reference = self.motion
        return duration

    def session_attrs(self) -> dict:
        return {sf.EXCITATION_ATTR: True, sf.EXCITATION_ARM_ATTR: self.excitation.arm,
                sf.EXCITATION_TRAJECTORY_ATTR: self.trajectory.to_json(),
                sf.EXCITATION_START_ATTR: float(self.motion.approach_s)}


def run_excitation(opts: RunOptions, excitation: ExcitationOptions | None = None) -> RunResult:
    """Run one excitation session (the module docstring); errors as collect.runner.run_session."""
    from .runner import run_with

    return run_with(ExcitationRun(opts, excitation or ExcitationOptions()))
