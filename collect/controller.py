"""4-channel bilateral control of a leader and a follower CRANE-X7 (pure numpy, no I/O).

Per bilateral joint, with nominal inertia J (constant, or following the pose: InertiaModel), gains
Kp, Kd, Kf and cutoff g (shared/crane_x7_facts.md section 6a; the Sakaino/Tsuji-lab structure):

- pseudo-derivative velocity: w = g (q - z),  z <- z + w dt  (a first-order filtered derivative);
- disturbance observer (DOB): tau_dis = LPF_g(tau_ref + g J w) - g J w, with tau_ref the torque
  actually applied in the previous cycle (after safety clamps);
- reaction-force observer (RFOB): tau_res = tau_dis - gravity(q) - D w  (what the outside world -
  the operator's hand on the leader, the environment on the follower - pushes against the arm, with
  the DOB's sign: a hand pushing the joint positive gives tau_res < 0); with an identified arm model
  (`arm_model`: its bodies in gravity(q) and J, its viscous friction as D) that has Coulomb friction c,
  tau_res = tau_dis - gravity(q) - D w - c tanh(w / v0), v0 = NOMINAL_COULOMB_VELOCITY (the smooth
  sign: no jump at rest, where the pseudo-derivative velocity is noise); with a learned model on an arm
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
  stays at least v_j where the arm's pose makes the joint heavy (docs/collect.md).

Goal torques become goal currents through each joint's torque constant. Joints that are not
bilateral get no current (they are held in position mode by the servos); their observer estimates are
NaN. The pseudo-derivative velocity is computed for every joint.

The arithmetic of a cycle is a backend's (collect/controller_layout.py declares their interface and the
compiled one's arrays): `NumpyLaw` (collect/controller_numpy.py, the reference: learned models, the dither,
runs on real arms) or `CompiledLaw` (collect/controller_kernel.py: the same operations per joint compiled
with numba, the same bits, one call per cycle instead of some sixty small numpy operations), which a
simulated run takes (numba being loaded there already). `BilateralController` holds the parameters and the
gravity and inertia models, chooses the backend when it is built (`compiled=`) and calls it.
"""

from __future__ import annotations

import math
import sys
import warnings

import numpy as np

from crane_io.description import ArmDescription, default_arm
from crane_io.errors import ConfigError

from . import controller_kernel as kernel
from .config import Config
from .controller_layout import ArmEstimates, ArmSignals, Commands, ControlLaw
from .controller_numpy import NumpyLaw
from .safety import Breach, SafetyMonitor

# rad/s, v0: the nominal observers subtract an identified arm model's Coulomb friction c as c tanh(w / v0)
NOMINAL_COULOMB_VELOCITY = 0.05

__all__ = ["ArmEstimates", "ArmSignals", "BilateralController", "Commands", "GravityModel", "InertiaModel"]


class GravityModel:
    """Motor torque (n,) needed to hold the arm against gravity, for the RFOB."""

    def __init__(self, kind: str, config: Config, arm: ArmDescription, identified=None):
        self.kind = kind
        self.arm = arm
        self.n = len(arm.joints)
        self._dyn = None
        self._dyn_idx = None
        self.unchecked = None  # (pinocchio's gravity, model, data): gravity_torque's call without its checks
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
                self._dyn = ArmDynamics(joints=joints, locked=locked, identified=identified)
                self._dyn_idx = np.array([names.index(n) for n in self._dyn.joint_names])
                if self._dyn._identity:  # the joints in the model's order: gravity_torque's one-pose call
                    import pinocchio

                    self.unchecked = (pinocchio.computeGeneralizedGravity, self._dyn.model, self._dyn.data)
        self._out = np.zeros(self.n)
        # the joints `values` gives, in its order
        self.index = np.array(self._dyn_idx if self.kind == "dynamics" else range(self.n), dtype=np.int64)

    def values(self, q: np.ndarray, checked: bool = True) -> np.ndarray:
        """The torques of the joints `index` covers (the compiled controller's gravity input): those
        `__call__` puts in its (n,) result, the other joints' being 0. checked=False: without the
        dynamics' check that those angles are finite (NaN in, NaN out; the caller checks them)."""
        if self.kind == "dynamics":
            if not checked and self.unchecked is not None:
                f, model, data = self.unchecked
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

    def __init__(self, kind: str, config: Config, arm: ArmDescription, J: np.ndarray, every: int,
                 identified=None):
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
                self._dyn = ArmDynamics(joints=joints, locked=locked, identified=identified)
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


class BilateralController:
    """`step(leader, follower, dt) -> Commands`; estimates of the last step in `.leader` and
    `.follower` (ArmEstimates). Call `applied(tau_leader, tau_follower)` after safety clamps so the
    observers see the torque that really went out (otherwise the unclamped reference is assumed).

    `compiled`: the backend. The compiled one (collect/controller_kernel.py: the same arithmetic, the same
    bits, in one call per cycle) covers the nominal observers without friction dither or an arm model's
    Coulomb friction; True asks for it (a ConfigError when numba is missing, a learned model is given,
    the dither is on or the arm model has Coulomb friction), False takes the numpy reference, None
    (default) the compiled one when it covers the configuration and numba is already loaded in this
    process (a simulated run: the simulator's kernels loaded it), so a run on real
    arms never imports numba for it."""

    def __init__(self, config: Config, arm: ArmDescription | None = None, models: dict | None = None,
                 compiled: bool | None = None, arm_model=None):
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
        # an identified arm model (crane_io.physics.identified_model): its bodies in the gravity and inertia
        # models, its viscous friction as the nominal D and its Coulomb friction c as c tanh(w / v0)
        # (NOMINAL_COULOMB_VELOCITY) in the nominal observers of the joints it covers
        self.arm_model = arm_model
        self.coulomb = None  # (n,) N m: the nominal observers' Coulomb friction (None: none subtracted)
        self.coulomb_velocity = NOMINAL_COULOMB_VELOCITY
        if arm_model is not None:
            if config.controller.gravity_model != "dynamics":
                raise ConfigError("an identified arm model needs controller.gravity_model = \"dynamics\"")
            coulomb = np.zeros(self.n)
            for joint, friction in arm_model.friction.items():
                if joint in names:
                    self.D[names.index(joint)] = friction.get("viscous", self.D[names.index(joint)])
                    coulomb[names.index(joint)] = friction.get("coulomb", 0.0)
            if np.any(coulomb * self.bil != 0.0):
                self.coulomb = coulomb * self.bil
        self.gravity = GravityModel(config.controller.gravity_model, config, self.arm, arm_model)
        self.inertia = InertiaModel(config.controller.inertia_model, config, self.arm, self.J,
                                    config.controller.inertia_update_cycles, arm_model)
        self.held = np.where(self.bil_mask, 0.0, np.nan)  # NaN on the held joints (their estimates)
        self._decay = (None, None, None)  # (g, dt, exp(-g dt)) of the last step (decay)
        c = config.controller
        self.dither_amplitude = float(c.dither_amplitude)
        self.dither_frequency = float(c.dither_frequency)
        self.dither_square = c.dither_wave == "square"
        self.dither_filter = c.dither_filter and self.dither_amplitude > 0.0
        # per joint: dither_amplitude x the joint's `dither` factor, bilateral joints only
        self.dither_amplitudes = self.dither_amplitude * np.array([gains[n].dither for n in names]) * self.bil
        # per joint a velocity floor, |A_j| >= v_j 2 pi f J_j(q) (the follower's inertia this cycle)
        self.dither_floor = (2.0 * np.pi * self.dither_frequency * self.bil
                             * np.array([gains[n].dither_min_velocity for n in names]))
        self._law: ControlLaw = self._choose_law(compiled)

    @property
    def compiled(self) -> bool:
        """Whether the compiled backend runs the cycles."""
        return self._law.compiled

    def _choose_law(self, compiled: bool | None) -> ControlLaw:
        """The backend (see the class docstring)."""
        if compiled is False:
            return NumpyLaw(self)
        why = ("a learned model in an observer" if any(self.models.values())
               else "the friction dither" if self.dither_amplitude > 0.0
               else "an identified arm model's Coulomb friction" if self.coulomb is not None else None)
        if compiled is None and (why is not None or "numba" not in sys.modules):
            return NumpyLaw(self)
        if why is not None:
            raise ConfigError(f"the compiled controller does not run {why}; use compiled=False")
        fns = kernel.compiled()
        if fns is None:
            if compiled:
                raise ConfigError("the compiled controller needs numba (pip install numba)")
            return NumpyLaw(self)
        return kernel.CompiledLaw(self, fns)

    @property
    def leader(self) -> ArmEstimates | None:
        """The leader's estimates of the last cycle (None before the first)."""
        return self._law.leader

    @property
    def follower(self) -> ArmEstimates | None:
        """The follower's estimates of the last cycle (None before the first)."""
        return self._law.follower

    @property
    def dither(self) -> np.ndarray:
        """(n,) N m: the dither added to the follower's last step."""
        return self._law.dither

    def observer(self, arm: str):
        """`arm`'s observer ("leader" or "follower"): z, y, applied (None before the first cycle), J, model
        (its ModelReaction or None), fallback."""
        return self._law.observer(arm)

    def decay(self, dt: float) -> np.ndarray:
        """exp(-g dt), the DOB low-pass factor of a step of dt; the last one is kept (the loop's dt is
        its constant period)."""
        g, (kept_g, kept_dt, kept) = self.g, self._decay
        if g is not kept_g or dt != kept_dt:
            kept = np.exp(-g * dt)
            self._decay = (g, dt, kept)
        return kept

    def reset(self) -> None:
        """Forget the observers' state (a fresh learned model each): the next cycle starts them again."""
        self._law.reset()

    def control(self, leader: ArmSignals, follower: ArmSignals, dt: float, safety: SafetyMonitor
                ) -> tuple[Commands, np.ndarray, np.ndarray, Breach | None]:
        """A bilateral cycle's control: `step`, the safety clamps of both goal torques
        (`safety.limit_torque(q, tau, dq_servo)`), `applied` of what they give, and the safety checks
        (`safety.check` of the leader, then of the follower). Returns (commands, clamped leader torque,
        clamped follower torque, the first breach or None): what those calls give in that order (the
        compiled backend: in one call, the safety monitor's own code only for an arm with a joint in its
        soft zone, past its stop or faster than its guard)."""
        return self._law.control(leader, follower, dt, safety)

    def step(self, leader: ArmSignals, follower: ArmSignals, dt: float) -> Commands:
        """A bilateral cycle: the observers, the 4-channel law (the module's docstring)."""
        return self._law.step(leader, follower, dt)

    def hold(self, leader: ArmSignals, follower: ArmSignals, ref_leader: tuple[np.ndarray, np.ndarray],
             ref_follower: tuple[np.ndarray, np.ndarray], dt: float) -> Commands:
        """Independent position control of each arm to a reference (q (n,), dq (n,)) with the same
        observers (DOB compensation): tau = (J/2) [Kp (q_ref - q) + Kd (dq_ref - w)] + tau_dis (the
        per-arm gains of the bilateral position term; full J Kp is too fast for the observers). Used to
        bring the arms into agreement before bilateral control; the observers carry over seamlessly."""
        return self._law.hold(leader, follower, ref_leader, ref_follower, dt)

    def applied(self, tau_leader: np.ndarray, tau_follower: np.ndarray) -> None:
        """Tell the observers the torques that were actually commanded this cycle."""
        self._law.applied(tau_leader, tau_follower)

    def reaction(self, arm: str):
        """The ModelReaction in `arm`'s observer ("leader" or "follower"), or None (nominal)."""
        return self._law.observer(arm).model

    def model_fallbacks(self) -> dict[str, np.ndarray | None]:
        """{arm: (J,) bool} for the arms with a learned model: which of its joints used the nominal
        reaction torque in the last cycle (None before the first cycle)."""
        out = {}
        for name in ("leader", "follower"):
            obs = self._law.observer(name)
            if obs.model is not None:
                out[name] = obs.fallback
        return out
