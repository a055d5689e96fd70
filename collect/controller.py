"""4-channel bilateral control of a leader and a follower CRANE-X7 (pure numpy, no I/O).

Per bilateral joint, with nominal inertia J (constant, or following the pose: InertiaModel), gains
Kp, Kd, Kf and cutoff g (shared/crane_x7_facts.md section 6a; the Sakaino/Tsuji-lab structure):

- pseudo-derivative velocity: w = g (q - z),  z <- z + w dt  (a first-order filtered derivative);
- disturbance observer (DOB): tau_dis = LPF_g(tau_ref + g J w) - g J w, with tau_ref the torque
  actually applied in the previous cycle (after safety clamps);
- reaction-force observer (RFOB): tau_res = tau_dis - gravity(q) - D w  (what the outside world -
  the operator's hand on the leader, the environment on the follower - pushes against the arm, with
  the DOB's sign: a hand pushing the joint positive gives tau_res < 0); with a learned model on an arm
  (`models`), the joints it covers take the model's reaction torque instead,
  tau_res = L(L(tau_applied)) - f(L(L(q)), L(D(q)), D(D(q))) with the training's filters
  (collect/model_reaction.py), and fall back to the nominal one in a cycle whose prediction is unusable;
- position term  tau_p = (J/2) [Kp (q_l - q_f) + Kd (w_l - w_f)]  (follower +, leader -);
- force term     tau_f = -(Kf/2) (tau_res_l + tau_res_f)  (both arms);
- references:  tau_ref_f = tau_p + tau_f + tau_dis_f,   tau_ref_l = -tau_p + tau_f + tau_dis_l,
  which drive q_l - q_f -> 0 (position tracking) and tau_res_l + tau_res_f -> 0 (action = reaction);
- friction dither (optional; docs/collect.md "Friction dither"): with `dither_amplitude` > 0 the
  follower's reference becomes  tau_ref_f = tau_p + tau_f + tau_dis_f + d(t),  d_j(t) = A_j w(2 pi f t)
  on every bilateral joint j, A_j = `dither_amplitude` x the joint's `dither` factor ([controller.jointN],
  default 1), w = sin (or its sign: `dither_wave` = "square"), f = `dither_frequency`, t the time since
  the first bilateral step (hold() is never dithered, nor is the leader). d is part of the applied
  torque the follower's DOB sees, so where the joint's motion shows it, it cancels against the J ddq it
  causes; at a standstill that motion is far below one encoder count and the DOB passes d attenuated
  only by its low-pass (about g / (2 pi f)). So with `dither_filter` (the default) the follower's
  tau_res, in the force term and as recorded, is the mean of its last N = round(rate / f) values: a
  comb that removes a wave of period N cycles exactly, for N / 2 cycles of delay. The point: a joint
  kept slipping has kinetic friction whose sign alternates within a period and averages out, so a
  joint pressed against something still no longer holds a static-friction offset in tau_res. With
  `dither_amplitude` = 0 (the default) the commands are exactly those without the term. A joint's
  `dither_min_velocity` v_j > 0 raises its amplitude to |A_j| >= v_j 2 pi f J_j(q) (J_j the follower's
  nominal inertia at this pose, `inertia_model`), sign kept: the wave's velocity amplitude A / (J 2 pi f)
  stays at least v_j where the arm's pose makes the joint heavy (issue 10, docs/collect.md).

Goal torques become goal currents through each joint's torque constant. Joints that are not
bilateral get no current (they are held in position mode by the servos); their observer estimates are
NaN. The pseudo-derivative velocity is computed for every joint.

Two paths compute all this with the same bits: the numpy one below (the reference; learned models,
the dither, runs on real arms) and a compiled kernel (collect/controller_kernel.py, issue 13: one call
per cycle instead of some sixty small numpy operations) that a simulated run takes, numba being loaded
there already (`BilateralController(compiled=...)`). `control()` is a bilateral cycle's step, safety
clamps, applied and safety checks in one call; on the compiled path it calls the kernel's native entry
(controller_kernel.direct: the arguments' types are guaranteed here, not matched per call), keeps the safety
monitor's limits between calls, and makes the commands' rows only when they are read.
"""

from __future__ import annotations

import functools
import math
import sys
import warnings
from dataclasses import dataclass

import numpy as np

from crane_io.description import ArmDescription, default_arm
from crane_io.errors import ConfigError

from . import controller_kernel as kernel
from .config import Config
from .safety import Breach, SafetyMonitor


@dataclass
class ArmSignals:
    """What one arm's bus read gave this cycle, in arm.joints order (SI)."""

    q: np.ndarray  # (n,) rad
    dq_servo: np.ndarray | None = None  # (n,) rad/s, servo-reported (recorded, not used by the law)
    current: np.ndarray | None = None  # (n,) A, servo-reported


@dataclass
class ArmEstimates:
    """The controller's internal signals for one arm, recorded in the session."""

    dq: np.ndarray  # (n,) rad/s, pseudo-derivative
    tau_dis: np.ndarray  # (n,) N m, DOB estimate (NaN for held joints)
    tau_res: np.ndarray  # (n,) N m, RFOB estimate (NaN for held joints)


@dataclass
class Commands:
    """Goal torques and currents for both arms, (n,) in arm.joints order; 0 for held joints."""

    leader_tau: np.ndarray
    follower_tau: np.ndarray
    leader_current: np.ndarray
    follower_current: np.ndarray


class _KernelCommands(Commands):
    """Commands on the compiled path: the rows of the kernel's output array (`controller_kernel.O_*`), each
    made when first read (BilateralController.control's caller reads the clamped torques instead)."""

    def __init__(self, out: np.ndarray | None = None, **fields):  # the fields are the properties below
        self._out = out
        if out is None:  # the fields given (dataclasses.replace, copy)
            Commands.__init__(self, **fields)

    @functools.cached_property
    def leader_tau(self) -> np.ndarray:
        return self._out[kernel.O_TAU_L]

    @functools.cached_property
    def follower_tau(self) -> np.ndarray:
        return self._out[kernel.O_TAU_F]

    @functools.cached_property
    def leader_current(self) -> np.ndarray:
        return self._out[kernel.O_CUR_L]

    @functools.cached_property
    def follower_current(self) -> np.ndarray:
        return self._out[kernel.O_CUR_F]


class GravityModel:
    """Motor torque (n,) needed to hold the arm against gravity, for the RFOB."""

    def __init__(self, kind: str, config: Config, arm: ArmDescription):
        self.kind = kind
        self.arm = arm
        self.n = len(arm.joints)
        self._dyn = None
        self._dyn_idx = None
        self._pin = None  # (pinocchio's gravity, model, data): gravity_torque's call without its checks
        names = arm.joint_names
        self._i2 = names.index("joint2") if "joint2" in names else None
        self._i4 = names.index("joint4") if "joint4" in names else None
        c = config.controller
        self._m = (c.gravity_m0, c.gravity_m1, c.gravity_m2)
        if kind == "dynamics":
            try:
                from crane_io.physics.dynamics import ArmDynamics
            except ImportError:
                warnings.warn("crane_io.physics.dynamics is not available; using the sine gravity "
                              "coefficients",
                              stacklevel=2)
                self.kind = "coefficients"
            else:
                joints = tuple(arm.bilateral_joints)
                locked = {n: config.held.get(n, 0.0) for n in names if n not in joints}
                self._dyn = ArmDynamics(joints=joints, locked=locked)
                self._dyn_idx = np.array([names.index(n) for n in self._dyn.joint_names])
                if self._dyn._identity:  # the joints in the model's order: gravity_torque's one-pose call
                    import pinocchio

                    self._pin = (pinocchio.computeGeneralizedGravity, self._dyn.model, self._dyn.data)
        self._out = np.zeros(self.n)
        # the joints `values` gives, in its order
        self.index = np.array(self._dyn_idx if self.kind == "dynamics" else range(self.n), dtype=np.int64)

    def values(self, q: np.ndarray, checked: bool = True) -> np.ndarray:
        """The torques of the joints `index` covers (the compiled controller's gravity input): those
        `__call__` puts in its (n,) result, the other joints' being 0. checked=False: without the
        dynamics' check that those angles are finite (NaN in, NaN out; the caller checks them)."""
        if self.kind == "dynamics":
            if not checked and self._pin is not None:
                f, model, data = self._pin
                return f(model, data, q[self._dyn_idx])  # a new array
            return self._dyn.gravity_torque(q[self._dyn_idx])
        return self(q)

    def __call__(self, q: np.ndarray) -> np.ndarray:
        out = self._out.copy()
        if self.kind == "dynamics":
            out[self._dyn_idx] = self._dyn.gravity_torque(q[self._dyn_idx])
        elif self.kind == "coefficients" and self._i2 is not None and self._i4 is not None:
            m0, m1, m2 = self._m
            s2 = np.sin(q[self._i2])
            s24 = np.sin(q[self._i2] + q[self._i4])
            out[self._i2] = -m0 * s2 - m1 * s24
            out[self._i4] = -m2 * s24
        return out


class InertiaModel:
    """Nominal inertia J (n,) of one arm at pose q.

    "constant": the configured J. "dynamics": the configured J is taken as the inertia at the zero
    pose (upright, elbow straight) and the change of the link inertia with the pose, M_ii(q) - M_ii(0)
    from crane_io.physics.dynamics, is added (never below half the configured value). Joint 1's inertia
    grows about 60x from upright to arm outstretched; a constant J then makes the DOB loop ring.
    """

    def __init__(self, kind: str, config: Config, arm: ArmDescription, J: np.ndarray, every: int):
        self.kind = kind
        self.J = J
        self.every = max(1, int(every))
        self._dyn = None
        self._crba = None  # (pinocchio.crba, model, data): `write`'s call of the dynamics, when it has one
        if kind == "dynamics":
            try:
                from crane_io.physics.dynamics import ArmDynamics
            except ImportError:
                warnings.warn("crane_io.physics.dynamics is not available; using constant nominal inertias",
                              stacklevel=2)
                self.kind = "constant"
            else:
                names = arm.joint_names
                joints = tuple(arm.bilateral_joints)
                locked = {n: config.held.get(n, 0.0) for n in names if n not in joints}
                self._dyn = ArmDynamics(joints=joints, locked=locked)
                self._idx = np.array([names.index(n) for n in self._dyn.joint_names])
                self._m0 = np.diag(self._dyn.mass_matrix(np.zeros(len(joints))))
                if self._dyn._identity:  # mass_matrix_diagonal's one-pose call (crba) without its checks
                    import pinocchio

                    self._crba = (pinocchio.crba, self._dyn.model, self._dyn.data)

    def __call__(self, q: np.ndarray) -> np.ndarray:
        if self._dyn is None:
            return self.J
        J = self.J.copy()
        i = self._idx
        m = self._dyn.mass_matrix_diagonal(q[i])
        J[i] = np.maximum(0.5 * self.J[i], self.J[i] + m - self._m0)
        return J

    def write(self, q: np.ndarray, g: np.ndarray, J_row: np.ndarray, gJ_row: np.ndarray) -> None:
        """self(q) into J_row and g self(q) into gJ_row ((n,) each), the compiled controller's state rows;
        J_row must hold self(q) of an earlier pose already, or J (the joints the dynamics do not cover keep
        their values). The same bits as those of self(q), in fewer operations."""
        if self._crba is None:
            J = self(q)
            J_row[:] = J
            np.multiply(g, J, out=gJ_row)
            return
        crba, model, data = self._crba
        i = self._idx
        qi = q[i]
        if not all(map(math.isfinite, qi.tolist())):  # as mass_matrix_diagonal
            raise ConfigError("the dynamics inputs contain NaN or infinite values")
        Ji = self.J[i]
        x = Ji + (crba(model, data, qi).diagonal() + 0.0)  # (J + m) - m0, as in __call__
        x -= self._m0
        J_row[i] = np.maximum(0.5 * Ji, x)
        np.multiply(g, J_row, out=gJ_row)


class _Observer:
    """Pseudo-derivative + DOB + RFOB state of one arm; with a learned model (ModelReaction) the
    reaction torque of the joints it covers comes from the model (collect/model_reaction.py)."""

    def __init__(self, ctl: BilateralController, model=None):
        self.ctl = ctl
        self.z = None  # pseudo-derivative integrator (n,)
        self.y = None  # DOB low-pass state (n,)
        self.applied = None  # torque applied in the previous cycle (n,)
        self.J = ctl.J
        self._k = 0
        self.model = model
        self.fallback = None  # (J,) bool: model joints on the nominal model this cycle (None: no model)

    def update(self, q: np.ndarray, dt: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        c = self.ctl
        grav = c.gravity(q)
        if self._k % c.inertia.every == 0:
            self.J = c.inertia(q)
        self._k += 1
        if self.z is None:
            self.z = q.copy()
            self.y = grav * c.bil  # DOB starts at the gravity torque: no sag when control engages
            self.applied = self.y.copy()
        w = c.g * (q - self.z)
        self.z += w * dt
        gjw = c.g * self.J * w
        a = c.decay(dt)
        self.y = a * self.y + (1.0 - a) * (self.applied + gjw)
        tau_dis = self.y - gjw
        tau_res = tau_dis - grav - c.D * w
        if self.model is not None:
            res_m, ok = self.model.update(q, self.applied, dt)
            i = self.model.idx
            tau_res[i] = np.where(ok, res_m, tau_res[i])
            self.fallback = ~ok
        return w, tau_dis, tau_res


class _KernelObserver:
    """One arm's observer state on the compiled path: rows of the controller's state array
    (collect/controller_kernel.py); z, y, applied and J read as _Observer's (copies)."""

    model = None  # the compiled path has no learned model
    fallback = None

    def __init__(self, ctl: BilateralController, row: int):
        self._ctl = ctl
        self._s = ctl._state
        self._r = row

    def _row(self, r: int) -> np.ndarray | None:
        return self._s[self._r + r].copy() if self._ctl._cycles else None

    @property
    def z(self):
        return self._row(kernel.S_Z)

    @property
    def y(self):
        return self._row(kernel.S_Y)

    @property
    def applied(self):
        return self._row(kernel.S_AP)

    @property
    def J(self) -> np.ndarray:
        return self._s[self._r + kernel.S_J].copy()


_F64 = np.dtype(np.float64)


def _kernel_input(x, n: int) -> np.ndarray:
    """x as the compiled functions take it, (n,) float64 C-contiguous and writeable (x itself when it is
    one already; otherwise numba would compile another specialisation at the call)."""
    if type(x) is np.ndarray and x.dtype is _F64 and x.shape == (n,) and x.flags.carray:
        return x  # the usual case (a bus read's array), without np.asarray's call
    a = np.asarray(x, dtype=float)
    if a.shape != (n,) or not a.flags.carray:
        a = np.array(np.broadcast_to(a, (n,)), dtype=float)
    return a


class BilateralController:
    """`step(leader, follower, dt) -> Commands`; estimates of the last step in `.leader` and
    `.follower` (ArmEstimates). Call `applied(tau_leader, tau_follower)` after safety clamps so the
    observers see the torque that really went out (otherwise the unclamped reference is assumed).

    `compiled`: run step, hold and applied on the compiled kernel (collect/controller_kernel.py: the
    same arithmetic, the same bits, in one call per cycle) instead of the numpy path. It covers the
    nominal observers without friction dither; True asks for it (a ConfigError when numba is missing,
    a learned model is given or the dither is on), False never uses it, None (default) uses it when it
    covers the configuration and numba is already loaded in this process (a simulated run: the
    simulator's kernels loaded it), so a run on real arms never imports numba for it."""

    def __init__(self, config: Config, arm: ArmDescription | None = None, models: dict | None = None,
                 compiled: bool | None = None):
        self.config = config
        # arm name ("leader", "follower") -> a factory of its ModelReaction (a fresh one per reset)
        self.models = dict(models or {})
        self.arm = arm or default_arm()
        names = self.arm.joint_names
        gains = config.controller.joints
        missing = [n for n in names if n not in gains]
        if missing:
            raise ConfigError(f"the configuration has no [controller.{missing[0]}] gains for that joint")
        self.n = len(names)
        self.J = np.array([gains[n].inertia for n in names])
        self.kp = np.array([gains[n].kp for n in names])
        self.kd = np.array([gains[n].kd for n in names])
        self.kf = np.array([gains[n].kf for n in names])
        self.g = np.array([gains[n].cutoff for n in names])
        self.D = np.array([gains[n].viscous for n in names])
        self.bil = np.array([n in self.arm.bilateral_joints for n in names], dtype=float)
        self.bil_mask = self.bil.astype(bool)
        self.kt = np.array([j.torque_constant for j in self.arm.joints])
        self.deadband = config.controller.position_deadband
        self.gravity = GravityModel(config.controller.gravity_model, config, self.arm)
        self.inertia = InertiaModel(config.controller.inertia_model, config, self.arm, self.J,
                                    config.controller.inertia_update_cycles)
        self._nan_held = np.where(self.bil_mask, 0.0, np.nan)
        self._decay = (None, None, None)  # (g, dt, exp(-g dt)) of the last step (decay)
        c = config.controller
        self.dither_amplitude = float(c.dither_amplitude)
        self.dither_frequency = float(c.dither_frequency)
        self.dither_square = c.dither_wave == "square"
        self.dither_filter = c.dither_filter and self.dither_amplitude > 0.0
        # per joint: dither_amplitude x the joint's `dither` factor, bilateral joints only
        self.dither_amplitudes = self.dither_amplitude * np.array([gains[n].dither for n in names]) * self.bil
        # issue 10: per joint a velocity floor, |A_j| >= v_j 2 pi f J_j(q) (the follower's inertia this cycle)
        self.dither_floor = (2.0 * np.pi * self.dither_frequency * self.bil
                             * np.array([gains[n].dither_min_velocity for n in names]))
        self._kernel = self._load_kernel(compiled)
        self.reset()

    @property
    def compiled(self) -> bool:
        """Whether step, hold and applied run on the compiled kernel."""
        return self._kernel is not None

    def _load_kernel(self, compiled: bool | None):
        """(step, hold) of collect/controller_kernel.py, compiled now (or loaded from numba's cache), with
        the constants array they read; None for the numpy path (see the class docstring)."""
        if compiled is False:
            return None
        why = ("a learned model in an observer" if any(self.models.values())
               else "the friction dither" if self.dither_amplitude > 0.0 else None)
        if compiled is None and (why is not None or "numba" not in sys.modules):
            return None
        if why is not None:
            raise ConfigError(f"the compiled controller does not run {why}; use compiled=False")
        fns = kernel.compiled()
        if fns is None:
            if compiled:
                raise ConfigError("the compiled controller needs numba (pip install numba)")
            return None
        c = np.zeros((kernel.N_CONST, self.n))
        for row, values in ((kernel.C_G, self.g), (kernel.C_KP, self.kp), (kernel.C_KD, self.kd),
                            (kernel.C_KF, self.kf), (kernel.C_D, self.D), (kernel.C_BIL, self.bil),
                            (kernel.C_KT, self.kt), (kernel.C_HELD, self._nan_held)):
            c[row] = values
        self._consts = c
        self._consts_decay = None  # the decay(dt) array in _consts' C_DECAY row
        self._gidx = np.ascontiguousarray(self.gravity.index, dtype=np.int64)
        self._finite = self.gravity.kind == "dynamics"  # the kernel checks those angles (as gravity_torque)
        self._band = float(self.deadband)
        self._limits = (None, None)  # (the SafetyMonitor control() was last given, its kernel_constants())
        # control's native entry (kernel.direct): control() passes it the signature's types only; so the
        # gravity's own call only when it gives a float64 C-contiguous array (as pinocchio's does)
        self._control_entry = kernel.direct(fns[2])
        self._pin = self.gravity._pin
        if self._pin is not None:
            f, model, data = self._pin
            g = f(model, data, np.zeros(len(self.gravity.index)))
            if not (type(g) is np.ndarray and g.dtype is _F64 and g.flags.carray
                    and g.shape == self.gravity.index.shape):
                self._pin = None
        return fns

    def decay(self, dt: float) -> np.ndarray:
        """exp(-g dt), the DOB low-pass factor of a step of dt; the last one is kept (the loop's dt is
        its constant period)."""
        g, (kept_g, kept_dt, kept) = self.g, self._decay
        if g is not kept_g or dt != kept_dt:
            kept = np.exp(-g * dt)
            self._decay = (g, dt, kept)
        return kept

    def reset(self) -> None:
        make = self.models
        if self._kernel is not None:
            self._state = np.zeros((kernel.N_STATE, self.n))
            for r in (0, kernel.S_ARM):
                self._state[r + kernel.S_J] = self.J
                self._state[r + kernel.S_GJ] = self.g * self.J
            self._cycles = 0  # observer updates so far (the inertia's schedule; 0: no state yet)
            self._obs_l = _KernelObserver(self, 0)
            self._obs_f = _KernelObserver(self, kernel.S_ARM)
        else:
            self._obs_l = _Observer(self, make["leader"]() if make.get("leader") else None)
            self._obs_f = _Observer(self, make["follower"]() if make.get("follower") else None)
        self.leader: ArmEstimates | None = None
        self.follower: ArmEstimates | None = None
        self._dither_t = 0.0  # s of bilateral control so far (the dither's time)
        self.dither = np.zeros(self.n)  # (n,) N m: the dither added to the follower's last step
        self._comb = None  # (N, n) the follower's last N tau_res (dither_filter), filled on the first step
        self._comb_k = 0

    def _comb_filter(self, res: np.ndarray, dt: float) -> np.ndarray:
        """The mean of the follower's last N = round(1 / (f dt)) reaction estimates (this one included)."""
        if self._comb is None:
            size = max(1, int(round(1.0 / (self.dither_frequency * dt))))
            self._comb = np.repeat(res[None, :], size, axis=0)
        self._comb[self._comb_k] = res
        self._comb_k = (self._comb_k + 1) % len(self._comb)
        return self._comb.mean(axis=0)

    def _dither(self, dt: float) -> np.ndarray | None:
        """d(t) (n,) for this step (bilateral joints only), and advance t; None when the dither is off."""
        if self.dither_amplitude <= 0.0:
            return None
        s = np.sin(2.0 * np.pi * self.dither_frequency * self._dither_t)
        self._dither_t += dt
        if self.dither_square:
            s = 1.0 if s >= 0.0 else -1.0
        a = self.dither_amplitudes
        if self.dither_floor.any():  # at least dither_min_velocity of velocity amplitude at this pose
            a = np.sign(a) * np.maximum(np.abs(a), self.dither_floor * self._obs_f.J)
        self.dither = a * s
        return self.dither

    def _kernel_observers(self, ql: np.ndarray, qf: np.ndarray, dt: float) -> tuple:
        """What _Observer.update does before its arithmetic, for the compiled path: both arms' gravity
        (the values the kernel takes; from the second cycle on unchecked, the kernel checks), the
        pose-dependent inertia when due, the first cycle's state; the current decay(dt) in the constants.
        Returns (gravity leader, gravity follower)."""
        s, grav = self._state, self.gravity
        k = self._cycles
        if k and self._pin is not None:  # GravityModel.values(q, checked=False), inline
            f, model, data = self._pin
            idx = grav._dyn_idx
            gl, gf = f(model, data, ql[idx]), f(model, data, qf[idx])
        else:  # as the kernel takes them (control's native entry does not check them)
            n = len(grav.index)
            gl, gf = _kernel_input(grav.values(ql, k == 0), n), _kernel_input(grav.values(qf, k == 0), n)
        if k % self.inertia.every == 0:
            write = self.inertia.write
            write(ql, self.g, s[kernel.S_J], s[kernel.S_GJ])
            write(qf, self.g, s[kernel.S_ARM + kernel.S_J], s[kernel.S_ARM + kernel.S_GJ])
            if not k:
                for q, g, r in ((ql, gl, 0), (qf, gf, kernel.S_ARM)):
                    full = np.zeros(self.n)
                    full[grav.index] = g
                    s[r + kernel.S_Z] = q
                    s[r + kernel.S_Y] = full * self.bil  # as _Observer.update: no sag when control engages
                    s[r + kernel.S_AP] = s[r + kernel.S_Y]
        self._cycles = k + 1
        a = self.decay(dt)
        if a is not self._consts_decay:
            self._consts[kernel.C_DECAY] = a
            self._consts_decay = a
        return gl, gf

    def _kernel_call(self, f: int, ql: np.ndarray, qf: np.ndarray, dt: float, before: tuple, after: tuple
                     ) -> tuple[np.ndarray, int]:
        """Kernel function f (0 step, 1 hold, 2 control) on the two arms' angles (_kernel_input arrays):
        (its output rows, its status). before, after: its arguments before the gravity and after the
        constants, up to `finite`."""
        out = np.empty((kernel.N_OUT_CONTROL if f == 2 else kernel.N_OUT, self.n))
        gl, gf = self._kernel_observers(ql, qf, dt)
        status = self._kernel[f](ql, qf, *before, gl, gf, self._gidx, self._state, self._consts, *after,
                                 self._finite, out)
        if status & kernel.NONFINITE:  # nothing changed (the first cycle's angles were checked before)
            self._cycles -= 1
            raise ConfigError("the dynamics inputs contain NaN or infinite values")
        return out, status

    def control(self, leader: ArmSignals, follower: ArmSignals, dt: float, safety: SafetyMonitor
                ) -> tuple[Commands, np.ndarray, np.ndarray, Breach | None]:
        """A bilateral cycle's control: `step`, the safety clamps of both goal torques
        (`safety.limit_torque(q, tau, dq_servo)`), `applied` of what they give, and the safety checks
        (`safety.check` of the leader, then of the follower). Returns (commands, clamped leader torque,
        clamped follower torque, the first breach or None): what those calls give in that order; on the
        compiled path in one kernel call (the safety monitor's own code only for an arm with a joint in
        its soft zone, past its stop or faster than its guard)."""
        if self._kernel is None:
            cmd = self.step(leader, follower, dt)
            tau_l = safety.limit_torque(leader.q, cmd.leader_tau, leader.dq_servo)
            tau_f = safety.limit_torque(follower.q, cmd.follower_tau, follower.dq_servo)
            self.applied(tau_l, tau_f)
            breach = safety.check("leader", leader.q, leader.dq_servo)
            if breach is None:
                breach = safety.check("follower", follower.q, follower.dq_servo)
            return cmd, tau_l, tau_f, breach
        n = self.n
        ql, qf = _kernel_input(leader.q, n), _kernel_input(follower.q, n)
        dql, dqf = leader.dq_servo, follower.dq_servo
        has_dq = (dql is not None) | (dqf is not None) << 1
        dql = ql if dql is None else _kernel_input(dql, n)
        dqf = qf if dqf is None else _kernel_input(dqf, n)
        dt = float(dt)
        seen = self._limits
        if seen[0] is safety:  # the limits are fixed once the monitor is built (kernel_constants)
            limits = seen[1]
        else:
            limits = safety.kernel_constants()
            if limits.shape != (kernel.N_SAFETY, n):  # the kernel does not check its indices
                raise ConfigError(f"the safety monitor has {limits.shape[1]} joints, the controller {n}")
            if not (type(limits) is np.ndarray and limits.dtype is _F64 and limits.flags.carray):
                raise ConfigError("the safety monitor's kernel_constants() are not a C-contiguous float64 "
                                  "array")
            self._limits = (safety, limits)
        # _kernel_call(2, ...), inline
        out = np.empty((kernel.N_OUT_CONTROL, n))
        gl, gf = self._kernel_observers(ql, qf, dt)
        status = self._control_entry(ql, qf, dql, dqf, gl, gf, self._gidx, self._state, self._consts, limits,
                                     dt, self._band, has_dq, self._finite, out)
        if status & kernel.NONFINITE:  # nothing changed (the first cycle's angles were checked before)
            self._cycles -= 1
            raise ConfigError("the dynamics inputs contain NaN or infinite values")
        self.leader = ArmEstimates(out[kernel.O_DQ_L], out[kernel.O_DIS_L], out[kernel.O_RES_L])
        self.follower = ArmEstimates(out[kernel.O_DQ_F], out[kernel.O_DIS_F], out[kernel.O_RES_F])
        lim_l, lim_f = out[kernel.O_LIM_L], out[kernel.O_LIM_F]
        breach = None
        if status:  # a joint in its soft zone, past its stop or faster than its guard
            tau_l, tau_f = out[kernel.O_TAU_L], out[kernel.O_TAU_F]
            if status & kernel.SOFT_ZONE:
                lim_l = safety.limit_torque(leader.q, tau_l, leader.dq_servo)
            if status & kernel.SOFT_ZONE << 1:
                lim_f = safety.limit_torque(follower.q, tau_f, follower.dq_servo)
            if status & (kernel.SOFT_ZONE | kernel.SOFT_ZONE << 1):
                self.applied(lim_l, lim_f)
            if status & kernel.CHECK:
                breach = safety.check("leader", leader.q, leader.dq_servo)
            if breach is None and status & kernel.CHECK << 1:
                breach = safety.check("follower", follower.q, follower.dq_servo)
        return _KernelCommands(out), lim_l, lim_f, breach

    def step(self, leader: ArmSignals, follower: ArmSignals, dt: float) -> Commands:
        if self._kernel is not None:
            n = self.n
            ql, qf = _kernel_input(leader.q, n), _kernel_input(follower.q, n)
            dt = float(dt)
            out, _ = self._kernel_call(0, ql, qf, dt, (), (dt, self._band))
            dq_l, dis_l, res_l, dq_f, dis_f, res_f, tau_l, tau_f, cur_l, cur_f = out
            self.leader = ArmEstimates(dq_l, dis_l, res_l)
            self.follower = ArmEstimates(dq_f, dis_f, res_f)
            return Commands(tau_l, tau_f, cur_l, cur_f)
        ql = np.asarray(leader.q, dtype=float)
        qf = np.asarray(follower.q, dtype=float)
        wl, dis_l, res_l = self._obs_l.update(ql, dt)
        wf, dis_f, res_f = self._obs_f.update(qf, dt)
        if self.dither_filter:
            res_f = self._comb_filter(res_f, dt)
        e = ql - qf
        if self.deadband > 0:
            e = np.sign(e) * np.maximum(np.abs(e) - self.deadband, 0.0)
        J = 0.5 * (self._obs_l.J + self._obs_f.J)
        tau_p = 0.5 * J * (self.kp * e + self.kd * (wl - wf))
        tau_f = -0.5 * self.kf * (res_l + res_f)
        tau_l = (-tau_p + tau_f + dis_l) * self.bil
        tau_f_ref = (tau_p + tau_f + dis_f) * self.bil
        d = self._dither(dt)
        if d is not None:
            tau_f_ref = tau_f_ref + d
        self._obs_l.applied = tau_l
        self._obs_f.applied = tau_f_ref
        held = self._nan_held
        self.leader = ArmEstimates(wl, dis_l + held, res_l + held)
        self.follower = ArmEstimates(wf, dis_f + held, res_f + held)
        return Commands(tau_l, tau_f_ref, tau_l / self.kt, tau_f_ref / self.kt)

    def hold(self, leader: ArmSignals, follower: ArmSignals, ref_leader: tuple[np.ndarray, np.ndarray],
             ref_follower: tuple[np.ndarray, np.ndarray], dt: float) -> Commands:
        """Independent position control of each arm to a reference (q (n,), dq (n,)) with the same
        observers (DOB compensation): tau = (J/2) [Kp (q_ref - q) + Kd (dq_ref - w)] + tau_dis (the
        per-arm gains of the bilateral position term; full J Kp is too fast for the observers). Used to
        bring the arms into agreement before bilateral control; the observers carry over seamlessly."""
        if self._kernel is not None:
            n = self.n
            ql, qf = _kernel_input(leader.q, n), _kernel_input(follower.q, n)
            refs = tuple(_kernel_input(x, n) for x in (*ref_leader, *ref_follower))
            dt = float(dt)
            out, _ = self._kernel_call(1, ql, qf, dt, (), (dt, *refs))
            dq_l, dis_l, res_l, dq_f, dis_f, res_f, tau_l, tau_f, cur_l, cur_f = out
            self.leader = ArmEstimates(dq_l, dis_l, res_l)
            self.follower = ArmEstimates(dq_f, dis_f, res_f)
            return Commands(tau_l, tau_f, cur_l, cur_f)
        out = []
        pairs = ((self._obs_l, leader, ref_leader), (self._obs_f, follower, ref_follower))
        for obs, sig, (q_ref, dq_ref) in pairs:
            q = np.asarray(sig.q, dtype=float)
            w, dis, res = obs.update(q, dt)
            tau = (0.5 * obs.J * (self.kp * (q_ref - q) + self.kd * (dq_ref - w)) + dis) * self.bil
            obs.applied = tau
            out.append((tau, ArmEstimates(w, dis + self._nan_held, res + self._nan_held)))
        (tau_l, est_l), (tau_f, est_f) = out
        self.leader, self.follower = est_l, est_f
        return Commands(tau_l, tau_f, tau_l / self.kt, tau_f / self.kt)

    def reaction(self, arm: str):
        """The ModelReaction in `arm`'s observer ("leader" or "follower"), or None (nominal)."""
        return (self._obs_l if arm == "leader" else self._obs_f).model

    def model_fallbacks(self) -> dict[str, np.ndarray | None]:
        """{arm: (J,) bool} for the arms with a learned model: which of its joints used the nominal
        reaction torque in the last cycle (None before the first cycle)."""
        out = {}
        for name, obs in (("leader", self._obs_l), ("follower", self._obs_f)):
            if obs.model is not None:
                out[name] = obs.fallback
        return out

    def applied(self, tau_leader: np.ndarray, tau_follower: np.ndarray) -> None:
        """Tell the observers the torques that were actually commanded this cycle."""
        if self._kernel is not None:
            s = self._state
            np.multiply(np.asarray(tau_leader, dtype=float), self.bil, out=s[kernel.S_AP])
            np.multiply(np.asarray(tau_follower, dtype=float), self.bil, out=s[kernel.S_ARM + kernel.S_AP])
            return
        self._obs_l.applied = np.asarray(tau_leader, dtype=float) * self.bil
        self._obs_f.applied = np.asarray(tau_follower, dtype=float) * self.bil
