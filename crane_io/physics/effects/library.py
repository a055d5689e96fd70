"""The built-in physical effects. See crane_io/physics/effects/base.py for the conventions and
docs/arm-model.md for the table (parameters, units, residual signature). Each one-joint effect with a
closed form defines its torque once, in `formula`: its regressor columns and the control loop's per-sample
torque are that formula; `plant_terms` gives the simulated plant the same torque as the plant's terms
(Coulomb levels, Stribeck terms, viscous, ...), which crane_io.sim.plant_layout evaluates for both of the
plant's steppers."""

from __future__ import annotations

import math

import numpy as np

from crane_io.errors import ConfigError
from crane_io.physics.effects.base import Effect, Param, joint_columns


class Coulomb(Effect):
    name = "coulomb"
    title = "Coulomb friction"
    description = "Constant friction torque opposing motion, the same in both directions: fc sign(dq)."
    signature = "the residual of {joint} steps by a constant amount where its velocity changes sign"
    params = (Param("coulomb", "N m", 0.2, "friction torque while moving"),)
    friction = True

    def formula(self, q, dq, ddq, c, shape, ops):
        return c[0] * ops.sign(dq)

    def static_band(self, values):
        v = self.check_values(values)
        return (abs(v["coulomb"]), abs(v["coulomb"]))

    def plant_terms(self, terms, k, values):
        if not self._same_physics(Coulomb):
            return super().plant_terms(terms, k, values)
        terms.coulomb_pos[k] += values["coulomb"]
        terms.coulomb_neg[k] += values["coulomb"]


class CoulombAsym(Effect):
    name = "coulomb-asym"
    title = "asymmetric Coulomb friction"
    description = ("Friction torque opposing motion with a different size in each direction: "
                   "fc+ when dq > 0, -fc- when dq < 0.")
    signature = ("the residual of {joint} steps where its velocity changes sign, by different amounts "
                 "in the two directions")
    params = (Param("coulomb_pos", "N m", 0.2, "friction while moving in the positive direction"),
              Param("coulomb_neg", "N m", 0.2, "friction (magnitude) while moving in the negative direction"))
    friction = True

    def formula(self, q, dq, ddq, c, shape, ops):
        return (c[0] * ops.positive(dq) + c[1] * ops.positive(-dq)) * ops.sign(dq)

    def static_band(self, values):
        v = self.check_values(values)
        return (abs(v["coulomb_neg"]), abs(v["coulomb_pos"]))

    def plant_terms(self, terms, k, values):
        if not self._same_physics(CoulombAsym):
            return super().plant_terms(terms, k, values)
        terms.coulomb_pos[k] += values["coulomb_pos"]
        terms.coulomb_neg[k] += values["coulomb_neg"]


class Viscous(Effect):
    name = "viscous"
    title = "viscous friction"
    description = "Friction torque proportional to velocity: b dq."
    signature = "the residual of {joint} grows in proportion to its velocity"
    params = (Param("viscous", "N m s/rad", 0.03, "torque per rad/s of velocity"),)

    def formula(self, q, dq, ddq, c, shape, ops):
        return c[0] * dq

    def plant_terms(self, terms, k, values):
        if not self._same_physics(Viscous):
            return super().plant_terms(terms, k, values)
        terms.viscous[k] += values["viscous"]


class Stribeck(Effect):
    name = "stribeck"
    title = "Stribeck friction"
    description = ("Extra friction at low speed that fades as speed grows (on top of Coulomb): "
                   "fs exp(-(dq/vs)^2) sign(dq).")
    signature = ("the residual of {joint} has a spike of the velocity's sign at low speed that fades "
                 "at higher speed")
    params = (Param("stribeck", "N m", 0.1, "extra friction at zero speed"),
              Param("stribeck_velocity", "rad/s", 0.05, "speed at which the extra friction has fallen to 1/e",
                    linear=False))
    shape_grid = {"stribeck_velocity": [0.02, 0.05, 0.1, 0.2, 0.4]}
    friction = True

    def formula(self, q, dq, ddq, c, shape, ops):
        return c[0] * ops.stribeck(dq, max(shape["stribeck_velocity"], 1e-9)) * ops.sign(dq)

    def static_band(self, values):
        v = self.check_values(values)
        return (abs(v["stribeck"]), abs(v["stribeck"]))

    def plant_terms(self, terms, k, values):
        if not self._same_physics(Stribeck):
            return super().plant_terms(terms, k, values)
        _stribeck_term(terms, k, values["stribeck"], values["stribeck_velocity"])


class Stiction(Effect):
    name = "stiction"
    title = "stiction (static friction with breakaway)"
    description = ("A joint at rest stays at rest until the net torque exceeds the breakaway torque; "
                   "once moving, Coulomb friction plus a short decay from breakaway. The simulated plant "
                   "does true stick-slip; the model side is fc sign(dq) + (fb - fc) exp(-(dq/vb)^2) "
                   "sign(dq).")
    signature = ("{joint} stands still while its torque varies (dead zones), and its residual steps where "
                 "the velocity changes sign")
    params = (Param("coulomb", "N m", 0.2, "friction while moving"),
              Param("breakaway", "N m", 0.28, "largest torque the joint resists at rest (>= coulomb)"),
              Param("stiction_velocity", "rad/s", 0.01, "speed over which friction falls from breakaway to "
                    "Coulomb", linear=False))
    shape_grid = {"stiction_velocity": [0.005, 0.01, 0.02, 0.05]}
    friction = True

    def formula(self, q, dq, ddq, c, shape, ops):
        return (c[0] + c[1] * ops.stribeck(dq, max(shape["stiction_velocity"], 1e-9))) * ops.sign(dq)

    def coefficients(self, values):
        v = self.check_values(values)
        return np.array([v["coulomb"], v["breakaway"] - v["coulomb"]])

    def values_from_coefficients(self, coefs, shape=None):
        c = np.asarray(coefs, dtype=float).ravel()
        return {"coulomb": float(c[0]), "breakaway": float(c[0] + c[1]), **self._shape(shape)}

    def column_names(self, joint, shape=None):
        names = super().column_names(joint, shape)
        return [names[0], names[1].replace(".breakaway", ".breakaway_excess")]

    def static_band(self, values):
        v = self.check_values(values)
        b = max(abs(v["breakaway"]), abs(v["coulomb"]))
        return (b, b)

    def plant_terms(self, terms, k, values):
        """Coulomb while moving plus the fall from breakaway as a Stribeck term; the plant's stick-slip
        holds the joint at rest up to the breakaway (static_band)."""
        if not self._same_physics(Stiction):
            return super().plant_terms(terms, k, values)
        terms.coulomb_pos[k] += values["coulomb"]
        terms.coulomb_neg[k] += values["coulomb"]
        _stribeck_term(terms, k, values["breakaway"] - values["coulomb"], values["stiction_velocity"])


class Offset(Effect):
    name = "offset"
    title = "torque offset"
    description = "A constant torque, e.g. a current-sensor offset or a cable pulling one way: c."
    signature = "the residual of {joint} has a constant non-zero mean, whatever the motion"
    params = (Param("offset", "N m", 0.1, "constant torque"),)

    def formula(self, q, dq, ddq, c, shape, ops):
        return c[0]

    def plant_terms(self, terms, k, values):
        if not self._same_physics(Offset):
            return super().plant_terms(terms, k, values)
        terms.offset[k] += values["offset"]


class Spring(Effect):
    name = "spring"
    title = "spring"
    description = ("A torque proportional to the angle away from a rest angle, e.g. a cable harness: "
                   "k (q - q0).")
    signature = "the residual of {joint} grows linearly with its angle"
    params = (Param("stiffness", "N m/rad", 0.5, "torque per rad away from the rest angle"),
              Param("rest_angle", "rad", 0.0, "angle at which the spring is relaxed", linear=False))
    shape_grid = {"rest_angle": [round(x, 3) for x in np.linspace(-1.5, 1.5, 13)]}

    def formula(self, q, dq, ddq, c, shape, ops):
        return ops.spring(q, c[0], shape["rest_angle"])

    def plant_terms(self, terms, k, values):
        if not self._same_physics(Spring):
            return super().plant_terms(terms, k, values)
        terms.springs[k].append((float(values["stiffness"]), float(values["rest_angle"])))


class RotorInertia(Effect):
    name = "rotor-inertia"
    title = "rotor inertia (reflected armature)"
    description = ("The motor rotor and gears seen through the gear ratio add inertia to the joint: Ia ddq. "
                   "On joints whose axis inertia is already a rigid-body base parameter (joint1, "
                   "joint2 in the "
                   "default model) a fitted rigid-body model absorbs it.")
    signature = "the residual of {joint} is proportional to its own acceleration"
    params = (Param("inertia", "kg m^2", 0.01, "reflected rotor inertia"),)

    def formula(self, q, dq, ddq, c, shape, ops):
        return c[0] * ddq

    def plant_terms(self, terms, k, values):
        """Rotor inertia goes into the plant's mass matrix (pinocchio's armature)."""
        if not self._same_physics(RotorInertia):
            return super().plant_terms(terms, k, values)
        terms.armature[k] += values["inertia"]


class Cogging(Effect):
    name = "cogging"
    title = "cogging / torque ripple"
    description = ("A torque ripple periodic in angle: A sin(n q + phi), n cycles per joint "
                   "revolution. Motor "
                   "cogging repeats (cycles per motor revolution) x (gear ratio) times per joint revolution "
                   "(353.5 or 272.5), far above a 25 rad/s filter; gear-train ripple has low n.")
    signature = "the residual of {joint} oscillates periodically with its angle"
    params = (Param("amplitude", "N m", 0.1, "ripple amplitude (from the sin/cos pair)"),
              Param("phase", "rad", 0.0, "ripple phase at q = 0 (from the sin/cos pair)"),
              Param("cycles_per_rev", "1/rev", 12.0, "ripple periods per joint revolution", linear=False))
    shape_grid = {"cycles_per_rev": [4.0, 6.0, 8.0, 12.0, 16.0, 24.0]}
    integer_shapes = ("cycles_per_rev",)

    def formula(self, q, dq, ddq, c, shape, ops):
        return ops.ripple(q, c[0], c[1], shape["cycles_per_rev"])

    def coefficients(self, values):
        v = self.check_values(values)
        return np.array([v["amplitude"] * math.cos(v["phase"]), v["amplitude"] * math.sin(v["phase"])])

    def values_from_coefficients(self, coefs, shape=None):
        c = np.asarray(coefs, dtype=float).ravel()
        return {"amplitude": float(math.hypot(c[0], c[1])), "phase": float(math.atan2(c[1], c[0])),
                **self._shape(shape)}

    def column_names(self, joint, shape=None):
        names = super().column_names(joint, shape)
        return [names[0].replace(".amplitude", ".sin"), names[1].replace(".phase", ".cos")]

    def plant_terms(self, terms, k, values):
        if not self._same_physics(Cogging):
            return super().plant_terms(terms, k, values)
        c = self.coefficients(values)
        terms.cogging.append((k, float(c[0]), float(c[1]), values["cycles_per_rev"]))


class Backlash(Effect):
    name = "backlash"
    title = "gear backlash"
    description = ("A dead band in the gear train: when the torque reverses, the motor crosses the "
                   "gap before "
                   "it drives the link again. The simulated plant models the gap (width) with the motor-side "
                   "inertia; the model side is a simple approximation: the inertia the motor seems to lose "
                   "near a velocity reversal, c ddq exp(-(dq/vr)^2).")
    signature = "the residual of {joint} jumps briefly right after its velocity or torque reverses"
    params = (Param("reversal_inertia", "kg m^2", -0.005, "apparent inertia change near reversals "
                    "(model-side approximation)"),
              Param("reversal_velocity", "rad/s", 0.05, "speed band of the approximation", linear=False),
              Param("width", "rad", 0.0044, "full gap width (0.25 deg spec = 0.0044 rad)", linear=False,
                    model=False),
              Param("motor_inertia", "kg m^2", 0.01, "motor-side (reflected) inertia that crosses the gap",
                    linear=False, model=False))
    shape_grid = {"reversal_velocity": [0.02, 0.05, 0.1, 0.2]}

    def formula(self, q, dq, ddq, c, shape, ops):
        return c[0] * ddq * ops.stribeck(dq, max(shape["reversal_velocity"], 1e-9))

    def plant_terms(self, terms, k, values):
        """The plant simulates the gear gap itself (width, motor_inertia): the motor side is a state of
        its own, coupled to the link when the gap has closed (crane_io.sim.arm_plant)."""
        joint = terms.joints[k]
        if k in terms.backlash:
            raise ConfigError(f"backlash is configured twice for {joint}; give one gap per joint")
        if not (values["width"] >= 0 and values["motor_inertia"] > 0):
            raise ConfigError(f"backlash on {joint} needs width >= 0 rad and motor_inertia > 0 "
                              f"kg m^2, got {values['width']} and {values['motor_inertia']}")
        terms.backlash[k] = (values["width"], values["motor_inertia"])


class _NeedsDynamics(Effect):
    """An effect whose columns come from the rigid-body dynamics (bound lazily to the default
    ArmDynamics of joints 1, 2, 4 unless one is given)."""

    def __init__(self, dynamics=None):
        self._dynamics = dynamics

    @property
    def dynamics(self):
        if self._dynamics is None:
            from crane_io.physics.dynamics import ArmDynamics

            self._dynamics = ArmDynamics()
        return self._dynamics

    def bind(self, dynamics):
        """A copy of this effect that uses `dynamics` (its joints must match the data's columns)."""
        return type(self)(dynamics)

    def _check_dims(self, q):
        if q.shape[1] != self.dynamics.n_joints:
            from crane_io.errors import ConfigError

            raise ConfigError(f"effect {self.name!r} is bound to dynamics of {self.dynamics.n_joints} joints "
                              f"({', '.join(self.dynamics.joint_names)}) but the data has "
                               "{q.shape[1]} columns")


class Payload(_NeedsDynamics):
    name = "payload"
    title = "payload at the tool"
    description = ("A point mass held at the tool (0.08 m beyond the gripper base): its weight and inertia "
                   "load every joint. Linear in the mass. A rigid-body model that fits its own base "
                   "parameters absorbs it (a point mass only changes the last body's parameters); it shows "
                   "against a model with fixed nominal parameters.")
    signature = ("the residual of every joint follows the gravity torque of the forearm, largest "
                 "with the arm "
                 "stretched out horizontally")
    params = (Param("mass", "kg", 0.2, "payload mass"),)
    scope = "arm"

    def _columns(self, q, dq, ddq, joint, shape):
        self._check_dims(q)
        return self.dynamics.payload_torque(q, dq, ddq, 1.0)[:, :, None]

    def plant_terms(self, terms, k, values):
        """The payload goes into the plant's rigid-body dynamics (a point mass at the tool)."""
        terms.payload += values["mass"]


class TorqueConstantError(_NeedsDynamics):
    name = "torque-constant-error"
    title = "torque-constant error"
    description = ("The recorded torque is goal current x the configured torque constant; if the "
                   "true constant "
                   "differs, the recorded torque is (1 + e) x the torque really applied, e = "
                   "Kt_cfg/Kt_true - 1. "
                   "Model side (first order): e x the nominal rigid-body torque of the joint (URDF "
                   "parameters).")
    signature = ("the residual of {joint} is proportional to its own torque (gravity load and acceleration "
                 "together)")
    params = (Param("scale_error", "1", 0.1, "Kt_cfg / Kt_true - 1"),)

    def _columns(self, q, dq, ddq, joint, shape):
        self._check_dims(q)
        return joint_columns(len(q), q.shape[1], joint, self.dynamics.inverse_dynamics(q, dq, ddq)[:, joint])

    def plant_terms(self, terms, k, values):
        """The plant's true torque constant is the configured one / (1 + e)."""
        joint = terms.joints[k]
        terms.torque_constant[joint] = terms.torque_constant[joint] / (1.0 + values["scale_error"])


def _stribeck_term(terms, k: int, amplitude: float, velocity: float) -> None:
    """A Stribeck-type term exp(-(v/vs)^2) sign(v) of the plant's kinetic friction (none when zero)."""
    if amplitude != 0:
        terms.stribeck[k].append((float(amplitude), max(velocity, 1e-6)))


BUILTIN_EFFECTS: tuple[type[Effect], ...] = (
    Coulomb, CoulombAsym, Viscous, Stribeck, Stiction, Offset, Spring, Payload, RotorInertia, Cogging,
    Backlash, TorqueConstantError,
)
