"""The simulated arm's rigid-body dynamics, written once: the joint-space mass matrix M(q) and the bias torque
C(q, dq) dq + g(q) of a serial chain of revolute joints, and the solve of M ddq = tau.

Both of crane_io.sim.arm_plant.ArmPlant's steppers take the rigid body from here: the compiled one
(crane_io.sim.plant_kernel) compiles these functions into its substep; the reference one
(crane_io.sim.plant_reference) calls `mass_and_bias`, compiled (crane_io.sim.plant_kernel.compiled) or as
this Python source. pinocchio is the oracle: tests/test_plant_rigid.py checks M, the bias and the forward
dynamics against its `crba`, `nonLinearEffects` and `aba` to 1e-12.

In the joints' local frames, with pinocchio's conventions (motion (linear, angular), the base accelerating
against gravity): the mass matrix by the composite-rigid-body algorithm plus the armature (rotor inertia)
on its diagonal, mirrored from the upper triangle; the bias torque by the recursive Newton-Euler algorithm
with zero acceleration; the accelerations by Gaussian elimination without pivoting (M is symmetric
positive definite). The arrays are crane_io.sim.plant_layout's `geo` (the chain's geometry and inertias),
`arm` (the armature per joint) and `scal` (gravity in scal[2:5]).

This module imports numpy, math and the layout only (the compiled kernel compiles it): plain IEEE
operations, so the compiled functions compute the Python source's bits.
"""

from __future__ import annotations

import math

import numpy as np

from crane_io.sim.plant_layout import G_AX, G_C, G_I, G_M, G_P, G_R


def kinematics(n, geo, q, rot, pos):
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


def body_times(geo, i, m, cx, cy, cz, v0, v1, v2, w0, w1, w2):
    """Body i's spatial inertia (mass m, centre of mass c, rotational inertia about c in geo) times the
    motion (v, w): (m (v - c x w), Ic w + c x f), f its linear part."""
    f0 = m * (v0 - (cy * w2 - cz * w1))
    f1 = m * (v1 - (cz * w0 - cx * w2))
    f2 = m * (v2 - (cx * w1 - cy * w0))
    a0 = (geo[i, G_I] * w0 + geo[i, G_I + 1] * w1 + geo[i, G_I + 2] * w2) + (cy * f2 - cz * f1)
    a1 = (geo[i, G_I + 3] * w0 + geo[i, G_I + 4] * w1 + geo[i, G_I + 5] * w2) + (cz * f0 - cx * f2)
    a2 = (geo[i, G_I + 6] * w0 + geo[i, G_I + 7] * w1 + geo[i, G_I + 8] * w2) + (cx * f1 - cy * f0)
    return f0, f1, f2, a0, a1, a2


def rnea(n, geo, rot, pos, dq, ddq, g0, g1, g2, tau, wk):
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
        # f = I a + v x* (I v)
        fl0, fl1, fl2, fa0, fa1, fa2 = body_times(geo, i, m, cx, cy, cz, bl0, bl1, bl2, bw0, bw1, bw2)
        hl0, hl1, hl2, ha0, ha1, ha2 = body_times(geo, i, m, cx, cy, cz, nl0, nl1, nl2, nw0, nw1, nw2)
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


def crba(n, geo, arm, rot, pos, cm, ch, ci, mass):
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
    kinematics(n, geo, q, rot, pos)
    crba(n, geo, arm, rot, pos, cm, ch, ci, mass)
    rnea(n, geo, rot, pos, dq, zero, scal[2], scal[3], scal[4], bias, wk)


def solve(a, idx, m, b, x, work):
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


def mass_and_bias(geo, arm, scal, q, dq):
    """(n + 1, n): M(q) (armature on the diagonal, symmetric) in the first n rows, C(q, dq) dq + g(q) in the
    last, for the chain of `geo` at angles q and velocities dq."""
    n = q.shape[0]
    out = np.empty((n + 1, n))
    fw = np.empty(38 * n)  # rot, ci (9 n each), wk (12 n), pos, ch (3 n each), zero, cm (n each)
    rot = fw[0:9 * n].reshape((n, 3, 3))
    ci = fw[9 * n:18 * n].reshape((n, 3, 3))
    wk = fw[18 * n:30 * n].reshape((n, 12))
    pos = fw[30 * n:33 * n].reshape((n, 3))
    ch = fw[33 * n:36 * n].reshape((n, 3))
    zero, cm = fw[36 * n:37 * n], fw[37 * n:38 * n]
    for i in range(n):
        zero[i] = 0.0
    dynamics(n, geo, arm, scal, q, dq, out[:n], out[n], rot, pos, wk, zero, cm, ch, ci)
    return out
