"""The simulated arm's steppers: ArmPlant picks one when it is built (`choose`) and steps through it.

A stepper has one interface, two implementations:

- `step(enabled, mode, goal_current, goal_position, gains, limit, dt)`: ArmPlant.step_lists' physics
  (lists in servo order); steps the plant's state;
- `step_command(cmds, position_mask, dt) -> bool`: the same from the commands as one (5, servos) array (the
  simulated chain's fast path); False when it does not take them (a plant with a servo health model);
- `step_args(dt)`, `cycle_args(dt)`, `read_args()`: the plant's arguments of the simulated chain's compiled
  lockstep cycle (crane_io.sim.lockstep_kernel), or None.

crane_io.sim.plant_reference.ReferenceStepper is the reference (Python floats per substep; every plant);
`CompiledStepper` calls crane_io.sim.plant_kernel (numba) on the arrays of crane_io.sim.plant_layout, for a
plant without backlash, user-defined effects or [[environment]] objects. Both take the rigid body from
crane_io.sim.plant_rigid, the reference stepper through `mass_and_bias` (compiled where numba works, else
its Python source); the two compute the same bits (tests/test_plant_kernel.py).
"""

from __future__ import annotations

import math
import os
import warnings

import numpy as np

from crane_io.dynamixel.units import AMPERE_PER_CURRENT_LSB, RADS_PER_VELOCITY_LSB
from crane_io.errors import ConfigError
from crane_io.sim import noise_kernel, plant_kernel, plant_layout, plant_rigid
from crane_io.sim.plant_reference import ReferenceStepper


def choose(plant, kernel: bool | None):
    """The stepper of `plant`: the compiled one when `kernel` is True (ConfigError when it cannot take the
    plant or numba is missing), the reference when False; None: the compiled one where it applies and
    works, unless the environment variable CRANE_PLANT_KERNEL is "0" (then the reference stepper with the
    rigid body's Python source: numba is not imported)."""
    fits = not (plant._backlash or plant._generic or plant.environment)
    required = kernel is True
    interpreted = kernel is None and os.environ.get("CRANE_PLANT_KERNEL", "1") == "0"
    if kernel is None:
        kernel = not interpreted and fits
    elif kernel and not fits:
        raise ConfigError("the compiled plant kernel does not simulate backlash, user-defined effects or "
                          "[[environment]] objects; use kernel=False for this plant")
    fns = None if interpreted else plant_kernel.compiled()
    if kernel:
        if fns is None and required:
            raise ConfigError("the compiled plant kernel needs numba (pip install numba)")
        if fns is not None:
            try:  # load (or compile) it now, with this plant's own argument types: no surprise later
                return CompiledStepper(plant, fns)
            except Exception as exc:  # e.g. a numba that cannot compile it here: the reference path
                if required:
                    raise
                warnings.warn(f"the compiled plant kernel is not usable here ({type(exc).__name__}: "
                              f"{exc}); the plant integrates on its reference path", stacklevel=3)
    return ReferenceStepper(plant, _mass_and_bias(plant, fns))


def _mass_and_bias(plant, fns):
    """plant_rigid.mass_and_bias compiled (from fns, plant_kernel.compiled()) when it runs here, else its
    Python source."""
    if fns is not None:
        q = np.asarray(plant.q, dtype=float)
        try:
            fns[2](plant.geo, plant.model.armature, plant.scal, q, np.zeros_like(q))
            return fns[2]
        except Exception as exc:  # e.g. a numba that cannot compile it here: the Python source
            warnings.warn(f"the compiled rigid-body dynamics are not usable here ({type(exc).__name__}: "
                          f"{exc}); the plant's reference path runs their Python source", stacklevel=4)
    return plant_rigid.mass_and_bias


class CompiledStepper:
    """Steps an ArmPlant with plant_kernel.step_arm (see the module docstring); the plant's state attributes
    become views of one packed array when the lockstep cycle steps it (`_state`)."""

    compiled = True

    def __init__(self, plant, fns):
        self.plant = plant
        self.step_arm, self.step_substeps = fns[0], fns[1]
        self.geo, self.par, self.cog, self.scal = plant.geo, plant.par, plant.cog, plant.scal
        self.arm = plant.model.armature  # a view of the model's vector (kept live: a test may change it)
        self.hpar = plant_layout.held_rows(plant._held_kt_l, plant._held_inertia_l, plant._held_visc_l,
                                           plant._held_lo_l, plant._held_hi_l, plant._held_l)
        self.pd0 = np.zeros((len(plant.joints), 6))  # no servo PD
        self.kpack, self.klay = plant_layout.pack(self.geo, self.par, self.cog, self.scal, self.hpar,
                                                  self.pd0, plant._bi_l, plant._held_l)
        self._hmat: dict[float, np.ndarray] = {}
        self._per_dt: dict[float, tuple] = {}  # dt -> (substep, its hmat, n_sub, dt / n_sub)
        self.state = self.views = None  # the packed state and its views (_state)
        self._supply = ([12.0] * len(plant.servo_ids), [35.0] * len(plant.servo_ids))  # (never changed)
        self._rng_kept = None  # cycle_args: the generator and its pointers (noise_kernel.RngPointers)
        self._call(np.zeros((5, len(plant.servo_ids))), self.pd0, plant.h)  # compiled (or loaded) now

    def held_matrix(self, dt: float) -> np.ndarray:
        """plant_layout.held_matrix as an array, kept per dt."""
        a = self._hmat.get(dt)
        if a is None:
            a = self._hmat[dt] = np.array(plant_layout.held_matrix(dt, self.plant.held_omega))
        return a

    def _call(self, cmds: np.ndarray, pd: np.ndarray, dt: float) -> np.ndarray:
        p = self.plant
        n_sub = max(1, math.ceil(dt / p.h - 1e-9))
        return self.step_arm(p.q, p.dq, p._held_q, p._held_dq, cmds, pd, p.external, p._held_ext,
                             dt / n_sub, n_sub, dt, self.held_matrix(dt), self.geo, self.arm, self.par,
                             self.cog, self.scal, self.hpar)

    def _take(self, out: np.ndarray, dt: float) -> None:
        p = self.plant
        n, k = len(p._bi_l), len(p._held_l)
        b = 3 * n
        p.q, p.dq, p.motor_torque = out[:n], out[n:2 * n], out[2 * n:b]
        p._held_q, p._held_dq, p._held_current = out[b:b + k], out[b + k:b + 2 * k], out[b + 2 * k:]

    def step(self, en_l, mode_l, gc_l, gp_l, gains_l, lim_l, dt: float) -> None:
        pd = self.pd0
        servo_pd = self.plant._servo_pd(en_l, mode_l, gc_l, gp_l, gains_l, lim_l)
        if servo_pd is not None:
            pd = np.array([(1.0, *c) if c is not None else (0.0,) * 6 for c in servo_pd])
        self._take(self._call(np.array((en_l, mode_l, gc_l, gp_l, lim_l), dtype=float), pd, dt), dt)

    def step_command(self, cmds: np.ndarray, position_mask: int, dt: float) -> bool:
        p = self.plant
        if p.health is not None or position_mask & p._bi_mask:
            return False
        self._take(self._call(cmds, self.pd0, dt), dt)
        return True

    # ---- the simulated chain's compiled lockstep cycle (crane_io.sim.lockstep_kernel) ---------------------
    def _state(self) -> np.ndarray | None:
        """The packed state whose views are the plant's `q`, `dq`, `motor_torque`, `_held_q`, `_held_dq` and
        `_held_current`; made anew (the same values) when one of them was replaced since. None when one has
        the wrong size."""
        p, v = self.plant, self.views
        if (v is not None and p.q is v[0] and p.dq is v[1] and p.motor_torque is v[2]
                and p._held_q is v[3] and p._held_dq is v[4] and p._held_current is v[5]):
            return self.state
        n, k = len(p._bi_l), len(p._held_l)
        parts = (p.q, p.dq, p.motor_torque, p._held_q, p._held_dq, p._held_current)
        if [np.shape(x) for x in parts] != [(n,)] * 3 + [(k,)] * 3:
            return None
        kst = np.concatenate([np.asarray(x, dtype=float) for x in parts])
        b = 3 * n
        views = (kst[:n], kst[n:2 * n], kst[2 * n:b], kst[b:b + k], kst[b + k:b + 2 * k], kst[b + 2 * k:])
        p.q, p.dq, p.motor_torque, p._held_q, p._held_dq, p._held_current = views
        self.state, self.views = kst, views
        return kst

    def step_args(self, dt: float) -> tuple | None:
        """ArmPlant.kernel_step_args."""
        p = self.plant
        if p.health is not None or not dt > 0:
            return None
        kst = self._state()
        if kst is None:
            return None
        per = self._per_dt.get(dt)
        if per is None or per[0] != p.h:
            n_sub = max(1, math.ceil(dt / p.h - 1e-9))
            per = self._per_dt[dt] = (p.h, self.held_matrix(dt), n_sub, dt / n_sub)
        return (p._bi_mask, kst, p.external, p._held_ext, per[1], self.arm, self.kpack, self.klay, per[3],
                per[2], dt)

    def cycle_args(self, dt: float) -> tuple | None:
        """ArmPlant.kernel_cycle_args."""
        p = self.plant
        step = self.step_args(dt)
        if step is None or p._chain_fns is False:
            return None
        if not noise_kernel.verified():  # numba's normal sampler is not numpy's here: draw with numpy
            return None
        rng = p.rng
        kept = self._rng_kept
        if kept is None or kept.rng is not rng:
            kept = self._rng_kept = noise_kernel.RngPointers(rng)
        s = p.config.sensor
        prob = s.position_noise_probability
        raw_signs = False
        if prob > 0:  # the signs as _position_noise draws them: raw when it would, else as integers(0, 2, n)
            raw_signs = p._raw_signs(len(p.servo_ids))
            if not raw_signs:
                p._raw_signs_ok = None
        vel_sd = s.velocity_noise_lsb * RADS_PER_VELOCITY_LSB if s.velocity_noise_lsb > 0 else 0.0
        cur_sd = s.current_noise_lsb * AMPERE_PER_CURRENT_LSB if s.current_noise_lsb > 0 else 0.0
        return (*step, p._kt_array(), kept.array, float(prob), raw_signs, vel_sd, cur_sd, *self._supply)

    def read_args(self) -> tuple | None:
        """ArmPlant.kernel_read_args."""
        p = self.plant
        if p._chain_fns is False or p.health is not None:  # (the health model's supply: read_arrays)
            return None
        kst = self._state()
        if kst is None:
            return None
        return (kst, self.klay, p._kt_array(), *p._noise(), *self._supply)
