"""The reaction-force observer of one arm with a learned inverse-dynamics model in place of the nominal one.

A crane-train model f(q, dq, ddq) says what motor torque the arm's own dynamics need (gravity, inertia,
friction, everything it learned). It was trained on signals that went through the paper's
preprocessing at the recording rate (train/data/preprocess.py): with the low-pass L (cutoff w) and the
pseudo-derivative D (cutoff g) of train/data/filters.py (first-order, Tustin),

    q_m = L(L(q)),   dq_m = L(D(q)),   ddq_m = D(D(q)),   tau_m = L(L(tau_applied)),

every one of them two first-order lags behind the raw signal (exactly equal lags when g = w, the
default 25 rad/s). The loop runs the SAME causal filters, sample by sample, at its own rate on the
servos' angles and on the torque it applied, so the model sees inputs built exactly as in training,
and the reaction torque is what the model cannot explain:

    tau_res = tau_m[k-1] - f(q_m[k-1], dq_m[k-1], ddq_m[k-1])

Both sides carry the same filtering and the same delay (two lags of the model's cutoff, about 2/w =
80 ms of group delay at 25 rad/s, against 1/g = 50..67 ms of the nominal observer's single lag at
15..20 rad/s). The pair is taken one cycle back because the torque of cycle k is only known after
the reaction of cycle k was used to compute it: row k of a training session pairs the angle read in
cycle k with the torque sent in cycle k, and so does the loop, one period (2 ms) later. In free motion
a perfect model gives tau_res = 0; against an object or a hand it gives -tau_ext (the world's torque on
the joint), the same sign convention as the nominal observer (collect/controller.py).

Standing still, the velocity is inside the paper's dead zone: |dq_m| <= alpha sigma_j (sigma_j the std of
the joint's velocity in the training data, recorded by crane-train fit as the preprocessing setting
`dead_zone_rad_s`). There the torque is not a function of (q, dq, ddq) - static friction holds the
joint anywhere in its band - and the masked loss never asked the model for it; a Coulomb term
sign(dq) would flip with the velocity's noise and throw steps of twice the friction into the force
channel. So the model is given dq = 0 for a joint inside its dead zone: it predicts what the joint
needs standing still apart from friction, and the friction it holds reads as reaction, as with the
nominal observer. A model saved without `dead_zone_rad_s` gets the filtered velocity as it is, and
so does a model whose Coulomb-type terms use the loop's smooth sign tanh(dq / v0) (`[controller]
model_coulomb_velocity` > 0, set on the model by collect/loop_models.py): there the tanh, not the dead
zone, keeps a creeping joint's friction near zero.

Two other filterings are options (`[controller]`, docs/collect.md "One lag" and "The loop's own
cutoff"). `model_cutoff = c` (`cutoff`): the same two lags on both sides at c rad/s instead of the
model's cutoffs; with `[controller.jointN] model_cutoff` set, `cutoff` is a pair (w, g) of per-joint
cutoffs (J,) (collect/loop_models.py), each joint's torque and inputs filtered at its own.
`model_filters = "observer"` (`one_lag`: each joint's observer cutoff g): the applied
torque through ONE first-order low-pass at g, the nominal observer's lag, and the model's inputs
through the training's filter structure at 2 g, whose group delay 2/(2g) = 1/g is that lag's:

    tau_res = L_g(tau_applied)[k-1] - f(x[k-1]),   x = (L_2g(L_2g(q)), L_2g(D_2g(q)), D_2g(D_2g(q)))

which is the nominal estimate minus the model's correction, f(x) less what the nominal observer
subtracts (gravity, J times its filtered acceleration, viscous): an outside torque reaches tau_res
through the nominal observer's single lag.

The filters run at the time that really passed: a cycle that came late (a loaded machine, a slow
adapter) is filtered with Tustin coefficients for its own dt, as the controller's observers are, so the
model's velocity and acceleration stay in rad/s and rad/s^2; at the nominal period they are exactly the
training's.

Per cycle the model is evaluated once (crane_io.physics.loop_model: numpy, a few microseconds). A prediction
that is not finite or exceeds `limit` on a joint is not used: that joint falls back to the nominal
reaction torque for that cycle (`ModelReaction.update` returns which joints did). A model is trusted
only near the poses it was trained on: when a filtered angle lies more than POSE_MARGIN_RAD outside the
training data's range (`input_range`, recorded by crane-train fit), every joint of the model falls back
(`out_of_range` says so). An arm resting outside the operator's workspace - lying on the table, say -
would otherwise get a model's extrapolation as false force the moment bilateral control engages.
"""

from __future__ import annotations

import numpy as np

POSE_MARGIN_RAD = 0.1  # how far outside the training data's angles the model is still trusted (5.7 deg)


def _cutoff(value):
    a = np.asarray(value, dtype=float)
    return float(a) if a.ndim == 0 else a


class LagFilters:
    """The paper's first-order low-pass w/(s+w) and pseudo-derivative g s/(s+g), Tustin at `rate_hz`,
    one sample at a time on (k,) vectors, started in steady state at the first sample (as
    train/data/filters.py: the low-pass output starts at the input, the derivative at 0).

    `set_period(dt)` re-discretises them for a cycle that took dt seconds (Tustin at 1/dt), so that a
    loop running late still filters and differentiates in real time: at the nominal period the
    coefficients are exactly those of `rate_hz`."""

    def __init__(self, cutoff_rad_s, pseudo_diff_rad_s, rate_hz: float):
        # scalars (rad/s), or (J,) arrays: one cutoff per joint
        self.w, self.g = _cutoff(cutoff_rad_s), _cutoff(pseudo_diff_rad_s)
        self.period = None
        self._set(2.0 * float(rate_hz))
        self.period = 1.0 / float(rate_hz)

    def _set(self, c: float) -> None:
        w, g = self.w, self.g
        # y[n] = b0 (x[n] + x[n-1]) - a1 y[n-1]                    (low-pass)
        self.lp_b, self.lp_a = w / (c + w), (w - c) / (c + w)
        # y[n] = d0 (x[n] - x[n-1]) - e1 y[n-1]                    (pseudo-derivative)
        self.pd_b, self.pd_a = g * c / (c + g), (g - c) / (c + g)

    def set_period(self, dt: float) -> None:
        """Discretise for a sample dt seconds after the previous one (nothing to do when dt is the last
        period)."""
        if dt != self.period and dt > 0:
            self._set(2.0 / dt)
            self.period = dt

    def low_pass(self, x: np.ndarray, x_prev: np.ndarray, y_prev: np.ndarray) -> np.ndarray:
        return self.lp_b * (x + x_prev) - self.lp_a * y_prev

    def derivative(self, x: np.ndarray, x_prev: np.ndarray, y_prev: np.ndarray) -> np.ndarray:
        return self.pd_b * (x - x_prev) - self.pd_a * y_prev


class ModelInputs:
    """q_m = L(L(q)), dq_m = L(D(q)), ddq_m = D(D(q)) and tau_m = L(L(tau)) of train/data/preprocess.py,
    causal, one sample at a time: `push(q, tau)` with (k,) arrays; the filtered signals in `.q`, `.dq`,
    `.ddq`, `.tau` (None before the first push)."""

    def __init__(self, filters: LagFilters):
        self.f = filters
        self._x = None  # the last raw (q, tau)
        self.q = self.dq = self.ddq = self.tau = None

    @property
    def started(self) -> bool:
        return self._x is not None

    def push(self, q: np.ndarray, tau: np.ndarray) -> None:
        f = self.f
        q = np.array(q, dtype=float)
        tau = np.array(tau, dtype=float)
        if self._x is None:  # steady state at the first sample
            z = np.zeros_like(q)
            self._x = (q, tau)
            self._lq, self.q = q.copy(), q.copy()  # L(q), L(L(q))
            self._d, self.dq, self.ddq = z.copy(), z.copy(), z.copy()  # D(q), L(D(q)), D(D(q))
            self._lt, self.tau = tau.copy(), tau.copy()  # L(tau), L(L(tau))
            return
        q0, t0 = self._x
        lq = f.low_pass(q, q0, self._lq)
        self.q = f.low_pass(lq, self._lq, self.q)
        d = f.derivative(q, q0, self._d)
        self.dq = f.low_pass(d, self._d, self.dq)
        self.ddq = f.derivative(d, self._d, self.ddq)
        lt = f.low_pass(tau, t0, self._lt)
        self.tau = f.low_pass(lt, self._lt, self.tau)
        self._lq, self._d, self._lt = lq, d, lt
        self._x = (q, tau)


class ModelReaction:
    """The learned-model reaction torque of one arm (see the module docstring).

    `model`: a crane_io.physics.loop_model.LoopModel (anything with `joint_names`, `preprocessing` and
    `predict_one(q, dq, ddq)`); `arm_joint_names`: the arm's joints in the controller's order;
    `limit`: (J,) N m per model joint, the largest plausible prediction (the joint's maximum motor
    torque); `rate_hz`: the loop's rate, at which the filters are discretised."""

    def __init__(self, model, arm_joint_names, limit: np.ndarray, rate_hz: float, one_lag=None,
                 cutoff=None):
        self.model = model
        names = list(arm_joint_names)
        self.joint_names = tuple(model.joint_names)
        self.idx = np.array([names.index(n) for n in self.joint_names], dtype=int)
        pre = model.preprocessing
        self.one_lag = None if one_lag is None else np.asarray(one_lag, dtype=float)  # (J,) rad/s or None
        if self.one_lag is None:  # the training's filters on both sides (two lags of the model's cutoff,
            # or of `cutoff` rad/s for both the low-pass and the pseudo-derivative when given)
            if isinstance(cutoff, tuple):  # per joint (w (J,), g (J,)): collect/loop_models.py
                w, g = np.broadcast_arrays(*(np.asarray(c, dtype=float) for c in cutoff))
                pairs = list(dict.fromkeys(zip(w.tolist(), g.tolist())))  # distinct (w, g), in joint order
                masks = [(w == a) & (g == b) for a, b in pairs]
                self._extra = [(m, LagFilters(a, b, rate_hz)) for m, (a, b) in zip(masks[1:], pairs[1:])]
                w, g = pairs[0]
            else:
                w, g = (pre["cutoff_rad_s"], pre["pseudo_diff_rad_s"]) if not cutoff else (cutoff, cutoff)
            self.filters = LagFilters(w, g, rate_hz)
            self.torque_filter = None
        else:  # the applied torque through one lag of g, the model's inputs through two lags of 2 g
            self.filters = LagFilters(2.0 * self.one_lag, 2.0 * self.one_lag, rate_hz)
            self.torque_filter = LagFilters(self.one_lag, self.one_lag, rate_hz)
        self._u = self._u_lag = None  # one-lag: the last applied torque (J,) and its low-pass
        self.inputs = ModelInputs(self.filters)
        # per-joint cutoffs: the joints of each further cutoff (mask (J,), filters, inputs at that cutoff);
        # each joint's torque and prediction come from the filters at its own cutoff, the model evaluated
        # once per cutoff on every joint's inputs at that cutoff (no mixed delays in coupled terms)
        self._extra = [(m, f, ModelInputs(f)) for m, f in getattr(self, "_extra", ())]
        self.limit = np.asarray(limit, dtype=float)
        dz = pre.get("dead_zone_rad_s")
        self.dead_zone = (np.asarray(dz, dtype=float) if dz is not None and len(dz) == len(self.idx)
                          else None)  # (J,) rad/s, or None: the velocity is given as it is
        rng = pre.get("input_range") or {}
        lo, hi = rng.get("q_min"), rng.get("q_max")
        self.q_lo = self.q_hi = None  # (J,) rad: the trusted poses, or None (a model saved without them)
        if lo is not None and hi is not None and len(lo) == len(hi) == len(self.idx):
            self.q_lo = np.asarray(lo, dtype=float) - POSE_MARGIN_RAD
            self.q_hi = np.asarray(hi, dtype=float) + POSE_MARGIN_RAD
        self.out_of_range = False  # the last prediction was at a pose outside the training data's
        self._pred = None  # prediction of the previous cycle (J,)
        self._ok = np.zeros(len(self.idx), dtype=bool)
        self.fallback_cycles = np.zeros(len(self.idx), dtype=int)  # cycles each joint fell back

    def update(self, q: np.ndarray, applied_prev: np.ndarray,
               dt: float | None = None) -> tuple[np.ndarray, np.ndarray]:
        """Push this cycle's angles (n,) and the torque applied in the previous cycle (n,) (arm order);
        return (tau_res (J,), ok (J,) bool) for the model's joints: the reaction torque of the previous
        cycle's pair, and which joints had a usable prediction (the others must use the nominal one).
        dt: seconds since the previous cycle (default: the nominal period); a late cycle's filters are
        discretised for the time that really passed, as the controller's own are."""
        i = self.idx
        inp = self.inputs
        if dt is not None:
            self.filters.set_period(dt)
            if self.torque_filter is not None:
                self.torque_filter.set_period(dt)
            for _, f, _ in self._extra:
                f.set_period(dt)
        first = not inp.started
        u = applied_prev[i]
        inp.push(q[i], u)
        tau_m = inp.tau
        for m, _, x in self._extra:
            x.push(q[i], u)
            tau_m = np.where(m, x.tau, tau_m)
        if first:  # nothing filtered yet: the steady state at this sample is the first pair
            self._predict()
        tau_res = (tau_m if self.torque_filter is None else self._one_lag(u)) - self._pred
        ok = self._ok.copy()
        self.fallback_cycles += ~ok
        self._predict()  # for the next cycle, on this cycle's filtered angles
        return tau_res, ok

    def _one_lag(self, u: np.ndarray) -> np.ndarray:
        """The applied torque (J,) through one first-order low-pass at `one_lag` (steady state at the
        first sample)."""
        if self._u is None:
            self._u_lag = np.array(u, dtype=float)
        else:
            self._u_lag = self.torque_filter.low_pass(u, self._u, self._u_lag)
        self._u = np.array(u, dtype=float)
        return self._u_lag

    def _predict_on(self, inp: ModelInputs) -> np.ndarray:
        dq = inp.dq
        if self.dead_zone is not None and not getattr(self.model, "coulomb_velocity", 0.0) > 0:
            dq = np.where(np.abs(dq) > self.dead_zone, dq, 0.0)
        return np.array(self.model.predict_one(inp.q, dq, inp.ddq), dtype=float)

    def _predict(self) -> None:
        inp = self.inputs
        pred = self._predict_on(inp)
        for m, _, x in self._extra:
            pred = np.where(m, self._predict_on(x), pred)
        self._ok = np.isfinite(pred) & (np.abs(pred) <= self.limit)
        if self.q_lo is not None:
            self.out_of_range = bool(((inp.q < self.q_lo) | (inp.q > self.q_hi)).any())
            if self.out_of_range:
                self._ok[:] = False
        self._pred = np.where(self._ok, pred, 0.0)
