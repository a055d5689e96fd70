"""The simulated CRANE-X7 arm: the physics behind the simulated servo chain for all 8 servos.

The integrated joints (`joints`: any of joint1..joint7, default the config's `joints` key, whose own
default is the paper's joint1, joint2, joint4) are integrated with the n-DOF pinocchio dynamics
(crane_io.physics.dynamics; the other joints locked at the configured angles), plus the configured physical
effects (crane_io.physics.effects), plus the actuator, plus the external torque (an operator's hand):

    M(q) ddq + C(q, dq) dq + g(q) + tau_effects(q, dq) + friction = Kt_true * I + tau_ext

- Actuator: current mode -> torque = Kt_true x goal current (the chain already clamped it to the
  Current Limit); position modes -> the servo's PD controller (as in crane_io.sim.simple_plant);
  torque off -> no motor torque: the joint is back-drivable (gravity + friction only).
- Rotor inertia goes into the mass matrix (pinocchio's armature); a payload into the dynamics.
- Friction effects (coulomb, coulomb-asym, stribeck, stiction, user effects with friction=True) do
  true stick-slip, resolved every substep (default 0.25 ms): a joint at rest stays EXACTLY at rest
  while the friction needed to hold it (the net of motor, gravity, coupling, external and other
  effect torques) lies inside its static band (sum of the effects' static levels, e.g. the
  breakaway torque); beyond it the joint breaks away and kinetic friction applies. A moving joint
  whose velocity would change sign in a substep stops at zero and is tested for sticking again.
  Several joints may stick at once; the coupled system is solved with the stuck joints' accelerations
  held at zero (semi-implicit Euler: velocity first, then position).
- Backlash (optional, per joint): the motor side (its own inertia `motor_inertia`, in link-side units)
  and the link are coupled only when the gear gap of `width` rad has closed, by a stiff unilateral
  spring-damper; inside the gap the motor torque moves only the motor, and the link coasts. The
  servo's encoder is on the output shaft, so Present Position is the link angle.
- Joint limits are stiff end stops (spring-damper) just beyond the description's limits.
- Every effect is compiled from its effect object (Effect.add_to_plant: the effect adds its closed
  form to a PlantTerms, or asks to be evaluated generically every substep); an effect or a joint wall
  on a joint the plant does not integrate is refused (ConfigError).
- Held joints (the others and the gripper) follow their servos with crane_io.sim.simple_plant-like
  followers (position controller or current, no gravity: they are locked in the dynamics).
- Sensors: position to the 4096-count grid is done by the chain; the plant adds an occasional
  one-count error, velocity noise and current noise (PlantConfig.sensor); present current is the
  motor torque / Kt_true.
- Overload (optional): a joint whose goal current sits at its Current Limit for `overload.time_s`
  gets Hardware Error Status bit 5; it stays set (the chain's Shutdown logic turns torque off).
- Contact (optional, the config's [[environment]]: joint walls and planes, crane_io.sim.environment): the
  objects' torque on the integrated joints is added to the external torque in every substep, so
  stick-slip friction sees it. `contact_torque()` and `in_contact` give it at the end of the last
  step. A plant without objects computes exactly what it did before they existed.

The truth (effects and parameters) is available as `truth()` / `write_truth(path)` only.
"""

from __future__ import annotations

import json
import math
import os
import struct
import warnings
from operator import add, sub
from pathlib import Path

import numpy as np
import pinocchio as pin

from crane_io.description import default_arm
from crane_io.dynamixel.units import AMPERE_PER_CURRENT_LSB, RAD_PER_PULSE, RADS_PER_VELOCITY_LSB
from crane_io.errors import ConfigError
from crane_io.physics.dynamics import ArmDynamics
from crane_io.physics.effects import PlantTerms
from crane_io.sim import chain_kernel, noise_kernel, plant_kernel
from crane_io.sim.environment import Environment
from crane_io.sim.plant_api import ActuatorCommand, SensorReading
from crane_io.sim.plant_config import ARM_JOINTS, PlantConfig, check_joints, load_plant_config
from crane_io.sim.simple_plant import DEFAULT_INERTIA, DEFAULT_VISCOUS, SimplePlant

_PULSE_SIGNS = np.array((-RAD_PER_PULSE, RAD_PER_PULSE))  # one-pulse position noise
_TWO_TO_MINUS_53 = 1.0 / 9007199254740992.0  # Generator.random: (64-bit output >> 11) x 2**-53
_EMPTY_U64, _EMPTY_F64 = np.zeros(0, dtype=np.uint64), np.zeros(0)


def _SUBSTEP_KEY(n: int) -> struct.Struct:  # noqa: N802 (it names a struct, as it did for 3 joints)
    """The struct packing a substep's inputs for n joints (q, dq, motor and external torque, h), bit exact."""
    key = _SUBSTEP_KEYS.get(n)
    if key is None:
        key = _SUBSTEP_KEYS[n] = struct.Struct(f"<{4 * n + 1}d")
    return key


_SUBSTEP_KEYS: dict[int, struct.Struct] = {}

OVERLOAD_BIT = 0x20
_HELD_OMEGA = 30.0  # rad/s: held joints follow their goal as a critically damped 2nd-order system
_STOP_MARGIN = math.radians(2.0)  # end stops sit this far beyond the software limits
_CONTACT_OMEGA_H = 0.25  # backlash contact: natural frequency on the motor inertia x substep
_CONTACT_DAMPING_RATIO = 1.5
# joint kinds the kernel takes: their axis (None: the model's)
_REVOLUTE = {"JointModelRX": (1.0, 0.0, 0.0), "JointModelRY": (0.0, 1.0, 0.0),
             "JointModelRZ": (0.0, 0.0, 1.0), "JointModelRevoluteUnaligned": None}
_SKL_INERTIA = dict(zip(("joint1", "joint2", "joint3", "joint4", "joint5", "joint6", "joint7", "gripper"),
                        DEFAULT_INERTIA))


class ArmPlant:
    """The simulated CRANE-X7 (see module docstring). `config`: a PlantConfig, a preset name or a
    TOML path (default "crane-x7"); `seed`: the sensor-noise seed (default: the config's); `joints`:
    the joints integrated with the rigid-body dynamics (any of joint1..joint7, put in arm order;
    default the config's `joints`, itself by default joint1, joint2, joint4); `kernel`: integrate with
    the compiled substep kernel (crane_io.sim.plant_kernel) or with the reference path (pinocchio calls
    and Python floats per substep). Default: the kernel when numba is installed and the plant has no
    backlash, user-defined effect or [[environment]] object (those run on the reference path), unless
    the environment variable CRANE_PLANT_KERNEL is "0" (then always the reference path). The two agree
    to rounding, not bit for bit (see crane_io.sim.plant_kernel)."""

    def __init__(self, config: PlantConfig | str | Path | None = None, seed: int | None = None,
                 joints=None, kernel: bool | None = None):
        if not isinstance(config, PlantConfig):
            config = load_plant_config("crane-x7" if config is None else config)
        self.config = config
        self.seed = config.seed if seed is None else int(seed)
        self.rng = np.random.default_rng(self.seed)
        joints = check_joints(config.joints if joints is None else joints, "ArmPlant joints")
        self.joints = joints
        n_int = len(joints)
        self._check_objects()
        arm = default_arm()
        self.arm = arm
        self.servo_ids = arm.servo_ids
        names = arm.joint_names
        self._bi = np.array([names.index(n) for n in joints])
        self._held = np.array([i for i in range(len(names)) if names[i] not in joints])
        self._held_names = tuple(names[i] for i in self._held)
        self._compile_effects()
        self._kt_l = self.kt.tolist()  # (torque-constant-error is applied by _compile_effects)
        self._held_kt_l = self.kt[self._held].tolist()
        self._bi_l, self._held_l = self._bi.tolist(), self._held.tolist()
        self._bi_mask = sum(1 << i for i in self._bi_l)  # bit i: servo i drives an integrated joint
        self._bi_a = self._held_a = None  # read_arrays' index arrays, made at first use
        self._kt_kept = (None, None)  # read_arrays: _kt_l and the array of it
        self._chain_fns = None  # read_arrays: chain_kernel.compiled(), loaded at first use
        locked = {n: v for n, v in config.locked.items() if n not in joints}  # an integrated joint is free
        self.dyn = ArmDynamics(joints, locked=locked, payload_mass=self._payload)
        self.model = self.dyn.model
        self.model.armature = self._armature.copy()
        self.data = self.model.createData()
        lo = np.array([arm.joint(n).lower for n in joints]) - _STOP_MARGIN
        hi = np.array([arm.joint(n).upper for n in joints]) + _STOP_MARGIN
        self._lo, self._hi = lo, hi
        self._lo_l, self._hi_l = lo.tolist(), hi.tolist()
        self._k_stop, self._d_stop = config.limits.stiffness, config.limits.damping
        init = np.array([config.initial.get(n, 0.0) for n in names])
        self.q = init[self._bi].copy()
        self.dq = np.zeros(n_int)
        # motor side of the joints with backlash (link-side units: motor angle / gear ratio), centred
        # in the gap
        self.motor_q, self.motor_dq = self.q.tolist(), [0.0] * n_int
        self.h = config.substep_s
        self._key = _SUBSTEP_KEY(n_int)
        self._joint_range = tuple(range(n_int))
        self._euler, self._drive, self._mirror = _written_out(n_int)
        # PD controller of the integrated servos in position modes (SimplePlant's servo model: the
        # joint's nominal inertia, the servo's stall torque)
        self._pd = SimplePlant(servo_ids=tuple(self.servo_ids[i] for i in self._bi),
                               inertia=[_SKL_INERTIA[n] for n in joints], viscous=0.0, coulomb=0.0,
                               kt=self.kt[self._bi],
                               stall_torque=[10.6 if arm.joint(n).model == "XM540-W270" else 4.1
                                             for n in joints])
        self._held_q = init[self._held].copy()
        self._held_dq = np.zeros(len(self._held))
        self._held_current = np.zeros(len(self._held))
        self._held_ext = np.zeros(len(self._held))
        self._held_inertia = np.array([DEFAULT_INERTIA[i] for i in self._held])
        self._held_visc = np.array([DEFAULT_VISCOUS[i] for i in self._held])
        self._held_lo = np.array([arm.joint(n).lower - _STOP_MARGIN for n in self._held_names])
        self._held_hi = np.array([arm.joint(n).upper + _STOP_MARGIN for n in self._held_names])
        self._held_lo_l, self._held_hi_l = self._held_lo.tolist(), self._held_hi.tolist()
        self._held_inertia_l, self._held_visc_l = self._held_inertia.tolist(), self._held_visc.tolist()
        self._held_cache: dict[float, tuple[float, float, float, float]] = {}
        self.external = np.zeros(n_int)
        self._external_all = np.zeros(len(names))  # the last set_external_torque, joint order
        self.environment = list(config.environment)  # the parsed [[environment]] objects
        self._env = (Environment(self.environment, model=self.model, joints=joints)
                     if self.environment else None)
        self._contact = np.zeros(n_int)  # the objects' torque at the end of the last step
        self._in_contact = False
        self.motor_torque = np.zeros(n_int)
        self._saturated_time = np.zeros(len(names))
        self._errors: dict[int, int] = {}
        self.time = 0.0
        self._last_key, self._last_out = b"", None  # the last substep's inputs and result (_substep)
        self._raw_signs_ok = None  # the generator _pulse_signs may read raw (see there)
        self._rng_kept = None  # kernel_cycle_args: the generator and its pointers (noise_kernel.RngPointers)
        # per-joint parameters of the substep's scalar loops: (Coulomb +, Coulomb -, Stribeck terms) and
        # (viscous, offset, spring stiffness, stiffness x rest angle, lower stop, upper stop)
        self._kinetic_l = [(self._fc_pos_l[i], self._fc_neg_l[i], tuple(self._strib_l[i]))
                           for i in range(n_int)]
        self._other_l = list(zip(self._visc_l, self._offset_l, self._spring_k_l, self._spring_q0k_l,
                                 self._lo_l, self._hi_l))
        self._kstep = None  # the compiled kernel's step, when this plant uses it
        required = kernel is True
        if kernel is None:
            kernel = os.environ.get("CRANE_PLANT_KERNEL", "1") != "0" and self._kernel_fits()
        elif kernel and not self._kernel_fits():
            raise ConfigError("the compiled plant kernel does not simulate backlash, user-defined effects or "
                              "[[environment]] objects; use kernel=False for this plant")
        if kernel:
            fns = plant_kernel.compiled()
            if fns is None and required:
                raise ConfigError("the compiled plant kernel needs numba (pip install numba)")
            if fns is not None:
                self._kstep_arm, self._kstep = fns[0], fns[1]
                self._kernel_arrays()
                try:  # load (or compile) it now, with this plant's own argument types: no surprise later
                    self._kstep_arm(self.q, self.dq, self._held_q, self._held_dq, np.zeros((5, len(names))),
                                    self._kpd0, self.external, self._held_ext, self.h, 0, self.h,
                                    np.array(self._held_matrix(self.h)), self._kgeo, self._karm, self._kpar,
                                    self._kcog, self._kscal, self._khpar)
                except Exception as exc:  # e.g. a numba that cannot compile it here: the reference path
                    if required:
                        raise
                    warnings.warn(f"the compiled plant kernel is not usable here ({type(exc).__name__}: "
                                  f"{exc}); the plant integrates on its reference path", stacklevel=2)
                    self._kstep = None

    # ---- the compiled kernel -------------------------------------------------------------------------
    def _kernel_fits(self) -> bool:
        """The kernel's model covers this plant: a serial chain of revolute joints, effects in closed form."""
        if self._backlash or self._generic or self.environment:
            return False
        m = self.model
        return all(m.parents[i] == i - 1 and m.joints[i].shortname() in _REVOLUTE
                   for i in range(1, m.njoints))

    def _kernel_arrays(self) -> None:
        """The kernel's parameter arrays (crane_io.sim.plant_kernel's layouts) from the model and effects."""
        k = plant_kernel
        m, n = self.model, len(self.joints)
        geo = np.zeros((n, k.GEO_COLS))
        for i in range(n):
            placement, inertia = m.jointPlacements[i + 1], m.inertias[i + 1]
            geo[i, k.G_R:k.G_R + 9] = placement.rotation.ravel()
            geo[i, k.G_P:k.G_P + 3] = placement.translation
            kind = m.joints[i + 1].shortname()
            geo[i, k.G_AX:k.G_AX + 3] = (_REVOLUTE[kind] if _REVOLUTE[kind] is not None
                                         else m.joints[i + 1].extract().axis)
            geo[i, k.G_M] = inertia.mass
            geo[i, k.G_C:k.G_C + 3] = inertia.lever
            geo[i, k.G_I:k.G_I + 9] = inertia.inertia.ravel()
        n_strib = max([len(s) for s in self._strib_l] + [0])
        par = np.zeros((n, k.P_STRIB + 2 * n_strib))
        for i in range(n):
            par[i, :k.P_STRIB] = (self._fc_pos_l[i], self._fc_neg_l[i], self._band_pos_l[i],
                                  self._band_neg_l[i], self._visc_l[i], self._offset_l[i],
                                  self._spring_k_l[i], self._spring_q0k_l[i], self._lo_l[i], self._hi_l[i],
                                  self._kt_l[self._bi_l[i]], self._bi_l[i], len(self._strib_l[i]))
            for j, (amp, vs) in enumerate(self._strib_l[i]):
                par[i, k.P_STRIB + 2 * j:k.P_STRIB + 2 * j + 2] = amp, vs
        self._kgeo, self._kpar = geo, par
        self._karm = m.armature  # a view of the model's vector (kept live: a test may change it)
        self._kcog = np.array(self._cogging, dtype=float).reshape(-1, 4)
        self._kscal = np.array([self._k_stop, self._d_stop, *m.gravity.linear, _HELD_OMEGA])
        self._khpar = np.array([(kt, inertia, visc, lo, hi, s) for kt, inertia, visc, lo, hi, s in zip(
            self._held_kt_l, self._held_inertia_l, self._held_visc_l, self._held_lo_l, self._held_hi_l,
            self._held_l)], dtype=float).reshape(-1, k.HELD_COLS)
        self._kpd0 = np.zeros((n, 6))  # no servo PD
        self._khmat: dict[float, np.ndarray] = {}
        # the same parameters packed for the simulated chain's compiled lockstep cycle (crane_io.sim.
        # lockstep_kernel's layout): one float array and its int64 layout, with the servo indices
        parts = (geo, par, self._kcog, self._kscal, self._khpar, self._kpd0)
        offsets = np.cumsum([0] + [p.size for p in parts])[:-1].tolist()
        self._kpack = np.concatenate([p.ravel() for p in parts])
        self._klay = np.array([n, len(self._held_l), par.shape[1], self._kcog.shape[0], *offsets, *self._bi_l,
                               *self._held_l], dtype=np.int64)
        self._kdt: dict[float, tuple] = {}  # dt -> (substep, its hmat, n_sub, dt / n_sub)
        self._kst = self._kviews = None  # the packed state and its views (_kernel_state)
        self._supply_lists = ([12.0] * len(self.servo_ids), [35.0] * len(self.servo_ids))  # (never changed)

    @property
    def kernel(self) -> bool:
        """True when this plant integrates with the compiled kernel (crane_io.sim.plant_kernel)."""
        return self._kstep is not None

    # ---- effects -> arrays ---------------------------------------------------------------------------
    def _check_objects(self) -> None:
        """Every joint effect and joint wall of the config is on an integrated joint (else ConfigError)."""
        for spec in self.config.all_effects:
            if spec.joint is not None and spec.joint not in self.joints:
                wanted = [j for j in ARM_JOINTS if j in self.joints or j == spec.joint]
                raise ConfigError(f"effect {spec.effect!r} acts on {spec.joint}, which this plant holds as a "
                                  f"servo instead of integrating it; integrate {spec.joint} (joints = "
                                  f"{wanted!r}) or remove the effect")
        for obj in self.config.environment:
            joint = getattr(obj, "joint", None)
            if joint is not None and joint not in self.joints:
                raise ConfigError(f"the joint wall on {joint} needs {joint} integrated, but this plant "
                                  f"holds it as a servo; integrate {joint} or remove the wall")

    def _compile_effects(self):
        """Every configured effect adds its own contribution to the plant's terms (Effect.add_to_plant),
        in configuration order; the terms become the substep's per-joint parameters."""
        names = self.arm.joint_names
        n = len(self.joints)
        index = {name: k for k, name in enumerate(self.joints)}
        terms = PlantTerms(self.joints, {name: float(self.config.torque_constant[name]) for name in names})
        for spec in self.config.all_effects:
            eff = spec.build()  # the library's, or the plant's own from its definition (data)
            eff.add_to_plant(terms, index[spec.joint] if spec.joint is not None else None,
                             eff.check_values(spec.values))
        self.terms = terms
        self.kt = np.array([terms.torque_constant[name] for name in names], dtype=float)
        self._armature = np.array(terms.armature)
        self._payload = terms.payload
        self._cogging = list(terms.cogging)
        self._generic = list(terms.generic)
        self._zero_row = np.zeros((1, n))
        self._fc_pos_l, self._fc_neg_l = list(terms.coulomb_pos), list(terms.coulomb_neg)
        self._band_pos_l, self._band_neg_l = list(terms.band_pos), list(terms.band_neg)
        self._strib_l = [list(t) for t in terms.stribeck]
        self._visc_l, self._offset_l = list(terms.viscous), list(terms.offset)
        self._spring_k_l, self._spring_q0k_l = list(terms.spring_k), list(terms.spring_q0k)
        backlash = terms.backlash
        # backlash: (joint, half gap, motor inertia, contact stiffness, contact damping). The contact is
        # a stiff unilateral spring-damper sized to the substep h: natural frequency x h = 0.25 on the
        # motor inertia, damping ratio 1.5 (stable for semi-implicit Euler; a torque step through a
        # closed gear overshoots by < 9 %). It yields 1e-4 rad per N m for J_m = 0.01 kg m^2 at
        # h = 0.25 ms (2 % of the 0.0044 rad gap).
        h = self.config.substep_s
        self._backlash = []
        for k, (width, jm) in sorted(backlash.items()):
            stiffness = jm * (_CONTACT_OMEGA_H / h) ** 2
            self._backlash.append((k, 0.5 * width, jm, stiffness,
                                   2 * _CONTACT_DAMPING_RATIO * math.sqrt(stiffness * jm)))

    # ---- forces (the hot path: plain Python floats per integrated joint, pinocchio for the arm) --------
    def _kinetic(self, i: int, v: float) -> float:
        """Kinetic friction of joint i at velocity v (v = +-tiny for a joint breaking away)."""
        fc_pos, fc_neg, stribeck = self._kinetic_l[i]
        if v > 0:
            f = fc_pos
        elif v < 0:
            f = -fc_neg
        else:
            return 0.0
        for amp, vs in stribeck:
            x = v / vs
            f += math.copysign(amp * math.exp(-x * x), v)
        return f

    def _other_torque(self, q, dq) -> list:
        """Non-friction effect torques and end stops (inverse-dynamics sense), per joint."""
        out = []
        k_stop, d_stop = self._k_stop, self._d_stop
        for qi, dqi, (visc, offset, spring_k, spring_q0k, lo, hi) in zip(q, dq, self._other_l):
            t = visc * dqi + offset + spring_k * qi - spring_q0k
            if qi < lo:
                t += k_stop * (qi - lo) + d_stop * dqi
            elif qi > hi:
                t += k_stop * (qi - hi) + d_stop * dqi
            out.append(t)
        for k, a, b, n in self._cogging:
            out[k] += a * math.sin(n * q[k]) + b * math.cos(n * q[k])
        return out

    def _generic_torques(self, q: list, dq: list) -> tuple[list, list]:
        """(non-friction, friction) torques of user-defined effects."""
        qa, dqa = np.array([q]), np.array([dq])
        n = len(q)
        nf, fr = [0.0] * n, [0.0] * n
        for eff, k, v in self._generic:
            t = eff.torque(qa, dqa, self._zero_row, k, v)[0].tolist()
            tgt = fr if eff.friction else nf
            for i in range(n):
                tgt[i] += t[i]
        return nf, fr

    # ---- Plant protocol ------------------------------------------------------------------------------
    def step(self, command: ActuatorCommand, dt: float) -> None:
        self.step_lists(np.asarray(command.torque_enabled, dtype=bool).tolist(),
                        np.asarray(command.operating_mode).tolist(),
                        np.asarray(command.goal_current, dtype=float).tolist(),
                        np.asarray(command.goal_position, dtype=float).tolist(),
                        np.asarray(command.position_gains, dtype=float).tolist(),
                        np.asarray(command.current_limit, dtype=float).tolist(), dt)

    def step_lists(self, en_l, mode_l, gc_l, gp_l, gains_l, lim_l, dt: float) -> None:
        """`step` with the ActuatorCommand's fields as sequences in servo order (torque enabled, operating
        mode, goal current A, goal position rad, (P, I, D) gains, current limit A): the simulated chain
        hands them over without arrays in between."""
        if dt <= 0:
            return
        if self.config.overload.enabled:
            self._overload(np.array(en_l, dtype=bool), np.array(mode_l), np.array(gc_l, dtype=float),
                           np.array(lim_l, dtype=float), dt)
        if self._kstep is not None:
            self._step_kernel(en_l, mode_l, gc_l, gp_l, gains_l, lim_l, dt)
            return
        # per joint in plain Python (8 values: cheaper than numpy's fancy indexing and reductions; the
        # same IEEE operations, so the same results)
        held = self._held_l
        self._step_held([en_l[i] for i in held], [mode_l[i] for i in held], [gc_l[i] for i in held],
                        [gp_l[i] for i in held], [lim_l[i] for i in held], dt)
        bi = self._bi_l
        kt = self._kt_l
        current_mode = [bool(en_l[i]) and mode_l[i] == 0 for i in bi]
        position_mode = any(en_l[i] and mode_l[i] != 0 for i in bi)
        tau_l = [kt[i] * gc_l[i] if cm else 0.0 for i, cm in zip(bi, current_mode)]
        pd = None  # per joint: (kp, kd, -cap, cap, goal) of a servo in a position mode, else None
        if position_mode:
            def pick(values, dtype=float):  # the integrated joints' entries as an array
                return np.array([values[i] for i in bi], dtype=dtype)

            bi_cmd = ActuatorCommand(pick(en_l, bool), pick(mode_l, None), pick(gc_l), pick(gp_l),
                                     pick(gains_l), pick(lim_l))
            pos, kp, kd, cap = self._pd.position_controller(bi_cmd)
            if kp is not None:
                pd = [(a, b, -c, c, float(g)) if p else None
                      for p, a, b, c, g in zip(pos.tolist(), kp.tolist(), kd.tolist(), cap.tolist(),
                                               bi_cmd.goal_position)]
        tau_base = tau_l  # current mode: Kt x goal current; otherwise none
        n_sub = max(1, math.ceil(dt / self.h - 1e-9))
        h = dt / n_sub
        ext = self.external.tolist()
        q, dq = self.q.tolist(), self.dq.tolist()
        for _ in range(n_sub):
            if pd is not None:  # the servo's PD (SimplePlant.motor_torque, the same operations in floats)
                tau_l = [b if c is None else _clip(c[0] * (c[4] - qi) - c[1] * dqi, c[2], c[3])
                         for c, b, qi, dqi in zip(pd, tau_base, q, dq)]
            q, dq = self._substep(q, dq, tau_l, ext, h)
        self.q, self.dq = np.array(q), np.array(dq)
        if self._env is not None:
            self._contact = np.array(self._env.torque_list(q, dq))
            self._in_contact = self._env.in_contact(self.q)
        self.motor_torque = np.array(tau_l)
        self.time += dt

    def _step_kernel(self, en_l, mode_l, gc_l, gp_l, gains_l, lim_l, dt: float) -> None:
        """step_lists on the compiled kernel: held and integrated joints in one call (step_arm)."""
        bi = self._bi_l
        pd = self._kpd0
        if any(en_l[i] and mode_l[i] != 0 for i in bi):  # the servos' PD (as step_lists computes it)
            def pick(values, dtype=float):
                return np.array([values[i] for i in bi], dtype=dtype)

            bi_cmd = ActuatorCommand(pick(en_l, bool), pick(mode_l, None), pick(gc_l), pick(gp_l),
                                     pick(gains_l), pick(lim_l))
            pos, kp, kd, cap = self._pd.position_controller(bi_cmd)
            if kp is not None:
                pd = np.array([(1.0, a, b, -c, c, float(g)) if p else (0.0,) * 6
                               for p, a, b, c, g in zip(pos.tolist(), kp.tolist(), kd.tolist(), cap.tolist(),
                                                        bi_cmd.goal_position)])
        hmat = self._khmat.get(dt)
        if hmat is None:
            hmat = self._khmat[dt] = np.array(self._held_matrix(dt))
        n_sub = max(1, math.ceil(dt / self.h - 1e-9))
        out = self._kstep_arm(self.q, self.dq, self._held_q, self._held_dq,
                              np.array((en_l, mode_l, gc_l, gp_l, lim_l), dtype=float), pd, self.external,
                              self._held_ext, dt / n_sub, n_sub, dt, hmat, self._kgeo, self._karm, self._kpar,
                              self._kcog, self._kscal, self._khpar)
        n, k = len(bi), len(self._held_l)
        b = 3 * n
        self.q, self.dq, self.motor_torque = out[:n], out[n:2 * n], out[2 * n:b]
        self._held_q, self._held_dq, self._held_current = out[b:b + k], out[b + k:b + 2 * k], out[b + 2 * k:]
        self.time += dt

    def _substep(self, q, dq, tau_m, ext, h: float) -> tuple:
        """One substep: ((q), (dq)) as tuples of n floats. Without backlash (motor-side state) and user
        effects, a substep is a pure function of its inputs: a joint set standing still (stuck) under an
        unchanged torque gives the same inputs substep after substep, so the last result is reused when
        the inputs are the same bits (pinocchio and the float arithmetic are deterministic: nothing
        changes)."""
        if self._backlash or self._generic:
            return self._substep_compute(q, dq, tau_m, ext, h)
        key = self._key.pack(*q, *dq, *tau_m, *ext, h)
        if key != self._last_key:
            self._last_key, self._last_out = key, self._substep_compute(q, dq, tau_m, ext, h)
        return self._last_out

    def _substep_compute(self, q, dq, tau_m, ext, h: float) -> tuple:
        if self._backlash:
            tau_m = self._gear_gap(q, dq, tau_m, h)
        if self._env is not None:  # the objects push like a hand: a pure function of q, dq
            ext = list(map(add, ext, self._env.torque_list(q, dq)))
        other = self._other_torque(q, dq)
        gen_fr = None
        if self._generic:
            gen_nf, gen_fr = self._generic_torques(q, dq)
            other = list(map(add, other, gen_nf))
        drive = self._drive(tau_m, ext, other)
        qa, dqa = np.array(q), np.array(dq)
        if 0.0 not in dq:  # every joint moves (== : -0.0 is at rest too)
            kinetic = self._kinetic
            f = [kinetic(i, v) for i, v in enumerate(dq)]
            if gen_fr is not None:
                f = list(map(add, f, gen_fr))
            net = np.array(list(map(sub, drive, f)))
            ddq = pin.aba(self.model, self.data, qa, dqa, net).tolist()
        else:
            ddq = self._stick_slip(qa, dqa, dq, drive, gen_fr)
        # semi-implicit Euler: velocity first, then position; friction stops a joint, it never reverses
        # it within a substep
        return self._euler(q, dq, ddq, h)

    def _gear_gap(self, q: list, dq: list, tau_m: list, h: float) -> list:
        """Backlash: the motor drives its own inertia; the link only gets the torque the gear passes
        on once the gap has closed (unilateral contact). Steps the motor side by one substep and
        returns the torques that reach the links."""
        tau = list(tau_m)
        mq, mdq = self.motor_q, self.motor_dq
        for i, half, jm, stiffness, damping in self._backlash:
            d = mq[i] - q[i]
            if d > half:
                tc = max(0.0, stiffness * (d - half) + damping * (mdq[i] - dq[i]))
            elif d < -half:
                tc = min(0.0, stiffness * (d + half) + damping * (mdq[i] - dq[i]))
            else:
                tc = 0.0
            mdq[i] += h * (tau_m[i] - tc) / jm
            mq[i] += h * mdq[i]
            tau[i] = tc
        return tau

    def _stick_slip(self, qa, dqa, dq, drive: list, gen_fr) -> list:
        """Accelerations when some joint stands still: the stuck joints are held while the friction needed
        to hold each lies inside its static band; the joint pushed furthest beyond its band breaks away
        first, in that direction (then the others are tested again)."""
        m = pin.crba(self.model, self.data, qa).tolist()  # the upper triangle; mirror it
        self._mirror(m)
        nle = pin.nonLinearEffects(self.model, self.data, qa, dqa).tolist()
        rhs = list(map(sub, drive, nle))
        free = [v != 0.0 for v in dq]
        vel = list(dq)  # velocity used for friction: tiny in the break-away direction
        kinetic, band_pos, band_neg = self._kinetic, self._band_pos_l, self._band_neg_l
        joints = self._joint_range
        n = len(joints)
        for _ in range(n + 1):  # each pass returns or frees one joint
            idx = [i for i in joints if free[i]]
            ddq = [0.0] * n
            if idx:
                net = []  # drive beyond the free joints' kinetic friction
                for a in idx:
                    f = kinetic(a, vel[a])
                    if gen_fr is not None:
                        f = f + gen_fr[a]
                    net.append(rhs[a] - f)
                for a, x in zip(idx, _solve_free(m, idx, net)):
                    ddq[a] = x
            worst, worst_excess, push = -1, 0.0, 0.0
            for s in joints:
                if free[s]:
                    continue
                coupled = 0  # sum(m[s][a] * ddq[a] for a in idx), added up as sum() does
                for a in idx:
                    coupled = coupled + m[s][a] * ddq[a]
                hold = rhs[s] - coupled  # friction needed to hold joint s
                above, below = hold - band_pos[s], -band_neg[s] - hold
                excess = below if below > above else above  # max(above, below)
                if excess > worst_excess:
                    worst, worst_excess, push = s, excess, hold
            if worst < 0:
                return ddq
            # the joint pushed furthest beyond its static band breaks away first, in that direction
            free[worst] = True
            vel[worst] = 1e-12 if push > 0 else -1e-12
        return ddq

    def _step_held(self, enabled, mode, goal_current, goal_position, limit, dt) -> None:
        """Held joints: position modes -> a critically damped second-order response to the goal
        (exact discretisation); current mode -> inertia + viscous friction; torque off -> at rest.
        The commands are lists over the held joints.

        Scalar Python over the held joints (cheaper than numpy on arrays this small); the arithmetic
        is the element-wise arithmetic of the array form, in the same order."""
        a00, a01, a10, a11 = self._held_matrix(dt)
        w = _HELD_OMEGA
        q_out, dq_out, cur_out = [], [], []
        for on, m, gc, gp, lim, q, dq, kt, inertia, visc, ext, lo, hi in zip(
                enabled, mode, goal_current, goal_position, limit, self._held_q.tolist(),
                self._held_dq.tolist(), self._held_kt_l,
                self._held_inertia_l, self._held_visc_l, self._held_ext.tolist(), self._held_lo_l,
                self._held_hi_l):
            current = 0.0
            if on and m != 0:  # position modes
                e = q - gp
                new_e = a00 * e + a01 * dq
                new_dq = a10 * e + a11 * dq
                torque = inertia * (-(w * w) * e - 2 * w * dq)
                current = _clip(torque / kt, -lim, lim)
                q, dq = gp + new_e, new_dq
            elif on:  # current mode
                tau = kt * gc + ext - visc * dq
                dq = dq + dt * (tau / inertia)
                q = q + dt * dq
                current = gc
            else:  # torque off
                dq = 0.0
            q_out.append(_clip(q, lo, hi))
            dq_out.append(dq)
            cur_out.append(current)
        self._held_q = np.array(q_out)
        self._held_dq = np.array(dq_out)
        self._held_current = np.array(cur_out)

    def _held_matrix(self, dt: float) -> tuple[float, float, float, float]:
        """(a00, a01, a10, a11): the exact transition matrix over dt of x'' = -w^2 x - 2 w x' (critically
        damped), kept per dt."""
        a = self._held_cache.get(dt)
        if a is None:
            w = _HELD_OMEGA
            e = math.exp(-w * dt)
            a = (e * (1 + w * dt), e * dt, -w * w * dt * e, e * (1 - w * dt))
            self._held_cache[dt] = a
        return a

    def _overload(self, enabled, mode, goal_current, limit, dt) -> None:
        if not self.config.overload.enabled:
            return
        sat = enabled & (mode == 0) & (np.abs(goal_current) >= limit * (1 - 1e-6)) & (limit > 0)
        self._saturated_time = np.where(sat, self._saturated_time + dt, 0.0)
        for i in np.flatnonzero(self._saturated_time >= self.config.overload.time_s):
            self._errors[self.servo_ids[i]] = self._errors.get(self.servo_ids[i], 0) | OVERLOAD_BIT

    def read(self) -> SensorReading:
        """What the sensors measure (arrays; `read_lists` gives the same numbers as lists)."""
        pos, vel, cur, voltage, temperature = self.read_lists()
        return SensorReading(position=np.array(pos), velocity=np.array(vel), current=np.array(cur),
                             voltage=np.array(voltage), temperature=np.array(temperature))

    def read_lists(self) -> tuple[list, list, list, list, list]:
        """(position, velocity, current, voltage, temperature) lists in servo order: the true state with
        an occasional one-count position error, velocity and current noise.

        Per servo in plain Python (8 values: cheaper than numpy's fancy indexing; the same IEEE
        operations as the array form) and with the random stream the array form drew: `rng.random(n)`
        for which positions are off, `rng.integers(0, 2, n)` for the sign of each, `rng.normal(0, s, n)`
        (= 0.0 + s * standard normal) for the velocity, then for the current noise."""
        n = len(self.servo_ids)
        s = self.config.sensor
        pos, vel, cur = [0.0] * n, [0.0] * n, [0.0] * n
        kt = self._kt_l
        for i, q, dq, tau in zip(self._bi_l, self.q.tolist(), self.dq.tolist(), self.motor_torque.tolist()):
            pos[i], vel[i], cur[i] = q, dq, tau / kt[i]
        for i, q, dq, c in zip(self._held_l, self._held_q.tolist(), self._held_dq.tolist(),
                               self._held_current.tolist()):
            pos[i], vel[i], cur[i] = q, dq, c
        if s.position_noise_probability > 0:
            p = s.position_noise_probability
            flips, signs = self._position_noise(n)
            pos = [x + (1.0 if f < p else 0.0) * sign for x, f, sign in zip(pos, flips, signs)]
        vel_sd = s.velocity_noise_lsb * RADS_PER_VELOCITY_LSB if s.velocity_noise_lsb > 0 else 0.0
        cur_sd = s.current_noise_lsb * AMPERE_PER_CURRENT_LSB if s.current_noise_lsb > 0 else 0.0
        draws = (vel_sd > 0) + (cur_sd > 0)
        if draws:  # the velocity's n normals, then the current's: one call, the same stream
            z = iter(self.rng.standard_normal(draws * n).tolist())
            if vel_sd > 0:
                vel = [x + (0.0 + vel_sd * next(z)) for x in vel]
            if cur_sd > 0:
                cur = [x + (0.0 + cur_sd * next(z)) for x in cur]
        return pos, vel, cur, [12.0] * n, [35.0] * n

    def read_arrays(self) -> tuple:
        """`read_lists` with position, velocity and current as float64 arrays (the same numbers, the same
        random stream; compiled with crane_io.sim.chain_kernel.reading): the simulated chain's fast path."""
        fns = self._chain_fns
        if fns is None:
            fns = self._chain_fns = chain_kernel.compiled() or False
        if not fns:
            pos, vel, cur, volt, temp = self.read_lists()
            return np.array(pos), np.array(vel), np.array(cur), volt, temp
        n = len(self.servo_ids)
        p, raw, flips, signs, vel_sd, cur_sd, z = self._noise()
        if self._bi_a is None:
            self._bi_a = np.array(self._bi_l, dtype=np.int64)
            self._held_a = np.array(self._held_l, dtype=np.int64)
        pos, vel, cur = fns[3](self.q, self.dq, self.motor_torque, self._held_q, self._held_dq,
                               self._held_current, self._bi_a, self._held_a, self._kt_array(), n, p, raw,
                               flips, signs, vel_sd, cur_sd, z)
        return pos, vel, cur, [12.0] * n, [35.0] * n

    def _kt_array(self) -> np.ndarray:
        """The torque constants as an array (kept while `_kt_l` holds the same values)."""
        kt_l, kt = self._kt_kept
        if kt_l is not self._kt_l or kt.tolist() != kt_l:  # (a test may change the torque constants)
            kt = np.array(self._kt_l, dtype=float)
            self._kt_kept = (self._kt_l, kt)
        return kt

    def _noise(self) -> tuple:
        """read_arrays' draws from the sensor-noise generator, in its order: (probability of a one-pulse
        position error, the raw PCG64 outputs for it (or empty), else its uniforms and signs, velocity noise
        sd, current noise sd, the standard normals of both)."""
        n = len(self.servo_ids)
        s = self.config.sensor
        p = s.position_noise_probability
        raw, flips, signs = _EMPTY_U64, _EMPTY_F64, _EMPTY_F64
        if p > 0:
            rng = self.rng
            if n % 2 == 0 and self._raw_signs_ok is not rng:  # as _position_noise decides it
                bg = rng.bit_generator
                pcg = type(bg) is np.random.PCG64 and not bg.state["has_uint32"]
                self._raw_signs_ok = rng if pcg else None
            if n % 2 == 0 and self._raw_signs_ok is rng:
                raw = rng.bit_generator.random_raw(n + n // 2)
            else:
                flips, signs = (np.array(x) for x in self._position_noise(n))
        vel_sd = s.velocity_noise_lsb * RADS_PER_VELOCITY_LSB if s.velocity_noise_lsb > 0 else 0.0
        cur_sd = s.current_noise_lsb * AMPERE_PER_CURRENT_LSB if s.current_noise_lsb > 0 else 0.0
        draws = (vel_sd > 0) + (cur_sd > 0)
        z = self.rng.standard_normal(draws * n) if draws else _EMPTY_F64
        return float(p), raw, flips, signs, vel_sd, cur_sd, z

    # ---- the simulated chain's compiled lockstep cycle (crane_io.sim.lockstep_kernel) ----------------------
    def kernel_step_args(self, dt: float) -> tuple | None:
        """The plant's arguments of lockstep_kernel.sync_write_goal for a step of dt (the step
        `step_command` takes to the compiled kernel; the kernel writes the new state into the packed state,
        and the caller calls `kernel_stepped(dt)`), or None when the kernel is off, the overload model on, or
        dt not positive (then the plant steps through step_command / step_lists)."""
        if self._kstep is None or self.config.overload.enabled or not dt > 0:
            return None
        kst = self._kernel_state()
        if kst is None:
            return None
        per = self._kdt.get(dt)
        if per is None or per[0] != self.h:
            n_sub = max(1, math.ceil(dt / self.h - 1e-9))
            hmat = self._khmat.get(dt)
            if hmat is None:
                hmat = self._khmat[dt] = np.array(self._held_matrix(dt))
            per = self._kdt[dt] = (self.h, hmat, n_sub, dt / n_sub)
        return (self._bi_mask, kst, self.external, self._held_ext, per[1], self._karm, self._kpack,
                self._klay, per[3], per[2], dt)

    def kernel_cycle_args(self, dt: float) -> tuple | None:
        """kernel_step_args(dt) and what lockstep_kernel.sync_write_read reads the plant with after the step:
        the torque constants, the noise generator's pointers (crane_io.sim.noise_kernel: the compiled call
        draws from `rng` what _noise would draw, in its order), the position noise probability, the velocity
        and current noise sd, then the voltages and temperatures (lists); or None when kernel_step_args is
        None or the plant draws its noise otherwise (a subclass's own _noise)."""
        step = self.kernel_step_args(dt)
        if step is None or self._chain_fns is False or type(self)._noise is not ArmPlant._noise:
            return None
        if not noise_kernel.verified():  # numba's normal sampler is not numpy's here: draw with numpy
            return None
        rng = self.rng
        kept = self._rng_kept
        if kept is None or kept.rng is not rng:
            kept = self._rng_kept = noise_kernel.RngPointers(rng)
        s = self.config.sensor
        p = s.position_noise_probability
        raw_signs = False
        if p > 0:  # the signs as _position_noise draws them: raw when it would, else as integers(0, 2, n)
            n = len(self.servo_ids)
            if n % 2 == 0 and self._raw_signs_ok is not rng:
                bg = rng.bit_generator
                pcg = type(bg) is np.random.PCG64 and not bg.state["has_uint32"]
                self._raw_signs_ok = rng if pcg else None
            raw_signs = n % 2 == 0 and self._raw_signs_ok is rng
            if not raw_signs:
                self._raw_signs_ok = None
        vel_sd = s.velocity_noise_lsb * RADS_PER_VELOCITY_LSB if s.velocity_noise_lsb > 0 else 0.0
        cur_sd = s.current_noise_lsb * AMPERE_PER_CURRENT_LSB if s.current_noise_lsb > 0 else 0.0
        return (*step, self._kt_array(), kept.array, float(p), raw_signs, vel_sd, cur_sd, *self._supply_lists)

    def kernel_stepped(self, dt: float) -> None:
        """The compiled lockstep cycle stepped the plant's packed state by dt."""
        self.time += dt

    def kernel_read_args(self) -> tuple | None:
        """read_arrays for lockstep_kernel.sense: (packed state, layout, torque constants, the noise drawn as
        read_arrays draws it, voltages, temperatures), or None (nothing drawn) when the kernel is off."""
        if self._kstep is None or self._chain_fns is False:
            return None
        kst = self._kernel_state()
        if kst is None:
            return None
        return (kst, self._klay, self._kt_array(), *self._noise(), *self._supply_lists)

    def _kernel_state(self) -> np.ndarray | None:
        """The packed state (integrated joints' angles, velocities, motor torques, held joints' angles,
        velocities, currents) whose views `q`, `dq`, `motor_torque`, `_held_q`, `_held_dq` and
        `_held_current` are; made anew (the same values) when one of them was replaced since. None when one
        has the wrong size."""
        v = self._kviews
        if (v is not None and self.q is v[0] and self.dq is v[1] and self.motor_torque is v[2]
                and self._held_q is v[3] and self._held_dq is v[4] and self._held_current is v[5]):
            return self._kst
        n, k = len(self._bi_l), len(self._held_l)
        parts = (self.q, self.dq, self.motor_torque, self._held_q, self._held_dq, self._held_current)
        if [np.shape(x) for x in parts] != [(n,)] * 3 + [(k,)] * 3:
            return None
        kst = np.concatenate([np.asarray(x, dtype=float) for x in parts])
        b = 3 * n
        views = (kst[:n], kst[n:2 * n], kst[2 * n:b], kst[b:b + k], kst[b + k:b + 2 * k], kst[b + 2 * k:])
        self.q, self.dq, self.motor_torque, self._held_q, self._held_dq, self._held_current = views
        self._kst, self._kviews = kst, views
        return kst

    def step_command(self, cmds: np.ndarray, position_mask: int, dt: float) -> bool:
        """`step_lists` from the commands as one (5, servos) float array (driving 1.0/0.0, operating mode,
        goal current A, goal position rad, current limit A; the simulated chain's fast path) when the kernel
        takes them as they are: no integrated joint's servo driving in a position mode (bit i of
        `position_mask`: servo i is), no overload model. Returns False (nothing done) otherwise."""
        if dt <= 0:
            return True
        if self._kstep is None or self.config.overload.enabled or position_mask & self._bi_mask:
            return False
        hmat = self._khmat.get(dt)
        if hmat is None:
            hmat = self._khmat[dt] = np.array(self._held_matrix(dt))
        n_sub = max(1, math.ceil(dt / self.h - 1e-9))
        out = self._kstep_arm(self.q, self.dq, self._held_q, self._held_dq, cmds, self._kpd0, self.external,
                              self._held_ext, dt / n_sub, n_sub, dt, hmat, self._kgeo, self._karm, self._kpar,
                              self._kcog, self._kscal, self._khpar)
        n, k = len(self._bi_l), len(self._held_l)
        b = 3 * n
        self.q, self.dq, self.motor_torque = out[:n], out[n:2 * n], out[2 * n:b]
        self._held_q, self._held_dq, self._held_current = out[b:b + k], out[b + k:b + 2 * k], out[b + 2 * k:]
        self.time += dt
        return True

    def _position_noise(self, n: int) -> tuple[list, list]:
        """(n uniforms, n signed one-pulse errors): `rng.random(n)`, then -+RAD_PER_PULSE as
        `rng.choice((-RAD_PER_PULSE, RAD_PER_PULSE), n)` draws them (Generator.choice draws
        `rng.integers(0, 2, n)`).

        With numpy's default bit generator (PCG64) both come from one call for its raw 64-bit outputs:
        a uniform is (output >> 11) / 2**53, as Generator.random makes it; for 0..1, Generator.integers
        takes 32-bit halves of the outputs, low half first (the high half is kept in the bit generator
        for the next 32-bit draw), and Lemire's method returns the top bit of each: bits 31 and 63 of
        every output. An even n with no half kept from before (the plant's own generator draws nothing
        else of 32 bits) takes this path, at a fifth of the cost; anything else calls random and
        integers."""
        rng = self.rng
        if n % 2 == 0 and self._raw_signs_ok is not rng:
            bg = rng.bit_generator
            self._raw_signs_ok = rng if type(bg) is np.random.PCG64 and not bg.state["has_uint32"] else None
        if n % 2 == 0 and self._raw_signs_ok is rng:
            raw = rng.bit_generator.random_raw(n + n // 2).tolist()
            flips = [(v >> 11) * _TWO_TO_MINUS_53 for v in raw[:n]]
            neg, pos = -RAD_PER_PULSE, RAD_PER_PULSE
            signs = []
            for v in raw[n:]:
                signs.append(pos if v & 0x80000000 else neg)
                signs.append(pos if v >> 63 else neg)
            return flips, signs
        self._raw_signs_ok = None  # an odd draw may leave a half behind: look again next time
        flips = rng.random(n).tolist()
        return flips, _PULSE_SIGNS.take(rng.integers(0, 2, size=n, dtype=np.int64)).tolist()

    def hardware_errors(self) -> dict[int, int]:
        return dict(self._errors)

    def clear_errors(self) -> None:
        """Clear latched hardware errors (what a servo reboot does)."""
        self._errors.clear()
        self._saturated_time[:] = 0.0

    def set_external_torque(self, torque: np.ndarray) -> None:
        torque = np.array(torque, dtype=float)  # a copy of its own
        if torque.shape != (len(self.servo_ids),):
            raise ValueError(f"external torque needs {len(self.servo_ids)} values, got {torque.shape}")
        if not all(map(math.isfinite, torque.tolist())):  # (per float: cheaper than numpy for 8 values)
            raise ValueError("external torque must be finite")
        self.external = torque.take(self._bi)
        self._held_ext = torque.take(self._held)
        self._external_all = torque

    def external_torque(self) -> np.ndarray:
        """(8,) the external torque (N m, e.g. the operator's hand) last set by set_external_torque,
        in joint order (zeros before the first call)."""
        return self._external_all.copy()

    def contact_torque(self) -> np.ndarray:
        """(8,) the environment's torque on the arm (N m, world on arm, positive pushes the joint
        positive) at the end of the last step, in joint order; zeros for the held joints and for a
        plant without [[environment]]."""
        out = np.zeros(len(self.servo_ids))
        out[self._bi] = self._contact
        return out

    @property
    def in_contact(self) -> bool:
        """True when an [[environment]] object was penetrated at the end of the last step."""
        return self._in_contact

    # ---- state and truth -----------------------------------------------------------------------------
    @property
    def joint_names(self) -> tuple[str, ...]:
        return self.arm.joint_names

    def state(self) -> tuple[np.ndarray, np.ndarray]:
        """True (noise-free) joint angles and velocities, (8,) each, in servo order."""
        n = len(self.servo_ids)
        q, dq = np.empty(n), np.empty(n)
        q[self._bi], q[self._held] = self.q, self._held_q
        dq[self._bi], dq[self._held] = self.dq, self._held_dq
        return q, dq

    def set_state(self, q=None, dq=None) -> None:
        """Set true joint angles / velocities ((8,) in servo order) e.g. to start a test pose."""
        if q is not None:
            q = np.asarray(q, dtype=float)
            self.q = q[self._bi].copy()
            self._held_q = q[self._held].copy()
            self.motor_q = self.q.tolist()  # the motor side centred in its gap
        if dq is not None:
            dq = np.asarray(dq, dtype=float)
            self.dq = dq[self._bi].copy()
            self._held_dq = dq[self._held].copy()
            self.motor_dq = self.dq.tolist()

    def truth(self) -> dict:
        """The plant's hidden truth (effects, parameters, true torque constants). Never in a session."""
        t = self.config.truth()
        t["seed"] = self.seed
        t["joints"] = list(self.joints)  # the joints this plant integrates
        t["torque_constant_effective"] = dict(zip(self.arm.joint_names, self.kt.tolist()))
        return t

    def write_truth(self, path) -> Path:
        """Write `truth()` (including the seed this plant runs with) as JSON to `path`."""
        path = Path(path)
        path.write_text(json.dumps(self.truth(), indent=2) + "\n")
        return path



def _written_out(n: int) -> tuple:
    """(euler, drive, mirror) for n joints: the per-joint float arithmetic of the substep written out
    (generated once per n: a loop over n small lists costs more than the arithmetic itself):

    - euler(q, dq, ddq, h) -> ((q'), (dq')): semi-implicit Euler, velocity first (a velocity that would
      change sign in the substep stops at zero: friction stops a joint, it never reverses it), then
      position;
    - drive(tau_m, ext, other) -> [tau_m + ext - other] per joint;
    - mirror(m): copies the upper triangle of the n x n list-of-lists m (pinocchio's crba) below the
      diagonal."""
    fns = _WRITTEN_OUT.get(n)
    if fns is None:
        r = range(n)
        src = ["def euler(q, dq, ddq, h):",
               f"    {', '.join(f'q{i}' for i in r)}, = q",
               f"    {', '.join(f'd{i}' for i in r)}, = dq",
               f"    {', '.join(f'a{i}' for i in r)}, = ddq"]
        for i in r:
            src += [f"    v{i} = d{i} + h * a{i}",
                    f"    if (d{i} > 0 and v{i} < 0) or (d{i} < 0 and v{i} > 0):",
                    f"        v{i} = 0.0"]
        src += [f"    return ({', '.join(f'q{i} + h * v{i}' for i in r)},), "
                f"({', '.join(f'v{i}' for i in r)},)",
                "def drive(t, e, o):",
                f"    return [{', '.join(f't[{i}] + e[{i}] - o[{i}]' for i in r)}]",
                "def mirror(m):"]
        lower = [(a, b) for a in range(1, n) for b in range(a)]
        src += [f"    {', '.join(f'm[{a}][{b}]' for a, b in lower)}, = "
                f"{', '.join(f'm[{b}][{a}]' for a, b in lower)}," if lower else "    pass"]
        space: dict = {}
        exec(compile("\n".join(src), f"<arm_plant substep, {n} joints>", "exec"), space)  # noqa: S102
        fns = _WRITTEN_OUT[n] = (space["euler"], space["drive"], space["mirror"])
    return fns


_WRITTEN_OUT: dict[int, tuple] = {}


def _clip(x: float, lo: float, hi: float) -> float:
    """np.clip for one float, exactly (NaN passes through; on a tie the bound wins, so signed zeros
    come out as numpy's do)."""
    x = x if (x != x or x > lo) else lo
    return x if (x != x or x < hi) else hi

def _solve_free(m: list, idx: list, b: list) -> list:
    """_solve of the rows and columns `idx` of m (the free joints), without building the submatrix for
    one or two unknowns."""
    if len(idx) == 1:
        i = idx[0]
        return [b[0] / m[i][i]]
    if len(idx) == 2:
        i, j = idx
        return _solve(((m[i][i], m[i][j]), (m[j][i], m[j][j])), b)
    return _solve([[m[a][c] for c in idx] for a in idx], b)


def _solve(a: list, b: list) -> list:
    """Solve a small symmetric positive-definite system. Up to 3 unknowns by Gaussian elimination in
    floats (the 1- and 2-unknown cases are the general loop written out: the same operations in the same
    order, `sum` included: it adds from 0.0); more (4..7 integrated joints) with LAPACK, which is cheaper
    there than the loop."""
    n = len(b)
    if n > 3:
        return np.linalg.solve(np.array(a), np.array(b)).tolist()
    if n == 1:
        return [b[0] / a[0][0]]
    if n == 2:
        (a00, a01), (a10, a11) = a
        f = a10 / a00
        x1 = (b[1] - f * b[0]) / (a11 - f * a01)
        return [(b[0] - (0.0 + a01 * x1)) / a00, x1]
    return _eliminate(a, b)


def _eliminate(a: list, b: list) -> list:
    """Gaussian elimination without pivoting on lists of floats, any size (what _solve writes out for 1
    and 2 unknowns)."""
    n = len(b)
    a = [row[:] for row in a]
    b = b[:]
    for k in range(n):
        p = a[k][k]
        for r in range(k + 1, n):
            f = a[r][k] / p
            for c in range(k, n):
                a[r][c] -= f * a[k][c]
            b[r] -= f * b[k]
    x = [0.0] * n
    for k in range(n - 1, -1, -1):
        x[k] = (b[k] - sum(a[k][c] * x[c] for c in range(k + 1, n))) / a[k][k]
    return x
