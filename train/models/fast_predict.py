"""One sample at a time, fast and without torch: the prediction a model makes inside a 2 ms control cycle.

    predictor = NumpyPredictor.from_model(load_model("models/masked"))
    tau = predictor.predict_one(q, dq, ddq)   # (J,) float64 arrays in the model's joint order -> (J,) N m

A thin adapter: the forward paths live in crane_io.physics.loop_model (where the control loop loads them
from a saved model's loop_model.npz without train or torch); this builds the same paths straight from a
fitted train model. Every method is covered and gives the model's own `predict` to 1e-6 relative
(float64 here; the torch network runs in float32):
- mlp-mse, mlp-masked: crane_io.physics.loop_model.MLPPath, the standardisation folded into the weights;
- rigid-body: crane_io.physics.loop_model.RigidPath, pinocchio's joint-torque regressor of the one sample
  times the base parameters spread over the standard ones (dependent columns zero), plus each effect term
  (built-in one-joint effects as scalars, any other effect through its `columns`);
- hybrid: the rigid-body path plus the network path.

Buffers are allocated once; `predict_one` writes its result into `out` (default: a buffer of the
predictor that the next call overwrites, so copy it to keep it). Inputs are not checked in the call.
This module imports numpy only (pinocchio comes with the rigid-body dynamics when a model needs it).
"""

from __future__ import annotations

from typing import TYPE_CHECKING, cast

import numpy as np

from crane_io.errors import CraneError
from crane_io.physics.loop_model import MLPPath, PathSum, RigidPath

if TYPE_CHECKING:
    from .base import Model
    from .hybrid import HybridModel


class PredictorError(CraneError):
    """A model that cannot be turned into a fast predictor (not fitted, unknown method)."""


def _one(a, ndim: int) -> np.ndarray:
    """float64 copy of one model's array out of a stack of one (leading dimensions of size 1 dropped)."""
    a = np.asarray(a, dtype=np.float64)
    return a.reshape(a.shape[a.ndim - ndim:])


def _mlp_path(model) -> MLPPath:
    if model.params is None:
        raise PredictorError(f"the {model.method} model has not been fitted or loaded")
    arrays = {k: _one(model.params[k], 2 if k.startswith("W") else 1) for k in ("W1", "b1", "W2", "b2")}
    arrays.update({k: _one(model.norm[k], 1) for k in ("x_mean", "x_std", "y_mean", "y_std")})
    return MLPPath(**arrays)


def _rigid_path(model) -> RigidPath:
    """The RigidPath of a fitted train.models.rigid_body.RigidBodyModel (its own cached dynamics)."""
    if model.theta is None:
        raise PredictorError("the rigid-body model has not been fitted or loaded")
    if getattr(model, "context_joints", ()):
        raise PredictorError(f"the rigid-body model's kinematics read the recorded angles of "
                             f"{', '.join(model.context_joints)} (context joints), which a one-sample "
                             f"predictor of the model's own joints does not get")
    dyn = model.dynamics
    indep = model.base_independent_columns()
    theta_full = np.zeros(10 * dyn.nbodies)
    theta_full[indep] = model.theta[:len(indep)]
    terms, k = [], len(indep)
    for term in model.terms:
        effect = model.effect_by_name(term["name"])  # the model's own, rebuilt from its recorded spec
        n = effect.n_columns()
        terms.append((effect, term["joint"], term["shape"], np.asarray(model.theta[k:k + n], dtype=float)))
        k += n
    if k != len(model.theta):
        raise PredictorError(f"the rigid-body model has {len(model.theta)} parameters but its regressor "
                             f"and effect terms have {k} columns")
    return RigidPath(model.joint_names, theta_full, terms, dynamics=dyn)


class NumpyPredictor(PathSum):
    """A fitted model's prediction for one sample, float64, no torch (see the module's docstring)."""

    @classmethod
    def from_model(cls, model: Model) -> NumpyPredictor:
        method = getattr(model, "method", "")
        if method in ("mlp-mse", "mlp-masked"):
            paths: list[MLPPath | RigidPath] = [_mlp_path(model)]
        elif method == "rigid-body":
            paths = [_rigid_path(model)]
        elif method == "hybrid":
            hybrid = cast("HybridModel", model)
            if hybrid.rigid is None or hybrid.mlp is None:
                raise PredictorError("the hybrid model has not been fitted or loaded")
            paths = [_rigid_path(hybrid.rigid), _mlp_path(hybrid.mlp)]
        else:
            raise PredictorError(f"no fast predictor for model method {method!r}")
        return cls(model.joint_names, paths)
