"""Shared test helper: write small synthetic crane-session files with known dynamics.

`write_synthetic_session(path, duration_s)` writes the contract minimum of the session format (README)
(plus `complete`) for an 8-column arm (joint1..joint7, gripper). Joints 1, 2 and 4 move in strokes
separated by stick phases (each joint independently, about `stick_fraction` of the time still); the
other columns are held. The torque of the moving joints is the arm's inverse dynamics
(crane_io.physics.dynamics when available, else a small analytic stand-in) plus Coulomb and viscous
friction; while a joint sticks its torque wanders inside the static-friction band (the dead zone the
paper masks).
"""

from __future__ import annotations

from pathlib import Path

import h5py
import numpy as np

ALL_JOINTS = ("joint1", "joint2", "joint3", "joint4", "joint5", "joint6", "joint7", "gripper")
LEARN = ("joint1", "joint2", "joint4")


def write_minimal_session(path, t, q, tau, joint_names, rate_hz, *, source="sim", seed=0, attrs=None) -> Path:
    """A session file with only the contract's required part (README, "The session file"), as another
    rig might export it, plus `complete`, `seed` and any extra root attributes."""
    path = Path(path)
    with h5py.File(path, "w") as f:
        f.attrs["format"] = "crane-session"
        f.attrs["format_version"] = 1
        f.attrs["rate_hz"] = float(rate_hz)
        f.attrs["joint_names"] = np.array(list(joint_names), dtype=h5py.string_dtype())
        f.attrs["source"] = source
        f.attrs["complete"] = True
        f.attrs["seed"] = int(seed)
        for k, v in (attrs or {}).items():
            f.attrs[k] = v
        g = f.create_group("follower")
        g.create_dataset("t", data=t)
        g.create_dataset("q", data=q)
        g.create_dataset("tau", data=tau)
    return path


def analytic_dynamics(q, dq, ddq):
    """A small stand-in 3-joint arm: inertia, gravity on joints 2 and 4, no coupling beyond that."""
    tau = np.empty_like(q)
    tau[:, 0] = 0.02 * ddq[:, 0]
    tau[:, 1] = 0.05 * ddq[:, 1] + 1.2 * np.sin(q[:, 1]) + 0.3 * np.sin(q[:, 1] + q[:, 2])
    tau[:, 2] = 0.01 * ddq[:, 2] + 0.3 * np.sin(q[:, 1] + q[:, 2])
    return tau


def default_dynamics():
    try:
        from crane_io.physics.dynamics import ArmDynamics
    except ImportError:
        return analytic_dynamics
    arm = ArmDynamics(joints=LEARN)
    return arm.inverse_dynamics


def stroke_trajectory(duration_s, rate_hz, rng, stick_fraction=0.3, amplitude=0.8, center=0.0,
                      stroke_s=(0.4, 1.6)):
    """(q, dq, ddq) of one joint: smooth velocity bumps between stick phases, q kept near `center`."""
    n = int(round(duration_s * rate_hz))
    dt = 1.0 / rate_hz
    dq = np.zeros(n)
    ddq = np.zeros(n)
    i, q_est = 0, center
    while i < n:
        length = int(rng.uniform(*stroke_s) * rate_hz)
        length = max(min(length, n - i), 1)
        if rng.random() >= stick_fraction:
            peak = rng.uniform(0.5, 1.5) * amplitude * 2.0 / (length * dt)
            sign = -np.sign(q_est - center) if abs(q_est - center) > 0.3 * amplitude else rng.choice([-1, 1])
            phase = np.linspace(0.0, np.pi, length, endpoint=False)
            dq[i:i + length] = sign * peak * np.sin(phase) ** 2
            ddq[i:i + length] = sign * peak * np.sin(2 * phase) * np.pi / (length * dt)
            q_est += dq[i:i + length].sum() * dt
        i += length
    q = center + np.cumsum(dq) * dt
    return q, dq, ddq


def write_synthetic_session(path, duration_s, rate_hz=500, seed=0, dynamics=None, stick_fraction=0.3,
                            coulomb=(0.15, 0.25, 0.12), viscous=(0.05, 0.08, 0.04), noise=0.005,
                            joint_names=ALL_JOINTS, source="sim", attrs=None, truth=False):
    """Write a session file; returns (path, truth dict of the noiseless learning-joint signals)."""
    rng = np.random.default_rng(seed)
    dynamics = dynamics or default_dynamics()
    n = int(round(duration_s * rate_hz))
    t = np.arange(n) / rate_hz
    centers = {"joint1": 0.0, "joint2": 0.6, "joint4": -1.2}
    q_l, dq_l, ddq_l = (np.zeros((n, 3)) for _ in range(3))
    for j, name in enumerate(LEARN):
        q_l[:, j], dq_l[:, j], ddq_l[:, j] = stroke_trajectory(duration_s, rate_hz, rng, stick_fraction,
                                                               center=centers[name])
    tau_l = np.asarray(dynamics(q_l, dq_l, ddq_l), dtype=float)
    moving = np.abs(dq_l) > 1e-9
    fc, fv = np.asarray(coulomb), np.asarray(viscous)
    wander = np.cumsum(rng.normal(0, 1, (n, 3)), axis=0)
    wander = fc * 0.8 * np.tanh(0.02 * (wander - wander.mean(axis=0)))
    tau_l = tau_l + np.where(moving, fc * np.sign(dq_l) + fv * dq_l, wander)
    tau_l = tau_l + rng.normal(0, noise, tau_l.shape)
    q = np.zeros((n, len(joint_names)))
    tau = np.zeros((n, len(joint_names)))
    for j, name in enumerate(LEARN):
        if name in joint_names:
            c = joint_names.index(name)
            q[:, c] = q_l[:, j] + rng.normal(0, 2e-4, n)
            tau[:, c] = tau_l[:, j]
    for c, name in enumerate(joint_names):
        if name not in LEARN:
            q[:, c] = 0.1 * c + rng.normal(0, 1e-4, n)
            tau[:, c] = rng.normal(0, 0.01, n)
    path = write_minimal_session(path, t, q, tau, joint_names, rate_hz, source=source, seed=seed,
                                 attrs=attrs)
    return path, {"t": t, "q": q_l, "dq": dq_l, "ddq": ddq_l, "tau": tau_l, "moving": moving}
