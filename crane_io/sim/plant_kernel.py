"""The compiled stepper of crane_io.sim.arm_plant.ArmPlant: a whole plant step (all its substeps) in one call,
compiled with numba when it is installed (crane_io.sim.plant_backend.CompiledStepper calls it).

`step(q, dq, cmd, h, n_sub, geo, arm, par, cog, scal)` integrates the plant's n integrated joints over n_sub
substeps of h seconds and returns one (3 n,) array: the new angles, velocities and the motor torque of the
last substep; `step_arm` adds the held joints. It is the reference stepper's substep
(crane_io.sim.plant_reference: Python floats per substep) in one compiled call, in the same order of
operations:

- the rigid body from crane_io.sim.plant_rigid (the mass matrix, the bias torque, the solve of M ddq =
  drive - friction - bias when every joint moves), the functions the reference stepper calls too;
- the effects with the layout's own functions (crane_io.sim.plant_layout: kinetic friction, static bands,
  viscous, offset, spring, cogging, the end stops; the reference stepper calls the same functions), the
  servos' PD controller in position modes, the stick-slip solve (the joint pushed furthest beyond its
  static band breaks away first) and the semi-implicit Euler update (a velocity that would change sign
  stops at zero).

The same floats go in, the same bits come out: a plant the kernel takes gives the reference stepper's
trajectory bit for bit (tests/test_plant_kernel.py).

Compiled with numba (`nopython`, `cache=True`: the machine code is kept in __pycache__ and loaded by later
processes; no `fastmath`, so LLVM neither reassociates nor contracts a*b+c into fused multiply-adds:
the compiled kernel computes the same IEEE operations as the Python source, `step.py_func`, which the
tests run as its reference). `error_model="numpy"`: a division by zero gives inf/nan instead of raising
(none occurs: the mass matrix is positive definite, Stribeck velocities positive). The arrays' layouts
are crane_io.sim.plant_layout's; `arm` is the armature (rotor inertia) of each joint, the pinocchio
model's own vector (a view: a change to `plant.model.armature` is seen).
"""

from __future__ import annotations

import math  # noqa: F401 (plant_rigid's functions use it here)

import numpy as np

# the layout's, the effect shapes' and the rigid body's names are the kernel's (its compiled functions,
# theirs included, run in this namespace; callers read the columns here too)
from crane_io.physics.effect_shapes import ripple, spring, stribeck  # noqa: F401
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
    P_NSPRING,
    P_NSTRIB,
    P_OFF,
    P_SERVO,
    P_SPRING,
    P_STRIB,
    P_VISC,
    cogging_torque,
    kinetic,
    other_torque,
)
from crane_io.sim.plant_rigid import (  # noqa: F401
    body_times,
    crba,
    dynamics,
    kinematics,
    mass_and_bias,
    rnea,
    solve,
)


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
            solve(mass, idx, n, net, ddq, work)
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
        solve(mass, idx, m, net, sol, work)
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
    "mass_and_bias": (f"({_F2}, {_F}, {_F}, {_F}, {_F})",),  # the reference stepper's rigid body
}


def compiled():
    """The numba-compiled (`step_arm`, `step`, `mass_and_bias`), or None when numba is not installed. The
    first call of a process compiles step_arm and mass_and_bias or loads them from numba's cache
    (crane_io.jit)."""
    global _COMPILED
    if _COMPILED is None:
        from crane_io.jit import compile_functions

        names = ("kinematics", "body_times", "rnea", "crba", "dynamics", "mass_and_bias", "stribeck",
                 "spring", "ripple", "kinetic", "other_torque", "cogging_torque", "solve", "_motor", "_drive",
                 "_free_accelerations", "_breaking_away", "_stick_slip", "_euler", "_integrate", "step",
                 "step_arm")
        fns = compile_functions(globals(), names, SIGNATURES, error_model="numpy")
        _COMPILED = False if fns is None else (fns["step_arm"], fns["step"], fns["mass_and_bias"])
    return _COMPILED or None


_COMPILED = None
