"""Find the missing physics: rank the library's effects by how much of a model's held-out error each
one removes.

The method, per joint j (names as in the session):

1. The samples judged are those where joint j MOVES (its dead-zone mask): in a dead zone the torque is
   whatever stiction holds, which no function of (q, dq, ddq) predicts, so those samples would only add
   noise — also for effects that act at rest (offset, spring), which leave their mark on the moving
   samples just as well. Every candidate is judged on the same samples, so their error reductions
   compare like with like.
2. The rows are cut into K contiguous time blocks (folds; blocks, not shuffled rows, because filtered
   signals are correlated in time). For each fold the model is refitted on the other K-1 blocks twice,
   without and with the candidate's regressor columns (`effect.columns`), and both predict the held-out
   block. For a physics model (rigid-body: base regressor + its effects' columns) the refit is the
   whole regressor, by least squares on the per-joint masked rows (each joint's equation where that
   joint moves: its equation holds whatever the other joints do), so a candidate competes with the
   rigid-body parameters it correlates with. For any other model (network, hybrid) the model is kept
   and the candidate is fitted to its residual. A candidate with shape parameters (Stribeck velocity,
   spring rest angle, cogging period ...) tries every value of its grid, keeps the one that fits the
   training blocks best and refines it there (scipy, within half a grid step; whole numbers for
   `integer_shapes`). The model's own grid-picked shapes are refined first (`refine_own_shapes`) so
   their leftovers are not found as new effects.
3. `error_reduction` = 1 - (held-out SSE with the candidate) / (held-out SSE without it): the fraction
   of the held-out mean squared error the candidate removes. A flexible candidate cannot win by
   overfitting: it is scored only on blocks it never saw. Ranking: by error reduction, except that a
   simpler candidate within one standard error (paired, per fold) of the best one goes first.
4. Parameters: each fold's fit gives one set of named values (`effect.values_from_coefficients`); the
   value is the mean over folds and its uncertainty the delete-a-block jackknife standard error
   sqrt((K-1)/K * sum (v_k - mean)^2), which stays honest when neighbouring samples are correlated
   (plain least-squares standard errors would not); refined shapes included. A candidate whose
   columns the basis spans is not identifiable: no value is given (cv.identifiability). For a physics
   model on data with zero-phase signals (Dataset.offline) the linear parameters' values and standard
   errors are those of the same fits on the zero-phase signals (train.diagnosis.offline_values: the
   causal acceleration's noise biases coefficients correlated with an inertia); the causal ones are kept
   as `loop_value` / `loop_std`, and `settings.values_from` says which.
5. Significant: error_reduction >= `min_reduction` AND the held-out error falls in every fold
   (`min_fold_fraction`), judged by forward selection (ranking.forward_selection): each
   candidate on top of the effects selected before it. A session with nothing missing yields no
   significant candidate. Each pick after the first reports its parameters from its fit with the earlier
   picks in the model (the model it joins); its values alone are kept as `parameters_alone`.

Arm-scope effects (payload) have one set of parameters for all joints: their fit is joint across all
joints and they are reported once, on the joint where they remove the largest fraction of the error,
with the other joints' fractions in the sentence. Effects the model already contains (same name on the
same joint, or on every joint, and the same definition: crane_io.physics.effects.spec's identity) are
not candidates.
"""

from __future__ import annotations

from typing import TYPE_CHECKING

import numpy as np

from crane_io.errors import CraneError

from ..data.angle_columns import columns_on
from ..data.dataset import Dataset
from ..models.recorded_effects import effect_entries, effect_identities
from .cv import CVFit, Engine, cross_validate, fold_ids, interval, interval_factor, jackknife, sparse_joint
from .defaults import DEFAULT_FOLDS, DEFAULT_MIN_FOLD_FRACTION, DEFAULT_MIN_REDUCTION
from .effects import (
    bind,
    candidate_columns,
    columns_at,
    complexity,
    effect_name,
    library_effects,
)
from .ranking import fit_parameters, forward_selection, is_significant, rank
from .result import Candidate, Diagnosis, DiagnosisError
from .text import (
    candidate_text,
    joint_summary,
    residual_correlations,
    residual_dependence,
    selected_suffix,
)

if TYPE_CHECKING:
    from collections.abc import Iterable
    from typing import Any

    from ..models.base import Model

__all__ = ["DEFAULT_FOLDS", "DEFAULT_MIN_FOLD_FRACTION", "DEFAULT_MIN_REDUCTION", "Candidate", "Diagnosis",
           "DiagnosisError", "diagnose", "diagnose_residual", "model_effects", "physics_basis",
           "refine_own_shapes", "residual_correlations", "residual_dependence"]

MIN_SAMPLES_PER_JOINT = 50


def model_effects(model: Model) -> set[tuple[str, str | None]]:
    """(effect name, joint name or None) pairs a model already contains (rigid-body / hybrid)."""
    return {(str(name), None if joint is None else str(joint)) for name, joint in effect_entries(model)}


def physics_basis(model: Model, ds: Dataset) -> np.ndarray | None:
    """(N, J, p) regressor of a physics model (rigid-body: base regressor + its effects' columns), or
    None for a model that is not linear in its parameters."""
    from ..models.base import basis_on

    # train.models.base.Model's linear_basis (a stand-in may lack it); on zero-phase signals with the
    # columns' angle-only part filtered as the torque is (train.data.angle_columns)
    X = columns_on(ds, lambda d: basis_on(model, d))
    if X is None:
        return None
    X = np.asarray(X, dtype=float)
    if X.ndim == 3 and X.shape[:2] == ds.tau.shape and np.isfinite(X).all():
        return X
    return None


def diagnose(model: Model, ds: Dataset, effects: Iterable[Any] | None = None, *, folds: int = DEFAULT_FOLDS,
             min_reduction: float = DEFAULT_MIN_REDUCTION,
             min_fold_fraction: float = DEFAULT_MIN_FOLD_FRACTION, progress: bool = False) -> Diagnosis:
    """Diagnose `model` on `ds` (see the module docstring): a physics model is refitted with each
    candidate; any other model keeps its predictions and the candidate explains its residual.

    effects: the candidate effects (default: the whole library); folds: cross-validation folds over
    time; min_reduction: the share of a joint's residual MSE (0..1) a candidate must remove to count;
    min_fold_fraction: the share of folds in which it must help; progress: a bar over the candidates."""
    from ..models.base import predict_on

    options = dict(folds=folds, min_reduction=min_reduction, min_fold_fraction=min_fold_fraction,
                   progress=progress)
    residual = ds.tau - np.asarray(predict_on(model, ds), dtype=float)
    X = physics_basis(model, ds)
    if X is None:
        return _run(ds, None, residual, residual, effects, exclude=model_effects(model),
                    own_ids=effect_identities(model), **options)
    return _run(ds, X, ds.tau, residual, effects, exclude=model_effects(model),
                own_ids=effect_identities(model), refit=True, model=model,
                **options)


def diagnose_residual(ds: Dataset, residual: np.ndarray, effects: Iterable[Any] | None = None, *,
                      folds: int = DEFAULT_FOLDS,
                      min_reduction: float = DEFAULT_MIN_REDUCTION,
                      min_fold_fraction: float = DEFAULT_MIN_FOLD_FRACTION,
                      progress: bool = False) -> Diagnosis:
    """Rank candidate effects by how much of `residual` (N, J) N m each explains, cross-validated (the
    options as for `diagnose`)."""
    residual = np.asarray(residual, dtype=float)
    return _run(ds, None, residual, residual, effects, folds=folds, min_reduction=min_reduction,
                min_fold_fraction=min_fold_fraction, progress=progress)


def _run(ds: Dataset, X, y, residual, effects=None, *, exclude=(), folds: int = DEFAULT_FOLDS,
         min_reduction: float = DEFAULT_MIN_REDUCTION, min_fold_fraction: float = DEFAULT_MIN_FOLD_FRACTION,
         refit: bool = False, progress: bool = False, model=None, own_ids: dict | None = None) -> Diagnosis:
    """Cross-validate every candidate (effect, joint) against the basis X (None: no basis, y is the
    residual), select forward, then rank and describe per joint. `own_ids`: name -> identity of the
    model's own effects (an effect of one of their names but another definition is still a candidate)."""
    fold = _check_data(ds, residual, folds)
    effects = [bind(e, ds.joint_names) for e in (library_effects() if effects is None else effects)]
    if X is None:
        X = np.zeros(ds.tau.shape + (0,))
    refinements, X = refine_own_shapes(model, ds, X, y, fold, folds, min_reduction, min_fold_fraction)
    engine = Engine(X, y, ds.moving, fold, folds)
    baseline = engine.baseline()

    results: dict[int, list[Candidate]] = {j: [] for j in range(len(ds.joint_names))}
    tried: dict[int, tuple] = {}  # id(candidate) -> (effect, columns_by_shape, fit, columns_at)
    for effect, j in _with_progress(_candidates_to_try(effects, ds.joint_names, exclude, own_ids),
                                      progress):
        columns_by_shape = candidate_columns(effect, ds, j)
        if not columns_by_shape:
            continue
        cols_at = columns_at(effect, ds, j)
        fit = cross_validate(engine, effect, columns_by_shape, baseline, cols_at)
        home, cand = _judge(effect, j, fit, ds.joint_names, min_reduction, min_fold_fraction)
        results[home].append(cand)
        tried[id(cand)] = (effect, columns_by_shape, fit, cols_at)

    selected, final = forward_selection(engine, ds.joint_names, results, tried, min_reduction,
                                        min_fold_fraction)
    # what remains once the selected effects (and the refined own shapes) are in: the refit on all rows
    remaining = final.y - final.X @ final.fit(None, list(range(folds)))[0] if final.p else residual
    values_from = _offline_values(ds, model, refinements, fold, folds, results, tried, selected)
    for c in selected:
        c.sentence = c.sentence[:-1] + selected_suffix(c) + "."
    settings = {"folds": folds, "min_reduction": min_reduction, "min_fold_fraction": min_fold_fraction,
                "method": "refit of the physics model with each candidate" if refit else
                          "candidate fitted to the model's residual",
                "selection": "forward: each effect judged on top of the ones selected before it",
                "samples": len(ds), "moving_samples": {name: int(ds.moving[:, j].sum())
                                                       for j, name in enumerate(ds.joint_names)}}
    settings["values_from"] = values_from
    result = _assemble(ds, remaining, results, settings, refinements, folds)
    result.selected = [f"{c.effect} on {c.joint}" for c in selected]
    return result


def _offline_values(ds: Dataset, model, refinements, fold, folds: int, results, tried, selected) -> str:
    """Where the reported values come from: the zero-phase signals of the same samples when the data
    carry them and the model is a physics model (train.diagnosis.offline_values), else the fits
    judged."""
    from .offline_values import SOURCE, offline_basis, report_offline_values

    X_off = offline_basis(model, ds, refinements, folds, fold) if model is not None else None
    if X_off is not None and report_offline_values(ds, X_off, fold, folds, results, tried, selected):
        return SOURCE
    return "the fits judged (the data the model runs on)"


def _own_shape_terms(model, ds: Dataset) -> list[dict]:
    """The model's own effect terms whose shape parameters `fit` picked from a grid (rigid-body models:
    `terms`, `theta`, `regressor(..., terms=)`), one entry per shape parameter."""
    terms, theta = getattr(model, "terms", None), getattr(model, "theta", None)
    dyn = getattr(model, "dynamics", None)
    if not terms or theta is None or dyn is None or not callable(getattr(model, "regressor", None)):
        return []
    from crane_io.physics import effects as fx
    out, k = [], int(dyn.n_base)
    for i, term in enumerate(terms):
        try:
            own = getattr(model, "effect_by_name", None)  # the model's own effect, not the library's by name
            effect = bind(own(term["name"]) if own else fx.get_effect(term["name"]), ds.joint_names)
        except CraneError:
            return []
        n = effect.n_columns()
        shape = dict(term.get("shape") or {})
        for p in effect.shape_params:
            if p.name in shape:
                out.append({"index": i, "effect": effect, "name": term["name"], "joint": term["joint"],
                            "offset": k, "n": n, "shape": shape, "parameter": p.name, "unit": p.unit})
        k += n
    return out if k == len(theta) else []


def _derivative_column(item: dict, ds: Dataset, coef: np.ndarray, value: float) -> np.ndarray | None:
    """(N, J, 1) d(torque of the term)/d(shape parameter) at `value`, the term's coefficients `coef`."""
    h = 1e-4 * max(abs(value), 1.0)
    cols = []
    for v in (value + h, value - h):
        C = columns_at(item["effect"], ds, item["joint"])({**item["shape"], item["parameter"]: v})
        if C is None:
            return None
        cols.append(C @ coef)
    D = ((cols[0] - cols[1]) / (2 * h))[:, :, None]
    return D if np.any(D * ds.moving[:, :, None]) else None


def _gauss_newton(X0: np.ndarray, item: dict, ds: Dataset, y, fold, folds: int, train: list[int],
                  value: float, steps: int = 8) -> tuple[float, np.ndarray, np.ndarray | None]:
    """Refine one shape parameter of the model's own term by Gauss-Newton on the training folds (the
    whole regressor X0, with the term's columns at the new value, refitted at each step); returns
    (value, regressor at it (X0 if no step could be made), its derivative column)."""
    cols_at = columns_at(item["effect"], ds, item["joint"])
    X = D = None
    for _ in range(steps):
        C = cols_at({**item["shape"], item["parameter"]: value})
        if C is None or C.shape[2] != item["n"]:
            break
        X = _replace_term(X0, C, item, whole=False)
        eng = Engine(X, y, ds.moving, fold, folds)
        th = eng.fit(None, train)[0]
        D = _derivative_column(item, ds, th[item["offset"]:item["offset"] + item["n"]], value)
        if D is None:
            break
        delta = float(eng.fit(D, train)[1][0])
        if not np.isfinite(delta):
            break
        value += delta
        if abs(delta) < 1e-5 * max(abs(value), 1.0):
            break
    return value, (X0 if X is None else X), D


def refine_own_shapes(model: Model | None, ds: Dataset, X: np.ndarray, y: np.ndarray, fold: np.ndarray,
                      folds: int, min_reduction: float,
                      min_fold_fraction: float) -> tuple[list[dict], np.ndarray]:
    """The model's own shape parameters (a spring's rest angle, a Stribeck velocity ...) were picked from
    a grid by `fit`; what the grid step leaves behind (a spring off by 0.2 rad leaves k x 0.2 N m of
    constant torque) must not come back as a new effect ("a torque offset"). Each is refined by
    Gauss-Newton on the training folds (cross-validated: the held-out fold judges the refined model
    against the model's own value) and reported as a refinement with its jackknife uncertainty; the
    basis the candidates are judged against is the regressor at the refined value plus the term's
    derivative column, so a candidate that only mimics the refinement explains nothing."""
    items = _own_shape_terms(model, ds) if model is not None else []
    if not items:
        return [], X
    base_engine = Engine(X, y, ds.moving, fold, folds)
    base = base_engine.baseline()
    out, extra = [], []
    names = list(ds.joint_names)
    for item in items:
        s0 = float(item["shape"][item["parameter"]])
        after, values = [], []
        for k in range(folds):
            train = [i for i in range(folds) if i != k]
            v, Xk, _ = _gauss_newton(X, item, ds, y, fold, folds, train, s0)
            eng = Engine(Xk, y, ds.moving, fold, folds)
            after.append(eng.heldout_sse(None, eng.fit(None, train)[0], None, k))
            values.append({item["parameter"]: v})
        v_all, X_all, D_all = _gauss_newton(X, item, ds, y, fold, folds, list(range(folds)), s0)
        j = item["joint"] if item["joint"] is not None else 0
        before_j = np.array([b[j] for b in base])
        after_j = np.array([a[j] for a in after])
        red = 0.0 if before_j.sum() <= 0 else float(1 - after_j.sum() / before_j.sum())
        improved = int(sum(a < b for a, b in zip(after_j, before_j)))
        mean, sd = jackknife(values)[item["parameter"]]
        out.append({"joint": names[j], "effect": item["name"], "parameter": item["parameter"],
                    "unit": item["unit"], "model_value": s0, "value": v_all, "fold_mean": mean, "std": sd,
                    "ci95": interval(mean, sd, interval_factor(folds)),
                    "error_reduction": red, "significant": is_significant(red, improved, folds, min_reduction,
                                                                         min_fold_fraction)})
        X = _replace_term(X, X_all, item)
        if D_all is not None:
            extra.append(D_all)
    return out, np.concatenate([X] + extra, axis=2) if extra else X


def _replace_term(X: np.ndarray, new: np.ndarray, item: dict, whole: bool = True) -> np.ndarray:
    """X with the term's columns taken from `new`: a whole regressor (whole) or the term's columns."""
    a, b = item["offset"], item["offset"] + item["n"]
    out = X.copy()
    out[:, :, a:b] = new[:, :, a:b] if whole else new
    return out


def _check_data(ds: Dataset, residual: np.ndarray, folds: int) -> np.ndarray:
    """The (N,) fold of each row, once the data are shown to support a diagnosis (DiagnosisError if
    not): a finite residual of the data's shape, and enough moving samples of every joint in every fold."""
    if residual.shape != ds.tau.shape:
        raise DiagnosisError(f"the residual has shape {residual.shape} but the data {ds.tau.shape}")
    if not np.isfinite(residual).all():
        raise DiagnosisError("the model predicts NaN or infinite torque on these data")
    if folds < 2:
        raise DiagnosisError(f"cross-validation needs at least 2 folds, not {folds}")
    fold = fold_ids(len(ds), folds)
    sparse = sparse_joint(ds.moving, fold, folds, ds.joint_names, MIN_SAMPLES_PER_JOINT)
    if sparse is not None:
        raise DiagnosisError(sparse.format(what="the diagnosis"))
    return fold


def _identity(effect) -> str | None:
    """The identity of an effect's definition (crane_io.physics.effects.spec), None when it has none."""
    from crane_io.physics.effects.spec import identity, spec_of

    try:
        return identity(spec_of(effect))
    except (CraneError, TypeError, ValueError, AttributeError):
        return None


def _candidates_to_try(effects, joint_names, exclude, own_ids=None) -> list[tuple[object, int | None]]:
    """(effect, joint index) for every joint-scope effect on every joint and (effect, None) for every
    arm-scope effect, except the effects the model already contains: the same name on the same joint (or
    on every joint), unless `own_ids` (name -> identity) shows the model's effect of that name is defined
    otherwise."""
    exclude = {(n, j) for n, j in exclude}
    work = []
    for effect in effects:
        name = effect_name(effect)
        mine = (own_ids or {}).get(name)
        if mine is not None and _identity(effect) not in (None, mine):
            exclude_here = set()  # another effect that shares the name: a candidate like any other
        else:
            exclude_here = exclude
        if getattr(effect, "scope", "joint") == "arm":
            if (name, None) not in exclude_here:
                work.append((effect, None))
        else:
            for j, joint in enumerate(joint_names):
                if (name, joint) not in exclude_here and (name, None) not in exclude_here:
                    work.append((effect, j))
    return work


def _with_progress(work: list, progress: bool):
    if not progress:
        return work
    from tqdm import tqdm

    return tqdm(work, desc="diagnose", unit="candidate", leave=False)


def _judge(effect, j: int | None, fit: CVFit, joint_names, min_reduction: float,
           min_fold_fraction: float) -> tuple[int, Candidate]:
    """(home joint index, Candidate) of one cross-validated candidate: an arm-scope one (j None) is
    reported on the joint where it removes the largest fraction of the error."""
    name = effect_name(effect)
    joints = [j] if j is not None else list(range(len(joint_names)))
    reductions = {jj: fit.reduction(jj) for jj in joints}
    home = max(joints, key=lambda jj: reductions[jj])
    fold_red = fit.fold_reductions(home)
    improved = int(sum(r > 0 for r in fold_red))
    parameters, loose = fit_parameters(effect, fit)
    red = reductions[home]
    cand = Candidate(
        joint=joint_names[home], rank=0, effect=name, title=getattr(effect, "title", name),
        scope="arm" if j is None else "joint", error_reduction=red, fold_reductions=fold_red,
        folds_improved=improved, parameters=parameters, shape=dict(fit.shape_all or {}),
        mse_before=float(fit.sse_before[home].sum() / max(fit.count[home], 1)),
        mse_after=float(fit.sse_after[home].sum() / max(fit.count[home], 1)),
        significant=fit.identifiable and is_significant(red, improved, len(fold_red), min_reduction,
                                                        min_fold_fraction),
        sentence="", other_joints={joint_names[jj]: reductions[jj] for jj in joints if jj != home},
        n_parameters=complexity(effect), identifiable=fit.identifiable,
        unidentifiable_parameters=loose)
    cand.sentence = candidate_text(effect, cand)
    return home, cand


def _assemble(ds: Dataset, remaining: np.ndarray, results: dict[int, list[Candidate]], settings: dict,
              refinements: list[dict], folds: int) -> Diagnosis:
    """Rank each joint's candidates (the selected ones first, in selection order), number them, and add
    the summaries, and what remains once the selected effects are in the model (`remaining`: the refit
    with them and with the model's refined shapes, or the residual itself without a basis) correlates
    with and depends on."""
    candidates, summary, correlations, dependence = [], {}, {}, {}
    for j, name in enumerate(ds.joint_names):
        chosen = sorted((c for c in results[j] if c.selection_step), key=lambda c: c.selection_step)
        ranked = chosen + [c for c in rank(results[j]) if not c.selection_step]
        for i, c in enumerate(ranked, start=1):
            c.rank = i
        candidates += ranked
        corr = residual_correlations(ds, remaining, j)
        dep = residual_dependence(ds, remaining, j, folds)
        correlations[name] = corr[:6]
        dependence[name] = [{"with": d["with"], "share": d["share"]} for d in dep[:6]]
        summary[name] = joint_summary(name, ranked, corr, dep, refinements)
    return Diagnosis(tuple(ds.joint_names), candidates, summary, correlations, settings,
                     refinements=refinements, dependence=dependence)
