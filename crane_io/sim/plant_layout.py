"""The simulated arm's parameter arrays, their layout, and the per-joint effect torques evaluated from them.

Both steppers of crane_io.sim.arm_plant.ArmPlant read the plant from these arrays
(crane_io.sim.plant_reference: Python floats; crane_io.sim.plant_kernel: compiled with numba), the rigid
body through crane_io.sim.plant_rigid, and
both evaluate the effects with the scalar functions below (`kinetic`, `other_torque`, `cogging_torque`):
the built-in effects' closed forms, as their `Effect.plant_terms` collect them in a
crane_io.physics.effects.PlantTerms, are evaluated in this one place (a plain Python function on a row of
floats: a list for the reference stepper, an array row in the compiled kernel).

This module imports numpy, math and crane_io.physics.effect_shapes (the built-in effects' shapes) only
(the compiled kernel imports it).

Layouts (float64):
- geo (n, GEO_COLS): per integrated joint, its placement in the parent joint's frame (rotation row-major,
  translation), its unit axis, the body's mass, centre of mass and rotational inertia about it (row-major);
- par (n, P_STRIB + 2 S + 2 R): Coulomb +, Coulomb -, static band +, static band -, viscous, offset,
  number of springs, the column of the first spring, lower and upper end stop, torque constant, servo
  index, number of Stribeck terms, then S (amplitude, velocity) pairs, then R (stiffness, rest angle)
  pairs;
- hpar (k, HELD_COLS): per held joint its torque constant, inertia, viscous friction, lower and upper end
  stop, servo index;
- cog (C, 4): cogging terms (joint, sin amplitude, cos amplitude, periods per turn); C may be 0;
- scal: (end-stop stiffness, end-stop damping, gravity x, y, z, the held joints' natural frequency);
- cmd (n, CMD_COLS): per joint the motor torque outside a position mode, 1.0 if its servo is in a position
  mode (then kp, kd, -cap, cap, goal of its PD), the external torque;
- the simulated chain's lockstep cycle (crane_io.sim.lockstep_kernel) gets them packed into one float array
  `kpack` with an int64 `klay`: n, k, par's columns, cogging terms, the offsets of geo, par, cog, scal, hpar,
  pd0 in kpack, then the integrated joints' servo indices, then the held ones'; and the state packed as
  `kst`: angles, velocities, motor torques of the integrated joints, then angles, velocities, currents of
  the held ones.
"""

from __future__ import annotations

import math

import numpy as np

from crane_io.physics.effect_shapes import ripple, spring, stribeck

G_R, G_P, G_AX, G_M, G_C, G_I = 0, 9, 12, 15, 16, 19
GEO_COLS = 28
(P_FCP, P_FCN, P_BANDP, P_BANDN, P_VISC, P_OFF, P_NSPRING, P_SPRING, P_LO, P_HI, P_KT, P_SERVO,
 P_NSTRIB) = range(13)
P_STRIB = 13
H_KT, H_INERTIA, H_VISC, H_LO, H_HI, H_SERVO = range(6)
HELD_COLS = 6
C_TAU, C_PD, C_KP, C_KD, C_LO, C_HI, C_GOAL, C_EXT = range(8)
CMD_COLS = 8
# the joint kinds of the simulated chain: their axis (None: the model's)
REVOLUTE = {"JointModelRX": (1.0, 0.0, 0.0), "JointModelRY": (0.0, 1.0, 0.0),
            "JointModelRZ": (0.0, 0.0, 1.0), "JointModelRevoluteUnaligned": None}


# ---- the effects, per joint (one row of par; a list of floats or an array row) ----------------------------
def kinetic(p, v):
    """Kinetic friction of the joint of row p at velocity v (v = +-tiny for a joint breaking away): the
    Coulomb level of its direction plus each Stribeck term amplitude x effect_shapes.stribeck x sign(v)."""
    if v > 0:
        f, sign = p[P_FCP], 1.0
    elif v < 0:
        f, sign = -p[P_FCN], -1.0
    else:
        return 0.0
    for k in range(int(p[P_NSTRIB])):
        f += p[P_STRIB + 2 * k] * stribeck(v, p[P_STRIB + 2 * k + 1]) * sign
    return f


def other_torque(p, qi, dqi, k_stop, d_stop):
    """Non-friction effect torques (viscous, offset, each spring: effect_shapes.spring) and the end stops of
    the joint of row p (inverse-dynamics sense)."""
    t = p[P_VISC] * dqi + p[P_OFF]
    first = int(p[P_SPRING])
    for k in range(int(p[P_NSPRING])):
        t += spring(qi, p[first + 2 * k], p[first + 2 * k + 1])
    if qi < p[P_LO]:
        t += k_stop * (qi - p[P_LO]) + d_stop * dqi
    elif qi > p[P_HI]:
        t += k_stop * (qi - p[P_HI]) + d_stop * dqi
    return t


def cogging_torque(c, qk):
    """The cogging term c (a row of cog) at its joint's angle qk (effect_shapes.ripple)."""
    return ripple(qk, c[1], c[2], c[3])


# ---- building the arrays ----------------------------------------------------------------------------
def revolute_chain(model) -> bool:
    """The pinocchio model is a serial chain of revolute joints (what crane_io.sim.plant_rigid integrates)."""
    return all(model.parents[i] == i - 1 and model.joints[i].shortname() in REVOLUTE
               for i in range(1, model.njoints))


def geometry(model) -> np.ndarray:
    """geo of a pinocchio model (a serial chain of revolute joints: `revolute_chain`)."""
    n = model.nv
    geo = np.zeros((n, GEO_COLS))
    for i in range(n):
        placement, inertia = model.jointPlacements[i + 1], model.inertias[i + 1]
        geo[i, G_R:G_R + 9] = placement.rotation.ravel()
        geo[i, G_P:G_P + 3] = placement.translation
        kind = model.joints[i + 1].shortname()
        geo[i, G_AX:G_AX + 3] = (REVOLUTE[kind] if REVOLUTE[kind] is not None
                                 else model.joints[i + 1].extract().axis)
        geo[i, G_M] = inertia.mass
        geo[i, G_C:G_C + 3] = inertia.lever
        geo[i, G_I:G_I + 9] = inertia.inertia.ravel()
    return geo


def effect_rows(terms, lo, hi, kt, servo) -> np.ndarray:
    """par from a PlantTerms and, per integrated joint, its end stops, true torque constant, servo index."""
    n = len(terms.joints)
    n_strib = max([len(s) for s in terms.stribeck] + [0])
    first = P_STRIB + 2 * n_strib  # the springs' pairs follow the Stribeck pairs
    par = np.zeros((n, first + 2 * max([len(s) for s in terms.springs] + [0])))
    for i in range(n):
        par[i, :P_STRIB] = (terms.coulomb_pos[i], terms.coulomb_neg[i], terms.band_pos[i], terms.band_neg[i],
                            terms.viscous[i], terms.offset[i], len(terms.springs[i]), first, lo[i], hi[i],
                            kt[i], servo[i], len(terms.stribeck[i]))
        for j, (amp, vs) in enumerate(terms.stribeck[i]):
            par[i, P_STRIB + 2 * j:P_STRIB + 2 * j + 2] = amp, vs
        for j, (k, q0) in enumerate(terms.springs[i]):
            par[i, first + 2 * j:first + 2 * j + 2] = k, q0
    return par


def cogging_rows(cogging) -> np.ndarray:
    """cog from PlantTerms.cogging ((joint, sin, cos, periods) tuples)."""
    return np.array(cogging, dtype=float).reshape(-1, 4)


def held_rows(kt, inertia, visc, lo, hi, servo) -> np.ndarray:
    """hpar from per-held-joint lists."""
    return np.array(list(zip(kt, inertia, visc, lo, hi, servo)), dtype=float).reshape(-1, HELD_COLS)


def held_matrix(dt: float, w: float) -> tuple[float, float, float, float]:
    """(a00, a01, a10, a11): the exact transition matrix over dt of x'' = -w^2 x - 2 w x' (critically
    damped)."""
    e = math.exp(-w * dt)
    return (e * (1 + w * dt), e * dt, -w * w * dt * e, e * (1 - w * dt))


def pack(geo, par, cog, scal, hpar, pd0, bi, held) -> tuple[np.ndarray, np.ndarray]:
    """(kpack, klay) for the lockstep cycle (see the module docstring)."""
    parts = (geo, par, cog, scal, hpar, pd0)
    offsets = np.cumsum([0] + [p.size for p in parts])[:-1].tolist()
    kpack = np.concatenate([p.ravel() for p in parts])
    klay = np.array([par.shape[0], len(held), par.shape[1], cog.shape[0], *offsets, *bi, *held],
                    dtype=np.int64)
    return kpack, klay
