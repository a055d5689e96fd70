"""The simulated CRANE-X7 arm: the physics behind the simulated servo chain for all 8 servos.

The integrated joints (`joints`: any of joint1..joint7, default the config's `joints` key, whose own
default is the paper's joint1, joint2, joint4) are integrated with the n-DOF rigid-body dynamics
(crane_io.sim.plant_rigid, on the geometry and inertias of crane_io.physics.dynamics' model; the other
joints locked at the configured angles), plus the configured physical
effects (crane_io.physics.effects), plus the actuator, plus the external torque (an operator's hand):

    M(q) ddq + C(q, dq) dq + g(q) + tau_effects(q, dq) + friction = Kt_true * I + tau_ext

- Actuator: current mode -> torque = Kt_true x goal current (the chain already clamped it to the
  Current Limit); position modes -> the servo's PD controller (as in crane_io.sim.simple_plant);
  torque off -> no motor torque: the joint is back-drivable (gravity + friction only).
- Rotor inertia goes into the mass matrix (the model's armature); a payload into the dynamics.
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
- Servo health (optional, the config's [overload], [thermal], [supply]; crane_io.sim.servo_health):
  winding temperature from I^2 R, the overload timer and the supply voltage, stepped with the plant;
  they set Present Temperature / Present Input Voltage and the Overload, Overheating and Input Voltage
  bits (the chain's servos latch them and act on their Shutdown mask). Without them the servos read a
  constant 12.0 V and 35 C and raise nothing.
- Contact (optional, the config's [[environment]]: joint walls and planes, crane_io.sim.environment): the
  objects' torque on the integrated joints is added to the external torque in every substep, so
  stick-slip friction sees it. `contact_torque()` and `in_contact` give it at the end of the last
  step. A plant without objects computes exactly what it did before they existed.

The truth (effects and parameters) is available as `truth()` / `write_truth(path)` only.
"""

from __future__ import annotations

import json
import math
from pathlib import Path

import numpy as np

from crane_io.description import default_arm
from crane_io.dynamixel.units import AMPERE_PER_CURRENT_LSB, RAD_PER_PULSE, RADS_PER_VELOCITY_LSB
from crane_io.errors import ConfigError
from crane_io.physics.dynamics import ArmDynamics
from crane_io.physics.effects import PlantTerms
from crane_io.sim import chain_kernel, plant_backend, plant_layout, servo_health
from crane_io.sim.environment import Environment
from crane_io.sim.plant_api import ActuatorCommand, SensorReading
from crane_io.sim.plant_config import ARM_JOINTS, PlantConfig, check_joints, load_plant_config
from crane_io.sim.simple_plant import DEFAULT_INERTIA, DEFAULT_VISCOUS, SimplePlant

_PULSE_SIGNS = np.array((-RAD_PER_PULSE, RAD_PER_PULSE))  # one-pulse position noise
_TWO_TO_MINUS_53 = 1.0 / 9007199254740992.0  # Generator.random: (64-bit output >> 11) x 2**-53
_EMPTY_U64, _EMPTY_F64 = np.zeros(0, dtype=np.uint64), np.zeros(0)

OVERLOAD_BIT = servo_health.OVERLOAD_BIT
_HELD_OMEGA = 30.0  # rad/s: held joints follow their goal as a critically damped 2nd-order system
_STOP_MARGIN = math.radians(2.0)  # end stops sit this far beyond the software limits
_CONTACT_OMEGA_H = 0.25  # backlash contact: natural frequency on the motor inertia x substep
_CONTACT_DAMPING_RATIO = 1.5
_SKL_INERTIA = dict(zip(("joint1", "joint2", "joint3", "joint4", "joint5", "joint6", "joint7", "gripper"),
                        DEFAULT_INERTIA))


class ArmPlant:
    """The simulated CRANE-X7 (see module docstring). `config`: a PlantConfig, a preset name or a
    TOML path (default "crane-x7"); `seed`: the sensor-noise seed (default: the config's); `joints`:
    the joints integrated with the rigid-body dynamics (any of joint1..joint7, put in arm order;
    default the config's `joints`, itself by default joint1, joint2, joint4); `kernel`: step with the
    compiled stepper (crane_io.sim.plant_backend.CompiledStepper, crane_io.sim.plant_kernel) or with the
    reference stepper (crane_io.sim.plant_reference: Python floats per substep),
    chosen once, when the plant is built (crane_io.sim.plant_backend.choose). Default: the compiled one
    when numba is installed and the plant has no backlash, user-defined effect or [[environment]] object
    (those run on the reference stepper), unless the environment variable CRANE_PLANT_KERNEL is "0" (then
    always the reference, numba not imported). The two compute the same bits (crane_io.sim.plant_kernel)."""

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
        self.dyn = ArmDynamics(joints, locked=locked, payload_mass=self._payload,
                               identified=config.arm_model)  # an identified arm model's bodies
        self.model = self.dyn.model
        self.model.armature = self._armature.copy()
        lo = np.array([arm.joint(n).lower for n in joints]) - _STOP_MARGIN
        hi = np.array([arm.joint(n).upper for n in joints]) + _STOP_MARGIN
        self._lo_l, self._hi_l = lo.tolist(), hi.tolist()
        self._k_stop, self._d_stop = config.limits.stiffness, config.limits.damping
        init = np.array([config.initial.get(n, 0.0) for n in names])
        self.q = init[self._bi].copy()
        self.dq = np.zeros(n_int)
        # motor side of the joints with backlash (link-side units: motor angle / gear ratio), centred
        # in the gap
        self.motor_q, self.motor_dq = self.q.tolist(), [0.0] * n_int
        self.h = config.substep_s
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
        self._held_inertia_l = [float(DEFAULT_INERTIA[i]) for i in self._held_l]
        self._held_visc_l = [float(DEFAULT_VISCOUS[i]) for i in self._held_l]
        self._held_lo_l = [arm.joint(n).lower - _STOP_MARGIN for n in self._held_names]
        self._held_hi_l = [arm.joint(n).upper + _STOP_MARGIN for n in self._held_names]
        self.external = np.zeros(n_int)
        self._external_all = np.zeros(len(names))  # the last set_external_torque, joint order
        self.environment = list(config.environment)  # the parsed [[environment]] objects
        self._env = (Environment(self.environment, model=self.model, joints=joints)
                     if self.environment else None)
        self._contact = np.zeros(n_int)  # the objects' torque at the end of the last step
        self._in_contact = False
        self.motor_torque = np.zeros(n_int)
        self.health = servo_health.build([arm.joint(n).model for n in names], config.overload, config.thermal,
                                         config.supply)
        self._idle_supply = ([servo_health.NOMINAL_VOLTAGE] * len(names),
                             [servo_health.IDLE_TEMPERATURE_C] * len(names))
        self.time = 0.0
        self._raw_signs_ok = None  # the generator _position_noise may read raw (see _raw_signs)
        # the effects and end stops per integrated joint, in crane_io.sim.plant_layout's layout
        self.par = plant_layout.effect_rows(self.terms, self._lo_l, self._hi_l,
                                            [self._kt_l[i] for i in self._bi_l], self._bi_l)
        self.cog = plant_layout.cogging_rows(self.terms.cogging)
        self.held_omega = _HELD_OMEGA
        if not plant_layout.revolute_chain(self.model):  # (every arm of joint1..joint7 in arm order is)
            raise ConfigError("the simulated arm integrates a serial chain of revolute joints only")
        self.geo = plant_layout.geometry(self.model)  # the rigid body (crane_io.sim.plant_rigid)
        self.scal = np.array([self._k_stop, self._d_stop, *self.model.gravity.linear, self.held_omega])
        self._stepper = plant_backend.choose(self, kernel)

    @property
    def kernel(self) -> bool:
        """True when this plant steps with the compiled kernel (crane_io.sim.plant_kernel)."""
        return self._stepper.compiled

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
        self._generic = list(terms.generic)
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
        self._stepper.step(en_l, mode_l, gc_l, gp_l, gains_l, lim_l, dt)
        self.time += dt
        if self.health is not None:
            _, vel, cur = self._true_lists()
            self.health.step(en_l, cur, vel, dt)

    def step_command(self, cmds: np.ndarray, position_mask: int, dt: float) -> bool:
        """`step_lists` from the commands as one (5, servos) float array (driving 1.0/0.0, operating mode,
        goal current A, goal position rad, current limit A; the simulated chain's fast path) when the
        stepper takes them as they are (the compiled one: no integrated joint's servo driving in a position
        mode (bit i of `position_mask`: servo i is), no servo health model). Returns False (nothing done)
        otherwise."""
        if dt <= 0:
            return True
        if not self._stepper.step_command(cmds, position_mask, dt):
            return False
        self.time += dt
        return True

    def _servo_pd(self, en_l, mode_l, gc_l, gp_l, gains_l, lim_l) -> list | None:
        """Per integrated joint (kp, kd, -cap, cap, goal) of its servo's PD in a position mode, else None;
        None when no integrated joint's servo is in a position mode."""
        bi = self._bi_l
        if not any(en_l[i] and mode_l[i] != 0 for i in bi):
            return None

        def pick(values, dtype=float):  # the integrated joints' entries as an array
            return np.array([values[i] for i in bi], dtype=dtype)

        bi_cmd = ActuatorCommand(pick(en_l, bool), pick(mode_l, None), pick(gc_l), pick(gp_l), pick(gains_l),
                                 pick(lim_l))
        pos, kp, kd, cap = self._pd.position_controller(bi_cmd)
        if kp is None:
            return None
        return [(a, b, -c, c, float(g)) if p else None
                for p, a, b, c, g in zip(pos.tolist(), kp.tolist(), kd.tolist(), cap.tolist(),
                                         bi_cmd.goal_position)]

    def _true_lists(self) -> tuple[list, list, list]:
        """(position, velocity, current) lists in servo order: the true state, no sensor noise."""
        n = len(self.servo_ids)
        pos, vel, cur = [0.0] * n, [0.0] * n, [0.0] * n
        kt = self._kt_l
        for i, q, dq, tau in zip(self._bi_l, self.q.tolist(), self.dq.tolist(), self.motor_torque.tolist()):
            pos[i], vel[i], cur[i] = q, dq, tau / kt[i]
        for i, q, dq, c in zip(self._held_l, self._held_q.tolist(), self._held_dq.tolist(),
                               self._held_current.tolist()):
            pos[i], vel[i], cur[i] = q, dq, c
        return pos, vel, cur

    def supply_lists(self) -> tuple[list, list]:
        """(voltages V, temperatures C) in servo order: the health model's, else 12.0 V and 35 C."""
        return self._idle_supply if self.health is None else self.health.readings()

    def watch_servo_limits(self, memories: np.ndarray) -> None:
        """Compare the health model's temperature and voltage with the Temperature Limit and Min/Max Voltage
        Limit in these control tables ((servos, bytes), servo order: the simulated chain's); without this,
        with the control table's defaults."""
        if self.health is not None and np.shape(memories)[0] == len(self.servo_ids):
            self.health.limits = servo_health.ControlTableLimits(memories)

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
        pos, vel, cur = self._true_lists()
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
        return pos, vel, cur, *self.supply_lists()

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
        return pos, vel, cur, *self.supply_lists()

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
            if self._raw_signs(n):  # as _position_noise decides it
                raw = self.rng.bit_generator.random_raw(n + n // 2)
            else:
                flips, signs = (np.array(x) for x in self._position_noise(n))
        vel_sd = s.velocity_noise_lsb * RADS_PER_VELOCITY_LSB if s.velocity_noise_lsb > 0 else 0.0
        cur_sd = s.current_noise_lsb * AMPERE_PER_CURRENT_LSB if s.current_noise_lsb > 0 else 0.0
        draws = (vel_sd > 0) + (cur_sd > 0)
        z = self.rng.standard_normal(draws * n) if draws else _EMPTY_F64
        return float(p), raw, flips, signs, vel_sd, cur_sd, z

    # ---- the simulated chain's compiled lockstep cycle (crane_io.sim.lockstep_kernel) ----------------------
    def kernel_step_args(self, dt: float) -> tuple | None:
        """The plant's arguments of lockstep_kernel.sync_write_goal for a step of dt (the step `step_command`
        takes; the kernel writes the new state into the packed state, crane_io.sim.plant_layout, and the
        caller calls `kernel_stepped(dt)`), or None when the compiled stepper is off, the health model on,
        or dt not positive (then the plant steps through step_command / step_lists)."""
        return self._stepper.step_args(dt)

    def kernel_cycle_args(self, dt: float) -> tuple | None:
        """kernel_step_args(dt) and what lockstep_kernel.sync_write_read reads the plant with after the step:
        the torque constants, the noise generator's pointers (crane_io.sim.noise_kernel: the compiled call
        draws from `rng` what _noise would draw, in its order), the position noise probability, the velocity
        and current noise sd, then the voltages and temperatures (lists); or None when kernel_step_args is
        None or the plant draws its noise otherwise (a subclass's own _noise)."""
        if type(self)._noise is not ArmPlant._noise:
            return None
        return self._stepper.cycle_args(dt)

    def kernel_stepped(self, dt: float) -> None:
        """The compiled lockstep cycle stepped the plant's packed state by dt."""
        self.time += dt

    def kernel_read_args(self) -> tuple | None:
        """read_arrays for lockstep_kernel.sense: (packed state, layout, torque constants, the noise drawn as
        read_arrays draws it, voltages, temperatures), or None (nothing drawn) when the kernel is off."""
        return self._stepper.read_args()

    def _raw_signs(self, n: int) -> bool:
        """The position noise's n uniforms and signs may come from the generator's raw outputs (see
        _position_noise); the answer is kept for the generator."""
        rng = self.rng
        if n % 2 == 0 and self._raw_signs_ok is not rng:
            bg = rng.bit_generator
            self._raw_signs_ok = rng if type(bg) is np.random.PCG64 and not bg.state["has_uint32"] else None
        return n % 2 == 0 and self._raw_signs_ok is rng

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
        if self._raw_signs(n):
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
        """{servo ID: bits} whose condition holds now (crane_io.sim.servo_health); {} without health model."""
        if self.health is None:
            return {}
        return {sid: b for sid, b in zip(self.servo_ids, self.health.error_bits().tolist()) if b}

    def clear_errors(self) -> None:
        """Restart the overload timers (the temperature and the supply stay what they are)."""
        if self.health is not None:
            self.health.reset_overload()

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


