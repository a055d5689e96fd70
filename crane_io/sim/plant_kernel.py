"""The compiled stepper of crane_io.sim.arm_plant.ArmPlant: a whole plant step (all its substeps) in one call,
compiled with numba when it is installed (crane_io.sim.plant_backend.CompiledStepper calls it).

`step(q, dq, cmd, h, n_sub, geo, arm, par, cog, scal)` integrates the plant's n integrated joints over n_sub
substeps of h seconds and returns one (3 n,) array: the new angles, velocities and the motor torque of the
last substep; `step_arm` adds the held joints. It is the model of the reference stepper
(crane_io.sim.plant_reference: pinocchio calls and Python floats per substep), for a serial chain of
revolute joints:

- rigid-body dynamics in the joints' local frames (pinocchio's conventions: motion (linear, angular),
  the base accelerating against gravity): the joint-space mass matrix by the composite-rigid-body
  algorithm plus the armature on its diagonal, mirrored from the upper triangle; the bias torque
  C(q, dq) dq + g(q) by the recursive Newton-Euler algorithm with zero acceleration. When every joint
  moves, the accelerations solve M ddq = drive - friction - bias by Gaussian elimination without
  pivoting (M is symmetric positive definite; the reference stepper uses pinocchio's ABA there);
- the effects with the layout's own functions (crane_io.sim.plant_layout: kinetic friction, static bands,
  viscous, offset, spring, cogging, the end stops; the reference stepper calls the same functions), the
  servos' PD controller in position modes, the stick-slip solve (the joint pushed furthest beyond its
  static band breaks away first) and the semi-implicit Euler update (a velocity that would change sign
  stops at zero), in the reference stepper's order of operations.

The same floats go in; the results agree with the reference stepper to rounding (the dynamics are summed
in another order than pinocchio's Eigen kernels): ~1e-15 relative per substep. Over a session, a stick-slip
decision taken at a rounding-level tie can go the other way, so trajectories agree closely but not bit
for bit (tests/test_plant_kernel.py).

Compiled with numba (`nopython`, `cache=True`: the machine code is kept in __pycache__ and loaded by later
processes; no `fastmath`, so LLVM neither reassociates nor contracts a*b+c into fused multiply-adds:
the compiled kernel computes the same IEEE operations as the Python source, `step.py_func`, which the
tests run as its reference). `error_model="numpy"`: a division by zero gives inf/nan instead of raising
(none occurs: the mass matrix is positive definite, Stribeck velocities positive). The arrays' layouts
are crane_io.sim.plant_layout's; `arm` is the armature (rotor inertia) of each joint, the pinocchio
model's own vector (a view: a change to `plant.model.armature` is seen).
"""

from __future__ import annotations

import math

import numpy as np

# the layout's names are the kernel's (its compiled functions, the layout's included, run in this namespace;
# callers read the columns here too)
from crane_io.sim.plant_layout import (  # noqa: F401
    C_EXT,
    C_GOAL,
    C_HI,
    C_KD,
    C_KP,
    C_LO,
    C_PD,
    C_TAU,
    CMD_COLS,
    G_AX,
    G_C,
    G_I,
    G_M,
    G_P,
    G_R,
    GEO_COLS,
    H_HI,
    H_INERTIA,
    H_KT,
    H_LO,
    H_SERVO,
    H_VISC,
    HELD_COLS,
    P_BANDN,
    P_BANDP,
    P_FCN,
    P_FCP,
    P_HI,
    P_KT,
    P_LO,
    P_NSTRIB,
    P_OFF,
    P_SERVO,
    P_SK,
    P_SQ0K,
    P_STRIB,
    P_VISC,
    cogging_torque,
    kinetic,
    other_torque,
)


def _kinematics(n, geo, q, rot, pos):
    """rot[i], pos[i]: joint i's frame in its parent's (placement x rotation about the axis by q[i])."""
    for i in range(n):
        x, y, z = geo[i, G_AX], geo[i, G_AX + 1], geo[i, G_AX + 2]
        c, s = math.cos(q[i]), math.sin(q[i])
        t = 1.0 - c
        j00, j01, j02 = t * x * x + c, t * x * y - s * z, t * x * z + s * y
        j10, j11, j12 = t * x * y + s * z, t * y * y + c, t * y * z - s * x
        j20, j21, j22 = t * x * z - s * y, t * y * z + s * x, t * z * z + c
        for r in range(3):
            p0, p1, p2 = geo[i, G_R + 3 * r], geo[i, G_R + 3 * r + 1], geo[i, G_R + 3 * r + 2]
            rot[i, r, 0] = p0 * j00 + p1 * j10 + p2 * j20
            rot[i, r, 1] = p0 * j01 + p1 * j11 + p2 * j21
            rot[i, r, 2] = p0 * j02 + p1 * j12 + p2 * j22
            pos[i, r] = geo[i, G_P + r]


def _rnea(n, geo, rot, pos, dq, ddq, g0, g1, g2, tau, wk):
    """tau = M(q) ddq + C(q, dq) dq + g(q) without the armature (gravity (g0, g1, g2)), for the kinematics
    in rot, pos. wk: (n, 12) work array (force on each body, linear then angular, in its own frame)."""
    vl0 = vl1 = vl2 = 0.0  # parent's velocity (linear, angular) and acceleration in the parent's frame
    vw0 = vw1 = vw2 = 0.0
    al0, al1, al2 = -g0, -g1, -g2
    aw0 = aw1 = aw2 = 0.0
    for i in range(n):
        r = rot[i]
        px, py, pz = pos[i, 0], pos[i, 1], pos[i, 2]
        ax, ay, az = geo[i, G_AX], geo[i, G_AX + 1], geo[i, G_AX + 2]
        d, dd = dq[i], ddq[i]
        # velocity: R^T (v - p x w, w) + S dq
        ul0, ul1, ul2 = vl0 - (py * vw2 - pz * vw1), vl1 - (pz * vw0 - px * vw2), vl2 - (px * vw1 - py * vw0)
        nl0 = r[0, 0] * ul0 + r[1, 0] * ul1 + r[2, 0] * ul2
        nl1 = r[0, 1] * ul0 + r[1, 1] * ul1 + r[2, 1] * ul2
        nl2 = r[0, 2] * ul0 + r[1, 2] * ul1 + r[2, 2] * ul2
        nw0 = r[0, 0] * vw0 + r[1, 0] * vw1 + r[2, 0] * vw2 + ax * d
        nw1 = r[0, 1] * vw0 + r[1, 1] * vw1 + r[2, 1] * vw2 + ay * d
        nw2 = r[0, 2] * vw0 + r[1, 2] * vw1 + r[2, 2] * vw2 + az * d
        # acceleration: R^T (a - p x aw, aw) + S ddq + v x (S dq)
        sx, sy, sz = ax * d, ay * d, az * d
        ul0, ul1, ul2 = al0 - (py * aw2 - pz * aw1), al1 - (pz * aw0 - px * aw2), al2 - (px * aw1 - py * aw0)
        bl0 = r[0, 0] * ul0 + r[1, 0] * ul1 + r[2, 0] * ul2 + (nl1 * sz - nl2 * sy)
        bl1 = r[0, 1] * ul0 + r[1, 1] * ul1 + r[2, 1] * ul2 + (nl2 * sx - nl0 * sz)
        bl2 = r[0, 2] * ul0 + r[1, 2] * ul1 + r[2, 2] * ul2 + (nl0 * sy - nl1 * sx)
        bw0 = r[0, 0] * aw0 + r[1, 0] * aw1 + r[2, 0] * aw2 + ax * dd + (nw1 * sz - nw2 * sy)
        bw1 = r[0, 1] * aw0 + r[1, 1] * aw1 + r[2, 1] * aw2 + ay * dd + (nw2 * sx - nw0 * sz)
        bw2 = r[0, 2] * aw0 + r[1, 2] * aw1 + r[2, 2] * aw2 + az * dd + (nw0 * sy - nw1 * sx)
        m = geo[i, G_M]
        cx, cy, cz = geo[i, G_C], geo[i, G_C + 1], geo[i, G_C + 2]
        # f = I a + v x* (I v); I (v, w) = (m (v - c x w), Ic w + c x f)
        fl0 = m * (bl0 - (cy * bw2 - cz * bw1))
        fl1 = m * (bl1 - (cz * bw0 - cx * bw2))
        fl2 = m * (bl2 - (cx * bw1 - cy * bw0))
        fa0 = (geo[i, G_I] * bw0 + geo[i, G_I + 1] * bw1 + geo[i, G_I + 2] * bw2) + (cy * fl2 - cz * fl1)
        fa1 = (geo[i, G_I + 3] * bw0 + geo[i, G_I + 4] * bw1 + geo[i, G_I + 5] * bw2) + (cz * fl0 - cx * fl2)
        fa2 = (geo[i, G_I + 6] * bw0 + geo[i, G_I + 7] * bw1 + geo[i, G_I + 8] * bw2) + (cx * fl1 - cy * fl0)
        hl0 = m * (nl0 - (cy * nw2 - cz * nw1))
        hl1 = m * (nl1 - (cz * nw0 - cx * nw2))
        hl2 = m * (nl2 - (cx * nw1 - cy * nw0))
        ha0 = (geo[i, G_I] * nw0 + geo[i, G_I + 1] * nw1 + geo[i, G_I + 2] * nw2) + (cy * hl2 - cz * hl1)
        ha1 = (geo[i, G_I + 3] * nw0 + geo[i, G_I + 4] * nw1 + geo[i, G_I + 5] * nw2) + (cz * hl0 - cx * hl2)
        ha2 = (geo[i, G_I + 6] * nw0 + geo[i, G_I + 7] * nw1 + geo[i, G_I + 8] * nw2) + (cx * hl1 - cy * hl0)
        # v x* h = (w x h_lin, w x h_ang + v x h_lin)
        wk[i, 0] = fl0 + (nw1 * hl2 - nw2 * hl1)
        wk[i, 1] = fl1 + (nw2 * hl0 - nw0 * hl2)
        wk[i, 2] = fl2 + (nw0 * hl1 - nw1 * hl0)
        wk[i, 3] = fa0 + ((nw1 * ha2 - nw2 * ha1) + (nl1 * hl2 - nl2 * hl1))
        wk[i, 4] = fa1 + ((nw2 * ha0 - nw0 * ha2) + (nl2 * hl0 - nl0 * hl2))
        wk[i, 5] = fa2 + ((nw0 * ha1 - nw1 * ha0) + (nl0 * hl1 - nl1 * hl0))
        vl0, vl1, vl2, vw0, vw1, vw2 = nl0, nl1, nl2, nw0, nw1, nw2
        al0, al1, al2, aw0, aw1, aw2 = bl0, bl1, bl2, bw0, bw1, bw2
    for i in range(n - 1, -1, -1):
        f0, f1, f2, t0, t1, t2 = wk[i, 0], wk[i, 1], wk[i, 2], wk[i, 3], wk[i, 4], wk[i, 5]
        tau[i] = geo[i, G_AX] * t0 + geo[i, G_AX + 1] * t1 + geo[i, G_AX + 2] * t2
        if i > 0:  # the parent carries this body's force: (R f, R t + p x R f)
            r = rot[i]
            px, py, pz = pos[i, 0], pos[i, 1], pos[i, 2]
            g0_ = r[0, 0] * f0 + r[0, 1] * f1 + r[0, 2] * f2
            g1_ = r[1, 0] * f0 + r[1, 1] * f1 + r[1, 2] * f2
            g2_ = r[2, 0] * f0 + r[2, 1] * f1 + r[2, 2] * f2
            wk[i - 1, 0] += g0_
            wk[i - 1, 1] += g1_
            wk[i - 1, 2] += g2_
            wk[i - 1, 3] += (r[0, 0] * t0 + r[0, 1] * t1 + r[0, 2] * t2) + (py * g2_ - pz * g1_)
            wk[i - 1, 4] += (r[1, 0] * t0 + r[1, 1] * t1 + r[1, 2] * t2) + (pz * g0_ - px * g2_)
            wk[i - 1, 5] += (r[2, 0] * t0 + r[2, 1] * t1 + r[2, 2] * t2) + (px * g1_ - py * g0_)


def _crba(n, geo, arm, rot, pos, cm, ch, ci, mass):
    """mass = M(q) (armature on the diagonal), the composite-rigid-body algorithm for the chain: each body's
    inertia as (mass, first moment, rotational inertia about the joint origin), the subtree's inertia
    carried into the parent's frame, then each joint's column from its subtree's momentum for a unit
    rotation, carried down to the root; the lower triangle mirrors the upper."""
    for i in range(n):  # the bodies' own inertias
        m = geo[i, G_M]
        cx, cy, cz = geo[i, G_C], geo[i, G_C + 1], geo[i, G_C + 2]
        cm[i] = m
        ch[i, 0], ch[i, 1], ch[i, 2] = m * cx, m * cy, m * cz
        cc = cx * cx + cy * cy + cz * cz
        for r in range(3):
            for c in range(3):
                ci[i, r, c] = geo[i, G_I + 3 * r + c] - m * (geo[i, G_C + r] * geo[i, G_C + c])
            ci[i, r, r] += m * cc
    for i in range(n - 1, 0, -1):  # subtree of i into its parent's frame: (m, R h + m p, ...)
        r_ = rot[i]
        m = cm[i]
        px, py, pz = pos[i, 0], pos[i, 1], pos[i, 2]
        hx = r_[0, 0] * ch[i, 0] + r_[0, 1] * ch[i, 1] + r_[0, 2] * ch[i, 2]
        hy = r_[1, 0] * ch[i, 0] + r_[1, 1] * ch[i, 1] + r_[1, 2] * ch[i, 2]
        hz = r_[2, 0] * ch[i, 0] + r_[2, 1] * ch[i, 1] + r_[2, 2] * ch[i, 2]
        k = i - 1
        cm[k] += m
        ch[k, 0] += hx + m * px
        ch[k, 1] += hy + m * py
        ch[k, 2] += hz + m * pz
        # R I R^T + (2 h.p + m |p|^2) E - (h p^T + p h^T + m p p^T)
        for a in range(3):
            t0 = r_[a, 0] * ci[i, 0, 0] + r_[a, 1] * ci[i, 1, 0] + r_[a, 2] * ci[i, 2, 0]
            t1 = r_[a, 0] * ci[i, 0, 1] + r_[a, 1] * ci[i, 1, 1] + r_[a, 2] * ci[i, 2, 1]
            t2 = r_[a, 0] * ci[i, 0, 2] + r_[a, 1] * ci[i, 1, 2] + r_[a, 2] * ci[i, 2, 2]
            for b in range(3):
                ci[k, a, b] += t0 * r_[b, 0] + t1 * r_[b, 1] + t2 * r_[b, 2]
        s = 2.0 * (hx * px + hy * py + hz * pz) + m * (px * px + py * py + pz * pz)
        hv0, hv1, hv2 = hx, hy, hz
        for a in range(3):
            pa = pos[i, a]
            ha = hv0 if a == 0 else (hv1 if a == 1 else hv2)
            for b in range(3):
                pb = pos[i, b]
                hb = hv0 if b == 0 else (hv1 if b == 1 else hv2)
                ci[k, a, b] -= ha * pb + pa * hb + m * (pa * pb)
            ci[k, a, a] += s
    for i in range(n):  # column i: the subtree's momentum for a unit rotation about axis i
        ax, ay, az = geo[i, G_AX], geo[i, G_AX + 1], geo[i, G_AX + 2]
        f0 = ay * ch[i, 2] - az * ch[i, 1]
        f1 = az * ch[i, 0] - ax * ch[i, 2]
        f2 = ax * ch[i, 1] - ay * ch[i, 0]
        t0 = ci[i, 0, 0] * ax + ci[i, 0, 1] * ay + ci[i, 0, 2] * az
        t1 = ci[i, 1, 0] * ax + ci[i, 1, 1] * ay + ci[i, 1, 2] * az
        t2 = ci[i, 2, 0] * ax + ci[i, 2, 1] * ay + ci[i, 2, 2] * az
        mass[i, i] = (ax * t0 + ay * t1 + az * t2) + arm[i]
        for j in range(i, 0, -1):  # into the parent's frame: (R f, R t + p x R f)
            r_ = rot[j]
            px, py, pz = pos[j, 0], pos[j, 1], pos[j, 2]
            g0 = r_[0, 0] * f0 + r_[0, 1] * f1 + r_[0, 2] * f2
            g1 = r_[1, 0] * f0 + r_[1, 1] * f1 + r_[1, 2] * f2
            g2 = r_[2, 0] * f0 + r_[2, 1] * f1 + r_[2, 2] * f2
            u0 = (r_[0, 0] * t0 + r_[0, 1] * t1 + r_[0, 2] * t2) + (py * g2 - pz * g1)
            u1 = (r_[1, 0] * t0 + r_[1, 1] * t1 + r_[1, 2] * t2) + (pz * g0 - px * g2)
            u2 = (r_[2, 0] * t0 + r_[2, 1] * t1 + r_[2, 2] * t2) + (px * g1 - py * g0)
            f0, f1, f2, t0, t1, t2 = g0, g1, g2, u0, u1, u2
            mass[j - 1, i] = geo[j - 1, G_AX] * t0 + geo[j - 1, G_AX + 1] * t1 + geo[j - 1, G_AX + 2] * t2
    for j in range(n):
        for k in range(j):
            mass[j, k] = mass[k, j]


def dynamics(n, geo, arm, scal, q, dq, mass, bias, rot, pos, wk, zero, cm, ch, ci):
    """mass = M(q) (armature on the diagonal, symmetric), bias = C(q, dq) dq + g(q)."""
    _kinematics(n, geo, q, rot, pos)
    _crba(n, geo, arm, rot, pos, cm, ch, ci, mass)
    _rnea(n, geo, rot, pos, dq, zero, scal[2], scal[3], scal[4], bias, wk)


def _solve(a, idx, m, b, x, work):
    """x[:m] = the solution of a[idx, idx] x = b[:m] (Gaussian elimination without pivoting)."""
    for r in range(m):
        for c in range(m):
            work[r, c] = a[idx[r], idx[c]]
    for k in range(m):
        p = work[k, k]
        for r in range(k + 1, m):
            f = work[r, k] / p
            for c in range(k, m):
                work[r, c] -= f * work[k, c]
            b[r] -= f * b[k]
    for k in range(m - 1, -1, -1):
        s = 0.0
        for c in range(k + 1, m):
            s += work[k, c] * x[c]
        x[k] = (b[k] - s) / work[k, k]


def step(q, dq, cmd, h, n_sub, geo, arm, par, cog, scal):
    """n_sub substeps of h; returns (3 n,): angles, velocities, the last substep's motor torque."""
    n = q.shape[0]
    out = np.empty(3 * n)
    _integrate(q, dq, cmd, h, n_sub, geo, arm, par, cog, scal, out)
    return out


def _integrate(q0, dq0, cmd, h, n_sub, geo, arm, par, cog, scal, out):
    """`step` into out[:3 n]; its work arrays are views of two allocations (one float, one int), not twenty
    (each allocation costs about as much as a joint's substep of arithmetic)."""
    n = q0.shape[0]
    fw = np.empty(n * (48 + 2 * n))  # 12 vectors, 2 (n, n), wk, pos, ch, rot, ci
    iw = np.zeros(2 * n, dtype=np.int64)
    q, dq, tau, drive, rhs = fw[0:n], fw[n:2 * n], fw[2 * n:3 * n], fw[3 * n:4 * n], fw[4 * n:5 * n]
    ddq, vel, net, sol = fw[5 * n:6 * n], fw[6 * n:7 * n], fw[7 * n:8 * n], fw[8 * n:9 * n]
    bias, zero, cm = fw[9 * n:10 * n], fw[10 * n:11 * n], fw[11 * n:12 * n]
    o = 12 * n
    mass = fw[o:o + n * n].reshape((n, n))
    work = fw[o + n * n:o + 2 * n * n].reshape((n, n))
    o += 2 * n * n
    wk = fw[o:o + 12 * n].reshape((n, 12))
    pos = fw[o + 12 * n:o + 15 * n].reshape((n, 3))
    ch = fw[o + 15 * n:o + 18 * n].reshape((n, 3))
    rot = fw[o + 18 * n:o + 27 * n].reshape((n, 3, 3))
    ci = fw[o + 27 * n:o + 36 * n].reshape((n, 3, 3))
    free, idx = iw[0:n], iw[n:2 * n]  # (free: 1 while the joint moves, in the stick-slip solve)
    for i in range(n):
        q[i], dq[i], zero[i] = q0[i], dq0[i], 0.0
    for _ in range(n_sub):
        _motor(n, cmd, q, dq, tau)
        moving = _drive(n, par, cog, cmd, scal, q, dq, tau, drive)
        dynamics(n, geo, arm, scal, q, dq, mass, bias, rot, pos, wk, zero, cm, ch, ci)
        for i in range(n):
            rhs[i] = drive[i] - bias[i]
        if moving:
            for i in range(n):
                idx[i] = i
                net[i] = rhs[i] - kinetic(par[i], dq[i])
            _solve(mass, idx, n, net, ddq, work)
        else:
            _stick_slip(n, par, mass, rhs, dq, ddq, free, vel, idx, net, sol, work)
        _euler(n, q, dq, ddq, h)
    for i in range(n):
        out[i], out[n + i], out[2 * n + i] = q[i], dq[i], tau[i]


def _motor(n, cmd, q, dq, tau):
    """tau: the motor torque of each joint; the servo's PD in position modes (SimplePlant.motor_torque),
    clipped as np.clip."""
    for i in range(n):
        if cmd[i, C_PD] != 0.0:
            x = cmd[i, C_KP] * (cmd[i, C_GOAL] - q[i]) - cmd[i, C_KD] * dq[i]
            lo, hi = cmd[i, C_LO], cmd[i, C_HI]
            x = x if (x != x or x > lo) else lo
            tau[i] = x if (x != x or x < hi) else hi
        else:
            tau[i] = cmd[i, C_TAU]


def _drive(n, par, cog, cmd, scal, q, dq, tau, drive):
    """drive = motor + external torque - the non-friction effect torques and end stops; True when every
    joint moves."""
    for i in range(n):
        drive[i] = other_torque(par[i], q[i], dq[i], scal[0], scal[1])
    for c in range(cog.shape[0]):
        k = int(cog[c, 0])
        drive[k] += cogging_torque(cog[c], q[k])
    moving = True
    for i in range(n):
        drive[i] = tau[i] + cmd[i, C_EXT] - drive[i]
        if dq[i] == 0.0:
            moving = False
    return moving


def _stick_slip(n, par, mass, rhs, dq, ddq, free, vel, idx, net, sol, work):
    """ddq when some joint stands still: the stuck joints are held while their holding torque lies in their
    static band; the joint pushed furthest beyond its band breaks away first, in that direction."""
    for i in range(n):
        free[i] = 1 if dq[i] != 0.0 else 0
        vel[i] = dq[i]
    for _pass in range(n + 1):
        m = _free_accelerations(n, par, mass, rhs, ddq, free, vel, idx, net, sol, work)
        worst, push = _breaking_away(n, par, mass, rhs, ddq, free, idx, m)
        if worst < 0:
            break
        free[worst] = 1
        vel[worst] = 1e-12 if push > 0 else -1e-12


def _free_accelerations(n, par, mass, rhs, ddq, free, vel, idx, net, sol, work):
    """ddq of the free joints with the stuck ones held (zero); returns their number (their indices in idx)."""
    m = 0
    for i in range(n):
        ddq[i] = 0.0
        if free[i]:
            idx[m] = i
            net[m] = rhs[i] - kinetic(par[i], vel[i])
            m += 1
    if m:
        _solve(mass, idx, m, net, sol, work)
        for a in range(m):
            ddq[idx[a]] = sol[a]
    return m


def _breaking_away(n, par, mass, rhs, ddq, free, idx, m):
    """(the stuck joint pushed furthest beyond its static band, or -1 when none is; its holding torque)."""
    worst, worst_excess, push = -1, 0.0, 0.0
    for s in range(n):
        if free[s]:
            continue
        coupled = 0.0
        for a in range(m):
            coupled = coupled + mass[s, idx[a]] * ddq[idx[a]]
        hold = rhs[s] - coupled
        above, below = hold - par[s, P_BANDP], -par[s, P_BANDN] - hold
        excess = below if below > above else above
        if excess > worst_excess:
            worst, worst_excess, push = s, excess, hold
    return worst, push


def _euler(n, q, dq, ddq, h):
    """Semi-implicit Euler: velocity first (friction stops a joint, it never reverses it), then position."""
    for i in range(n):
        d = dq[i]
        v = d + h * ddq[i]
        if (d > 0 and v < 0) or (d < 0 and v > 0):
            v = 0.0
        dq[i] = v
        q[i] = q[i] + h * v


def step_arm(q, dq, hq, hdq, cmds, pd, ext, hext, h, n_sub, dt, hmat, geo, arm, par, cog, scal, hpar):
    """A whole ArmPlant step: the held joints (ReferenceStepper._step_held, the same operations), then the
    integrated joints' n_sub substeps (`step`). cmds (5, servos): torque enabled, operating mode, goal
    current, goal position, current limit per servo; pd (n, 6): per integrated joint 1.0 when its servo's
    PD drives it, then kp, kd, -cap, cap, goal; ext, hext: the external torque on the integrated and the
    held joints; hmat: the held joints' transition matrix over dt (a00, a01, a10, a11); scal[5]: their
    natural frequency. Returns (3 n + 3 k,): angles, velocities, motor torques of the integrated joints,
    then angles, velocities, currents of the held ones."""
    n, k = q.shape[0], hq.shape[0]
    out = np.empty(3 * n + 3 * k)
    a00, a01, a10, a11 = hmat[0], hmat[1], hmat[2], hmat[3]
    w = scal[5]
    b = 3 * n
    for j in range(k):
        s = int(hpar[j, H_SERVO])
        on, mode, gc, gp, lim = cmds[0, s] != 0.0, cmds[1, s], cmds[2, s], cmds[3, s], cmds[4, s]
        qj, dqj = hq[j], hdq[j]
        kt, inertia = hpar[j, H_KT], hpar[j, H_INERTIA]
        current = 0.0
        if on and mode != 0:  # position modes: the exact discretisation, clipped current
            e = qj - gp
            new_e = a00 * e + a01 * dqj
            new_dq = a10 * e + a11 * dqj
            torque = inertia * (-(w * w) * e - 2 * w * dqj)
            x = torque / kt
            lo = -lim
            x = x if (x != x or x > lo) else lo
            current = x if (x != x or x < lim) else lim
            qj, dqj = gp + new_e, new_dq
        elif on:  # current mode
            tau = kt * gc + hext[j] - hpar[j, H_VISC] * dqj
            dqj = dqj + dt * (tau / inertia)
            qj = qj + dt * dqj
            current = gc
        else:  # torque off
            dqj = 0.0
        lo, hi = hpar[j, H_LO], hpar[j, H_HI]
        qj = qj if (qj != qj or qj > lo) else lo
        out[b + j] = qj if (qj != qj or qj < hi) else hi
        out[b + k + j] = dqj
        out[b + 2 * k + j] = current
    cmd = np.empty((n, CMD_COLS))
    for i in range(n):
        s = int(par[i, P_SERVO])
        cmd[i, C_TAU] = par[i, P_KT] * cmds[2, s] if (cmds[0, s] != 0.0 and cmds[1, s] == 0.0) else 0.0
        for c in range(6):
            cmd[i, C_PD + c] = pd[i, c]
        cmd[i, C_EXT] = ext[i]
    _integrate(q, dq, cmd, h, n_sub, geo, arm, par, cog, scal, out)
    return out


_F, _F2 = "float64[::1]", "float64[:, ::1]"
# the argument types ArmPlant calls step_arm with (compiled up front, crane_io.jit)
SIGNATURES = {
    "step_arm": (f"({_F}, {_F}, {_F}, {_F}, {_F2}, {_F2}, {_F}, {_F}, float64, int64, float64, {_F}, {_F2}, "
                 f"{_F}, {_F2}, {_F2}, {_F}, {_F2})",),
}


def compiled():
    """The numba-compiled (`step_arm`, `step`, `dynamics`), or None when numba is not installed. The first
    call of a process compiles step_arm or loads it from numba's cache (crane_io.jit)."""
    global _COMPILED
    if _COMPILED is None:
        from crane_io.jit import compile_functions

        names = ("_kinematics", "_rnea", "_crba", "dynamics", "kinetic", "other_torque", "cogging_torque",
                 "_solve", "_motor", "_drive", "_free_accelerations", "_breaking_away", "_stick_slip",
                 "_euler", "_integrate", "step", "step_arm")
        fns = compile_functions(globals(), names, SIGNATURES, error_model="numpy")
        _COMPILED = False if fns is None else (fns["step_arm"], fns["step"], fns["dynamics"])
    return _COMPILED or None


_COMPILED = None
