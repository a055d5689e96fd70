"""A simulated person's hand on the leader arm, for `crane-collect run --sim`.

Each bilateral joint has its own on/off process: a moving phase (gamma-distributed length, mean
`mean_on_s`) made of back-to-back minimum-jerk moves to random targets inside the workspace (the
software joint limits shrunk by `workspace_margin`), then a pause (mean `mean_on_s (1 - duty) / duty`).
The processes are independent, so each joint moves about `duty` (70 %) of the time and all three
together about duty^3 (a third), as in the paper's recordings. Move sizes, durations and pauses are
random (seeded), the peak speed of each move stays below `peak_speed`.

The hand is an impedance: torque = stiffness (q_ref - q) + damping (dq_ref - dq), limited to
`max_torque`, applied to the leader plant via `Plant.set_external_torque`. Joints that are not
bilateral get no torque (the servos hold them).
"""

from __future__ import annotations

import numpy as np

from crane_io.description import ArmDescription, default_arm

from .config import Config, load_config


def minimum_jerk(tau: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Normalised minimum-jerk profile s(tau) and ds/dtau for tau in [0, 1]."""
    tau = np.clip(tau, 0.0, 1.0)
    t2 = tau * tau
    s = t2 * tau * (10.0 - 15.0 * tau + 6.0 * t2)
    ds = 30.0 * t2 * (1.0 - 2.0 * tau + t2)
    return s, ds


class SimulatedOperator:
    """`SimulatedOperator(seed, arm, rate)`; `start(q0, t0)` then `torque(t, q, dq) -> (n,)` each cycle."""

    def __init__(self, seed: int = 0, arm: ArmDescription | None = None, rate: float = 500.0,
                 config: Config | None = None):
        self.arm = arm or default_arm()
        self.config = config or load_config()
        self.o = self.config.operator
        self.rate = float(rate)
        self.rng = np.random.default_rng(seed)
        names = self.arm.joint_names
        self.idx = np.array([names.index(n) for n in self.arm.bilateral_joints], dtype=int)
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
        self.started = False

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

    def _pause_mean(self) -> float:
        return self.o.mean_on_s * (1.0 - self.o.duty) / self.o.duty

    def _new_move(self, j: int, t: float) -> None:
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
        for j in np.flatnonzero(t >= self._seg_t0 + self._seg_T):
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

    def reference(self, t: float) -> tuple[np.ndarray, np.ndarray]:
        """Reference angle and velocity (k,) of the bilateral joints at time t."""
        if not self.started:
            raise RuntimeError("call start(q0) before asking for the reference")
        self._advance(t)
        tau = (t - self._seg_t0) / self._seg_T
        s, ds = minimum_jerk(tau)
        d = self._seg_b - self._seg_a
        return self._seg_a + d * s, d * ds / self._seg_T

    def moving(self) -> np.ndarray:
        """Which bilateral joints are in a moving phase now (bool (k,))."""
        return self._on.copy()

    # ---- the hand -----------------------------------------------------------------------------------
    def torque(self, t: float, q: np.ndarray, dq: np.ndarray) -> np.ndarray:
        """External torque (n,) the hand applies to the leader's joints, in arm.joints order."""
        q_ref, dq_ref = self.reference(t)
        o = self.o
        tau = o.stiffness * (q_ref - q[self.idx]) + o.damping * (dq_ref - dq[self.idx])
        out = self._out.copy()
        out[self.idx] = np.clip(tau, -o.max_torque, o.max_torque)
        return out
