"""Test helper: short simulated sessions from a planted-effect plant preset, fast enough for CI.

Why not `crane-collect run --sim`: the full pipeline (two arms, the servo chain's protocol bytes, the
bilateral controller) runs at about 1.4x real time on the 2-core CI machine, i.e. ~45 s of wall time
per minute of session and several minutes for the seven presets the diagnosis tests need. The physics
is what the diagnosis is about, so these sessions drive crane_io.sim.arm_plant.ArmPlant (the same plant
`crane-collect run --sim --plant PRESET` uses) directly, at the control rate (500 Hz), with what a
human operator does to the follower under bilateral control: each driven joint (`joints`, default
joints 1, 2 and 4, the paper's set; any of joint1..joint7, e.g. all seven for the wrist presets)
independently makes smooth minimum-jerk moves between random targets and pauses in between (the
reference moves about 80 % of the time; the dead-zone masks of crane-train, |dq| > 0.1 std, count 50-68 %
of the samples as moving on each joint of a 60-90 s session, seeds 0-2, three or seven joints driven),
tracked by a PD controller with rigid-body feed-forward in current mode; the other joints are servos held
in position mode. Joints stick in the
pauses (the plant's true stick-slip), so the data have the paper's dead zones. What is recorded is what
the recorder stores: the quantised servo position and the commanded torque = goal current x the
configured torque constant (not the plant's true one), in the contract-minimum session format.
"""

from __future__ import annotations

from pathlib import Path

import h5py
import numpy as np

from crane_io.description import default_arm
from crane_io.dynamixel.units import RAD_PER_PULSE
from crane_io.physics.dynamics import ArmDynamics
from crane_io.session_format import TAU_FROM_GOAL, TAU_SOURCE_ATTR
from crane_io.sim.arm_plant import ArmPlant
from crane_io.sim.plant_api import ActuatorCommand
from crane_io.sim.plant_config import ARM_JOINTS, check_joints, load_plant_config
from tests.sessions import write_minimal_session

LEARN = ("joint1", "joint2", "joint4")  # the default driven joints (the paper's set)
ALL = ARM_JOINTS  # joint1..joint7
# rad: the middle of each joint's working range, and targets within CENTER +- SPAN (well inside the limits;
# joint5's range covers the hidden-wrist-spring rest angle 0.5 rad on both sides)
CENTER = {"joint1": 0.0, "joint2": 0.5, "joint3": 0.0, "joint4": -1.3, "joint5": 0.0, "joint6": 0.0,
          "joint7": 0.0}
SPAN = {"joint1": 0.9, "joint2": 0.7, "joint3": 0.8, "joint4": 0.7, "joint5": 1.0, "joint6": 0.9,
        "joint7": 1.0}
# PD gains per joint, N m/rad and N m s/rad. Joints 1, 2, 4: the paper-set values (the three-joint
# sessions depend on them bit for bit). Joint3 carries the elbow and forearm like joint1
# (similar gains, a little softer); the wrist joints (5, 6, 7) move only the hand, about 0.006 kg m^2 of
# rotor inertia plus a few thousandths of link inertia: small gains (by estimate ~25 rad/s bandwidth and
# damping ratio ~0.6; the quantised position's velocity noise times KD stays a few hundredths of a N m).
KP_BY_JOINT = {"joint1": 25.0, "joint2": 45.0, "joint3": 20.0, "joint4": 20.0, "joint5": 6.0,
               "joint6": 6.0, "joint7": 5.0}
KD_BY_JOINT = {"joint1": 1.2, "joint2": 2.5, "joint3": 1.0, "joint4": 0.9, "joint5": 0.25,
               "joint6": 0.25, "joint7": 0.2}
KP = np.array([KP_BY_JOINT[n] for n in LEARN])  # N m/rad, of LEARN (as before)
KD = np.array([KD_BY_JOINT[n] for n in LEARN])  # N m s/rad


def driven_joints(joints=None) -> tuple[str, ...]:
    """The driven joint set in arm order: None -> LEARN, "all" -> joint1..joint7, or a list of names."""
    if joints is None:
        return LEARN
    if isinstance(joints, str):
        joints = ALL if joints == "all" else joints.split(",")
    return check_joints(joints, "simulate_session joints")


def operator_reference(duration_s: float, rate_hz: float, rng,
                       joints=LEARN) -> tuple[np.ndarray, ...]:
    """(q, dq, ddq) references (N, len(joints)): per joint, minimum-jerk moves of 1-2.5 s between random
    targets, separated by pauses of 0.1-0.7 s (independent per joint; drawn joint after joint)."""
    n = int(round(duration_s * rate_hz))
    dt = 1.0 / rate_hz
    nj = len(joints)
    q, dq, ddq = np.zeros((n, nj)), np.zeros((n, nj)), np.zeros((n, nj))
    for j, name in enumerate(joints):
        pos, i = CENTER[name], 0
        q[:, j] = pos
        while i < n:
            pause = int(rng.uniform(0.1, 0.7) * rate_hz)
            q[i:i + pause, j] = pos
            i += pause
            if i >= n:
                break
            T = rng.uniform(1.0, 2.5)
            m = min(int(T * rate_hz), n - i)
            target = CENTER[name] + rng.uniform(-1, 1) * SPAN[name]
            s = np.arange(m) * dt / T
            d = target - pos
            q[i:i + m, j] = pos + d * (10 * s ** 3 - 15 * s ** 4 + 6 * s ** 5)
            dq[i:i + m, j] = d / T * (30 * s ** 2 - 60 * s ** 3 + 30 * s ** 4)
            ddq[i:i + m, j] = d / T ** 2 * (60 * s - 180 * s ** 2 + 120 * s ** 3)
            pos = q[i + m - 1, j] if m < int(T * rate_hz) else target
            i += m
    return q, dq, ddq


def simulate_session(path, preset: str, duration_s: float = 60.0, seed: int = 0,
                     rate_hz: float = 500.0, joints=None) -> Path:
    """Simulate `duration_s` of operator-like motion on the plant `preset` and write a session file (all
    eight servos recorded).

    joints: the driven (current-mode) joints, default LEARN (joint1, joint2, joint4), "all" for the seven
    arm joints, or a list. The plant integrates exactly these (PlantConfig.restricted_to when the preset
    integrates another set): effects of the preset on other joints are not simulated, those joints are
    held servos; joints the preset does not integrate but `joints` names are integrated with none of
    its effects (rigid body and the plant's own servo model only)."""
    joints = driven_joints(joints)
    config = load_plant_config(preset)
    if joints != tuple(config.joints):
        config = config.restricted_to(joints)
    plant = ArmPlant(config, seed=seed)
    arm = default_arm()
    names = arm.joint_names
    bi = np.array([names.index(n) for n in joints])
    nj = len(joints)
    kp = np.array([KP_BY_JOINT[n] for n in joints])
    kd = np.array([KD_BY_JOINT[n] for n in joints])
    n_servo = len(names)
    kt_cfg = np.array([arm.joint(n).torque_constant for n in names])
    limit = np.array([arm.joint(n).current_limit for n in names])
    locked = {k: v for k, v in config.locked.items() if k not in joints}
    nominal = ArmDynamics(joints, locked=locked)
    rng = np.random.default_rng(seed)
    q_ref, dq_ref, ddq_ref = operator_reference(duration_s, rate_hz, rng, joints)
    start = np.zeros(n_servo)
    start[bi] = q_ref[0]
    for name, angle in locked.items():
        start[names.index(name)] = angle
    plant.set_state(q=start, dq=np.zeros(n_servo))
    ff = nominal.inverse_dynamics(q_ref, dq_ref, ddq_ref)  # feed-forward of the reference (no friction)
    n = len(q_ref)
    dt = 1.0 / rate_hz
    t = np.arange(n) * dt
    Q, TAU = np.zeros((n, n_servo)), np.zeros((n, n_servo))
    enabled = np.ones(n_servo, bool)
    mode = np.full(n_servo, 3)
    mode[bi] = 0  # current mode for the learning joints, position mode for the held ones
    goal_position = start.copy()
    gains = np.tile([800, 0, 0], (n_servo, 1))
    goal_current = np.zeros(n_servo)
    q_prev, dq_b_prev = None, np.zeros(nj)
    for i in range(n):
        reading = plant.read()
        q_meas = np.rint(np.asarray(reading.position) / RAD_PER_PULSE) * RAD_PER_PULSE
        q_b = q_meas[bi]
        dq_b = np.zeros(nj) if q_prev is None else (q_b - q_prev) / dt * 0.3 + dq_b_prev * 0.7
        tau_cmd = ff[i] + kp * (q_ref[i] - q_b) + kd * (dq_ref[i] - dq_b)
        goal_current[:] = 0.0
        goal_current[bi] = np.clip(tau_cmd / kt_cfg[bi], -limit[bi], limit[bi])
        Q[i] = q_meas
        TAU[i] = goal_current * kt_cfg
        plant.step(ActuatorCommand(enabled, mode, goal_current.copy(), goal_position, gains, limit), dt)
        q_prev, dq_b_prev = q_b, dq_b
    # every column is the current commanded right after the row's read, as crane-collect records it
    sources = np.array([TAU_FROM_GOAL] * n_servo, dtype=h5py.string_dtype())
    return write_minimal_session(path, t, Q, TAU, names, rate_hz, source="sim", seed=seed,
                                 attrs={TAU_SOURCE_ATTR: sources})
