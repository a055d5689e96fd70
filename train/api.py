"""The Python front door of crane-train: the modelling loop in a notebook, without the command line.

    import train

    ds = train.load_sessions("day1.h5")                      # the follower's data, preprocessed
    fit = train.fit(ds, "rigid-body", scale_to_data=True)    # a FitResult: .model, .metrics, .splits
    fit.save("models/rb")
    found = train.diagnose_model("models/rb", "day1.h5")     # which effect is missing?
    terms = train.discover_terms("models/rb", "day1.h5")     # ... and one the library lacks?
    better = train.fit(ds, "rigid-body", effects=["coulomb:joint=joint2"], scale_to_data=True)
    better.save("models/rb-coulomb")
    table = train.compare_models(["models/rb", "models/rb-coulomb"])
    train.make_report("models/rb-coulomb", "day1.h5", "rb.html")

Every function takes and returns SI values, numpy arrays and small objects (a Dataset, a Model, a
Diagnosis, a Comparison); problems are raised as crane_io.errors.CraneError subclasses with one sentence.
The `crane-train` commands are thin wrappers over these functions. (The names differ from the modules
train.diagnosis.diagnose, train.evaluation.compare and train.evaluation.report, which hold the machinery.)
"""

from __future__ import annotations

import json
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING

from crane_io.errors import ConfigError

from .diagnosis.defaults import DEFAULT_FOLDS, DEFAULT_MIN_REDUCTION

if TYPE_CHECKING:
    from .data.dataset import Dataset
    from .data.splits import Splits
    from .diagnosis.discovery import Discovery
    from .diagnosis.result import Diagnosis
    from .evaluation.compare import Comparison
    from .models.base import Model

PathLike = str | Path
Sessions = PathLike | Sequence[PathLike]
Effect = str | tuple  # "coulomb", "coulomb:joint=joint2", or (name, joint, shape)


def _paths(sessions: Sessions) -> list[str]:
    if isinstance(sessions, (str, Path)):
        return [str(sessions)]
    out = [str(s) for s in sessions]
    if not out:
        raise ConfigError("give at least one session file")
    return out


def _effect(e: Effect) -> tuple[str, str | None, dict | None]:
    from .settings import parse_effect

    if isinstance(e, str):
        return parse_effect(e)
    name, joint, shape = (tuple(e) + (None, None))[:3]
    return str(name), joint, dict(shape) if shape else None


def load_settings(config: PathLike | None = None) -> dict:
    """The training settings {'preprocess', 'splits', 'mlp'}: train/config/train.toml's documented
    defaults, overlaid with the TOML file `config` (same sections)."""
    from .settings import load_config

    return load_config(config)


def load_sessions(sessions: Sessions, *, arm: str | None = None, joints: Sequence[str] | str | None = None,
                  alpha: float | None = None, zero_phase: bool = False,
                  config: PathLike | None = None) -> Dataset:
    """Read one arm's data from session files and preprocess it the paper's way (50 Hz, causal filters,
    dead-zone masks): a train.data.dataset.Dataset with q, dq, ddq (rad, rad/s, rad/s^2), tau (N m) and the
    masks, (N, J) each.

    arm: "follower" (default) or "leader" (only from a session recorded with the hand on the follower);
    joints: the learning joints (default joint1, joint2, joint4; "all": every arm joint the sessions
    record); the Dataset also carries the other arm joints' filtered q, dq, ddq as context
    (`context_names`, `context_q`, ...), which the rigid-body model's kinematics use; alpha: the
    dead-zone threshold
    (|dq| > alpha std(dq) moves, default 0.1); zero_phase: filter forward and backward instead."""
    from .settings import load_dataset

    return load_dataset(_paths(sessions), joints, alpha, zero_phase, load_settings(config)["preprocess"], arm)


@dataclass
class FitResult:
    """A fitted model with what it was fitted and scored on."""

    model: Model
    metrics: dict  # the test metrics document (fit_metrics.json): mse, rmse, nmse per joint, sizes, seed
    dataset: Dataset = field(repr=False)
    splits: Splits = field(repr=False)
    documents: dict = field(default_factory=dict, repr=False)  # more files: name -> text or a JSON object

    def save(self, out_dir: PathLike, *, force: bool = False) -> Path:
        """Write the model (fit_metrics.json and any other `documents`) to `out_dir`, whole or not at all;
        returns its path. An existing model folder is replaced only with `force` (check_model_output)."""
        from crane_io.output_files import atomic_directory

        inputs = [*self.metrics.get("sources", ()), *self.model.options.get("effect_files", ())]
        path = check_model_output(out_dir, inputs, force)
        with atomic_directory(path, "model folder") as tmp:
            self.model.save(tmp)
            (tmp / "fit_metrics.json").write_text(json.dumps(self.metrics, indent=2))
            for name, doc in self.documents.items():  # text as it is, anything else as JSON
                (tmp / name).write_text(doc if isinstance(doc, str) else json.dumps(doc, indent=2))
        return path


def check_model_output(out_dir: PathLike, inputs: Sequence[PathLike] = (), force: bool = False) -> Path:
    """The model folder `out_dir`, checked before any work (crane_io.output_files.check_output): not one
    of `inputs` nor holding one, its missing folders made when it is written; an existing one is replaced
    whole, so only with `force` and only when it is a model folder (it holds model.json) or empty."""
    from crane_io.output_files import OutputPathError, check_output

    from .models.base import MODEL_JSON

    path = check_output(out_dir, inputs=inputs, force=force, what="model folder", directory=True,
                        make_folders=True)
    if path.is_dir() and any(path.iterdir()) and not (path / MODEL_JSON).is_file():
        raise OutputPathError(f"the model folder {path} exists and holds no model ({MODEL_JSON}); it would "
                              "be replaced whole, so write the model elsewhere")
    return path


def fit(data: Dataset | Sessions, method: str, *, effects: Sequence[Effect] = (),
        effect_files: Sequence[PathLike] = (), train_size: int | None = None, seed: int = 0,
        epochs: int | None = None, scale_to_data: bool = False, config: PathLike | None = None,
        arm: str | None = None, joints: Sequence[str] | str | None = None, alpha: float | None = None,
        zero_phase: bool = False, progress: Callable[[int, int], None] | None = None,
        eval_set: str | None = None, start_from: PathLike | None = None,
        start_weight: float = 100.0) -> FitResult:
    """Fit one model the paper's way: split the data (pool, validation, test; `scale_to_data` shrinks the
    sizes to short data), fit on `train_size` samples of the pool (all by default) and score on the test
    set.

    data: a Dataset from load_sessions, or session file(s) (then arm, joints, alpha, zero_phase, config
    apply as in load_sessions); method: "rigid-body", "mlp-mse", "mlp-masked" or "hybrid"; effects
    (rigid-body, hybrid): physical effects added to the model, e.g. "coulomb", "coulomb:joint=joint2",
    "stribeck:joint=joint4,stribeck_velocity=0.05"; effect_files: files defining more effects (effect-spec
    files .json, read as data; Python files .py, run: the model records their SHA-256);
    epochs: of the network (default from the settings, 100); progress(done, total): called per epoch;
    start_from (rigid-body): an identified arm model (arm_model.toml) the fit starts from and is
    regularised towards, with the weight of `start_weight` torque equations
    (train.models.rigid_body_prior)."""
    import numpy as np

    from .data.data_checks import fit_rows_finding, warn
    from .data.splits import make_splits
    from .models.registry import make_model

    if (effects or effect_files) and method not in ("rigid-body", "hybrid"):
        raise ConfigError(f"effects apply to rigid-body and hybrid models, not {method}")
    if start_from is not None and method != "rigid-body":
        raise ConfigError(f"`start_from` applies to the rigid-body model, not {method}")
    _define_effects(effect_files)
    effects = [_effect(e) for e in effects]  # bad input is refused before any work
    settings = load_settings(config)
    if eval_set is not None:  # "auto", "all-moving" or "per-joint" (train.data.splits), over the config's
        from .data.splits import SplitConfig

        settings["splits"] = SplitConfig(**{**vars(settings["splits"]), "eval_set": eval_set})
    if not hasattr(data, "tau"):  # session file(s), not a Dataset
        data = load_sessions(data, arm=arm, joints=joints, alpha=alpha, zero_phase=zero_phase, config=config)
    ds = data
    splits = make_splits(ds, settings["splits"], seed=seed, scale_to_data=scale_to_data)
    pool = splits.pool
    if train_size is not None:
        if not 0 < train_size <= len(pool):
            raise ConfigError(f"the training size must be between 1 and the pool size {len(pool)}, "
                              f"got {train_size}")
        rows = np.sort(np.random.default_rng([seed, train_size]).choice(len(pool), train_size, replace=False))
        pool = pool.subset(rows)
    options = {}
    if effects or effect_files:
        options["effects"] = [list(e) for e in effects]  # the model records each effect's spec as data
    if start_from is not None:
        from .models.rigid_body_prior import arm_model_table

        options.update(start_from=arm_model_table(start_from), start_weight=start_weight)
    has_net = method.startswith("mlp-") or method == "hybrid"  # hybrid: a masked net on the residual
    if has_net:
        m = settings["mlp"]
        options.update(seed=seed, hidden=m.hidden, lr=m.lr, batch_size=m.batch_size,
                       epochs=epochs if epochs is not None else m.epochs)
        import torch  # only the networks need it (a rigid-body fit starts ~1.5 s sooner without it)

        torch.set_num_threads(1)
    model = make_model(method, ds.joint_names, preprocessing=model_preprocessing(ds, splits), **options)
    per_joint_eval = splits.test.meta.get("eval_set", "all-moving") == "per-joint"
    few = fit_rows_finding(method, pool.moving, per_joint=per_joint_eval)
    if few is not None:
        warn([few])
    if has_net and progress is not None:
        model.fit(pool, splits.val, progress=progress)
    else:
        model.fit(pool, splits.val)
    return FitResult(model, test_metrics(model, ds, splits, pool, method, seed, [few] if few else []), ds,
                     splits)


def model_preprocessing(ds: Dataset, splits: Splits) -> dict:
    """What a model records of its data besides the preprocessing: the dead-zone velocity alpha sigma_j of
    the training data (where the loop's model treats a joint as standing still, collect/model_reaction.py),
    the poses the model saw (the loop trusts it only there) and the kind of evaluation sets
    (train.data.splits, so report, compare and diagnose split alike: heldout)."""
    dead_zone = [float(ds.meta["alpha"]) * float(s) for s in ds.meta["sigma"]]
    q_range = {"q_min": ds.q.min(axis=0).tolist(), "q_max": ds.q.max(axis=0).tolist()}
    eval_set = {"eval_set": splits.test.meta.get("eval_set", "all-moving")}
    return {**ds.meta["preprocessing"], "dead_zone_rad_s": dead_zone, "input_range": q_range,
            "splits": eval_set}


def test_metrics(model: Model, ds: Dataset, splits: Splits, pool: Dataset, method: str, seed: int,
                 findings=()) -> dict:
    """The fit_metrics.json document: the held-out test error per joint, the sizes, the seed, the sources,
    and the data checks' findings (train.data.data_checks: the sessions', then `findings` of the fit)."""
    from .data.splits import eval_mask
    from .evaluation.metrics import metrics_table

    test = splits.test
    return {"method": method, "arm": ds.meta["arm"], "joints": list(ds.joint_names),
            "train_samples": len(pool),
            "train_samples_all_moving": int(pool.all_moving.sum()), "test_samples": len(test),
            "seed": seed,
            "test": metrics_table(test.tau, model.predict_dataset(test), ds.joint_names, eval_mask(test)),
            "eval_set": test.meta.get("eval_set", "all-moving"),
            "usable_fraction": ds.meta["usable_fraction"],
            "sources": [str(Path(f).resolve()) for f in ds.meta["sources"]],  # found from any directory
            "data_checks": [*ds.meta.get("data_checks", []), *(f.to_dict() for f in findings)]}


def _define_effects(effect_files: Sequence[PathLike]) -> None:
    """Register the effects of files the user named to define effects (fit, diagnose): an effect-spec
    file is read as data, a Python file is run. Two files defining one name differently (their specs'
    identities differ) are refused: which of them a model used could not be told."""
    from crane_io.physics.effects import get_effect, load_effect_file
    from crane_io.physics.effects.spec import identity, spec_of

    defined: dict[str, tuple[str, PathLike]] = {}
    for path in effect_files:
        for name in load_effect_file(path):
            key = identity(spec_of(get_effect(name)))
            if name in defined and defined[name][0] != key:
                raise ConfigError(f"{defined[name][1]} and {path} both define the effect {name!r}, "
                                  f"differently; give it another name in one of them")
            defined[name] = (key, path)


def load_model(model_dir: PathLike, effect_files: Sequence[PathLike] = ()) -> Model:
    """A saved model (any method); `model.predict(q, dq, ddq)` takes (N, J) arrays in rad, rad/s, rad/s^2
    and returns (N, J) N m. Loading runs no code: a model that uses an effect defined in a user's Python
    file needs that file in `effect_files`, and the file runs only when its SHA-256 is the recorded one."""
    from crane_io.physics.effects.spec import offer_effect_files

    from .models.registry import load_model as _load

    offer_effect_files(effect_files)
    return _load(model_dir)


def diagnosis_inputs(model_dir: PathLike, sessions: Sessions,
                     effect_files: Sequence[PathLike] = ()) -> tuple[Model, Dataset, str]:
    """What a diagnosis works on: the model, the sessions' data preprocessed as its training was (its
    own arm; a network only the samples it never trained on) and a phrase saying which samples those are.
    `effect_files` may rebuild the model's own user effects (a Python file runs only when its SHA-256 is
    the one the model records), then their effects become candidates."""
    from .data.preprocess import read_preprocessed
    from .evaluation.heldout import diagnosis_data, model_settings

    model = load_model(model_dir, effect_files)
    _define_effects(effect_files)
    pconf = model_settings(model, model_dir)[0]
    ds, judged = diagnosis_data(model, read_preprocessed(_paths(sessions), pconf), model_dir)
    return model, ds, judged


def diagnose_model(model_dir: PathLike, sessions: Sessions, *, folds: int = DEFAULT_FOLDS,
                   min_reduction: float = DEFAULT_MIN_REDUCTION, effect_files: Sequence[PathLike] = (),
                   progress: bool = False) -> Diagnosis:
    """Which physical effect is the model at `model_dir` missing on `sessions`? The library's effects
    (and those of `effect_files`) ranked by how much of the model's held-out error each removes, with
    cross-validation over `folds` contiguous time blocks and a forward, nested selection; a candidate
    must remove at least `min_reduction` of what remains to count. The Diagnosis has `.candidates`,
    `.summary` and `.to_json()`."""
    from .diagnosis.diagnose import diagnose as run_diagnosis

    model, ds, judged = diagnosis_inputs(model_dir, sessions, effect_files)
    result = run_diagnosis(model, ds, folds=folds, min_reduction=min_reduction, progress=progress)
    result.settings["judged_on"] = judged
    return result


def discover_terms(model_dir: PathLike, sessions: Sessions, *, every_joint: bool = False,
                   folds: int = DEFAULT_FOLDS, min_reduction: float = DEFAULT_MIN_REDUCTION,
                   effect_files: Sequence[PathLike] = (), progress: bool = False) -> Discovery:
    """What term would explain the model's residual? A sparse regression per joint on a basis of physical
    terms (train/diagnosis/discovery.py), on top of the library's best effect where that one is significant
    (from the model alone on every joint with `every_joint`). Returns a train.diagnosis.discovery.Discovery
    (`.discovered`: per joint the expression, its terms with coefficients and uncertainties, the held-out
    error it removes, whether it is significant; `.to_json()`)."""
    from .diagnosis.diagnose import diagnose as run_diagnosis
    from .diagnosis.discovery import discover

    model, ds, _ = diagnosis_inputs(model_dir, sessions, effect_files)
    ranking = run_diagnosis(model, ds, folds=folds, min_reduction=min_reduction, progress=progress)
    return discover(model, ds, ranking, every_joint=every_joint, folds=folds, min_reduction=min_reduction,
                    progress=progress)


def compare_models(model_dirs: Sequence[PathLike], sessions: Sessions | None = None,
            progress: bool = False, effect_files: Sequence[PathLike] = ()) -> Comparison:
    """The held-out error per joint of successive models on the same samples (default: the first model's
    training sessions); `.to_json()`, and train.evaluation.compare.table_text / plot for a table and a
    chart. `effect_files`: Python files defining user effects the models need (see load_model)."""
    from crane_io.physics.effects.spec import offer_effect_files

    from .evaluation import compare

    offer_effect_files(effect_files)
    return compare.compare_models([str(d) for d in model_dirs], _paths(sessions) if sessions else [],
                          progress=progress)


def make_report(model_dir: PathLike, sessions: Sessions, output: PathLike, *, seed: int | None = None,
                diagnosis: bool = True, discover: bool = False, force: bool = False,
                effect_files: Sequence[PathLike] = ()) -> Path:
    """Write the self-contained HTML page of the model's error on the held-out part of `sessions` (with
    the diagnosis sentences unless `diagnosis=False`, and with `discover` the terms discovery finds in
    the residual, each against it); `seed`: the split seed (default: the model's); `effect_files`: Python
    files defining user effects the model needs (see load_model). The output is checked first (never an
    input; an existing file replaced only with `force`) and written atomically."""
    from crane_io.output_files import check_output

    from .evaluation.heldout import evaluation_data
    from .evaluation.report import report_html, write_report

    paths = _paths(sessions)
    check_output(output, inputs=[model_dir, *paths], force=force, what="report", make_folders=True)
    model = load_model(model_dir, effect_files)
    ds, _, held = evaluation_data(model, paths, seed=seed, model_dir=model_dir)
    diag = found = None
    if diagnosis or discover:
        from .diagnosis.diagnose import diagnose as run_diagnosis
        from .evaluation.heldout import diagnosis_data

        judged = diagnosis_data(model, ds, model_dir, seed)[0]
        diag = run_diagnosis(model, judged)
        if discover:
            from .diagnosis.discovery import discover as run_discovery

            found = run_discovery(model, judged, diag)
        if not diagnosis:
            diag = None
    return write_report(output, report_html(model, model_dir, held, paths, diag, discovery=found))


__all__ = ["FitResult", "compare_models", "diagnose_model", "diagnosis_inputs", "discover_terms", "fit",
           "load_model", "load_sessions", "load_settings", "make_report"]
