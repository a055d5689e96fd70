"""The reference stepper of crane_io.sim.arm_plant.ArmPlant: Python floats per substep.

It steps everything the plant models (backlash, user-defined effects, [[environment]] objects included);
crane_io.sim.plant_backend.CompiledStepper is its compiled twin for the plants the kernel covers, and
computes the same bits (tests/test_plant_kernel.py). The rigid body comes from
crane_io.sim.plant_rigid (`mass_and_bias`: compiled, or its Python source), the effects from the layout's
functions (crane_io.sim.plant_layout): the functions the compiled kernel compiles.

Per joint in plain Python: a plant has up to 8 joints, for which floats cost less than numpy's fancy
indexing and reductions; the IEEE operations are those of the compiled kernel, in the same order.
"""

from __future__ import annotations

import math
import struct
from operator import add, sub

import numpy as np

from crane_io.sim.plant_layout import P_BANDN, P_BANDP, cogging_torque, held_matrix, kinetic, other_torque


class ReferenceStepper:
    """Steps an ArmPlant's state (its attributes q, dq, motor_torque, the held joints', motor_q, motor_dq)
    with the plant's parameters (see the module docstring)."""

    compiled = False

    def __init__(self, plant, mass_and_bias):
        """`mass_and_bias`: crane_io.sim.plant_rigid.mass_and_bias, compiled or not."""
        self.plant = plant
        n = len(plant.joints)
        self._mass_and_bias = mass_and_bias
        self._arm = plant.model.armature  # a view of the model's vector (kept live: a test may change it)
        self._rows = plant.par.tolist()  # par's rows as lists of floats
        self._cog_rows = plant.cog.tolist()
        self._key = struct.Struct(f"<{4 * n + 1}d")  # a substep's inputs (q, dq, motor, external torque, h)
        self._joint_range = tuple(range(n))
        self._euler, self._drive = written_out(n)
        self._last_key, self._last_out = b"", None  # the last substep's inputs and result (_substep)
        self._held_cache: dict[float, tuple[float, float, float, float]] = {}
        self._zero_row = np.zeros((1, n))

    # ---- the stepper's interface (crane_io.sim.plant_backend) ------------------------------------------
    def step(self, en_l, mode_l, gc_l, gp_l, gains_l, lim_l, dt: float) -> None:
        """ArmPlant.step_lists' physics: the held joints, then the integrated ones."""
        p = self.plant
        held = p._held_l
        self._step_held([en_l[i] for i in held], [mode_l[i] for i in held], [gc_l[i] for i in held],
                        [gp_l[i] for i in held], [lim_l[i] for i in held], dt)
        bi = p._bi_l
        kt = p._kt_l
        tau_base = [kt[i] * gc_l[i] if (bool(en_l[i]) and mode_l[i] == 0) else 0.0 for i in bi]
        pd = p._servo_pd(en_l, mode_l, gc_l, gp_l, gains_l, lim_l)
        n_sub = max(1, math.ceil(dt / p.h - 1e-9))
        h = dt / n_sub
        ext = p.external.tolist()
        q, dq = p.q.tolist(), p.dq.tolist()
        tau_l = tau_base
        for _ in range(n_sub):
            if pd is not None:  # the servo's PD (SimplePlant.motor_torque, the same operations in floats)
                tau_l = [b if c is None else _clip(c[0] * (c[4] - qi) - c[1] * dqi, c[2], c[3])
                         for c, b, qi, dqi in zip(pd, tau_base, q, dq)]
            q, dq = self._substep(q, dq, tau_l, ext, h)
        p.q, p.dq = np.array(q), np.array(dq)
        if p._env is not None:
            p._contact = np.array(p._env.torque_list(q, dq))
            p._in_contact = p._env.in_contact(p.q)
        p.motor_torque = np.array(tau_l)

    def step_command(self, cmds, position_mask: int, dt: float) -> bool:
        return False  # the commands as arrays are the compiled stepper's

    def step_args(self, dt: float) -> None:
        return None

    def cycle_args(self, dt: float) -> None:
        return None

    def read_args(self) -> None:
        return None

    # ---- the integrated joints ---------------------------------------------------------------------------
    def _substep(self, q, dq, tau_m, ext, h: float) -> tuple:
        """One substep: ((q), (dq)) as tuples of n floats. Without backlash (motor-side state) and user
        effects, a substep is a pure function of its inputs: a joint set standing still (stuck) under an
        unchanged torque gives the same inputs substep after substep, so the last result is reused when
        the inputs are the same bits (pinocchio and the float arithmetic are deterministic: nothing
        changes)."""
        p = self.plant
        if p._backlash or p._generic:
            return self._substep_compute(q, dq, tau_m, ext, h)
        key = self._key.pack(*q, *dq, *tau_m, *ext, h)
        if key != self._last_key:
            self._last_key, self._last_out = key, self._substep_compute(q, dq, tau_m, ext, h)
        return self._last_out

    def _substep_compute(self, q, dq, tau_m, ext, h: float) -> tuple:
        p = self.plant
        if p._backlash:
            tau_m = self._gear_gap(q, dq, tau_m, h)
        if p._env is not None:  # the objects push like a hand: a pure function of q, dq
            ext = list(map(add, ext, p._env.torque_list(q, dq)))
        other = self.other_torques(q, dq)
        gen_fr = None
        if p._generic:
            gen_nf, gen_fr = self._generic_torques(q, dq)
            other = list(map(add, other, gen_nf))
        drive = self._drive(tau_m, ext, other)
        m = self._mass_and_bias(p.geo, self._arm, p.scal, np.array(q), np.array(dq)).tolist()
        rhs = list(map(sub, drive, m.pop()))  # (the last row: the bias torque; the others: M)
        if 0.0 not in dq:  # every joint moves (== : -0.0 is at rest too)
            rows = self._rows
            f = [kinetic(rows[i], v) for i, v in enumerate(dq)]
            if gen_fr is not None:
                f = list(map(add, f, gen_fr))
            ddq = _solve(m, list(map(sub, rhs, f)))
        else:
            ddq = self._stick_slip(m, rhs, dq, gen_fr)
        # semi-implicit Euler: velocity first, then position; friction stops a joint, it never reverses
        # it within a substep
        return self._euler(q, dq, ddq, h)

    def other_torques(self, q, dq) -> list:
        """Non-friction effect torques and end stops (inverse-dynamics sense), per joint."""
        k_stop, d_stop = self.plant._k_stop, self.plant._d_stop
        out = [other_torque(row, qi, dqi, k_stop, d_stop) for row, qi, dqi in zip(self._rows, q, dq)]
        for c in self._cog_rows:
            k = int(c[0])
            out[k] += cogging_torque(c, q[k])
        return out

    def kinetic_torques(self, dq) -> list:
        """Kinetic friction per joint."""
        return [kinetic(row, v) for row, v in zip(self._rows, dq)]

    def _generic_torques(self, q: list, dq: list) -> tuple[list, list]:
        """(non-friction, friction) torques of user-defined effects."""
        qa, dqa = np.array([q]), np.array([dq])
        n = len(q)
        nf, fr = [0.0] * n, [0.0] * n
        for eff, k, v in self.plant._generic:
            t = eff.torque(qa, dqa, self._zero_row, k, v)[0].tolist()
            tgt = fr if eff.friction else nf
            for i in range(n):
                tgt[i] += t[i]
        return nf, fr

    def _gear_gap(self, q: list, dq: list, tau_m: list, h: float) -> list:
        """Backlash: the motor drives its own inertia; the link only gets the torque the gear passes
        on once the gap has closed (unilateral contact). Steps the motor side by one substep and
        returns the torques that reach the links."""
        tau = list(tau_m)
        mq, mdq = self.plant.motor_q, self.plant.motor_dq
        for i, half, jm, stiffness, damping in self.plant._backlash:
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

    def _stick_slip(self, m: list, rhs: list, dq, gen_fr) -> list:
        """Accelerations when some joint stands still (m: the mass matrix, rhs: drive - bias): the stuck
        joints are held while the friction needed to hold each lies inside its static band; the joint
        pushed furthest beyond its band breaks away first, in that direction (then the others are tested
        again)."""
        free = [v != 0.0 for v in dq]
        vel = list(dq)  # velocity used for friction: tiny in the break-away direction
        rows = self._rows
        joints = self._joint_range
        n = len(joints)
        for _ in range(n + 1):  # each pass returns or frees one joint
            idx = [i for i in joints if free[i]]
            ddq = [0.0] * n
            if idx:
                net = []  # drive beyond the free joints' kinetic friction
                for a in idx:
                    f = kinetic(rows[a], vel[a])
                    if gen_fr is not None:
                        f = f + gen_fr[a]
                    net.append(rhs[a] - f)
                for a, x in zip(idx, _solve_free(m, idx, net)):
                    ddq[a] = x
            worst, push = _breaking_away(rows, m, rhs, ddq, free, idx)
            if worst < 0:
                return ddq
            # the joint pushed furthest beyond its static band breaks away first, in that direction
            free[worst] = True
            vel[worst] = 1e-12 if push > 0 else -1e-12
        return ddq

    # ---- the held joints ---------------------------------------------------------------------------------
    def held_matrix(self, dt: float) -> tuple[float, float, float, float]:
        """plant_layout.held_matrix for the plant's held joints, kept per dt."""
        a = self._held_cache.get(dt)
        if a is None:
            a = self._held_cache[dt] = held_matrix(dt, self.plant.held_omega)
        return a

    def _step_held(self, enabled, mode, goal_current, goal_position, limit, dt) -> None:
        """Held joints: position modes -> a critically damped second-order response to the goal
        (exact discretisation); current mode -> inertia + viscous friction; torque off -> at rest.
        The commands are lists over the held joints; the arithmetic is the element-wise arithmetic of the
        array form, in the same order."""
        p = self.plant
        a00, a01, a10, a11 = self.held_matrix(dt)
        w = p.held_omega
        q_out, dq_out, cur_out = [], [], []
        for on, m, gc, gp, lim, q, dq, kt, inertia, visc, ext, lo, hi in zip(
                enabled, mode, goal_current, goal_position, limit, p._held_q.tolist(), p._held_dq.tolist(),
                p._held_kt_l, p._held_inertia_l, p._held_visc_l, p._held_ext.tolist(), p._held_lo_l,
                p._held_hi_l):
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
        p._held_q = np.array(q_out)
        p._held_dq = np.array(dq_out)
        p._held_current = np.array(cur_out)


def _breaking_away(rows, m, rhs, ddq, free, idx) -> tuple[int, float]:
    """(the stuck joint pushed furthest beyond its static band, or -1 when none is; its holding torque)."""
    worst, worst_excess, push = -1, 0.0, 0.0
    for s in range(len(free)):
        if free[s]:
            continue
        coupled = 0  # sum(m[s][a] * ddq[a] for a in idx), added up as sum() does
        for a in idx:
            coupled = coupled + m[s][a] * ddq[a]
        hold = rhs[s] - coupled  # friction needed to hold joint s
        above, below = hold - rows[s][P_BANDP], -rows[s][P_BANDN] - hold
        excess = below if below > above else above  # max(above, below)
        if excess > worst_excess:
            worst, worst_excess, push = s, excess, hold
    return worst, push


def written_out(n: int) -> tuple:
    """(euler, drive) for n joints: the per-joint float arithmetic of the substep written out
    (generated once per n: a loop over n small lists costs more than the arithmetic itself):

    - euler(q, dq, ddq, h) -> ((q'), (dq')): semi-implicit Euler, velocity first (a velocity that would
      change sign in the substep stops at zero: friction stops a joint, it never reverses it), then
      position;
    - drive(tau_m, ext, other) -> [tau_m + ext - other] per joint."""
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
                f"    return [{', '.join(f't[{i}] + e[{i}] - o[{i}]' for i in r)}]"]
        space: dict = {}
        exec(compile("\n".join(src), f"<arm_plant substep, {n} joints>", "exec"), space)  # noqa: S102
        fns = _WRITTEN_OUT[n] = (space["euler"], space["drive"])
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
    """Solve a small symmetric positive-definite system by Gaussian elimination without pivoting in floats:
    `_eliminate` written out for len(b) unknowns (generated once per size: the same operations in the same
    order, `sum` included: it adds from 0.0), crane_io.sim.plant_rigid.solve's operations."""
    n = len(b)
    fn = _SOLVERS.get(n)
    if fn is None:
        fn = _SOLVERS[n] = _written_solve(n)
    return fn(a, b)


def _written_solve(n: int):
    """_eliminate for n unknowns as straight-line code (the entries below the diagonal it zeroes are never
    read again, so they are not written)."""
    r = range(n)
    src = ["def solve(a, b):", *[f"    {', '.join(f'a{i}_{c}' for c in r)}, = a[{i}]" for i in r],
           f"    {', '.join(f'b{i}' for i in r)}, = b"]
    for k in r:
        for i in range(k + 1, n):
            src.append(f"    f = a{i}_{k} / a{k}_{k}")
            src += [f"    a{i}_{c} -= f * a{k}_{c}" for c in range(k + 1, n)]
            src.append(f"    b{i} -= f * b{k}")
    for k in range(n - 1, -1, -1):
        total = "0.0"
        for c in range(k + 1, n):
            total = f"({total} + a{k}_{c} * x{c})"
        src.append(f"    x{k} = (b{k} - {total}) / a{k}_{k}" if k < n - 1 else f"    x{k} = b{k} / a{k}_{k}")
    src.append(f"    return [{', '.join(f'x{i}' for i in r)}]")
    space: dict = {}
    exec(compile("\n".join(src), f"<arm_plant solve, {n} unknowns>", "exec"), space)  # noqa: S102
    return space["solve"]


_SOLVERS: dict[int, object] = {}


def _eliminate(a: list, b: list) -> list:
    """Gaussian elimination without pivoting on lists of floats, any size (crane_io.sim.plant_rigid.solve
    on lists; what _solve writes out for 1 and 2 unknowns)."""
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
