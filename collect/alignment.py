"""The alignment before bilateral control: both arms under independent position control
(DOB-compensated) while the follower is moved slowly (homing speed, minimum-jerk) to the leader's pose
and the held joints to their held pose. On hardware arms that differ by more than
`safety.max_start_difference` are refused; in simulation the leader is first brought to
`operator.start`. Nothing of it is recorded.

    message = align(pair, ctl, safety, config, arm, simulated=True, lockstep=True, say=print)
"""

from __future__ import annotations

import time
from collections.abc import Callable

import numpy as np

from crane_io.description import ArmDescription
from crane_io.errors import HardwareError

from .arm_pair import ARMS, ArmPair
from .config import Config
from .controller import ArmSignals, BilateralController
from .operator import minimum_jerk
from .pacing import CycleTimer
from .safety import SafetyMonitor

SETTLE_S = 0.3  # s of holding the target after the move
READING, WRITING = "reading the arms while aligning", "writing to the arms while aligning"
# A simulated arm that cannot be held still during the alignment is almost always a plant TOML without
# the damping every real joint has: with no viscous friction or rotor inertia on the bilateral joints the
# default gains make the arm oscillate into the velocity guard.
SIM_HINT = ("; with `sim` this usually means the plant lacks damping: give the bilateral joints viscous "
            "friction and rotor inertia (start a plant TOML from base = \"baseline\", or "
            "\"baseline-7dof\" for joints beyond joint1, joint2, joint4)")


class SafetyStop(HardwareError):
    """The run ended in a safety stop (the session file is valid and says why)."""


class StartRefused(HardwareError):
    """The arms could not be brought into agreement safely."""


def checked(results, what: str) -> list:
    """The two values of a read_both / write result of (leader, follower); a failed transfer is a safety
    stop (SafetyStop naming `what` was being done, e.g. "reading the arms while aligning"): the caller's
    clean-up stops both arms, as after any other breach."""
    for name, (_value, exc, _) in zip(ARMS, results):
        if exc is not None:
            reason = str(exc).rstrip(".") or type(exc).__name__
            raise SafetyStop(f"safety stop {what}: the {name} arm failed ({reason})") from exc
    return [value for value, _, _ in results]


def _targets(q_l0, q_f0, config: Config, arm: ArmDescription, simulated: bool, own_pose: bool = False):
    """Where (leader, follower) go: the leader's pose (hardware) or operator.start (simulation) on the
    bilateral joints, the held pose on the others; with `own_pose` each arm stays where it is on the
    bilateral joints. Hardware arms too far apart are refused (not with `own_pose`)."""
    bil = np.array([n in arm.bilateral_joints for n in arm.joint_names])
    held_goal = np.array([config.held.get(n, 0.0) for n in arm.joint_names])
    s = config.safety
    if own_pose:
        return np.where(bil, q_l0, held_goal), np.where(bil, q_f0, held_goal)
    if simulated:
        start = config.operator.start
        target = np.array([start.get(n, 0.0) for n in arm.joint_names])
    else:
        target = q_l0.copy()
        diff = np.abs(q_l0 - q_f0) * bil
        if diff.max() > s.max_start_difference:
            i = int(np.argmax(diff))
            raise StartRefused(
                f"leader and follower {arm.joint_names[i]} differ by {np.degrees(diff[i]):.0f} deg, "
                f"more than the {np.degrees(s.max_start_difference):.0f} deg allowed at start; bring the "
                "arms closer by hand (torque is off) and start again")
    target = np.where(bil, target, held_goal)
    return target, target.copy()


def align(pair: ArmPair, ctl: BilateralController, safety: SafetyMonitor, config: Config,
          arm: ArmDescription, *, simulated: bool, lockstep: bool, say: Callable[[str], None],
          paced: bool | None = None, between_cycles: Callable[[], None] | None = None,
          own_pose: bool = False) -> str:
    """Bring both arms to their start pose; returns the sentence for the session's start event.
    Raises StartRefused, or SafetyStop for a breach or a failed transfer (read or write) while aligning.

    lockstep: the (simulated) arms advance one control period per goal sync write, so a cycle (goal
    current + goal position) is two periods of their time and the controller's dt is exactly that.
    paced: wait for the wall clock between cycles (default: not lockstep). Lockstep arms can be paced
    too (`--sim --realtime`): the cycles then come every two periods of real time.
    between_cycles: called after the writes, outside the timed part of the cycle (e.g. a small
    garbage collection).
    own_pose: each arm keeps its own pose on the bilateral joints (no start difference is refused); only
    the held joints move to their held pose."""
    s = config.safety
    kt = np.array([j.torque_constant for j in arm.joints])
    bil = np.array([n in arm.bilateral_joints for n in arm.joint_names])
    first_l, first_f = checked(pair.read_both(), READING)
    q_l0, q_f0 = first_l.position, first_f.position
    target_l, target_f = _targets(q_l0, q_f0, config, arm, simulated, own_pose)
    dist = max(np.abs(target_l - q_l0).max(), np.abs(target_f - q_f0).max())
    move_s = max(0.5, 1.875 * dist / s.homing_speed) if dist > s.agree_tolerance else 0.0
    say(f"aligning the arms: {np.degrees(dist):.1f} deg at most, {move_s + SETTLE_S:.1f} s")
    period = config.loop.period_s
    # With every servo bilateral (the gripper too) there is no held joint and no goal position to send:
    # an empty sync write is no packet at all.
    held = not bool(bil.all())
    ticks = 2 if lockstep and held else 1  # in lockstep each goal sync write advances the plant
    if paced is None:
        paced = not lockstep
    t = 0.0
    timer = CycleTimer(config.loop.rate_hz / ticks, lockstep=not paced, spin_s=config.loop.spin_s)
    timer.start()
    last = time.perf_counter()
    while t < move_s + SETTLE_S:
        if move_s > 0:
            sj, dsj = minimum_jerk(np.array(min(t / move_s, 1.0)))
            ds = float(dsj) / move_s if t < move_s else 0.0
        else:
            sj, ds = np.array(1.0), 0.0
        ref_l = (q_l0 + (target_l - q_l0) * float(sj), (target_l - q_l0) * ds)
        ref_f = (q_f0 + (target_f - q_f0) * float(sj), (target_f - q_f0) * ds)
        sl, sf = checked(pair.read_both(), READING)
        for name, st in zip(ARMS, (sl, sf)):
            b = safety.check(name, st.position, st.velocity)
            if b is not None:
                raise SafetyStop(f"safety stop while aligning: {b.message}" + (SIM_HINT if simulated else ""))
        now = time.perf_counter()
        dt = ticks * period if lockstep else max(now - last, 1e-4)
        last = now
        cmd = ctl.hold(ArmSignals(sl.position), ArmSignals(sf.position), ref_l, ref_f, dt)
        tau_l = safety.limit_torque(sl.position, cmd.leader_tau, sl.velocity, spring=False)
        tau_f = safety.limit_torque(sf.position, cmd.follower_tau, sf.velocity, spring=False)
        ctl.applied(tau_l, tau_f)
        # Goal current first: it is what the current-mode joints act on, so it leaves right after the
        # read; the held joints' goal positions follow.
        checked(pair.write_currents(tau_l / kt, tau_f / kt), WRITING)
        if held:
            checked(pair.write_positions(ref_l[0], ref_f[0]), WRITING)
        if between_cycles is not None:
            between_cycles()
        timer.wait()
        t += dt
    final_l, final_f = checked(pair.read_both(), READING)
    ql, qf = final_l.position, final_f.position
    if own_pose:
        return f"arms held at their own poses for {t:.1f} s"
    gap = float(np.abs(ql - qf)[bil].max())
    return f"arms aligned in {t:.1f} s; largest leader-follower difference {np.degrees(gap):.2f} deg"
