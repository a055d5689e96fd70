"""The values a diagnosis reports, estimated from the zero-phase signals of the same samples.

The candidates are judged on the data the model runs on (held-out error of the loop model's own, causal
signals), but a parameter's value is a statement about the arm, and with the paper's causal filters the
acceleration regressor is noisy enough to bias every coefficient correlated with an inertia (errors in a
regressor shrink the fitted inertia, and in back-and-forth moves ddq ~ -w^2 (q - centre), so a spring's
stiffness, a rotor inertia or a payload take what the smaller inertia leaves out). An offline estimate
needs no causal filter: when the Dataset carries its zero-phase signals (Dataset.offline,
train.data.preprocess) each candidate's per-fold fit is repeated on them — the same rows and folds, the
same basis (the model's regressor with its refined shapes and the picks the candidate joined), starting
from the shape that fold's causal fit chose and refining it on the zero-phase signals within the same
bracket (a spring's rest angle correlates with its stiffness) — and its parameters' mean and
delete-a-block jackknife standard error are reported from those fits. The causal fit's values stay with
each parameter as `loop_value` / `loop_std`. On the zero-phase signals every column's angle-only part (a
cogging ripple, a spring, gravity) is filtered from the unfiltered angle as the torque is
(train.data.angle_columns, through physics_basis and columns_at).
"""

from __future__ import annotations

from typing import TYPE_CHECKING

import numpy as np

from .cv import Engine, interval, interval_factor, jackknife, refine_shape
from .effects import candidate_columns, columns_at, named_values
from .text import candidate_text

if TYPE_CHECKING:
    from collections.abc import Sequence

    from ..data.dataset import Dataset
    from .result import Candidate

SOURCE = "zero-phase derivatives of the same samples"


def offline_basis(model, ds: Dataset, refinements: list[dict], folds: int,
                  fold: np.ndarray) -> np.ndarray | None:
    """The model's regressor on `ds.offline` with the refined values of its own shape parameters and
    their derivative columns (as train.diagnosis.diagnose.refine_own_shapes builds the causal one), or
    None when the data carry no zero-phase signals or the model is not linear in its parameters."""
    from .diagnose import _derivative_column, _own_shape_terms, _replace_term, physics_basis

    off = ds.offline
    if off is None or model is None:
        return None
    X = physics_basis(model, off)
    if X is None:
        return None
    items = _own_shape_terms(model, off) if refinements else []
    extra = []
    for item, ref in zip(items, refinements):
        value = float(ref["value"])
        C = columns_at(item["effect"], off, item["joint"])({**item["shape"], item["parameter"]: value})
        if C is None or C.shape[2] != item["n"]:
            return None
        X = _replace_term(X, C, item, whole=False)
        th = Engine(X, off.tau, off.moving, fold, folds).fit(None, list(range(folds)))[0]
        D = _derivative_column(item, off, th[item["offset"]:item["offset"] + item["n"]], value)
        if D is not None:
            extra.append(D)
    return np.concatenate([X, *extra], axis=2) if extra else X


def _columns(effect, off: Dataset, joint: int | None, shape: dict | None) -> np.ndarray | None:
    """The candidate's columns on the zero-phase signals at `shape` (its only option when it has none)."""
    if shape:
        return columns_at(effect, off, joint)(shape)
    options = candidate_columns(effect, off, joint)
    return options[0][1] if options else None


def report_offline_values(ds: Dataset, X_off: np.ndarray, fold: np.ndarray, folds: int,
                          results: dict[int, list[Candidate]], tried: dict[int, tuple],
                          selected: Sequence[Candidate]) -> bool:
    """Replace each candidate's parameter values (mean over folds and jackknife standard error)
    with those of the same per-fold fits on the zero-phase signals (in place; the causal ones kept as
    `loop_value` / `loop_std`). True when any was replaced."""
    off = ds.offline
    engines: dict[int, Engine] = {}
    picks: list[np.ndarray] = []  # the zero-phase columns of the selected ones, in order
    for c in selected:
        effect, _, fit, _ = tried[id(c)]
        picks.append(_columns(effect, off, _joint(c, ds), fit.shape_all))
    done = False
    for cands in results.values():
        for c in cands:
            if not c.parameters or id(c) not in tried:
                continue
            step = c.selection_step - 1 if (c.selection_step and c.given) else 0
            if any(p is None for p in picks[:step]):
                continue
            if step not in engines:
                engines[step] = Engine(np.concatenate([X_off, *picks[:step]], axis=2), off.tau, off.moving,
                                       fold, folds)
            done |= _replace_values(c, tried[id(c)], engines[step], off, _joint(c, ds), folds)
    return done


def _joint(c: Candidate, ds: Dataset) -> int | None:
    return None if c.scope == "arm" else list(ds.joint_names).index(c.joint)


def _replace_values(c: Candidate, entry: tuple, engine: Engine, off: Dataset, joint: int | None,
                    folds: int) -> bool:
    effect, _, fit, _ = entry
    if len(fit.fold_shapes) != folds:
        return False
    grid = dict(getattr(effect, "shape_grid", None) or {})
    integers = tuple(getattr(effect, "integer_shapes", ()) or ())
    at = columns_at(effect, off, joint)
    values = []
    for k, shape in enumerate(fit.fold_shapes):
        train = [i for i in range(folds) if i != k]
        C = _columns(effect, off, joint, shape)
        if C is None:
            return False
        shape2, C2, _ = refine_shape(engine, at, grid, shape, train, engine.fit(C, train)[2], integers)
        if C2 is not None:
            shape, C = shape2, C2
        values.append(named_values(effect, engine.fit(C, train)[1], shape))
    stats = jackknife(values)
    for name, entry_ in c.parameters.items():
        if name in stats:
            mean, sd = stats[name]
            entry_.update({"loop_value": entry_["value"], "loop_std": entry_["std"], "value": mean, "std": sd,
                           "ci95": interval(mean, sd, interval_factor(folds)), "from": SOURCE})
    if not c.explained_by:  # a demoted one's sentence names what explains it, not its values
        c.sentence = candidate_text(effect, c)
    return True
