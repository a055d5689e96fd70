"""What `crane-collect selftest` concludes from what it read and measured: one Finding (one sentence)
per check and joint. No I/O here: collect/selftest.py drives the arm and hands the measurements in.

- identity: each servo answers with the model number the description expects; its firmware is named.
- encoder: each joint's calibrated angle at rest lies within the joint's limits (and within the range
  its calibration recorded).
- direction: a joint commanded a few degrees up and back, then down and back, must move that way
  (position and velocity), and the motor current while it moves up must exceed the current while it
  moves down over the same angles (friction opposes the motion, so the motor pushes the way it moves;
  gravity is the same in both and drops out of the difference).
- gravity: the torque each joint holds at rest (present current x the description's torque constant,
  approached from above and from below so that static friction cancels) against the model's gravity
  torque g(q) at the angles the arm reads.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

PASS, FAIL, NOTE = "pass", "fail", "note"
POSITION_TOLERANCE = 0.5  # a move must cover at least this share of its commanded angle, the right way
LIMIT_MARGIN_RAD = math.radians(3.0)  # a joint at rest may read this far beyond its limits
RANGE_MARGIN_RAD = math.radians(5.0)  # ... and this far beyond its calibration's recorded range
CURRENT_DIFFERENCE_A = 0.01  # current up minus down below this: too small to tell the direction
GRAVITY_ABS_NM = 0.3  # held torque may differ from g(q) by this much ...
GRAVITY_REL = 0.3  # ... plus this share of |g(q)|
GRAVITY_SIGN_NM = 0.5  # where |g(q)| exceeds this, the held torque must have its sign
MIN_FIRMWARE = 45  # Drive Mode bit 3 (torque on by goal update) needs v45 (facts section 4)


@dataclass(frozen=True)
class Finding:
    check: str  # identity, encoder, direction, gravity, motion
    joint: str  # the joint (or "arm")
    status: str  # pass, fail or note
    sentence: str

    @property
    def failed(self) -> bool:
        return self.status == FAIL


def _deg(rad: float) -> str:
    return f"{math.degrees(rad):+.1f} deg"


def identity_findings(rows: list[dict]) -> list[Finding]:
    """From crane_io.dynamixel.servo_report rows: answering, model number, firmware."""
    out = []
    for r in rows:
        joint, sid = r["joint"], r["id"]
        if not r.get("answering"):
            out.append(Finding("identity", joint, FAIL,
                               f"ID {sid} does not answer: check its cable, power, ID and baud rate."))
            continue
        if r["model"] != r["expected_model"]:
            out.append(Finding("identity", joint, FAIL,
                               f"ID {sid} is a {r['model']} (model number {r['model_number']}) but the "
                               f"description puts a {r['expected_model']} there: a servo with the wrong ID "
                               "(two IDs swapped?) or the wrong servo fitted."))
            continue
        fw = r["firmware"]
        if fw < MIN_FIRMWARE:
            out.append(Finding("identity", joint, NOTE,
                               f"ID {sid} is a {r['model']} as described, firmware v{fw} is older than "
                               f"v{MIN_FIRMWARE}: update it with Dynamixel Wizard 2.0."))
        else:
            out.append(Finding("identity", joint, PASS, f"ID {sid} is a {r['model']} as described, "
                                                        f"firmware v{fw}."))
    return out


def encoder_findings(arm, q_cal: np.ndarray, calibration=None) -> list[Finding]:
    """Each joint's calibrated angle at rest against its limits and its calibration's recorded range."""
    out = []
    for i, joint in enumerate(arm.joints):
        q = float(q_cal[i])
        lo, hi, what = joint.lower, joint.upper, "limits"
        cal = calibration.joints.get(joint.name) if calibration is not None else None
        if cal is not None and cal.min_rad is not None:
            lo, hi, what = cal.min_rad - RANGE_MARGIN_RAD, cal.max_rad + RANGE_MARGIN_RAD, "calibrated range"
        else:
            lo, hi = lo - LIMIT_MARGIN_RAD, hi + LIMIT_MARGIN_RAD
        if lo <= q <= hi:
            out.append(Finding("encoder", joint.name, PASS, f"reads {_deg(q)}, within its {what}."))
        else:
            out.append(Finding("encoder", joint.name, FAIL,
                               f"reads {_deg(q)}, outside its {what} {_deg(lo)}..{_deg(hi)}: a reversed "
                               "joint, a wrong calibration or an encoder off by a turn; recalibrate or "
                               "check how the servo is mounted."))
    return out


@dataclass
class JointMove:
    """One joint's small move: commanded `step_rad` up and back, then down and back."""

    joint: str
    step_rad: float
    up: float  # rad moved on the way up (rest after - rest before)
    down: float  # rad moved on the way down (negative when right)
    velocity_up: float  # mean rad/s while moving up
    velocity_down: float  # mean rad/s while moving down
    current_up: float  # mean A over the legs moving up (up and the return from below)
    current_down: float  # mean A over the legs moving down


def direction_finding(m: JointMove) -> Finding:
    """Position, velocity and current of one joint's move against the command."""
    step = m.step_rad
    if not (m.up > POSITION_TOLERANCE * step and m.down < -POSITION_TOLERANCE * step):
        return Finding("direction", m.joint, FAIL,
                       f"commanded {_deg(step)} and {_deg(-step)}, it moved {_deg(m.up)} and {_deg(m.down)}: "
                       "it does not follow its goal position (blocked, or motor and encoder disagree).")
    if not (m.velocity_up > 0 > m.velocity_down):
        return Finding("direction", m.joint, FAIL,
                       f"Present Velocity reads {m.velocity_up:+.3f} rad/s moving up and "
                       f"{m.velocity_down:+.3f} rad/s moving down: its velocity has the wrong sign.")
    diff = m.current_up - m.current_down
    if diff < -CURRENT_DIFFERENCE_A:
        return Finding("direction", m.joint, FAIL,
                       f"the current moving up is {diff:+.3f} A below the current moving down: the current "
                       "reads the wrong sign (a current sensor or motor reversed against the encoder).")
    if diff <= CURRENT_DIFFERENCE_A:
        return Finding("direction", m.joint, NOTE,
                       f"moves {_deg(m.up)} and {_deg(m.down)} as commanded; its current up and down "
                       f"differ by only {diff:+.3f} A, too little to tell the current's sign here.")
    return Finding("direction", m.joint, PASS,
                   f"moves {_deg(m.up)} and {_deg(m.down)} as commanded, velocity and current "
                   f"({diff:+.3f} A up minus down) the same way.")


def _gravity_cause(ratio: float) -> str:
    if ratio < -0.5:
        return ("the current has the wrong sign (a reversed joint or current sensor) or the arm is not "
                "where it reads")
    if 1.6 <= ratio <= 2.6 or 0.3 <= ratio <= 0.65:
        return (f"the torque constant or the current sensor's scale is off by about x{ratio:.1f} (check the "
                "servo model and the description's torque_constant)")
    return ("the arm is not in the pose it reads (two IDs swapped, a joint reversed) or carries a load the "
            "model does not have")


def gravity_findings(arm, poses_q: np.ndarray, held_a: np.ndarray, gravity_nm: np.ndarray) -> list[Finding]:
    """poses_q (P, n) calibrated angles read at rest, held_a (P, n) A held there, gravity_nm (P, m) the
    model's g(q) for the first m joints (the arm joints; the gripper has none)."""
    out = []
    n_poses, m = gravity_nm.shape
    for i in range(m):
        joint = arm.joints[i]
        tau = held_a[:, i] * joint.torque_constant
        g = gravity_nm[:, i]
        bad = None
        for p in range(n_poses):
            wrong_sign = abs(g[p]) > GRAVITY_SIGN_NM and np.sign(tau[p]) != np.sign(g[p])
            too_far = abs(tau[p] - g[p]) > GRAVITY_ABS_NM + GRAVITY_REL * abs(g[p])
            if (wrong_sign or too_far) and (bad is None or abs(tau[p] - g[p]) > abs(tau[bad] - g[bad])):
                bad = p
        if bad is None:
            worst = int(np.argmax(np.abs(tau - g)))
            out.append(Finding("gravity", joint.name, PASS,
                               f"holds what the model expects at {n_poses} poses (largest difference "
                               f"{abs(tau[worst] - g[worst]):.2f} N m, at {g[worst]:+.2f} N m)."))
            continue
        ratio = tau[bad] / g[bad] if abs(g[bad]) > GRAVITY_SIGN_NM else float("nan")
        out.append(Finding("gravity", joint.name, FAIL,
                           f"at pose {bad + 1} it holds {tau[bad]:+.2f} N m ({held_a[bad, i]:+.3f} A x "
                           f"{joint.torque_constant:.2f} N m/A) where the model expects {g[bad]:+.2f} N m: "
                           f"{_gravity_cause(ratio)}."))
    return out


def passed(findings: list[Finding]) -> bool:
    return bool(findings) and not any(f.failed for f in findings)


def table(findings: list[Finding]) -> str:
    """The findings as a plain-text table, one line each."""
    lines = [f"{'check':<10} {'joint':<8} {'result':<6} finding"]
    lines += [f"{f.check:<10} {f.joint:<8} {f.status.upper():<6} {f.sentence}" for f in findings]
    return "\n".join(lines)
