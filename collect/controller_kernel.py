"""The 4-channel controller's compiled backend (collect/controller_layout.ControlLaw): both arms' observers
(pseudo-derivative, DOB, RFOB) and the bilateral law (`step`), the per-arm position control (`hold`) or the
law with the safety monitor's usual case (`control`) in one call over the joints.

Every line of the compiled functions is the operation of the numpy reference (collect/controller_numpy.py)
for one joint, in the same order (`(g J) w`, `a y + (1 - a) (applied + g J w)`, `(tau_dis - gravity) - D
w`, `((-tau_p + tau_f) + tau_dis) bil`, ...), compiled with numba through crane_io.jit (`cache=True`, no
`fastmath`, so no reassociation and no fused multiply-add: the same IEEE results bit for bit, which
tests/test_controller_kernel.py asserts against the reference on random inputs). `error_model="numpy"`:
a division by zero gives inf or NaN as numpy's does, not an exception.

`CompiledLaw` keeps the state in one (N_STATE, n) array and the parameters in one (N_CONST, n) array (the
rows of collect/controller_layout.py); the gravity torque comes in as the values of the joints it covers
(`grav`) and their indices (`gidx`), 0 on the others. Each function fills the rows `O_*` of the array
`out` it is given (each arm's dq, tau_dis, tau_res with NaN on the held joints, `C_HELD`; the goal torques
and currents; `control`: the clamped goal torques) and returns a status: 0, or the bits of what the caller
has to see to, NONFINITE before any state changed.

This module imports numpy, crane_io.jit (numba, when compiling) and its layout only.
"""

from __future__ import annotations

import numpy as np

from .controller_layout import (
    C_BIL,
    C_D,
    C_DECAY,
    C_G,
    C_HELD,
    C_KD,
    C_KF,
    C_KP,
    C_KT,
    CHECK,
    K_BIL,
    K_SOFT_HI,
    K_SOFT_LO,
    K_STOP_HI,
    K_STOP_LO,
    K_TAU_MAX,
    K_VMAX,
    N_CONST,
    N_OUT,
    N_OUT_CONTROL,
    N_SAFETY,
    N_STATE,
    NONFINITE,
    O_CUR_F,
    O_CUR_L,
    O_DIS_F,
    O_DIS_L,
    O_DQ_F,
    O_DQ_L,
    O_LIM_F,
    O_LIM_L,
    O_RES_F,
    O_RES_L,
    O_TAU_F,
    O_TAU_L,
    PARAMETERS,
    S_AP,
    S_ARM,
    S_GJ,
    S_GRAV,
    S_J,
    S_Y,
    S_Z,
    SOFT_ZONE,
    ArmEstimates,
    Commands,
    ControlLaw,
    RowCommands,
)


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


def _clamp(s, c, k, arm, out):
    """SafetyMonitor.limit_torque's usual case for `arm` (0 leader, 1 follower): its goal torque times bil
    clamped to +-tau_max (numpy's NaN rules) into O_LIM_L + arm, and applied() of it into its state."""
    r = arm * S_ARM
    for i in range(out.shape[1]):
        top = k[K_TAU_MAX, i]
        v = out[O_TAU_L + arm, i] * k[K_BIL, i]
        low = -top
        if not (v >= low or v != v):  # np.maximum(v, -top)
            v = low
        if not (v <= top or v != v):  # np.minimum(v, top)
            v = top
        out[O_LIM_L + arm, i] = v
        s[r + S_AP, i] = v * c[C_BIL, i]


def _breached(q, dq, k, with_dq):
    """Not SafetyMonitor.check's usual case: a joint past its stop, or (with_dq) faster than its guard."""
    if _outside(q, k[K_STOP_LO], k[K_STOP_HI]):
        return True
    if with_dq:
        for i in range(dq.shape[0]):
            if abs(dq[i]) > k[K_VMAX, i]:
                return True
    return False


def control(ql, qf, dql, dqf, grav_l, grav_f, gidx, s, c, k, dt, band, has_dq, finite, out):
    """`step`, then SafetyMonitor.limit_torque's usual case (no joint in its soft zone: `_clamp`),
    applied() of the clamped torques, and SafetyMonitor.check's usual case (no joint past its stop, none
    faster than its guard; dq of arm a only when bit a of has_dq is set). The clamped torques go to
    O_LIM_L, O_LIM_F; the status has the SOFT_ZONE and CHECK bits of the arms the safety monitor itself
    has to see to."""
    status = step(ql, qf, grav_l, grav_f, gidx, s, c, dt, band, finite, out)
    if status:
        return status
    for arm in range(2):
        q, dq = (ql, dql) if arm == 0 else (qf, dqf)
        if _outside(q, k[K_SOFT_LO], k[K_SOFT_HI]):
            status |= SOFT_ZONE << arm
        else:
            _clamp(s, c, k, arm, out)
        if _breached(q, dq, k, (has_dq >> arm) & 1):
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

        names = ("_prepare", "_observe", "_deadband", "step", "_outside", "_clamp", "_breached", "control",
                 "hold")
        fns = compile_functions(globals(), names, SIGNATURES, qualname_prefix="controller.",
                                error_model="numpy")
        if fns is None:
            _COMPILED = False
        else:
            _COMPILED = (fns["step"], fns["hold"], fns["control"])
            for f in _COMPILED:
                f.disable_compile()
    return _COMPILED or None


_COMPILED = None
_F64 = np.dtype(np.float64)


def _input(x, n: int) -> np.ndarray:
    """x as the compiled functions take it, (n,) float64 C-contiguous and writeable (x itself when it is
    one already; numba would otherwise refuse it: no other specialisation is compiled)."""
    if type(x) is np.ndarray and x.dtype is _F64 and x.shape == (n,) and x.flags.carray:
        return x  # the usual case (a bus read's array), without np.asarray's call
    a = np.asarray(x, dtype=float)
    if a.shape != (n,) or not a.flags.carray:
        a = np.array(np.broadcast_to(a, (n,)), dtype=float)
    return a


class _Observer:
    """One arm's observer state as rows of the state array, read as NumpyLaw's observers (copies)."""

    model = None  # the compiled backend has no learned model
    fallback = None

    def __init__(self, law: CompiledLaw, row: int):
        self._law = law
        self._r = row

    def _row(self, r: int) -> np.ndarray | None:
        return self._law.state[self._r + r].copy() if self._law.cycles else None

    @property
    def z(self):
        return self._row(S_Z)

    @property
    def y(self):
        return self._row(S_Y)

    @property
    def applied(self):
        return self._row(S_AP)

    @property
    def J(self) -> np.ndarray:
        return self._law.state[self._r + S_J].copy()


class CompiledLaw(ControlLaw):
    """The compiled backend of `ctl` (a BilateralController: its parameters, gravity and inertia models,
    `decay`): nominal observers, no dither. `fns`: `compiled()`'s functions. `control` keeps the safety
    monitor's limits between calls and leaves the clamps and checks of an arm with a joint in its soft
    zone, past its stop or faster than its guard to the monitor's own code."""

    compiled = True

    def __init__(self, ctl, fns: tuple):
        self.ctl = ctl
        self.n = ctl.n
        self._step, self._hold, self._control = fns
        self.consts = np.zeros((N_CONST, self.n))
        for row, name in enumerate(PARAMETERS):
            self.consts[row] = getattr(ctl, name)
        self._consts_decay = None  # the decay(dt) array in the constants' C_DECAY row
        self.gravity, self.inertia = ctl.gravity, ctl.inertia
        self._gidx = np.ascontiguousarray(self.gravity.index, dtype=np.int64)
        self._finite = self.gravity.kind == "dynamics"  # the kernel checks those angles (as gravity_torque)
        self._band = float(ctl.deadband)
        self._limits = (None, None)  # (the monitor control() was last given, its kernel_constants())
        # pinocchio's gravity call, taken inline from the second cycle on when it gives the array the
        # compiled functions take (float64, C-contiguous)
        self._pin = self.gravity.unchecked
        if self._pin is not None:
            f, model, data = self._pin
            g = f(model, data, np.zeros(len(self.gravity.index)))
            if not (type(g) is np.ndarray and g.dtype is _F64 and g.flags.carray
                    and g.shape == self.gravity.index.shape):
                self._pin = None
        self.dither = np.zeros(self.n)
        self.reset()

    def reset(self) -> None:
        self.state = np.zeros((N_STATE, self.n))
        for r in (0, S_ARM):
            self.state[r + S_J] = self.ctl.J
            self.state[r + S_GJ] = self.ctl.g * self.ctl.J
        self.cycles = 0  # observer updates so far (the inertia's schedule; 0: no state yet)
        self._obs = (_Observer(self, 0), _Observer(self, S_ARM))
        self.leader: ArmEstimates | None = None
        self.follower: ArmEstimates | None = None

    def observer(self, arm: str) -> _Observer:
        return self._obs[arm != "leader"]

    def _first(self, ql, qf, gl, gf) -> None:
        """The first cycle's state: z at the angles, the DOB at the gravity torque (as NumpyLaw's)."""
        s = self.state
        for q, g, r in ((ql, gl, 0), (qf, gf, S_ARM)):
            full = np.zeros(self.n)
            full[self.gravity.index] = g
            s[r + S_Z] = q
            s[r + S_Y] = full * self.ctl.bil  # no sag when control engages
            s[r + S_AP] = s[r + S_Y]

    def _observers(self, ql: np.ndarray, qf: np.ndarray, dt: float) -> tuple:
        """What NumpyLaw's observers do before their arithmetic: both arms' gravity (the values the kernel
        takes; from the second cycle on unchecked, the kernel checks), the pose-dependent inertia when
        due, the first cycle's state; the current decay(dt) in the constants. Returns (gravity leader,
        gravity follower)."""
        s, grav = self.state, self.gravity
        k = self.cycles
        if k and self._pin is not None:  # GravityModel.values(q, checked=False), inline
            f, model, data = self._pin
            idx = grav.index
            gl, gf = f(model, data, ql[idx]), f(model, data, qf[idx])
        else:  # as the kernel takes them (the compiled call does not check them)
            n = len(grav.index)
            gl, gf = _input(grav.values(ql, k == 0), n), _input(grav.values(qf, k == 0), n)
        if k % self.inertia.every == 0:
            write, g = self.inertia.write, self.ctl.g
            write(ql, g, s[S_J], s[S_GJ])
            write(qf, g, s[S_ARM + S_J], s[S_ARM + S_GJ])
            if not k:
                self._first(ql, qf, gl, gf)
        self.cycles = k + 1
        a = self.ctl.decay(dt)
        if a is not self._consts_decay:
            self.consts[C_DECAY] = a
            self._consts_decay = a
        return gl, gf

    def _refused(self, ql, qf) -> None:
        """A compiled call found a joint of the gravity model NaN or infinite and changed nothing: the
        gravity model's own check says so (its error)."""
        self.cycles -= 1
        self.gravity.values(ql)
        self.gravity.values(qf)
        raise FloatingPointError("the dynamics inputs contain NaN or infinite values")

    def _estimates(self, out: np.ndarray) -> None:
        self.leader = ArmEstimates(out[O_DQ_L], out[O_DIS_L], out[O_RES_L])
        self.follower = ArmEstimates(out[O_DQ_F], out[O_DIS_F], out[O_RES_F])

    def step(self, leader, follower, dt: float) -> Commands:
        n = self.n
        ql, qf = _input(leader.q, n), _input(follower.q, n)
        dt = float(dt)
        out = np.empty((N_OUT, n))
        gl, gf = self._observers(ql, qf, dt)
        if self._step(ql, qf, gl, gf, self._gidx, self.state, self.consts, dt, self._band, self._finite,
                      out):
            self._refused(ql, qf)
        self._estimates(out)
        return Commands(out[O_TAU_L], out[O_TAU_F], out[O_CUR_L], out[O_CUR_F])

    def hold(self, leader, follower, ref_leader: tuple, ref_follower: tuple, dt: float) -> Commands:
        n = self.n
        ql, qf = _input(leader.q, n), _input(follower.q, n)
        refs = tuple(_input(x, n) for x in (*ref_leader, *ref_follower))
        dt = float(dt)
        out = np.empty((N_OUT, n))
        gl, gf = self._observers(ql, qf, dt)
        if self._hold(ql, qf, gl, gf, self._gidx, self.state, self.consts, dt, *refs, self._finite, out):
            self._refused(ql, qf)
        self._estimates(out)
        return Commands(out[O_TAU_L], out[O_TAU_F], out[O_CUR_L], out[O_CUR_F])

    def applied(self, tau_leader: np.ndarray, tau_follower: np.ndarray) -> None:
        s, bil = self.state, self.ctl.bil
        np.multiply(np.asarray(tau_leader, dtype=float), bil, out=s[S_AP])
        np.multiply(np.asarray(tau_follower, dtype=float), bil, out=s[S_ARM + S_AP])

    def _safety_rows(self, safety) -> np.ndarray:
        """The monitor's limits as `control` reads them, kept (they are fixed once the monitor is built)."""
        limits = safety.kernel_constants()
        if not (type(limits) is np.ndarray and limits.dtype is _F64 and limits.flags.carray
                and limits.shape == (N_SAFETY, self.n)):  # the compiled code does not check its indices
            raise ValueError(f"the safety monitor's limits are not a C-contiguous float64 array of "
                             f"{N_SAFETY} rows by the controller's {self.n} joints")
        self._limits = (safety, limits)
        return limits

    def control(self, leader, follower, dt: float, safety) -> tuple:
        n = self.n
        ql, qf = _input(leader.q, n), _input(follower.q, n)
        dql, dqf = leader.dq_servo, follower.dq_servo
        has_dq = (dql is not None) | (dqf is not None) << 1
        dql = ql if dql is None else _input(dql, n)
        dqf = qf if dqf is None else _input(dqf, n)
        dt = float(dt)
        seen = self._limits
        limits = seen[1] if seen[0] is safety else self._safety_rows(safety)
        out = np.empty((N_OUT_CONTROL, n))
        gl, gf = self._observers(ql, qf, dt)
        status = self._control(ql, qf, dql, dqf, gl, gf, self._gidx, self.state, self.consts, limits, dt,
                               self._band, has_dq, self._finite, out)
        if status & NONFINITE:
            self._refused(ql, qf)
        self.leader = ArmEstimates(out[O_DQ_L], out[O_DIS_L], out[O_RES_L])  # _estimates(out), inline
        self.follower = ArmEstimates(out[O_DQ_F], out[O_DIS_F], out[O_RES_F])
        if status:  # a joint in its soft zone, past its stop or faster than its guard
            return self._monitor(status, leader, follower, safety, out)
        return RowCommands(out), out[O_LIM_L], out[O_LIM_F], None

    def _monitor(self, status: int, leader, follower, safety, out: np.ndarray) -> tuple:
        """`control`'s end where the safety monitor's own code sees to an arm (the status bits)."""
        lim_l, lim_f = out[O_LIM_L], out[O_LIM_F]
        if status & SOFT_ZONE:
            lim_l = safety.limit_torque(leader.q, out[O_TAU_L], leader.dq_servo)
        if status & SOFT_ZONE << 1:
            lim_f = safety.limit_torque(follower.q, out[O_TAU_F], follower.dq_servo)
        if status & (SOFT_ZONE | SOFT_ZONE << 1):
            self.applied(lim_l, lim_f)
        breach = None
        if status & CHECK:
            breach = safety.check("leader", leader.q, leader.dq_servo)
        if breach is None and status & CHECK << 1:
            breach = safety.check("follower", follower.q, follower.dq_servo)
        return RowCommands(out), lim_l, lim_f, breach
