"""A simulated person's hand on the leader arm, for `crane-collect run --sim`.

Each bilateral joint has its own on/off process: a moving phase (gamma-distributed length, mean
`mean_on_s`) made of back-to-back minimum-jerk moves to random targets inside the workspace (the
software joint limits shrunk by `workspace_margin`), then a pause (mean `mean_on_s (1 - duty) / duty`).
The processes are independent, so each joint moves about 70 % of the time (the moving phases take
`duty` of it, and the reference is nearly still at the turns between moves) and all n bilateral
joints together about 0.7^n (a third at the paper's three joints, 8 % at seven), as in the paper's
recordings. Move sizes, durations and pauses are
random (seeded), the peak speed of each move stays below `peak_speed`.

The hand is an impedance: torque = stiffness (q_ref - q) + damping (dq_ref - dq), limited to
`max_torque`, applied to the leader plant via `Plant.set_external_torque`. Joints that are not
bilateral get no torque (the servos hold them).

Tasks ([operator] task):
- "free" (default): the above, nothing else.
- "contact": the operator is told the follower's objects (`environment=`: the follower plant's
  parsed [[environment]] list, crane_io.sim.plant_config; or a crane_io.sim.environment.Environment). The
  leader and follower start at the same pose and the follower tracks the leader, so the operator
  plans on the leader's joint angles. Free-motion phases as above (targets kept out of the objects:
  joint walls shrink the joint's workspace by 0.05 rad of clearance, a plane's contact frame stays
  0.02 m above it at the move's end and midpoint) alternate with press episodes: when a free phase
  ends (gamma-distributed, sized so that pressing takes about `press_fraction` of the time) the
  running moves finish, then one object is picked at random and the hand
    1. approaches: a minimum-jerk move of the reference to the object's surface (a joint wall: the
       wall's angle on its joint; a plane: the nearest pose found by minimum-norm Newton steps on the
       kinematics of crane_io.physics.dynamics over the bilateral joints, the held joints at [held]),
    2. presses (`pressing` is True): ramps the reference in 0.3 s past the surface by
       target x (1/stiffness + 1/k_object) along the joint-space direction into the object (k_object:
       the object's stiffness in N m/rad along it; a plane's is stiffness |n^T J|^2), so the hand's
       torque (norm over the bilateral joints) settles near a target drawn from
       [press_torque_min, press_torque_max] N m; holds it; the press lasts a draw from
       [press_min_s, press_max_s] s,
    3. withdraws: a minimum-jerk move back to where the approach began; then a short pause and the
       next free phase.
  Everything is drawn from the operator's seeded generator: the same seed gives the same hand.
"""

from __future__ import annotations

import math
import sys

import numpy as np

from crane_io.description import ArmDescription, default_arm
from crane_io.errors import ConfigError

from . import operator_kernel
from .config import PAPER_JOINTS, Config, load_config
from .operator_kernel import CompiledHand, hand_torque, min_jerk
from .operator_layout import Hand

_PUSH_RAMP_S = 0.3  # s: the press force ramps up over this long
_WALL_CLEARANCE = 0.05  # rad: free-motion targets stay this far from a joint wall
_PLANE_CLEARANCE = 0.02  # m: free-motion poses keep the contact frame this far above a plane


def minimum_jerk(tau: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Normalised minimum-jerk profile s(tau) and ds/dtau for tau in [0, 1] (outside: clipped)."""
    return min_jerk(np.clip(tau, 0.0, 1.0))


class PythonHand(Hand):
    """The hand's reference backend: hand_torque in Python floats, joint by joint."""

    compiled = False

    def moves(self, rows: list) -> list:
        return rows

    def torque(self, t: float, moves: list, q: np.ndarray, dq: np.ndarray) -> np.ndarray:
        k_p, k_d, top = self._gains
        q, dq = q.tolist(), dq.tolist()
        out = [0.0] * self.n
        for i, t0, T, a, d in moves:
            out[i] = hand_torque(t, t0, T, a, d, q[i], dq[i], k_p, k_d, top)
        return np.array(out)


def _hand_backend(compiled: bool | None, n: int, o) -> Hand:
    """The hand's backend (collect/operator_kernel.py): compiled when asked for (`compiled=True`; a
    ConfigError without numba) or by default when numba is already loaded in this process (the simulator's
    kernels load it), else the Python one."""
    use = compiled if compiled is not None else "numba" in sys.modules
    fn = operator_kernel.compiled() if use else None
    if compiled and fn is None:
        raise ConfigError("the compiled operator needs numba (pip install numba)")
    if fn is None:
        return PythonHand(n, o.stiffness, o.damping, o.max_torque)
    return CompiledHand(fn, n, o.stiffness, o.damping, o.max_torque)


class _Objects:
    """The follower's objects as the operator plans with them, over the run's bilateral joints (k,):
    joint walls indexed into them, planes on the kinematics of crane_io.physics.dynamics.ArmDynamics over them
    (the other joints locked at [held]). `environment`: an Environment (the follower plant's) or its
    parsed [[environment]] list. An object on a joint the run holds cannot be pressed: one sentence."""

    def __init__(self, environment, joints: tuple[str, ...], held: dict[str, float]):
        from crane_io.sim.environment import Environment, JointWall, Plane
        from crane_io.sim.plant_config import JointWallSpec

        if not isinstance(environment, Environment) and not environment:
            raise ConfigError("the operator's contact task needs the follower's objects "
                              "(environment=, a plant with [[environment]] entries)")
        given = environment if isinstance(environment, Environment) else None
        specs = list(given.specs) if given is not None else list(environment)
        paper = joints == PAPER_JOINTS  # the plant's own planes are on these joints' kinematics
        model = None
        self.walls, self.planes, self.objects = [], [], []
        for spec in specs:
            if isinstance(spec, JointWallSpec):
                if spec.joint not in joints:
                    raise ConfigError(f"the follower's joint wall on {spec.joint} sits on a joint this run "
                                      f"holds; make {spec.joint} bilateral (`joints`) or use another plant")
                obj = JointWall(spec, joints.index(spec.joint))
                self.walls.append(obj)
            else:
                obj = next((p for p in given.planes if p.spec is spec), None) if given and paper else None
                if obj is None:
                    if model is None:
                        from crane_io.physics.dynamics import ArmDynamics

                        locked = {n: v for n, v in held.items() if n not in joints}
                        model = ArmDynamics(joints, locked=locked).model
                    obj = Plane(spec, model)
                self.planes.append(obj)
            self.objects.append(obj)


class SimulatedOperator:
    """`SimulatedOperator(seed, arm, rate)`; `start(q0, t0)` then `torque(t, q, dq) -> (n,)` each cycle.
    The hand's arithmetic is a backend's (`_hand_backend`: compiled, the same bits, when numba is already
    loaded in this process; `compiled=True` asks for it, False never uses it)."""

    def __init__(self, seed: int = 0, arm: ArmDescription | None = None, rate: float = 500.0,
                 config: Config | None = None, environment=None, compiled: bool | None = None):
        self.arm = arm or default_arm()
        self.config = config or load_config()
        self.o = self.config.operator
        self.rate = float(rate)
        self.rng = np.random.default_rng(seed)
        names = self.arm.joint_names
        self.idx = np.array([names.index(n) for n in self.arm.bilateral_joints], dtype=int)
        self._idx_list = self.idx.tolist()
        m = self.config.safety.limit_margin + self.o.workspace_margin
        lo = np.array([self.arm.joints[i].lower for i in self.idx]) + m
        hi = np.array([self.arm.joints[i].upper for i in self.idx]) - m
        mid = 0.5 * (lo + hi)
        self.lo = np.minimum(lo, mid)
        self.hi = np.maximum(hi, mid)
        self.n = len(names)
        k = len(self.idx)
        self._seg_t0 = np.zeros(k)
        self._seg_T = np.ones(k)
        self._seg_a = np.zeros(k)
        self._seg_b = np.zeros(k)
        self._on = np.zeros(k, dtype=bool)
        self._phase_end = np.zeros(k)  # end of the current on or off phase
        self._out = np.zeros(self.n)
        self._moves = None  # the moves as torque() reads them (_move_rows, _contact_rows); None: to be made
        self._hand = _hand_backend(compiled, self.n, self.o)
        self.started = False
        self.task = self.o.task
        self._pressing = False
        self._phase = "free"
        self._episode: list[tuple[str, float, np.ndarray]] = []  # press stages still to come
        self.env = self._contact_setup(environment) if self.task == "contact" else None

    def _contact_setup(self, environment):
        """The contact task's objects (an _Objects over the bilateral joints) and the free workspace kept
        out of the walls."""
        env = _Objects(environment, tuple(self.arm.bilateral_joints), self.config.held)
        self._reach_lo, self._reach_hi = self.lo.copy(), self.hi.copy()
        for wall in env.walls:
            j = wall.index
            if wall.sign > 0:
                self.hi[j] = min(self.hi[j], wall.angle - _WALL_CLEARANCE)
            else:
                self.lo[j] = max(self.lo[j], wall.angle + _WALL_CLEARANCE)
            if self.lo[j] > self.hi[j]:
                raise ConfigError(f"the joint walls leave {self.arm.bilateral_joints[j]} no free workspace "
                                  "for the simulated operator")
        self._free_end = math.inf
        self._transit = self.o.min_move_s + self.o.max_move_s  # approach + withdraw, last episode
        self._t_start, self._pressed = 0.0, 0.0  # when the task started, the time pressed since (s)
        return env

    @property
    def pressing(self) -> bool:
        """True while the hand presses against an object (contact task: force ramp and hold)."""
        return self._pressing

    @property
    def phase(self) -> str:
        """What the hand does now: "free" (free motion), or in a press episode of the contact task
        "approach", "ramp", "hold" (these two are `pressing`), "withdraw"."""
        return self._phase

    # ---- reference ----------------------------------------------------------------------------------
    def start(self, q0: np.ndarray, t0: float = 0.0) -> None:
        """Begin from the leader's pose q0 (n,) at time t0: every joint starts with a short pause."""
        q0 = np.asarray(q0, dtype=float)[self.idx]
        self._seg_a[:] = q0
        self._seg_b[:] = q0
        self._seg_t0[:] = t0
        self._seg_T[:] = 1e-9
        self._on[:] = False
        self._phase_end[:] = t0 + self.rng.uniform(0.1, 1.0, size=len(self.idx))
        self.started = True
        self._moves = None
        if self.env is not None:
            self._episode = []
            self._pressing, self._phase = False, "free"
            self._t_start, self._pressed = t0, 0.0
            self._free_end = t0 + self._free_length(t0)

    def _pause_mean(self) -> float:
        return self.o.mean_on_s * (1.0 - self.o.duty) / self.o.duty

    def _new_move(self, j: int, t: float) -> None:
        if self.env is not None:
            self._new_free_move(j, t)
            return
        o = self.o
        q = self._seg_b[j]
        span = self.hi[j] - self.lo[j]
        for _ in range(8):
            target = q + self.rng.uniform(-0.5, 0.5) * span
            if self.lo[j] <= target <= self.hi[j] and abs(target - q) > 0.05 * span:
                break
        else:
            target = self.rng.uniform(self.lo[j], self.hi[j])
        dist = abs(target - q)
        T = max(self.rng.uniform(o.min_move_s, o.max_move_s), 1.875 * dist / o.peak_speed)
        self._seg_t0[j] = t
        self._seg_T[j] = T
        self._seg_a[j] = q
        self._seg_b[j] = target

    def _advance(self, t: float) -> None:
        t0s, Ts = self._seg_t0.tolist(), self._seg_T.tolist()
        ended = [j for j in range(len(t0s)) if t >= t0s[j] + Ts[j]]
        if ended:
            self._moves = None
        for j in ended:
            # the joint is at rest at the end of its move: continue, pause or resume
            if t < self._phase_end[j]:
                if self._on[j]:
                    self._new_move(j, t)
                continue
            if self._on[j] and self.o.duty < 1.0:
                self._on[j] = False
                self._phase_end[j] = t + self.rng.gamma(2.0, self._pause_mean() / 2.0)
                self._seg_a[j] = self._seg_b[j]
            else:
                self._on[j] = True
                self._phase_end[j] = t + self.rng.gamma(2.0, self.o.mean_on_s / 2.0)
                self._new_move(j, t)

    # ---- contact task --------------------------------------------------------------------------------
    def _free_length(self, t: float) -> float:
        """Length (s) of the next free phase, drawn at time t (gamma, shape 2). Its mean makes the time
        pressed so far plus one mean press come to `press_fraction` of the time by the end of the next
        press, counting the last episode's approach and withdrawal as free time (at least 0.5 s)."""
        o = self.o
        mean_press = 0.5 * (o.press_min_s + o.press_max_s)
        total = (self._pressed + mean_press) / o.press_fraction  # elapsed time at the next press's end
        mean = max(0.5, total - (t - self._t_start) - mean_press - self._transit)
        return float(self.rng.gamma(2.0, mean / 2.0))

    def _free_ok(self, j: int, target: float) -> bool:
        """Whether moving joint j to `target` (rad) keeps the planes' contact frames clear (at the end and
        the midpoint of the move, the other joints at the ends of their moves)."""
        if not self.env.planes:
            return True
        end = self._seg_b.copy()
        end[j] = target
        mid = 0.5 * (self._seg_b + end)
        return all(p.distance(x) >= _PLANE_CLEARANCE for p in self.env.planes for x in (end, mid))

    def _new_free_move(self, j: int, t: float) -> None:
        """A free move of joint j (contact task): like _new_move, with targets out of the objects; a joint
        that finds none stays where it is for one short move."""
        o = self.o
        q = self._seg_b[j]
        span = self.hi[j] - self.lo[j]
        target = q
        for _ in range(8):
            x = q + self.rng.uniform(-0.5, 0.5) * span
            if self.lo[j] <= x <= self.hi[j] and abs(x - q) > 0.05 * span and self._free_ok(j, x):
                target = x
                break
        dist = abs(target - q)
        self._seg_t0[j] = t
        self._seg_T[j] = max(self.rng.uniform(o.min_move_s, o.max_move_s), 1.875 * dist / o.peak_speed)
        self._seg_a[j] = q
        self._seg_b[j] = target

    def _move_time(self, a: np.ndarray, b: np.ndarray) -> float:
        """Duration (s) of a minimum-jerk move of all joints from a to b (rad)."""
        dist = float(np.max(np.abs(b - a)))
        return max(float(self.rng.uniform(self.o.min_move_s, self.o.max_move_s)),
                   1.875 * dist / self.o.peak_speed)

    def _plan_press(self, q0: np.ndarray) -> list[tuple[str, float, np.ndarray]] | None:
        """The stages (name, duration s, reference at its end rad) of a press from rest at q0, or None
        when the picked object is out of reach."""
        o = self.o
        obj = self.env.objects[int(self.rng.integers(len(self.env.objects)))]
        if hasattr(obj, "normal"):
            plan = obj.surface(q0, self._reach_lo, self._reach_hi)
        else:
            plan = obj.surface(q0)
        target = float(self.rng.uniform(o.press_torque_min, o.press_torque_max))
        hold = float(self.rng.uniform(o.press_min_s, o.press_max_s))
        if plan is None:
            return None
        q_s, direction, k_object = plan
        q_press = q_s + direction * target * (1.0 / o.stiffness + 1.0 / k_object)
        ramp = min(_PUSH_RAMP_S, 0.5 * hold)
        approach, withdraw = self._move_time(q0, q_s), self._move_time(q_press, q0)
        self._transit = approach + withdraw
        self._pressed += hold
        return [("approach", approach, q_s), ("ramp", ramp, q_press), ("hold", hold - ramp, q_press),
                ("withdraw", withdraw, q0.copy())]

    def _next_stage(self) -> None:
        """Start the next stage of the press episode where the current one ends (or resume free motion)."""
        end = float(self._seg_t0[0] + self._seg_T[0])
        if not self._episode:
            self._pressing, self._phase = False, "free"
            self._on[:] = False
            self._phase_end[:] = end + self.rng.uniform(0.1, 1.0, size=len(self.idx))
            self._free_end = end + self._free_length(end)
            return
        name, duration, target = self._episode.pop(0)
        self._seg_a[:] = self._seg_b
        self._seg_b[:] = target
        self._seg_t0[:] = end
        self._seg_T[:] = max(duration, 1e-9)
        self._phase = name
        self._pressing = name in ("ramp", "hold")

    def _advance_contact(self, t: float) -> None:
        """The contact task's schedule: free phases (the per-joint processes), press episodes (all joints
        on one stage at a time; `_free_end` is infinite while an episode runs)."""
        if self._free_end == math.inf:
            while self._free_end == math.inf and t >= self._seg_t0[0] + self._seg_T[0]:
                self._next_stage()
            return
        if t < self._free_end:
            self._advance(t)
            return
        if np.all(t >= self._seg_t0 + self._seg_T):  # the free phase is over and every move has ended
            stages = self._plan_press(self._seg_b.copy())
            if stages is None:
                self._free_end = t + self._free_length(t)
                return
            self._episode = stages
            self._seg_t0[:] = t
            self._seg_T[:] = 0.0
            self._free_end = math.inf
            self._next_stage()

    def reference(self, t: float) -> tuple[np.ndarray, np.ndarray]:
        """Reference angle and velocity (k,) of the bilateral joints at time t."""
        if not self.started:
            raise RuntimeError("call start(q0) before asking for the reference")
        if self.env is not None:
            self._advance_contact(t)
        else:
            self._advance(t)
        self._moves = None  # torque() makes its moves again
        return self._profile(t)

    def _profile(self, t: float) -> tuple[np.ndarray, np.ndarray]:
        tau = (t - self._seg_t0) / self._seg_T
        s, ds = minimum_jerk(tau)
        d = self._seg_b - self._seg_a
        return self._seg_a + d * s, d * ds / self._seg_T

    def _move_rows(self, ends: bool = True) -> tuple[float, bool, object]:
        """The moves, made again whenever the schedule changes: (the time before which `_advance` has
        nothing to do; no T is 0; per joint (index, t0, T, a, b - a) in the hand backend's form).
        That time is the earliest over the joints of the end t0 + T of a moving joint's move, and of a
        pausing joint's max(t0 + T, end of its pause): `_advance` leaves a pausing joint alone until both
        have passed (it does not draw, nor change its segment). ends=False: that time is not needed (inf)."""
        t0s, Ts, a_s, b_s = (x.tolist() for x in (self._seg_t0, self._seg_T, self._seg_a, self._seg_b))
        end = math.inf
        if ends:
            for on, t0, T, pause_end in zip(self._on.tolist(), t0s, Ts, self._phase_end.tolist()):
                e = t0 + T
                if not on and pause_end > e:
                    e = pause_end
                if e < end:
                    end = e
        rows = [(i, t0, T, a, b - a) for i, t0, T, a, b in zip(self._idx_list, t0s, Ts, a_s, b_s)]
        return end, 0.0 not in Ts, self._hand.moves(rows)

    def _contact_rows(self) -> tuple[float, bool, object]:
        """_move_rows for the contact task, after `_advance_contact`: the time before which it has nothing to
        do first. In a press episode the end of the stage; in a free phase the next event of its joints'
        processes (`_advance`) when it comes before the phase's end, else the end of the phase or of the
        last move running then, whichever is later (a press then starts)."""
        if self._free_end == math.inf:
            rows = self._move_rows(False)
            return (float(self._seg_t0[0] + self._seg_T[0]),) + rows[1:]
        rows = self._move_rows()
        if rows[0] < self._free_end:
            return rows
        last = max((t0 + T for t0, T in zip(self._seg_t0.tolist(), self._seg_T.tolist())), default=-math.inf)
        return (max(self._free_end, last),) + rows[1:]

    def moving(self) -> np.ndarray:
        """Which bilateral joints are in a moving phase now (bool (k,))."""
        return self._on.copy()

    # ---- the hand -----------------------------------------------------------------------------------
    def torque(self, t: float, q: np.ndarray, dq: np.ndarray) -> np.ndarray:
        """External torque (n,) the hand applies to the leader's joints, in arm.joints order."""
        if self.started:
            moves = self._moves
            if moves is None or not t < moves[0]:  # a move or phase may have ended: the schedule goes on
                if self.env is not None:
                    self._advance_contact(t)
                    moves = self._moves = self._contact_rows()
                else:
                    self._advance(t)
                    moves = self._moves = self._move_rows()
            if moves[1]:  # the arithmetic of `_profile` and the impedance below, joint by joint
                return self._hand.torque(t, moves[2], q, dq)
            q_ref, dq_ref = self._profile(t)
        else:
            q_ref, dq_ref = self.reference(t)
        o = self.o
        tau = o.stiffness * (q_ref - q[self.idx]) + o.damping * (dq_ref - dq[self.idx])
        out = self._out.copy()
        out[self.idx] = np.clip(tau, -o.max_torque, o.max_torque)
        return out
