"""Model methods by name: make a model, load a saved one.

    model = make_model("mlp-masked", joint_names, epochs=50)
    model = load_model("models/masked")

"hybrid" resolves lazily to train.models.hybrid:HybridModel, so this file works before that exists.
"""

from __future__ import annotations

import importlib
import re
from pathlib import Path
from typing import TYPE_CHECKING

from crane_io.errors import CraneError

from .base import Model, ModelFileError, read_model_json
from .method_names import METHOD_NAMES
from .model_files import check_hybrid_parts, check_loaded

if TYPE_CHECKING:
    from collections.abc import Sequence
    from typing import Any

# method -> ("module:Class", options the method fixes)
METHODS: dict[str, tuple[str, dict]] = {
    "rigid-body": ("train.models.rigid_body:RigidBodyModel", {}),
    "mlp-mse": ("train.models.mlp:MLPModel", {"loss": "mse"}),
    "mlp-masked": ("train.models.mlp:MLPModel", {"loss": "masked"}),
    "hybrid": ("train.models.hybrid:HybridModel", {}),
}
assert tuple(METHODS) == METHOD_NAMES, "train/models/method_names.py lists every method, in this order"


class UnknownMethodError(CraneError):
    """A method name that is not in METHODS."""


def model_class(method: str) -> tuple[type[Model], dict]:
    if method not in METHODS:
        raise UnknownMethodError(f"unknown model method {method!r}; choose one of {', '.join(METHODS)}")
    target, fixed = METHODS[method]
    module, cls = target.split(":")
    try:
        return getattr(importlib.import_module(module), cls), dict(fixed)
    except (ImportError, AttributeError):
        raise UnknownMethodError(f"model method {method!r} is not available in this installation") from None


def make_model(method: str, joint_names: Sequence[str], preprocessing: dict | None = None,
               **options: Any) -> Model:
    """A fresh, unfitted model of `method` for `joint_names`; options as the method documents."""
    cls, fixed = model_class(method)
    for k, v in fixed.items():
        if k in options and options[k] != v:
            raise CraneError(f"method {method} fixes {k}={v!r}; do not pass {k}={options[k]!r}")
    options.update(fixed)
    try:
        return cls(joint_names, preprocessing=preprocessing, **options)
    except TypeError as exc:
        raise CraneError(f"bad option for method {method}: {exc}") from None


def load_model(directory: Path | str) -> Model:
    """Load a model directory written by Model.save (never needs the training data)."""
    doc = read_model_json(directory)
    method = doc.get("method")
    if method not in METHODS:
        raise ModelFileError(f"{Path(directory)} holds a model of unknown method {method!r}")
    cls, _ = model_class(method)
    try:
        model = cls(doc["joint_names"], preprocessing=doc.get("preprocessing") or {},
                    **(doc.get("options") or {}))
    except KeyError as exc:
        raise ModelFileError(f"{Path(directory) / 'model.json'} lacks {exc.args[0]!r}; it is damaged or "
                             f"not written by crane-train fit") from None
    except (TypeError, ValueError) as exc:
        unknown = re.search(r"keyword argument '(\w+)'", str(exc))
        what = (f"the option {unknown[1]!r}, which a {method} model does not take" if unknown
                else "unusable options")
        raise ModelFileError(f"{Path(directory) / 'model.json'} has {what}; fit the model again") from None
    if method == "hybrid":
        check_hybrid_parts(directory, doc.get("state") or {})
    model._load_extra(Path(directory), doc.get("state") or {})
    check_loaded(directory, model)
    return model
