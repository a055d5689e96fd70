"""One sample at a time, fast and without torch: the prediction a model makes inside a 2 ms control cycle.

    predictor = NumpyPredictor.from_model(load_model("models/masked"))
    tau = predictor.predict_one(q, dq, ddq)   # (J,) float64 arrays in the model's joint order -> (J,) N m

Every method is covered and gives the model's own `predict` to 1e-6 relative (float64 here; the torch
network runs in float32):
- mlp-mse, mlp-masked: the network in float64 numpy with the input and output standardisation folded
  into the weights once (W1 / x_std, ...), so a call is two small matrix products, a bias and a ReLU;
- rigid-body: pinocchio's joint-torque regressor of the one sample (one compiled call) times the base
  parameters spread over the standard ones (dependent columns zero), plus each effect term; the
  built-in one-joint effects are evaluated on scalars (their formulas as in crane_io/effects/library.py),
  any other effect (payload, torque-constant error, a user's own) through its `columns`;
- hybrid: the rigid-body path plus the network path.

Buffers are allocated once; `predict_one` writes its result into `out` (default: a buffer of the
predictor that the next call overwrites, so copy it to keep it). Inputs are not checked in the call.
This module imports numpy only (pinocchio comes with the rigid-body dynamics when a model needs it).
"""

from __future__ import annotations

import math

import numpy as np

from crane_io.errors import CraneError


class PredictorError(CraneError):
    """A model that cannot be turned into a fast predictor (not fitted, unknown method)."""


class MLPPath:
    """The paper's network, float64: y = relu(x W1' + b1') W2' + b2' with the standardisation folded in."""

    def __init__(self, params: dict, norm: dict):
        w1, w2 = (_one(params[k], 2) for k in ("W1", "W2"))  # (D, H), (H, J)
        b1, b2 = (_one(params[k], 1) for k in ("b1", "b2"))
        x_mean, x_std, y_mean, y_std = (_one(norm[k], 1) for k in ("x_mean", "x_std", "y_mean", "y_std"))
        self.w1 = w1 / x_std[:, None]
        self.b1 = b1 - (x_mean / x_std) @ w1
        self.w2 = w2 * y_std[None, :]
        self.b2 = b2 * y_std + y_mean
        self.n_joints = self.w2.shape[1]
        self._x = np.empty(self.w1.shape[0])
        self._h = np.empty(self.w1.shape[1])

    def __call__(self, q, dq, ddq, out: np.ndarray) -> np.ndarray:
        j, x, h = self.n_joints, self._x, self._h
        x[:j] = q
        x[j:2 * j] = dq
        x[2 * j:] = ddq
        np.dot(x, self.w1, out=h)
        h += self.b1
        np.maximum(h, 0.0, out=h)
        np.dot(h, self.w2, out=out)
        out += self.b2
        return out


def _one(a, ndim: int) -> np.ndarray:
    """float64 copy of one model's array out of a stack of one (leading dimensions of size 1 dropped)."""
    a = np.asarray(a, dtype=np.float64)
    return a.reshape(a.shape[a.ndim - ndim:])


def _sgn(v: float) -> float:
    return 1.0 if v > 0 else (-1.0 if v < 0 else 0.0)  # as np.sign: 0 at 0


def _gauss(v: float, width: float) -> float:
    return math.exp(-((v / max(width, 1e-9)) ** 2))


# name -> (scalar torque of one joint from (q, dq, ddq) of that joint, coefficients c, shape s); the same
# formulas as the columns of crane_io/effects/library.py, used only when the registered effect is that
# built-in class (tests check each against the model's own prediction)
_SCALAR_EFFECTS = {
    "coulomb": lambda q, v, a, c, s: c[0] * _sgn(v),
    "coulomb-asym": lambda q, v, a, c, s: c[0] if v > 0 else (-c[1] if v < 0 else 0.0),
    "viscous": lambda q, v, a, c, s: c[0] * v,
    "stribeck": lambda q, v, a, c, s: c[0] * _gauss(v, s["stribeck_velocity"]) * _sgn(v),
    "stiction": lambda q, v, a, c, s: c[0] * _sgn(v) + c[1] * _gauss(v, s["stiction_velocity"]) * _sgn(v),
    "offset": lambda q, v, a, c, s: c[0],
    "spring": lambda q, v, a, c, s: c[0] * (q - s["rest_angle"]),
    "rotor-inertia": lambda q, v, a, c, s: c[0] * a,
    "cogging": lambda q, v, a, c, s: (c[0] * math.sin(s["cycles_per_rev"] * q)
                                      + c[1] * math.cos(s["cycles_per_rev"] * q)),
    "backlash": lambda q, v, a, c, s: c[0] * a * _gauss(v, s["reversal_velocity"]),
}


def _builtin_class(name: str):
    from crane_io.effects import library

    return next((cls for cls in library.BUILTIN_EFFECTS if cls.name == name), None)


class RigidPath:
    """Base regressor of one sample (pinocchio) @ parameters, plus the effect terms of a fitted
    train.models.rigid_body.RigidBodyModel."""

    def __init__(self, model):
        if model.theta is None:
            raise PredictorError("the rigid-body model has not been fitted or loaded")
        import pinocchio as pin

        from crane_io.effects import get_effect

        dyn = model.dynamics
        indep, _, _ = dyn._base_decomposition()
        self._pin = pin
        self._model = dyn.model
        self._data = dyn.model.createData()  # a data of its own: the cached dynamics may be used elsewhere
        self._perm = None if dyn._identity else np.asarray(dyn._perm)
        self.n_joints = dyn.n_joints
        self.theta_full = np.zeros(10 * dyn.nbodies)
        self.theta_full[indep] = model.theta[:dyn.n_base]
        self._qm, self._dqm, self._ddqm = (np.empty(self.n_joints) for _ in range(3))
        self._tau_model = np.empty(self.n_joints)
        self.scalar_terms: list[tuple] = []  # (joint, function, coefficients, shape)
        self.generic_terms: list[tuple] = []  # (effect, joint or None, shape, coefficients)
        k = dyn.n_base
        for term in model.terms:
            effect = get_effect(term["name"])
            n = effect.n_columns()
            coefs = np.asarray(model.theta[k:k + n], dtype=float)
            k += n
            scalar = _SCALAR_EFFECTS.get(effect.name)
            builtin = type(effect) is _builtin_class(effect.name)
            if scalar is not None and builtin and term["joint"] is not None:
                shape = effect._shape(term["shape"])
                self.scalar_terms.append((int(term["joint"]), scalar, tuple(float(c) for c in coefs), shape))
            else:
                self.generic_terms.append((effect, term["joint"], term["shape"], coefs))
        if k != len(model.theta):
            raise PredictorError(f"the rigid-body model has {len(model.theta)} parameters but its regressor "
                                 f"and effect terms have {k} columns")

    def __call__(self, q, dq, ddq, out: np.ndarray) -> np.ndarray:
        if self._perm is None:
            qm, dqm, ddqm = q, dq, ddq
        else:
            qm, dqm, ddqm = self._qm, self._dqm, self._ddqm
            qm[self._perm] = q
            dqm[self._perm] = dq
            ddqm[self._perm] = ddq
        y = self._pin.computeJointTorqueRegressor(self._model, self._data, qm, dqm, ddqm)
        if self._perm is None:
            np.dot(y, self.theta_full, out=out)
        else:
            np.dot(y, self.theta_full, out=self._tau_model)
            out[:] = self._tau_model[self._perm]
        for joint, fn, coefs, shape in self.scalar_terms:
            out[joint] += fn(q[joint], dq[joint], ddq[joint], coefs, shape)
        for effect, joint, shape, coefs in self.generic_terms:
            out += effect.columns(q[None], dq[None], ddq[None], joint, shape)[0] @ coefs
        return out


class NumpyPredictor:
    """A fitted model's prediction for one sample, float64, no torch (see the module's docstring)."""

    def __init__(self, joint_names, paths):
        self.joint_names = tuple(joint_names)
        self.paths = list(paths)
        self._out = np.zeros(len(self.joint_names))
        self._part = np.zeros(len(self.joint_names))

    @classmethod
    def from_model(cls, model) -> NumpyPredictor:
        method = getattr(model, "method", "")
        if method in ("mlp-mse", "mlp-masked"):
            paths = [_mlp_path(model)]
        elif method == "rigid-body":
            paths = [RigidPath(model)]
        elif method == "hybrid":
            if model.rigid is None or model.mlp is None:
                raise PredictorError("the hybrid model has not been fitted or loaded")
            paths = [RigidPath(model.rigid), _mlp_path(model.mlp)]
        else:
            raise PredictorError(f"no fast predictor for model method {method!r}")
        return cls(model.joint_names, paths)

    def predict_one(self, q: np.ndarray, dq: np.ndarray, ddq: np.ndarray,
                    out: np.ndarray | None = None) -> np.ndarray:
        """(J,) motor torque, N m, for one sample of (J,) q rad, dq rad/s, ddq rad/s^2."""
        out = self._out if out is None else out
        first, *rest = self.paths
        first(q, dq, ddq, out)
        for path in rest:
            out += path(q, dq, ddq, self._part)
        return out


def _mlp_path(model) -> MLPPath:
    if model.params is None:
        raise PredictorError(f"the {model.method} model has not been fitted or loaded")
    return MLPPath(model.params, model.norm)
