"""What loading a saved model checks before anything predicts with it (train.models.registry.load_model
and the methods' loaders call these), each refusal a ModelFileError whose one sentence names the
directory's file:

* model.json: a regular file of bounded size, UTF-8 JSON whose top level is an object of format
  "crane-model" and a known `format_version`; `method` a known method; `joint_names` distinct non-empty
  strings; `preprocessing`, `options`, `state` objects; `units` SI; the options of the method of their
  types and ranges (OPTIONS); the preprocessing record's settings of their types
  (train.data.preprocess.PreprocessConfig and train.data.splits.SplitConfig check the values) and its
  per-joint lists one finite number per joint (crane_io.physics.loop_model_check);
* the method's state: a network's normalisation (one finite number per input and output, input scales
  > 0, output scales >= 0), a hybrid's parts (folders inside the directory holding a rigid-body and an
  mlp-masked model) and network weights (in [0, 1] per joint), a rigid body's parameter names;
* weight files: an .npz read without pickle (crane_io.physics.loop_model_check: numbers only, finite,
  at most MAX_ABS), a PyTorch file read with `weights_only=True` (never unpickling an object), every array
  of the shape the architecture in model.json gives it, and a rigid body's parameters as many as its
  regressor's columns.

Which effects a model names and how they are stored is the effects' loader's to check; only the
containers are checked here. Files are only read.
"""

from __future__ import annotations

import json
import math
import warnings
from pathlib import Path

import numpy as np

from crane_io.physics.loop_model import SI_UNITS
from crane_io.physics.loop_model_check import (
    MAX_ABS,
    array_problem,
    file_problem,
    npz_arrays,
    preprocessing_problem,
    read_bytes,
    scales_problem,
)

from .base import MODEL_JSON, ModelFileError
from .method_names import METHOD_NAMES

MODEL_FORMAT = "crane-model"
FORMAT_VERSIONS = (1,)  # the model.json versions this installation reads
MAX_JSON_BYTES = 64 * 2 ** 20
MAX_SEED = 2 ** 32 - 1
MAX_HIDDEN = 65536


def _int(lo, hi=None):
    def check(v):
        return isinstance(v, int) and not isinstance(v, bool) and v >= lo and (hi is None or v <= hi)
    return check, f"a whole number from {lo} to {hi}" if hi is not None else f"a whole number >= {lo}"


def _number(lo, strict=False):
    def check(v):
        return (isinstance(v, (int, float)) and not isinstance(v, bool) and math.isfinite(v)
                and (v > lo if strict else v >= lo) and abs(v) <= MAX_ABS)
    return check, f"a finite number {'>' if strict else '>='} {lo:g}"


def _choice(values):
    return (lambda v: isinstance(v, str) and v in values), f"one of {', '.join(values)}"


_BOOL = (lambda v: isinstance(v, bool)), "true or false"
_ANGLES = (lambda v: isinstance(v, dict) and all(isinstance(k, str) and _number(-MAX_ABS)[0](x)
                                                   for k, x in v.items())), "joint names with finite angles"
_MLP = {"hidden": _int(1, MAX_HIDDEN), "lr": _number(0, strict=True), "epochs": _int(1),
        "batch_size": _int(1), "seed": _int(0, MAX_SEED)}
_RIGID = {"block": _int(1), "p0": _number(0, strict=True), "payload_mass": _number(0), "locked": _ANGLES,
          "context": _BOOL, "rows": _choice(("auto", "all-moving", "per-joint"))}
OPTIONS = {"rigid-body": _RIGID, "mlp-mse": {**_MLP, "loss": _choice(("mse",))},
           "mlp-masked": {**_MLP, "loss": _choice(("masked",))}, "hybrid": {**_MLP, **_RIGID}}
_PREPROCESS_NUMBERS = ("cutoff_rad_s", "pseudo_diff_rad_s", "downsample_hz", "alpha", "settle_s",
                       "split_gap_s")
_SPLIT_TYPES = {"n_pool": _int(1), "n_val": _int(1), "n_test": _int(1), "window_s": _number(0),
                "block_s": _number(0), "gap_s": _number(0),
                "eval_set": ((lambda v: isinstance(v, str)), "a word")}


def _shown(value) -> str:
    text = json.dumps(value) if not isinstance(value, str) else repr(value)
    return text if len(text) <= 60 else text[:57] + "..."


def _names_ok(names) -> bool:
    return (isinstance(names, list) and bool(names) and len(set(map(str, names))) == len(names)
            and all(isinstance(n, str) and n and n.isprintable() for n in names))


def read_model_json(directory: Path | str) -> dict:
    """model.json of `directory`, checked (see the module docstring)."""
    directory = Path(directory)
    path = directory / MODEL_JSON
    if not directory.is_dir() or not (path.exists() or path.is_symlink()):
        raise ModelFileError(f"{directory} is not a crane-x7 model directory (no {MODEL_JSON})")
    raw, problem = read_bytes(path)
    if problem is None and len(raw) > MAX_JSON_BYTES:
        problem = f"is larger than any model.json ({MAX_JSON_BYTES // 2 ** 20} MB at most)"
    if problem is not None:
        raise ModelFileError(f"{path} {problem}")
    try:
        doc = json.loads(raw.decode("utf-8"))
    except UnicodeDecodeError:
        raise ModelFileError(f"{path} is corrupt: it is not text (UTF-8 JSON)") from None
    except json.JSONDecodeError as exc:
        raise ModelFileError(f"{path} is corrupt: {exc.msg}") from None
    except (ValueError, RecursionError):
        raise ModelFileError(f"{path} is corrupt: it is not readable JSON") from None
    if not isinstance(doc, dict) or doc.get("format") != MODEL_FORMAT:
        raise ModelFileError(f"{path} is not a crane-x7 model file (its top level is not a {MODEL_FORMAT} "
                             f"object)")
    check_document(path, doc)
    return doc


def check_document(path: Path, doc: dict) -> None:
    """The parts of a model.json every method has (see the module docstring)."""
    version = doc.get("format_version")
    if isinstance(version, bool) or version not in FORMAT_VERSIONS:
        raise ModelFileError(f"{path} has format_version {_shown(version)}, which this installation does "
                             f"not read (it reads {', '.join(map(str, FORMAT_VERSIONS))}); update crane-x7 "
                             f"or fit the model again")
    method = doc.get("method")
    if not isinstance(method, str) or method not in METHOD_NAMES:
        raise ModelFileError(f"{path.parent} holds a model of unknown method {_shown(method)}")
    if "joint_names" not in doc:
        raise ModelFileError(f"{path} lacks 'joint_names'; it is damaged or not written by crane-train fit")
    if not _names_ok(doc["joint_names"]):
        raise ModelFileError(f"{path} has joint_names {_shown(doc['joint_names'])}, not a list of distinct "
                             f"joint names")
    for key in ("preprocessing", "options", "state"):
        if doc.get(key) is not None and not isinstance(doc[key], dict):
            raise ModelFileError(f"{path} has {key} = {_shown(doc[key])}, not an object of settings")
    if "units" in doc and doc["units"] != SI_UNITS:
        raise ModelFileError(f"{path} has units {_shown(doc['units'])}, not the SI units {SI_UNITS}")
    _check_options(path, method, doc.get("options") or {})
    _check_preprocessing(path, doc.get("preprocessing") or {}, len(doc["joint_names"]))
    _check_state(path, method, doc.get("state") or {}, len(doc["joint_names"]))


def _check_options(path: Path, method: str, options: dict) -> None:
    for key, (check, what) in OPTIONS[method].items():
        if key in options and not check(options[key]):
            raise ModelFileError(f"{path} has the option {key} = {_shown(options[key])}; it must be {what}")


def _check_preprocessing(path: Path, pre: dict, joints: int) -> None:
    cfg = pre.get("preprocessing", pre)
    if not isinstance(cfg, dict):
        raise ModelFileError(f"{path} has a preprocessing record of {_shown(cfg)}, not an object of settings")
    _check_preprocess_settings(path, cfg)
    _check_split_settings(path, pre.get("splits"))
    if "seed" in pre and not _int(0, MAX_SEED)[0](pre["seed"]):
        raise ModelFileError(f"{path} has the seed {_shown(pre['seed'])}; it must be a whole number from 0 "
                             f"to {MAX_SEED}")
    for key in ("sources", "sessions"):
        if pre.get(key) is not None and not (isinstance(pre[key], list)
                                             and all(isinstance(s, str) for s in pre[key])):
            raise ModelFileError(f"{path} has {key} = {_shown(pre[key])}, not a list of session file names")
    problem = preprocessing_problem(pre, joints)
    if problem is not None:
        raise ModelFileError(f"{path} records an unusable preprocessing setting: {problem}")


def _check_preprocess_settings(path: Path, cfg: dict) -> None:
    """Each recorded preprocessing setting is of its type."""
    for key in _PREPROCESS_NUMBERS:
        if key in cfg and not _number(0)[0](cfg[key]):
            raise ModelFileError(f"{path} has the preprocessing setting {key} = {_shown(cfg[key])}; it must "
                                 f"be a finite number >= 0")
    checks = {"zero_phase": _BOOL, "arm": _choice(("leader", "follower")),
              "joints": ((lambda v: _names_ok(v)), "a list of distinct joint names"),
              "extra": ((lambda v: isinstance(v, dict)), "an object")}
    for key, (check, what) in checks.items():
        if key in cfg and not check(cfg[key]):
            raise ModelFileError(f"{path} has the preprocessing setting {key} = {_shown(cfg[key])}; it must "
                                 f"be {what}")


def _check_split_settings(path: Path, splits) -> None:
    """The recorded split settings (if any) are an object of settings, each of its type."""
    if splits is not None and not isinstance(splits, dict):
        raise ModelFileError(f"{path} has splits settings of {_shown(splits)}, not an object of settings")
    for key, (check, what) in _SPLIT_TYPES.items():
        if splits and key in splits and not check(splits[key]):
            raise ModelFileError(f"{path} has the split setting {key} = {_shown(splits[key])}; it must be "
                                 f"{what}")


def _numbers(value, n: int) -> bool:
    return isinstance(value, list) and len(value) == n and all(_number(-MAX_ABS)[0](v) for v in value)


def _check_state(path: Path, method: str, state: dict, joints: int) -> None:
    if method in ("mlp-mse", "mlp-masked"):
        _check_network_state(path, state, joints)
    elif method == "hybrid":
        _check_hybrid_state(path, state)
    elif method == "rigid-body":
        _check_rigid_state(path, state)


def _check_network_state(path: Path, state: dict, joints: int) -> None:
    """A network's normalisation: finite means and usable scales of the right sizes."""
    norm = state.get("norm")
    if not isinstance(norm, dict):
        raise ModelFileError(f"{path} lacks the network's normalisation (state.norm); fit the model "
                             f"again")
    for key, n in (("x_mean", 3 * joints), ("x_std", 3 * joints), ("y_mean", joints), ("y_std", joints)):
        if not _numbers(norm.get(key), n):
            raise ModelFileError(f"{path} has a normalisation {key} of {_shown(norm.get(key))}, not {n} "
                                 f"finite numbers")
    problem = scales_problem(norm["x_std"], norm["y_std"])
    if problem is not None:
        raise ModelFileError(f"{path} has an unusable normalisation: {problem}")


def _check_hybrid_state(path: Path, state: dict) -> None:
    """A hybrid's part folders and its per-joint network weights."""
    parts = state.get("parts", {})
    if not isinstance(parts, dict) or not all(
            isinstance(parts.get(k, k), str) and _plain_name(parts.get(k, k)) for k in ("rigid", "mlp")):
        raise ModelFileError(f"{path} names its parts {_shown(parts)}, not folders inside the model "
                             f"directory")
    weights = state.get("network_weight") or {}
    if not isinstance(weights, dict) or not all(
            isinstance(k, str) and _number(0)[0](v) and v <= 1 for k, v in weights.items()):
        raise ModelFileError(f"{path} has network weights {_shown(weights)}, not a number in [0, 1] per "
                             f"joint")
    problem = _share_record_problem(state.get("blend"))
    if problem is not None:
        raise ModelFileError(f"{path} has a network share record (state.blend) that {problem}")


def _share_record_problem(blend) -> str | None:
    """What is wrong with a hybrid's record of how its network shares were chosen (state.blend; its
    "share": per joint the least-squares weight and the number of blocks), or None."""
    if blend is None:
        return None
    if not isinstance(blend, dict):
        return "is not a record"
    share = blend.get("share")
    if share is None:
        return None
    if not isinstance(share, dict) or not all(isinstance(k, str) and isinstance(v, dict)
                                              for k, v in share.items()):
        return "does not give a record per joint"
    for joint, rec in share.items():
        w, blocks = rec.get("weight_all"), rec.get("blocks")
        if not (_number(0)[0](w) and w <= 1) or isinstance(blocks, bool) or not isinstance(blocks, int) \
                or blocks < 0:
            return f"gives {joint} a weight {_shown(w)} over {_shown(blocks)} blocks"
    return None


def _check_rigid_state(path: Path, state: dict) -> None:
    """A rigid-body model's joint name lists and locked angles."""
    for key in ("names", "context_joints"):
        value = state.get(key)
        if value is not None and not (isinstance(value, list) and all(isinstance(v, str) for v in value)):
            raise ModelFileError(f"{path} has a state {key} of {_shown(value)}, not a list of names")
    lr = state.get("locked_resolved")
    if lr is not None and not _ANGLES[0](lr):
        raise ModelFileError(f"{path} has locked angles {_shown(lr)}, not joint names with finite angles")


def _plain_name(name: str) -> bool:
    return bool(name) and "/" not in name and "\\" not in name and name not in (".", "..")


def part_method(directory: Path, name: str) -> str:
    """The method of the part `name` of a hybrid model in `directory` (read from its own model.json)."""
    return read_model_json(directory / name)["method"]


def check_hybrid_parts(directory: Path | str, state: dict) -> None:
    """A hybrid's parts are a rigid-body and an mlp-masked model (checked before they are loaded, so a
    part that is itself a hybrid cannot make loading go round in circles)."""
    directory = Path(directory)
    parts = state.get("parts", {})
    for key, want in (("rigid", "rigid-body"), ("mlp", "mlp-masked")):
        got = part_method(directory, parts.get(key, key))
        if got != want:
            raise ModelFileError(f"{directory / parts.get(key, key) / MODEL_JSON} holds a {got} model where "
                                 f"the hybrid's {key} part must be {want}")


def read_arrays(directory: Path | str, name: str, shapes: dict) -> dict:
    """The arrays `shapes` names ({key: number of dimensions}) of the .npz `name` in `directory`, read
    without pickle and checked (numbers, finite, bounded, dimensions)."""
    path = Path(directory) / name
    if not path.exists() and not path.is_symlink():
        raise ModelFileError(f"{directory} lacks its parameters {name}; fit the model again")
    raw, problem = read_bytes(path)
    arrays = None
    if problem is None:
        arrays, problem = npz_arrays(raw)
    if problem is not None:
        raise ModelFileError(f"{path} {problem}; fit the model again")
    for key, ndim in shapes.items():
        if key not in arrays:
            raise ModelFileError(f"{path} lacks the array {key!r}; fit the model again")
        problem = array_problem(key, arrays[key], ndim)
        if problem is not None:
            raise ModelFileError(f"{path} is unusable: {problem}; fit the model again")
    return {k: np.asarray(arrays[k], dtype=np.float64) for k in shapes}


def read_torch_weights(directory: Path | str, name: str, shapes: dict) -> dict:
    """The tensors `shapes` names ({key: shape}) of the PyTorch file `name`, loaded with weights_only=True
    (plain tensors and containers only, never an object) and checked (shape, numbers, finite, bounded);
    as float32 numpy arrays."""
    import torch

    path = Path(directory) / name
    if not path.exists():
        raise ModelFileError(f"{directory} lacks its network weights {name}")
    problem = file_problem(path)
    if problem is not None:
        raise ModelFileError(f"{path} {problem}")
    try:
        with warnings.catch_warnings():  # a damaged file's pickle protocol warns before it fails
            warnings.simplefilter("ignore")
            weights = torch.load(path, map_location="cpu", weights_only=True)
    except Exception:  # a damaged file fails in many ways (pickle, zip, EOF, key, runtime, unsafe global)
        raise ModelFileError(f"{path} is corrupt, not a readable PyTorch weights file; fit the model "
                             f"again") from None
    if not isinstance(weights, dict):
        raise ModelFileError(f"{path} holds a {type(weights).__name__}, not the named weights crane-train "
                             f"fit writes; fit the model again")
    out = {}
    for key, shape in shapes.items():
        w = weights.get(key)
        if not isinstance(w, torch.Tensor) or w.is_complex() or w.dtype == torch.bool:
            raise ModelFileError(f"{path} lacks the weight tensor {key!r} (or holds something else there); "
                                 f"fit the model again")
        a = w.detach().cpu().to(torch.float64).numpy()
        if a.shape != tuple(shape):
            raise ModelFileError(f"{path} has {key} of shape {a.shape}, but the network that model.json "
                                 f"describes needs {tuple(shape)}; fit the model again")
        problem = array_problem(key, a)
        if problem is not None:
            raise ModelFileError(f"{path} is unusable: {problem}; fit the model again")
        out[key] = a.astype(np.float32)
    return out


def mlp_shapes(joints: int, hidden: int) -> dict:
    """The shapes of the paper's network's tensors for `joints` joints and `hidden` units."""
    return {"W1": (3 * joints, hidden), "b1": (hidden,), "W2": (hidden, joints), "b2": (joints,)}


def stderr_record_problem(fit_info) -> str | None:
    """What is wrong with the record of how a rigid-body model's standard errors were computed (its
    fit_info's stderr_method, stderr_blocks, ci95_factor; absent in models whose standard errors are
    the least-squares covariance's), or None."""
    if not isinstance(fit_info, dict):
        return None if fit_info is None else "has a fit_info that is not a record"
    if not any(k in fit_info for k in ("stderr_method", "stderr_blocks", "ci95_factor")):
        return None
    blocks, factor = fit_info.get("stderr_blocks"), fit_info.get("ci95_factor")
    if not isinstance(fit_info.get("stderr_method"), str):
        return "records standard errors without saying how they were computed (stderr_method)"
    if isinstance(blocks, bool) or not isinstance(blocks, int) or blocks < 2:
        return f"records standard errors over {blocks!r} blocks, not a whole number of at least 2"
    if isinstance(factor, bool) or not isinstance(factor, (int, float)) or not 0 < factor < 100:
        return f"records a 95 % interval factor of {factor!r}, not a positive number"
    return None


def check_rigid_loaded(directory: Path | str, model) -> None:
    """A loaded rigid-body model's parameters: one per column of its regressor (base parameters and effect
    terms), as many names as values, standard errors >= 0."""
    theta, stderr = model.theta, model.stderr
    path = Path(directory) / "rigid_body.npz"
    if theta.shape != stderr.shape:
        raise ModelFileError(f"{path} has {theta.size} parameters but {stderr.size} standard errors")
    if np.any(stderr < 0):
        raise ModelFileError(f"{path} has a negative standard error")
    problem = stderr_record_problem(getattr(model, "fit_info", None))
    if problem is not None:
        raise ModelFileError(f"{Path(directory) / MODEL_JSON} {problem}; fit the model again")
    if len(model.names) != theta.size:
        raise ModelFileError(f"{Path(directory) / MODEL_JSON} names {len(model.names)} parameters but "
                             f"{path.name} holds {theta.size}")
    try:
        columns = len(model._parameter_names(model.terms))
    except ModelFileError:
        raise
    except (KeyError, TypeError, ValueError, IndexError, AttributeError):
        raise ModelFileError(f"{Path(directory) / MODEL_JSON} has effect terms that are damaged (not the "
                             f"records crane-train fit writes); fit the model again") from None
    if columns != theta.size:
        raise ModelFileError(f"{path} holds {theta.size} parameters but the model's regressor has {columns} "
                             f"columns; fit the model again")


def check_loaded(directory: Path | str, model) -> None:
    """What can only be checked once a model's files are loaded (a rigid body's parameter count)."""
    if model.method == "rigid-body":
        check_rigid_loaded(directory, model)
