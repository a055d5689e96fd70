"""The numeric export of a fitted model for the control loop: `loop_model.npz` next to model.json, read by
crane_io.physics.loop_model.LoopModel without train or torch (the keys are described there).

    path, sha256 = write_loop_export(model, "models/masked")   # Model.save calls it for every fitted model

Only the export file is written (atomically: a temporary file renamed over it), so `crane-train export`
can add it to a model directory saved before exports existed without touching anything else.
"""

from __future__ import annotations

import hashlib
import io
import json
import zipfile
from pathlib import Path
from typing import TYPE_CHECKING, cast

import numpy as np

from crane_io.errors import CraneError
from crane_io.output_files import write_bytes_atomic
from crane_io.physics.loop_model import EXPORT_FILE, EXPORT_FORMAT_VERSION, SI_UNITS, sources_sha256

if TYPE_CHECKING:
    from .base import Model
    from .hybrid import HybridModel

# the weight files of each method, relative to the model directory (what the export was made from)
SOURCE_FILES = {"mlp-mse": ("mlp.pt",), "mlp-masked": ("mlp.pt",), "rigid-body": ("rigid_body.npz",),
                "hybrid": ("rigid/rigid_body.npz", "mlp/mlp.pt")}


class LoopExportError(CraneError):
    """A model that cannot be exported for the control loop (not fitted, unknown method)."""


def is_fitted(model: Model) -> bool:
    """Whether `model` has learned parameters to export (train.models.base.Model.is_fitted)."""
    return bool(getattr(model, "is_fitted", False))


def _mlp_arrays(mlp) -> dict:
    out = {}
    for k in ("W1", "b1", "W2", "b2"):
        a = np.asarray(mlp.params[k], dtype=np.float64)
        ndim = 2 if k.startswith("W") else 1
        out[f"mlp_{k}"] = a.reshape(a.shape[a.ndim - ndim:])  # drop the stack of one
    for k in ("x_mean", "x_std", "y_mean", "y_std"):
        out[f"mlp_{k}"] = np.asarray(mlp.norm[k], dtype=np.float64).reshape(-1)
    return out


def _rigid_arrays(rigid) -> dict:
    from crane_io.physics.effects.spec import identity

    dyn = rigid.dynamics
    indep = rigid.base_independent_columns()
    n_base = len(indep)
    theta = np.asarray(rigid.theta, dtype=np.float64)
    theta_full = np.zeros(10 * dyn.nbodies)
    theta_full[indep] = theta[:n_base]
    table = rigid.effect_table()
    recorded = {s["name"]: s for s in rigid.options.get("effect_specs", [])}
    specs, k = [], n_base
    for term in rigid.terms:
        n = table[term["name"]].n_columns()
        specs.append({"name": term["name"], "joint": None if term["joint"] is None else int(term["joint"]),
                      "shape": term["shape"], "n_coefs": n, "identity": identity(recorded[term["name"]])})
        k += n
    if k != len(theta):
        raise LoopExportError(f"the rigid-body model has {len(theta)} parameters but its regressor and "
                              f"effect terms have {k} columns")
    # the angles the dynamics were built with: the still context joints at their recorded medians
    # (train.models.rigid_body), or the options' `locked` for a model without context
    resolved = getattr(rigid, "locked_resolved", None)
    locked = (rigid.options.get("locked") or {}) if resolved is None else resolved
    used = [recorded[name] for name in dict.fromkeys(t["name"] for t in rigid.terms)]
    return {"rigid_theta_full": theta_full,
            "rigid_locked_joints": np.array(list(locked), dtype=str),
            "rigid_locked_angles": np.array([float(v) for v in locked.values()], dtype=np.float64),
            "rigid_payload_mass": np.float64(rigid.options.get("payload_mass", 0.0)),
            "rigid_effects": np.array(json.dumps(specs)),
            "rigid_effect_coefs": theta[n_base:].copy(),
            "rigid_effect_specs": np.array(json.dumps(used)),  # the effects as data (no code to run)
            # only when the kinematics read other joints' recorded motion (the loop refuses such a model)
            **({"rigid_context_joints": np.array(list(rigid.context_joints), dtype=str)}
               if getattr(rigid, "context_joints", ()) else {})}


def export_arrays(model: Model, directory: Path | str) -> dict:
    """The export's arrays for a fitted `model` whose weight files are saved in `directory`."""
    method = getattr(model, "method", "")
    if method not in SOURCE_FILES:
        raise LoopExportError(f"a model of method {method!r} cannot be exported for the control loop")
    if not is_fitted(model):
        raise LoopExportError(f"the {method} model has not been fitted, so there is nothing to export")
    directory = Path(directory)
    sources = SOURCE_FILES[method]
    missing = [f for f in sources if not (directory / f).is_file()]
    if missing:
        raise LoopExportError(f"{directory} lacks {missing[0]}, the model's weights; save or fit the model "
                              f"again")
    arrays = {"format_version": np.int64(EXPORT_FORMAT_VERSION), "method": np.array(method),
              "joint_names": np.array(list(model.joint_names), dtype=str),
              "units": np.array(json.dumps(SI_UNITS)),
              "source_files": np.array(list(sources), dtype=str),
              "source_sha256": np.array(sources_sha256(directory, sources))}
    if method in ("rigid-body", "hybrid"):
        arrays.update(_rigid_arrays(cast("HybridModel", model).rigid if method == "hybrid" else model))
    if method in ("mlp-mse", "mlp-masked", "hybrid"):
        arrays.update(_mlp_arrays(cast("HybridModel", model).mlp if method == "hybrid" else model))
    return arrays


def npz_bytes(arrays: dict) -> bytes:
    """An uncompressed .npz of `arrays` whose bytes depend on the arrays only (np.savez stamps each member
    with the current time): the same weights give the same file and the same SHA-256."""
    buf = io.BytesIO()
    with zipfile.ZipFile(buf, "w", compression=zipfile.ZIP_STORED) as zf:
        for name, value in arrays.items():
            info = zipfile.ZipInfo(f"{name}.npy", date_time=(1980, 1, 1, 0, 0, 0))
            with zf.open(info, "w", force_zip64=True) as f:
                np.lib.format.write_array(f, np.asanyarray(value), allow_pickle=False)
    return buf.getvalue()


def write_loop_export(model: Model, directory: Path | str) -> tuple[Path, str]:
    """Write `directory`/loop_model.npz for a fitted model saved there; (path, SHA-256 of its bytes)."""
    directory = Path(directory)
    arrays = export_arrays(model, directory)
    raw = npz_bytes(arrays)
    path = write_bytes_atomic(directory / EXPORT_FILE, raw, "loop export")
    return path, hashlib.sha256(raw).hexdigest()
