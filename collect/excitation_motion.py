"""The reference an excitation run's arm follows, and the cycle's control that makes it follow it.

In session time t (s), for the driven arm's bilateral joints (the trajectory's joints):

1. approach, 0 <= t < T_a: a minimum-jerk move (collect/operator.py `minimum_jerk`, the alignment's
   profile) from the pose at the start of recording to the trajectory's first pose, T_a =
   max(MIN_APPROACH_S, 1.875 d / homing_speed) for the largest joint distance d (peak speed
   `homing_speed`, as the alignment);
2. the trajectory, T_a <= t < T_a + D: q(t - T_a) of crane_io.physics.excitation_trajectory for its
   whole periods at their speeds (`play`), D in all; it starts and ends at rest (dq = ddq = 0), so the
   stop is as slow as the start;
3. rest: the trajectory's first pose (where it ended), held for SETTLE_S.

The other arm is held where it was at the start of recording. Both arms run the controller's
independent position control with the bilateral run's observers (`BilateralController.hold`: DOB
compensation, (J/2) Kp, Kd), the safety clamps (`SafetyMonitor.limit_torque` with the soft-zone spring)
and checks (`SafetyMonitor.check`, leader then follower) of a bilateral cycle.
"""

from __future__ import annotations

import numpy as np

from crane_io.description import ArmDescription
from crane_io.physics.excitation_trajectory import FourierTrajectory

from .controller import ArmSignals
from .controller_layout import guarded
from .operator import minimum_jerk

MIN_APPROACH_S = 1.0
SETTLE_S = 0.5


class ExcitationMotion:
    """`start(q_leader, q_follower)` at the start of recording, then `control(...)` every cycle (the
    loop's `reference` hook, collect/bilateral_loop.py)."""

    def __init__(self, trajectory: FourierTrajectory, arm: ArmDescription, driven: str, homing_speed: float):
        self.trajectory = trajectory
        self.arm = arm
        self.driven = driven
        self.homing_speed = float(homing_speed)
        self.cols = np.array([arm.joint_names.index(n) for n in trajectory.joints])
        self.approach_s = MIN_APPROACH_S
        self.q_start: np.ndarray | None = None  # (n,) the driven arm's pose at the start of recording
        self.hold: np.ndarray | None = None  # (n,) the other arm's
        self._first = np.zeros(len(arm.joint_names))
        self._zero = np.zeros(len(arm.joint_names))
        self._err_sq = np.zeros(len(self.cols))  # the driven arm's tracking error, summed over the cycles
        self._cycles = 0

    @property
    def duration(self) -> float:
        """s of recording: approach, the trajectory's periods, rest."""
        return self.approach_s + self.trajectory.duration + SETTLE_S

    def start(self, q_leader: np.ndarray, q_follower: np.ndarray) -> float:
        """The poses at the start of recording; returns `duration`."""
        q_driven, q_other = (q_follower, q_leader) if self.driven == "follower" else (q_leader, q_follower)
        self.q_start = np.array(q_driven, dtype=float)
        self.hold = np.array(q_other, dtype=float)
        self._first = self.q_start.copy()
        self._first[self.cols] = self.trajectory.start()
        dist = float(np.max(np.abs(self._first - self.q_start)[self.cols]))
        self.approach_s = max(MIN_APPROACH_S, 1.875 * dist / self.homing_speed)
        return self.duration

    def reference(self, t: float) -> tuple[np.ndarray, np.ndarray]:
        """(q, dq) of the driven arm at session time t (n,): the module docstring's three phases."""
        ta = self.approach_s
        if t < ta:
            s, ds = minimum_jerk(np.array(t / ta))
            delta = self._first - self.q_start
            return self.q_start + delta * float(s), delta * (float(ds) / ta)
        tt = t - ta
        if tt >= self.trajectory.duration:
            return self._first, self._zero
        q, dq, _ = self.trajectory.play(tt)
        q_ref, dq_ref = self._first.copy(), self._zero.copy()
        q_ref[self.cols], dq_ref[self.cols] = q, dq
        return q_ref, dq_ref

    def control(self, t: float, sl, sf, dt: float, ctl, safety):
        """A cycle: both arms' position control to their references, the safety clamps, the observers
        told what was applied, the safety checks: (tau_leader, tau_follower, breach or None)."""
        ref = self.reference(t)
        e = ((sf if self.driven == "follower" else sl).position - ref[0])[self.cols]
        self._err_sq += e * e
        self._cycles += 1
        other = (self.hold, self._zero)
        ref_l, ref_f = (other, ref) if self.driven == "follower" else (ref, other)
        leader = ArmSignals(sl.position, sl.velocity, sl.current)
        follower = ArmSignals(sf.position, sf.velocity, sf.current)
        cmd = ctl.hold(leader, follower, ref_l, ref_f, dt)
        return guarded(cmd, leader, follower, safety, ctl.applied)

    def summary_lines(self) -> list[str]:
        """The summary's line on how closely the driven arm followed its reference."""
        if not self._cycles:
            return []
        rms = np.degrees(np.sqrt(self._err_sq / self._cycles))
        return [f"excitation: the {self.driven} followed its reference within "
                + ", ".join(f"{n} {x:.2f}" for n, x in zip(self.trajectory.joints, rms)) + " deg rms"]
