"""The 4-channel controller's per-cycle arithmetic compiled (collect/controller.py, issue 13): both arms'
observers (pseudo-derivative, DOB, RFOB) and the bilateral law (`step`) or the per-arm position control
(`hold`) in one call over the joints, in Python floats' order.

Every line is the operation of collect/controller.py's numpy path for one joint, in the same order
(`(g J) w`, `a y + (1 - a) (applied + g J w)`, `(tau_dis - gravity) - D w`, `((-tau_p + tau_f) +
tau_dis) bil`, ...), compiled with numba through crane_io.jit (`cache=True`, no `fastmath`, so no
reassociation and no fused multiply-add: the same IEEE results bit for bit, which
tests/test_controller_kernel.py asserts against the numpy path on random inputs). `error_model="numpy"`:
a division by zero gives inf or NaN as numpy's does, not an exception.

The controller keeps its state in one (12, n) array (`S_*` rows: per arm z, y, applied, g J, J and the
gravity torque) and its constants in one (9, n) array (`C_*` rows); the gravity torque comes in as the
values of the joints it covers (`grav`) and their indices (`gidx`), 0 on the others. Each function fills
the rows `O_*` of the array `out` it is given (each arm's dq, tau_dis, tau_res with NaN on the held
joints, `C_HELD`; the goal torques and currents; `control`: the clamped goal torques) and returns a
status: 0, or the bits of what the caller has to see to, NONFINITE before any state changed.
"""

from __future__ import annotations

import numpy as np

# state rows: leader z, y, applied, g J, J, gravity torque; then the follower's
S_Z, S_Y, S_AP, S_GJ, S_J, S_GRAV = 0, 1, 2, 3, 4, 5
S_ARM = 6  # the follower's rows are S_* + S_ARM
N_STATE = 12
# constant rows
C_G, C_KP, C_KD, C_KF, C_D, C_BIL, C_KT, C_HELD, C_DECAY = 0, 1, 2, 3, 4, 5, 6, 7, 8
N_CONST = 9
# output rows; `control` adds both arms' goal torques after the safety clamps
O_DQ_L, O_DIS_L, O_RES_L, O_DQ_F, O_DIS_F, O_RES_F, O_TAU_L, O_TAU_F, O_CUR_L, O_CUR_F = range(10)
O_LIM_L, O_LIM_F = 10, 11
N_OUT, N_OUT_CONTROL = 10, 12
# the safety monitor's rows (SafetyMonitor.kernel_constants)
K_SOFT_LO, K_SOFT_HI, K_TAU_MAX, K_STOP_LO, K_STOP_HI, K_VMAX, K_BIL = 0, 1, 2, 3, 4, 5, 6
N_SAFETY = 7
# status bits. `control`, per arm (leader << 0, follower << 1): in the soft zone (the clamps are left to
# SafetyMonitor.limit_torque), past a stop or the velocity guard (SafetyMonitor.check says which).
# NONFINITE: a joint the gravity model covers is NaN or infinite (the dynamics' ConfigError); nothing done.
SOFT_ZONE, CHECK, NONFINITE = 1, 4, 16


def _prepare(ql, qf, grav_l, grav_f, gidx, s, finite):
    """The gravity torques into the state (the joints in gidx); False when `finite` and one of those
    joints' angles is not finite (then nothing is changed)."""
    if finite:
        for k in range(gidx.shape[0]):
            if not (np.isfinite(ql[gidx[k]]) and np.isfinite(qf[gidx[k]])):
                return False
    for k in range(gidx.shape[0]):
        s[S_GRAV, gidx[k]] = grav_l[k]
        s[S_ARM + S_GRAV, gidx[k]] = grav_f[k]
    return True


def _observe(q, s, r, c, dt, i):
    """One joint i of _Observer.update for the arm whose state rows start at r: (w, tau_dis, tau_res)."""
    w = c[C_G, i] * (q[i] - s[r + S_Z, i])
    s[r + S_Z, i] = s[r + S_Z, i] + w * dt
    gjw = s[r + S_GJ, i] * w
    a = c[C_DECAY, i]
    y = a * s[r + S_Y, i] + (1.0 - a) * (s[r + S_AP, i] + gjw)
    s[r + S_Y, i] = y
    dis = y - gjw
    res = dis - s[r + S_GRAV, i] - c[C_D, i] * w
    return w, dis, res


def _deadband(e, band):
    """np.sign(e) * np.maximum(np.abs(e) - band, 0.0) for one float (numpy's NaN and zero rules)."""
    if e > 0.0:
        s = 1.0
    elif e < 0.0:
        s = -1.0
    elif e == 0.0:
        s = 0.0
    else:
        s = e  # NaN
    m = abs(e) - band
    if not (m >= 0.0 or m != m):
        m = 0.0
    return s * m


def step(ql, qf, grav_l, grav_f, gidx, s, c, dt, band, finite, out):
    """BilateralController.step's arithmetic for both arms (band: position_deadband, 0 for none)."""
    if not _prepare(ql, qf, grav_l, grav_f, gidx, s, finite):
        return NONFINITE
    f = S_ARM
    for i in range(ql.shape[0]):
        wl, dis_l, res_l = _observe(ql, s, 0, c, dt, i)
        wf, dis_f, res_f = _observe(qf, s, f, c, dt, i)
        e = ql[i] - qf[i]
        if band > 0:
            e = _deadband(e, band)
        J = 0.5 * (s[S_J, i] + s[f + S_J, i])
        tau_p = 0.5 * J * (c[C_KP, i] * e + c[C_KD, i] * (wl - wf))
        tau_f = -0.5 * c[C_KF, i] * (res_l + res_f)
        bil = c[C_BIL, i]
        tau_l = (-tau_p + tau_f + dis_l) * bil
        tau_fr = (tau_p + tau_f + dis_f) * bil
        s[S_AP, i] = tau_l
        s[f + S_AP, i] = tau_fr
        held = c[C_HELD, i]
        kt = c[C_KT, i]
        out[O_DQ_L, i] = wl
        out[O_DIS_L, i] = dis_l + held
        out[O_RES_L, i] = res_l + held
        out[O_DQ_F, i] = wf
        out[O_DIS_F, i] = dis_f + held
        out[O_RES_F, i] = res_f + held
        out[O_TAU_L, i] = tau_l
        out[O_TAU_F, i] = tau_fr
        out[O_CUR_L, i] = tau_l / kt
        out[O_CUR_F, i] = tau_fr / kt
    return 0


def _outside(q, lo, hi):
    """SafetyMonitor._outside: any q[i] above hi[i] or below lo[i] (NaN is neither)."""
    for i in range(q.shape[0]):
        if q[i] > hi[i] or q[i] < lo[i]:
            return True
    return False


def control(ql, qf, dql, dqf, grav_l, grav_f, gidx, s, c, k, dt, band, has_dq, finite, out):
    """`step`, then SafetyMonitor.limit_torque's usual case (no joint in its soft zone: tau bil clamped to
    +-tau_max, numpy's NaN rules), applied() of the clamped torques, and SafetyMonitor.check's usual case
    (no joint past its stop, none faster than its guard; dq of arm a only when bit a of has_dq is set).
    The clamped torques go to O_LIM_L, O_LIM_F; the status has the SOFT_ZONE and CHECK bits of the arms
    the safety monitor itself has to see to."""
    status = step(ql, qf, grav_l, grav_f, gidx, s, c, dt, band, finite, out)
    if status:
        return status
    for arm in range(2):
        q, dq = (ql, dql) if arm == 0 else (qf, dqf)
        if _outside(q, k[K_SOFT_LO], k[K_SOFT_HI]):
            status |= SOFT_ZONE << arm
        else:
            r = arm * S_ARM
            for i in range(q.shape[0]):
                top = k[K_TAU_MAX, i]
                v = out[O_TAU_L + arm, i] * k[K_BIL, i]
                low = -top
                if not (v >= low or v != v):  # np.maximum(v, -top)
                    v = low
                if not (v <= top or v != v):  # np.minimum(v, top)
                    v = top
                out[O_LIM_L + arm, i] = v
                s[r + S_AP, i] = v * c[C_BIL, i]
        bad = _outside(q, k[K_STOP_LO], k[K_STOP_HI])
        if not bad and (has_dq >> arm) & 1:
            for i in range(dq.shape[0]):
                if abs(dq[i]) > k[K_VMAX, i]:
                    bad = True
        if bad:
            status |= CHECK << arm
    return status


def hold(ql, qf, grav_l, grav_f, gidx, s, c, dt, ref_ql, ref_dql, ref_qf, ref_dqf, finite, out):
    """BilateralController.hold's arithmetic for both arms (their references q, dq)."""
    if not _prepare(ql, qf, grav_l, grav_f, gidx, s, finite):
        return NONFINITE
    for arm in range(2):
        r = arm * S_ARM
        q = ql if arm == 0 else qf
        q_ref, dq_ref = (ref_ql, ref_dql) if arm == 0 else (ref_qf, ref_dqf)
        o = arm * 3
        for i in range(q.shape[0]):
            w, dis, res = _observe(q, s, r, c, dt, i)
            tau = (0.5 * s[r + S_J, i] * (c[C_KP, i] * (q_ref[i] - q[i]) + c[C_KD, i] * (dq_ref[i] - w))
                   + dis) * c[C_BIL, i]
            s[r + S_AP, i] = tau
            held = c[C_HELD, i]
            out[o + O_DQ_L, i] = w
            out[o + O_DIS_L, i] = dis + held
            out[o + O_RES_L, i] = res + held
            out[O_TAU_L + arm, i] = tau
            out[O_CUR_L + arm, i] = tau / c[C_KT, i]
    return 0


_F, _F2, _I = "float64[::1]", "float64[:, ::1]", "int64[::1]"
# the argument types the controller calls them with (compiled up front, crane_io.jit)
SIGNATURES = {
    "step": (f"int64({_F}, {_F}, {_F}, {_F}, {_I}, {_F2}, {_F2}, float64, float64, boolean, {_F2})",),
    "hold": (f"int64({_F}, {_F}, {_F}, {_F}, {_I}, {_F2}, {_F2}, float64, {_F}, {_F}, {_F}, {_F}, boolean, "
             f"{_F2})",),
    "control": (f"int64({_F}, {_F}, {_F}, {_F}, {_F}, {_F}, {_I}, {_F2}, {_F2}, {_F2}, float64, float64, "
                f"int64, boolean, {_F2})",),
}


def compiled():
    """(step, hold, control) compiled with numba, or None without numba: compiled, or loaded from numba's
    cache, by the first call of a process (crane_io.jit), and then closed to any other argument types
    (a call with others is a TypeError, never a compilation at run time)."""
    global _COMPILED
    if _COMPILED is None:
        from crane_io.jit import compile_functions

        names = ("_prepare", "_observe", "_deadband", "step", "_outside", "control", "hold")
        fns = compile_functions(globals(), names, SIGNATURES, error_model="numpy")
        if fns is None:
            _COMPILED = False
        else:
            _COMPILED = (fns["step"], fns["hold"], fns["control"])
            for f in _COMPILED:
                f.disable_compile()
    return _COMPILED or None


_COMPILED = None


def direct(dispatcher):
    """The native entry of a compiled function with one signature (numba's `overloads[sig].entry_point`):
    called without the dispatcher's matching of the argument types to the signature, about a microsecond
    less per call. Its caller must pass exactly the signature's types (an array of another dtype would be
    read as the signature's: numba does not check it there); the dispatcher itself when there is no such
    entry (another numba, another signature count)."""
    sigs = getattr(dispatcher, "signatures", ())
    if len(sigs) != 1:
        return dispatcher
    entry = getattr(getattr(dispatcher, "overloads", {}).get(sigs[0]), "entry_point", None)
    return entry if callable(entry) else dispatcher
