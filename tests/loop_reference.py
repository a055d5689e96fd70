"""Reference paths the fast paths are compared with in several test files.

- `control_reference`: what `BilateralController.control` stands for, written out as the bilateral loop
  did it before: step, both torque clamps, applied, both checks.
- `count_advances`: wraps an operator's schedule-advancing method to count its calls and the calls that
  changed nothing (the cached schedule must only advance when something happens).
"""

from __future__ import annotations


def control_reference(ctl, safety, leader, follower, dt):
    """(commands, clamped leader torque, clamped follower torque, first breach or None)."""
    cmd = ctl.step(leader, follower, dt)
    tau_l = safety.limit_torque(leader.q, cmd.leader_tau, leader.dq_servo)
    tau_f = safety.limit_torque(follower.q, cmd.follower_tau, follower.dq_servo)
    ctl.applied(tau_l, tau_f)
    breach = safety.check("leader", leader.q, leader.dq_servo)
    if breach is None:
        breach = safety.check("follower", follower.q, follower.dq_servo)
    return cmd, tau_l, tau_f, breach


def count_advances(op, method: str, state):
    """Replace `op.<method>(t)` by a counting wrapper; returns (calls, idle): the times of every call and
    of those after which `state(op)` was unchanged."""
    calls, idle = [], []
    advance = getattr(op, method)

    def counted(t):
        before = state(op)
        advance(t)
        calls.append(t)
        if state(op) == before:
            idle.append(t)

    setattr(op, method, counted)
    return calls, idle
