"""The one interface every inverse-dynamics model implements (scikit-learn's conventions where they fit).

    model = make_model("mlp-masked", joint_names=ds.joint_names, **options)
    model.fit(train_ds, val_ds)          # uses train_ds.moving as its per-joint mask as its method says
    tau_hat = model.predict(q, dq, ddq)  # SI arrays (N, J) -> (N, J) N m
    model.save(directory); model = load_model(directory)

As in scikit-learn: the constructor only stores its parameters (`get_params()` returns them, and
`type(model)(**model.get_params())` is an unfitted copy); `fit` returns the model and never changes its
parameters; `is_fitted` says whether it learned anything (fitted or loaded); `predict` before that raises
NotFittedError with one sentence. tests/test_model_conformance.py holds every model class to this.

A saved model is a directory holding `model.json` (method, joint names, options, preprocessing
settings the data went through, normalisation, units) plus method-specific files (weights as .pt, arrays
as .npz), and for a fitted model the control loop's numeric export `loop_model.npz` (train/models/
loop_export.py; read by crane_io.physics.loop_model without torch), whose SHA-256 model.json records under
"loop_export". Loading never needs the training data.
"""

from __future__ import annotations

import abc
import json
from pathlib import Path

import numpy as np

from crane_io.errors import CraneError
from crane_io.physics.loop_model import SI_UNITS

from ..data.dataset import Dataset

MODEL_JSON = "model.json"


class ModelFileError(CraneError):
    """A model directory that cannot be loaded."""


class NotFittedError(CraneError):
    """A model asked to predict before it was fitted or loaded."""


class Model(abc.ABC):
    method: str = ""

    def __init__(self, joint_names, preprocessing: dict | None = None, **options):
        self.joint_names = tuple(joint_names)
        self.preprocessing = dict(preprocessing or {})
        self.options = options

    def get_params(self) -> dict:
        """The constructor's parameters: `type(self)(**self.get_params())` is an unfitted copy."""
        return {"joint_names": list(self.joint_names), "preprocessing": dict(self.preprocessing),
                **self.options}

    @property
    @abc.abstractmethod
    def is_fitted(self) -> bool:
        """True once the model has learned its parameters (by `fit` or by loading a saved model)."""

    def _check_fitted(self) -> None:
        if not self.is_fitted:
            raise NotFittedError(f"the {self.method} model has not been fitted or loaded yet; call "
                                 "fit(train, val) first")

    @abc.abstractmethod
    def fit(self, train: Dataset, val: Dataset | None = None) -> Model: ...

    @abc.abstractmethod
    def predict(self, q: np.ndarray, dq: np.ndarray, ddq: np.ndarray) -> np.ndarray:
        """(N, J) joint torques, N m, from positions q (N, J) rad, velocities dq (N, J) rad/s and
        accelerations ddq (N, J) rad/s^2."""

    def predict_dataset(self, ds: Dataset) -> np.ndarray:
        """Predict on a Dataset; a model whose kinematics read context joints (rigid-body, hybrid)
        takes them from the Dataset here."""
        return self.predict(ds.q, ds.dq, ds.ddq)

    def linear_basis(self, q: np.ndarray, dq: np.ndarray, ddq: np.ndarray) -> np.ndarray | None:
        """(N, J, p) columns the fitted model is linear in (predict = columns @ parameters), for a model
        that is a linear regression (the rigid body with its effects); None for any other (a network),
        whose predictions the diagnosis then takes as they are."""
        return None

    # ---- persistence -----------------------------------------------------------------------------
    def _state(self) -> dict:
        """JSON-able method-specific state; arrays go through _save_arrays."""
        return {}

    def _save_extra(self, directory: Path) -> None:
        """Write method-specific files (weights, arrays); nothing by default."""
        return None

    def _load_extra(self, directory: Path, state: dict) -> None:
        """Read what _save_extra wrote; nothing by default."""
        return None

    def save(self, directory: Path | str) -> Path:
        """Write the model to `directory`, whole or not at all: into a new folder beside it that then
        replaces it (crane_io.output_files.atomic_directory; a full disk is one sentence)."""
        from crane_io.output_files import atomic_directory

        directory = Path(directory)
        with atomic_directory(directory, "model folder") as tmp:
            self._save_into(tmp)
        return directory

    def _save_into(self, directory: Path) -> None:
        doc = {"format": "crane-model", "format_version": 1, "method": self.method,
               "joint_names": list(self.joint_names), "preprocessing": self.preprocessing,
               "units": dict(SI_UNITS), "options": self.options, "state": self._state()}
        (directory / MODEL_JSON).write_text(json.dumps(doc, indent=2, default=_jsonable))
        self._save_extra(directory)
        from .loop_export import EXPORT_FILE, write_loop_export

        if self.is_fitted:  # the control loop's numeric export; model.json records its digest
            _, sha = write_loop_export(self, directory)
            doc["loop_export"] = {"file": EXPORT_FILE, "sha256": sha}
            (directory / MODEL_JSON).write_text(json.dumps(doc, indent=2, default=_jsonable))


def predict_on(model: Model, ds: Dataset) -> np.ndarray:
    """model's prediction on the rows of `ds`, with the Dataset's context joints for a model that reads
    them (a stand-in with only `predict(q, dq, ddq)` works too)."""
    fn = getattr(model, "predict_dataset", None)
    return fn(ds) if fn is not None else model.predict(ds.q, ds.dq, ds.ddq)


def basis_on(model: Model, ds: Dataset) -> np.ndarray | None:
    """model.linear_basis on the rows of `ds` (with the Dataset's context joints): (N, J, p), or None."""
    basis = getattr(model, "linear_basis", None)
    if basis is None:
        return None
    if getattr(model, "context_joints", ()):
        return basis(ds.q, ds.dq, ds.ddq, context=ds.context)
    return basis(ds.q, ds.dq, ds.ddq)


def _jsonable(obj):
    if isinstance(obj, np.ndarray):
        return obj.tolist()
    if isinstance(obj, np.generic):
        return obj.item()
    if isinstance(obj, tuple):
        return list(obj)
    raise TypeError(f"cannot store {type(obj).__name__} in model.json")


def read_model_json(directory: Path | str) -> dict:
    """model.json of a model directory, checked (train.models.model_files.read_model_json)."""
    from .model_files import read_model_json as read_checked

    return read_checked(directory)
