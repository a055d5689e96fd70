"""Method "hybrid": the physics model with chosen effects plus a masked network on its residual.

    tau_hat = rigid_body(q, dq, ddq) + mlp(q, dq, ddq)

1. The rigid-body model (train.models.rigid_body, with the given `effects`) is fitted first, as
   `crane-train fit --model rigid-body` would (on the samples where every joint moves).
2. Its prediction is subtracted from the measured torque of the training and validation data, and the
   paper's network with the masked loss (train.models.mlp, "mlp-masked") learns that residual: each
   joint's error counts only where the joint moves, so dead-zone samples are kept for the other joints.

3. The network's share is chosen per joint by cross-validation over contiguous time blocks
   (train.models.hybrid_share): networks trained like this one on all but one of 3 time blocks of the
   training data predict the block left out; on those out-of-fold predictions the network's output gets
   the least-squares weight w in [0, 1] of physics + w x network (on the samples where the joint
   moves), shrunk to the part of its gain that survives leaving each 3 s block out (each block's
   gain the fraction of its own physics error removed, every block alike; counted one standard error
   below their mean, 0 unless that bound is positive, or with fewer than 50 samples), and
   capped so that the hybrid is no worse than the physics on the validation data. w = 0 falls back to
   the physics alone, so a network that learnt noise, or too little, does not make the hybrid worse than
   its physics part on held-out data. The weight is folded into the network's output scaling (its
   `y_mean`, `y_std`), so the saved network part, the loop export and the numpy fast path all predict
   physics + w x network.

The physics carries what it can explain (and extrapolates outside the training range); the network
mops up what no chosen effect covers. Saved as a directory with model.json plus the two parts in
`rigid/` and `mlp/` (each a model directory of its own).
"""

from __future__ import annotations

from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

from ..data.dataset import Dataset
from .base import Model, ModelFileError
from .hybrid_share import Share, block_cv_share, cross_fit, time_order, validation_cap
from .recorded_effects import refuse_effect_files, specs_for

if TYPE_CHECKING:
    from collections.abc import Callable

RIGID_DIR = "rigid"
MLP_DIR = "mlp"


class HybridModel(Model):
    method = "hybrid"

    def __init__(self, joint_names, preprocessing: dict | None = None, effects=(), hidden: int = 64,
                 lr: float = 0.01, epochs: int = 100, batch_size: int = 32, seed: int = 0, **rigid_options):
        effects = [list(e) if isinstance(e, (list, tuple)) else e for e in (effects or [])]
        refuse_effect_files(rigid_options.pop("effect_files", ()))
        if rigid_options.get("effect_specs") is None:  # the effects as data, passed on to the physics part
            rigid_options["effect_specs"] = specs_for(e if isinstance(e, str) else e[0] for e in effects)
        super().__init__(joint_names, preprocessing, effects=effects, hidden=hidden, lr=lr, epochs=epochs,
                         batch_size=batch_size, seed=seed, **rigid_options)
        self.rigid_options = dict(rigid_options)
        self.mlp_options = {"hidden": hidden, "lr": lr, "epochs": epochs, "batch_size": batch_size,
                            "seed": seed}
        self.rigid = None
        self.mlp = None
        self.network_weight: dict[str, float] = {}  # joint -> share of the network (chosen on validation)
        self.blend_info: dict = {}

    def _make_parts(self):
        from .rigid_body import RigidBodyModel

        effects = [tuple(e) if isinstance(e, list) else e for e in self.options.get("effects", [])]
        rigid = RigidBodyModel(self.joint_names, self.preprocessing, effects=effects, **self.rigid_options)
        return rigid, self._make_network()

    def _make_network(self):
        from .mlp import MLPModel

        return MLPModel(self.joint_names, self.preprocessing, loss="masked", **self.mlp_options)

    @staticmethod
    def _residual(ds: Dataset | None, physics) -> Dataset | None:
        if ds is None:
            return None
        out = ds.subset(np.arange(len(ds)))
        out.tau = ds.tau - physics.predict_dataset(ds)
        return out

    def fit(self, train: Dataset, val: Dataset | None = None,
            progress: Callable[[int, int], object] | None = None) -> HybridModel:
        rigid, mlp = self._make_parts()
        rigid.fit(train, val)
        residual, val_residual = self._residual(train, rigid), self._residual(val, rigid)
        mlp.fit(residual, val_residual, progress=progress)
        oof = cross_fit(self._make_network, residual, val_residual)
        self.network_weight, self.blend_info = _choose_weight(rigid, mlp, residual, oof, val)
        _scale_network(mlp, [self.network_weight[n] for n in self.joint_names])
        self.rigid, self.mlp = rigid, mlp
        if not self.preprocessing:
            self.preprocessing = dict(train.meta.get("preprocessing", {}))
        return self

    @property
    def is_fitted(self) -> bool:
        return self.rigid is not None and self.mlp is not None and self.rigid.is_fitted and self.mlp.is_fitted

    def predict(self, q: np.ndarray, dq: np.ndarray, ddq: np.ndarray,
                context: dict | None = None) -> np.ndarray:
        """(N, J) joint torques, N m, from positions q (N, J) rad, velocities dq (N, J) rad/s and
        accelerations ddq (N, J) rad/s^2;
        `context`: the context joints' {'names', 'q', 'dq', 'ddq'} (Dataset.context)."""
        self._check_fitted()
        return self.rigid.predict(q, dq, ddq, context=context) + self.mlp.predict(q, dq, ddq)

    def predict_dataset(self, ds: Dataset) -> np.ndarray:
        return self.predict(ds.q, ds.dq, ds.ddq, context=ds.context)

    @property
    def context_joints(self) -> tuple[str, ...]:
        """The physics part's context joints (train.models.rigid_body)."""
        return tuple(getattr(self.rigid, "context_joints", ()) or ())

    def parameters_table(self) -> list[dict]:
        """The physics part's parameters (names, values, standard errors)."""
        return self.rigid.parameters_table() if self.rigid is not None else []

    # ---- persistence --------------------------------------------------------------------------------
    def _state(self) -> dict:
        return {"parts": {"rigid": RIGID_DIR, "mlp": MLP_DIR}, "network_weight": dict(self.network_weight),
                "blend": dict(self.blend_info)}

    def _save_extra(self, directory: Path) -> None:
        if self.rigid is None or self.mlp is None:
            raise ModelFileError("cannot save a hybrid model that has not been fitted")
        self.rigid.save(directory / RIGID_DIR)
        self.mlp.save(directory / MLP_DIR)

    def _load_extra(self, directory: Path, state: dict) -> None:
        from .registry import load_model

        parts = state.get("parts", {})
        self.rigid = load_model(directory / parts.get("rigid", RIGID_DIR))
        self.mlp = load_model(directory / parts.get("mlp", MLP_DIR))
        if self.mlp.method != "mlp-masked":
            raise ModelFileError(f"{directory} is a hybrid model whose network part is not mlp-masked")
        # older files have no weight: their network counts fully (and is saved unscaled)
        self.network_weight = {str(k): float(v) for k, v in (state.get("network_weight") or {}).items()}
        self.blend_info = dict(state.get("blend") or {})


def _choose_weight(rigid, mlp, residual: Dataset, oof: np.ndarray | None,
                   val: Dataset | None) -> tuple[dict[str, float], dict]:
    """Per joint, the network's share w in [0, 1] chosen by cross-validation over time blocks of the
    out-of-fold network predictions `oof` (N, J) on the training residual (train.models.hybrid_share),
    capped so the hybrid is no worse than the physics on the validation samples where the joint moves;
    and the validation MSEs of the physics alone, the unweighted sum and the weighted hybrid."""
    names = list(rigid.joint_names)
    order = time_order(residual)
    r, moving = residual.tau[order], residual.moving[order]
    m = oof[order] if oof is not None else None
    info = {"chosen_on": f"out-of-fold predictions on {len(residual)} training samples (each joint where "
                         f"it moves), cross-validated over contiguous time blocks",
            "val_mse_physics": {}, "val_mse_sum": {}, "val_mse_hybrid": {}, "share": {}}
    weights = {}
    for j, name in enumerate(names):
        rows = moving[:, j]
        if m is None:
            share = Share(0.0, 0.0, 0, 0.0, 0.0, 0.0, "too few training samples to cross-fit the network")
        else:
            share = block_cv_share(r[rows, j], m[rows, j], float(residual.rate_hz))
        weights[name] = share.weight
        info["share"][name] = {"weight_all": share.weight_all, "blocks": share.blocks,
                               "cv_gain": share.cv_gain, "cv_gain_se": share.cv_gain_se,
                               "in_sample_gain": share.in_sample_gain, "reason": share.reason}
    if val is not None and len(val):
        rv, mv = val.tau - rigid.predict_dataset(val), mlp.predict(val.q, val.dq, val.ddq)
        for j, name in enumerate(names):
            rows = val.moving[:, j]
            rj, mj = rv[rows, j], mv[rows, j]
            cap = validation_cap(rj, mj)
            if weights[name] > cap:
                weights[name] = cap
                info["share"][name]["reason"] += "; capped: no worse than the physics on the validation data"
            if rows.any():
                info["val_mse_physics"][name] = float((rj ** 2).mean())
                info["val_mse_sum"][name] = float(((rj - mj) ** 2).mean())
                info["val_mse_hybrid"][name] = float(((rj - weights[name] * mj) ** 2).mean())
    return weights, info


def _scale_network(mlp, weights) -> None:
    """Scale the network's output by `weights` (J,) in place: its output de-normalisation
    (y std + mean) becomes w y std + w mean, which every predictor of a saved network applies."""
    w = np.asarray(weights, dtype=np.float32)
    for key in ("y_mean", "y_std"):
        mlp.norm[key] = (np.asarray(mlp.norm[key], dtype=np.float32) * w).astype(np.float32)
