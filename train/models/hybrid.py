"""Method "hybrid": the physics model with chosen effects plus a masked network on its residual.

    tau_hat = rigid_body(q, dq, ddq) + mlp(q, dq, ddq)

1. The rigid-body model (train.models.rigid_body, with the given `effects`) is fitted first, as
   `crane-train fit --model rigid-body` would (on the samples where every joint moves).
2. Its prediction is subtracted from the measured torque of the training and validation data, and the
   paper's network with the masked loss (train.models.mlp, "mlp-masked") learns that residual: each
   joint's error counts only where the joint moves, so dead-zone samples are kept for the other joints.

The physics carries what it can explain (and extrapolates outside the training range); the network
mops up what no chosen effect covers. Saved as a directory with model.json plus the two parts in
`rigid/` and `mlp/` (each a model directory of its own).
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from ..dataset import Dataset
from .base import Model, ModelFileError

RIGID_DIR = "rigid"
MLP_DIR = "mlp"


class HybridModel(Model):
    method = "hybrid"

    def __init__(self, joint_names, preprocessing: dict | None = None, effects=(), hidden: int = 64,
                 lr: float = 0.01, epochs: int = 100, batch_size: int = 32, seed: int = 0, **rigid_options):
        effects = [list(e) if isinstance(e, (list, tuple)) else e for e in (effects or [])]
        super().__init__(joint_names, preprocessing, effects=effects, hidden=hidden, lr=lr, epochs=epochs,
                         batch_size=batch_size, seed=seed, **rigid_options)
        self.rigid_options = dict(rigid_options)
        self.mlp_options = {"hidden": hidden, "lr": lr, "epochs": epochs, "batch_size": batch_size,
                            "seed": seed}
        self.rigid = None
        self.mlp = None

    def _make_parts(self):
        from .mlp import MLPModel
        from .rigid_body import RigidBodyModel

        effects = [tuple(e) if isinstance(e, list) else e for e in self.options.get("effects", [])]
        rigid = RigidBodyModel(self.joint_names, self.preprocessing, effects=effects, **self.rigid_options)
        mlp = MLPModel(self.joint_names, self.preprocessing, loss="masked", **self.mlp_options)
        return rigid, mlp

    @staticmethod
    def _residual(ds: Dataset | None, physics) -> Dataset | None:
        if ds is None:
            return None
        out = ds.subset(np.arange(len(ds)))
        out.tau = ds.tau - physics.predict(ds.q, ds.dq, ds.ddq)
        return out

    def fit(self, train: Dataset, val: Dataset | None = None, progress=None) -> HybridModel:
        rigid, mlp = self._make_parts()
        rigid.fit(train, val)
        mlp.fit(self._residual(train, rigid), self._residual(val, rigid), progress=progress)
        self.rigid, self.mlp = rigid, mlp
        if not self.preprocessing:
            self.preprocessing = dict(train.meta.get("preprocessing", {}))
        return self

    def predict(self, q, dq, ddq) -> np.ndarray:
        if self.rigid is None or self.mlp is None:
            raise ModelFileError("the hybrid model has not been fitted or loaded")
        return self.rigid.predict(q, dq, ddq) + self.mlp.predict(q, dq, ddq)

    def parameters_table(self):
        """The physics part's parameters (names, values, standard errors)."""
        return self.rigid.parameters_table() if self.rigid is not None else []

    # ---- persistence --------------------------------------------------------------------------------
    def _state(self) -> dict:
        return {"parts": {"rigid": RIGID_DIR, "mlp": MLP_DIR}}

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
