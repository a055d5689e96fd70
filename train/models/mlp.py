"""The paper's network: a 3-layer feed-forward net (3J inputs [q, dq, ddq] -> 64 ReLU -> J torques).

method "mlp-mse"    : MSE on the training samples in which every joint moves (the paper's baseline)
method "mlp-masked" : the paper's masked loss (eq. 3) on all training samples

Adam (lr 0.01), 100 epochs, minibatches of 32 (the paper gives no size), inputs and outputs standardised
with the training rows' mean and std (stored with the model), and the weights kept are those of the
epoch with the best validation MSE (validation = all-moving samples of the validation set). Training
goes through train.models.batched with M = 1, the same code the sweep uses for many models at once.
"""

from __future__ import annotations

from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np
import torch

from crane_io.errors import CraneError

from ..data.dataset import Dataset
from .base import Model, ModelFileError
from .batched import MLPSettings, predict, train_mlps
from .model_files import mlp_shapes, read_torch_weights

if TYPE_CHECKING:
    from collections.abc import Callable

WEIGHTS = "mlp.pt"
LOSSES = ("mse", "masked")


def features(q: np.ndarray, dq: np.ndarray, ddq: np.ndarray) -> np.ndarray:
    """(N, 3J) network input [q, dq, ddq] (rad, rad/s, rad/s^2), from three (N, J) arrays."""
    return np.hstack([np.atleast_2d(q), np.atleast_2d(dq), np.atleast_2d(ddq)]).astype(float)


def training_arrays(ds: Dataset, loss: str) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """(X, Y, W, rows): inputs (N, 3J) [rad, rad/s, rad/s^2], targets (N, J) N m, loss weights (N, J)
    and the rows a method may train on (indices)."""
    X, Y = features(ds.q, ds.dq, ds.ddq), ds.tau
    if loss == "masked":
        return X, Y, ds.moving.astype(np.float32), np.arange(len(ds))
    return X, Y, np.ones_like(Y, dtype=np.float32), np.flatnonzero(ds.all_moving)


class MLPModel(Model):
    def __init__(self, joint_names, preprocessing: dict | None = None, loss: str = "masked", hidden: int = 64,
                 lr: float = 0.01, epochs: int = 100, batch_size: int = 32, seed: int = 0):
        if loss not in LOSSES:
            raise CraneError(f"unknown MLP loss {loss!r}; use one of {', '.join(LOSSES)}")
        super().__init__(joint_names, preprocessing, loss=loss, hidden=hidden, lr=lr, epochs=epochs,
                         batch_size=batch_size, seed=seed)
        self.method = f"mlp-{loss}"
        self.loss = loss
        self.settings = MLPSettings(hidden=int(hidden), lr=float(lr), epochs=int(epochs),
                                    batch_size=int(batch_size))
        self.seed = int(seed)
        self.params: dict | None = None
        self.norm: dict | None = None
        self.history: dict = {}

    def fit(self, train: Dataset, val: Dataset | None = None,
            progress: Callable[[int, int], object] | None = None) -> MLPModel:
        if tuple(train.joint_names) != self.joint_names:
            raise CraneError(f"the data has joints {', '.join(train.joint_names)} but the model was made "
                             f"for {', '.join(self.joint_names)}")
        X, Y, W, rows = training_arrays(train, self.loss)
        if len(rows) < 2:
            what = "samples" if self.loss == "masked" else "samples with every joint moving"
            raise CraneError(f"{self.method} needs at least 2 training {what}, the data has {len(rows)}")
        if val is None:
            val = train  # no separate validation data: pick the epoch by the training data itself
        from ..data.splits import per_joint

        if per_joint(val):  # a per-joint validation set: each joint scored where it moves
            vrows, w_val = np.arange(len(val)), val.moving
        else:
            vrows, w_val = np.flatnonzero(val.all_moving), None
        if len(vrows) == 0:
            raise CraneError("the validation data has no sample with every joint moving")
        Xv = features(val.q, val.dq, val.ddq)[vrows]
        res = train_mlps(X, Y, W, [rows], Xv, val.tau[vrows], self.settings, seeds=[self.seed],
                         progress=progress, W_val=w_val)
        self.params, self.norm = res.model(0)
        self.history = {"best_epoch": int(res.best_epoch[0]), "best_val_mse": float(res.best_val[0]),
                        "train_loss": res.train_loss[:, 0].tolist(), "val_mse": res.val_mse[:, 0].tolist(),
                        "train_rows": int(len(rows))}
        if not self.preprocessing:
            self.preprocessing = dict(train.meta.get("preprocessing", {}))
        return self

    @property
    def is_fitted(self) -> bool:
        return self.params is not None

    def predict(self, q: np.ndarray, dq: np.ndarray, ddq: np.ndarray) -> np.ndarray:
        """(N, J) joint torques, N m, from positions q (N, J) rad, velocities dq (N, J) rad/s and
        accelerations ddq (N, J) rad/s^2."""
        self._check_fitted()
        return predict(self.params, self.norm, features(q, dq, ddq))[0].astype(float)

    # ---- persistence -----------------------------------------------------------------------------
    def _state(self) -> dict:
        return {"norm": {k: v[0] for k, v in (self.norm or {}).items()}, "history": self.history}

    def _save_extra(self, directory: Path) -> None:
        torch.save({k: torch.as_tensor(v[0]) for k, v in self.params.items()}, directory / WEIGHTS)

    def _load_extra(self, directory: Path, state: dict) -> None:
        shapes = mlp_shapes(len(self.joint_names), self.settings.hidden)
        weights = read_torch_weights(directory, WEIGHTS, shapes)  # weights_only: never unpickles an object
        self.params = {k: w[None] for k, w in weights.items()}
        try:
            self.norm = {k: np.asarray(state["norm"][k], dtype=np.float32)[None]
                         for k in ("x_mean", "x_std", "y_mean", "y_std")}
        except (KeyError, TypeError):
            raise ModelFileError(f"{directory} is incomplete: its model.json lacks the network's "
                                 f"normalisation; fit the model again") from None
        self.history = state.get("history", {})
