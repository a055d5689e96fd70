"""The 4-channel controller's reference backend (collect/controller_layout.ControlLaw): numpy arrays over the
joints, the learned reaction models and the friction dither (the law: collect/controller.py's docstring)."""

from __future__ import annotations

import numpy as np

from .controller_layout import ArmEstimates, ArmSignals, Commands, ControlLaw


class _Observer:
    """Pseudo-derivative + DOB + RFOB state of one arm; with a learned model (ModelReaction) the
    reaction torque of the joints it covers comes from the model (collect/model_reaction.py)."""

    def __init__(self, ctl, model=None):
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
        if c.coulomb is not None:
            tau_res = tau_res - c.coulomb * np.tanh(w / c.coulomb_velocity)
        if self.model is not None:
            res_m, ok = self.model.update(q, self.applied, dt)
            i = self.model.idx
            tau_res[i] = np.where(ok, res_m, tau_res[i])
            self.fallback = ~ok
        return w, tau_dis, tau_res


class NumpyLaw(ControlLaw):
    """The reference backend of `ctl` (a BilateralController: its parameters, models and `decay`)."""

    compiled = False

    def __init__(self, ctl):
        self.ctl = ctl
        self.reset()

    def reset(self) -> None:
        ctl, make = self.ctl, self.ctl.models
        self._obs_l = _Observer(ctl, make["leader"]() if make.get("leader") else None)
        self._obs_f = _Observer(ctl, make["follower"]() if make.get("follower") else None)
        self.leader: ArmEstimates | None = None
        self.follower: ArmEstimates | None = None
        self._dither_t = 0.0  # s of bilateral control so far (the dither's time)
        self.dither = np.zeros(ctl.n)  # (n,) N m: the dither added to the follower's last step
        self._comb = None  # (N, n) the follower's last N tau_res (dither_filter), filled on the first step
        self._comb_k = 0

    def observer(self, arm: str) -> _Observer:
        return self._obs_l if arm == "leader" else self._obs_f

    def _comb_filter(self, res: np.ndarray, dt: float) -> np.ndarray:
        """The mean of the follower's last N = round(1 / (f dt)) reaction estimates (this one included)."""
        if self._comb is None:
            size = max(1, int(round(1.0 / (self.ctl.dither_frequency * dt))))
            self._comb = np.repeat(res[None, :], size, axis=0)
        self._comb[self._comb_k] = res
        self._comb_k = (self._comb_k + 1) % len(self._comb)
        return self._comb.mean(axis=0)

    def _dither(self, dt: float) -> np.ndarray | None:
        """d(t) (n,) for this step (bilateral joints only), and advance t; None when the dither is off."""
        c = self.ctl
        if c.dither_amplitude <= 0.0:
            return None
        s = np.sin(2.0 * np.pi * c.dither_frequency * self._dither_t)
        self._dither_t += dt
        if c.dither_square:
            s = 1.0 if s >= 0.0 else -1.0
        a = c.dither_amplitudes
        if c.dither_floor.any():  # at least dither_min_velocity of velocity amplitude at this pose
            a = np.sign(a) * np.maximum(np.abs(a), c.dither_floor * self._obs_f.J)
        self.dither = a * s
        return self.dither

    def step(self, leader: ArmSignals, follower: ArmSignals, dt: float) -> Commands:
        c = self.ctl
        ql = np.asarray(leader.q, dtype=float)
        qf = np.asarray(follower.q, dtype=float)
        wl, dis_l, res_l = self._obs_l.update(ql, dt)
        wf, dis_f, res_f = self._obs_f.update(qf, dt)
        if c.dither_filter:
            res_f = self._comb_filter(res_f, dt)
        e = ql - qf
        if c.deadband > 0:
            e = np.sign(e) * np.maximum(np.abs(e) - c.deadband, 0.0)
        J = 0.5 * (self._obs_l.J + self._obs_f.J)
        tau_p = 0.5 * J * (c.kp * e + c.kd * (wl - wf))
        tau_f = -0.5 * c.kf * (res_l + res_f)
        tau_l = (-tau_p + tau_f + dis_l) * c.bil
        tau_f_ref = (tau_p + tau_f + dis_f) * c.bil
        d = self._dither(dt)
        if d is not None:
            tau_f_ref = tau_f_ref + d
        self._obs_l.applied = tau_l
        self._obs_f.applied = tau_f_ref
        held = c.held
        self.leader = ArmEstimates(wl, dis_l + held, res_l + held)
        self.follower = ArmEstimates(wf, dis_f + held, res_f + held)
        return Commands(tau_l, tau_f_ref, tau_l / c.kt, tau_f_ref / c.kt)

    def hold(self, leader: ArmSignals, follower: ArmSignals, ref_leader: tuple, ref_follower: tuple,
             dt: float) -> Commands:
        c = self.ctl
        out = []
        pairs = ((self._obs_l, leader, ref_leader), (self._obs_f, follower, ref_follower))
        for obs, sig, (q_ref, dq_ref) in pairs:
            q = np.asarray(sig.q, dtype=float)
            w, dis, res = obs.update(q, dt)
            tau = (0.5 * obs.J * (c.kp * (q_ref - q) + c.kd * (dq_ref - w)) + dis) * c.bil
            obs.applied = tau
            out.append((tau, ArmEstimates(w, dis + c.held, res + c.held)))
        (tau_l, est_l), (tau_f, est_f) = out
        self.leader, self.follower = est_l, est_f
        return Commands(tau_l, tau_f, tau_l / c.kt, tau_f / c.kt)

    def applied(self, tau_leader: np.ndarray, tau_follower: np.ndarray) -> None:
        bil = self.ctl.bil
        self._obs_l.applied = np.asarray(tau_leader, dtype=float) * bil
        self._obs_f.applied = np.asarray(tau_follower, dtype=float) * bil
