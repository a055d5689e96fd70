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
   spring rest angle, cogging period ...) tries every value of its grid and keeps the one that fits the
   training blocks best.
3. `error_reduction` = 1 - (held-out SSE with the candidate) / (held-out SSE without it): the fraction
   of the held-out mean squared error the candidate removes. A flexible candidate cannot win by
   overfitting: it is scored only on blocks it never saw. Ranking: by error reduction, except that a
   simpler candidate within one standard error (paired, per fold) of the best one goes first.
4. Parameters: each fold's fit gives one set of named values (`effect.values_from_coefficients`); the
   value is the mean over folds and its uncertainty the delete-a-block jackknife standard error
   sqrt((K-1)/K * sum (v_k - mean)^2), which stays honest when neighbouring samples are correlated
   (plain least-squares standard errors would not).
5. Significant: error_reduction >= `min_reduction` AND the held-out error falls in every fold
   (`min_fold_fraction`). A session with nothing missing yields no significant candidate.

Arm-scope effects (payload) have one set of parameters for all joints: their fit is joint across all
joints and they are reported once, on the joint where they remove the largest fraction of the error,
with the other joints' fractions in the sentence. Effects the model already contains (same name on the
same joint, or on every joint) are not candidates.
"""

from __future__ import annotations

import numpy as np

from .dataset import Dataset
from .diagnosis_cv import CVFit, Engine, cross_validate, fold_ids, jackknife
from .diagnosis_defaults import DEFAULT_FOLDS, DEFAULT_MIN_FOLD_FRACTION, DEFAULT_MIN_REDUCTION
from .diagnosis_effects import bind, candidate_columns, complexity, effect_name, library_effects, param_units
from .diagnosis_ranking import is_significant, rank, spill_over_check
from .diagnosis_result import Candidate, Diagnosis, DiagnosisError
from .diagnosis_text import candidate_sentence, joint_summary, residual_correlations
from .model_effects import effect_entries

__all__ = ["DEFAULT_FOLDS", "DEFAULT_MIN_FOLD_FRACTION", "DEFAULT_MIN_REDUCTION", "Candidate", "Diagnosis",
           "DiagnosisError", "diagnose", "diagnose_residual", "model_effects", "physics_basis",
           "residual_correlations"]

MIN_SAMPLES_PER_JOINT = 50


def model_effects(model) -> set[tuple[str, str | None]]:
    """(effect name, joint name or None) pairs a model already contains (rigid-body / hybrid)."""
    return {(str(name), None if joint is None else str(joint)) for name, joint in effect_entries(model)}


def physics_basis(model, ds: Dataset) -> np.ndarray | None:
    """(N, J, p) regressor of a physics model (rigid-body: base regressor + its effects' columns), or
    None for a model that is not linear in its parameters."""
    regressor = getattr(model, "regressor", None)
    if callable(regressor) and getattr(model, "theta", None) is not None:
        X = np.asarray(regressor(ds.q, ds.dq, ds.ddq), dtype=float)
        if X.ndim == 3 and X.shape[:2] == ds.tau.shape and np.isfinite(X).all():
            return X
    return None


def diagnose(model, ds: Dataset, effects=None, **kwargs) -> Diagnosis:
    """Diagnose `model` on `ds` (see the module docstring): a physics model is refitted with each
    candidate; any other model keeps its predictions and the candidate explains its residual."""
    residual = ds.tau - np.asarray(model.predict(ds.q, ds.dq, ds.ddq), dtype=float)
    X = physics_basis(model, ds)
    if X is None:
        return _run(ds, None, residual, residual, effects, exclude=model_effects(model), **kwargs)
    return _run(ds, X, ds.tau, residual, effects, exclude=model_effects(model), refit=True, **kwargs)


def diagnose_residual(ds: Dataset, residual: np.ndarray, effects=None, **kwargs) -> Diagnosis:
    """Rank candidate effects by how much of `residual` (N, J) each explains, cross-validated."""
    residual = np.asarray(residual, dtype=float)
    return _run(ds, None, residual, residual, effects, **kwargs)


def _run(ds: Dataset, X, y, residual, effects=None, *, exclude=(), folds: int = DEFAULT_FOLDS,
         min_reduction: float = DEFAULT_MIN_REDUCTION, min_fold_fraction: float = DEFAULT_MIN_FOLD_FRACTION,
         refit: bool = False, progress: bool = False) -> Diagnosis:
    """Cross-validate every candidate (effect, joint) against the basis X (None: no basis, y is the
    residual), run the spill-over check, then rank and describe per joint."""
    fold = _check_data(ds, residual, folds)
    effects = [bind(e, ds.joint_names) for e in (library_effects() if effects is None else effects)]
    if X is None:
        X = np.zeros(ds.tau.shape + (0,))
    engine = Engine(X, y, ds.moving, fold, folds)
    baseline = engine.baseline()

    results: dict[int, list[Candidate]] = {j: [] for j in range(len(ds.joint_names))}
    tried: dict[int, tuple] = {}  # id(candidate) -> (effect, columns_by_shape, fit): the spill-over check
    for effect, j in _with_progress(_candidates_to_try(effects, ds.joint_names, exclude), progress):
        columns_by_shape = candidate_columns(effect, ds, j)
        if not columns_by_shape:
            continue
        fit = cross_validate(engine, effect, columns_by_shape, baseline)
        home, cand = _judge(effect, j, fit, ds.joint_names, min_reduction, min_fold_fraction)
        results[home].append(cand)
        tried[id(cand)] = (effect, columns_by_shape, fit)

    spill_over_check(engine, ds.joint_names, results, tried, min_reduction, min_fold_fraction)
    settings = {"folds": folds, "min_reduction": min_reduction, "min_fold_fraction": min_fold_fraction,
                "method": "refit of the physics model with each candidate" if refit else
                          "candidate fitted to the model's residual",
                "samples": len(ds), "moving_samples": {name: int(ds.moving[:, j].sum())
                                                       for j, name in enumerate(ds.joint_names)}}
    return _assemble(ds, residual, results, settings)


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
    need = max(MIN_SAMPLES_PER_JOINT, 5 * folds)
    for j, name in enumerate(ds.joint_names):
        per_fold = np.bincount(fold[ds.moving[:, j]], minlength=folds)
        if per_fold.sum() < need or per_fold.min() == 0:
            raise DiagnosisError(f"{name} moves in only {int(per_fold.sum())} samples (or not "
                                 f"in every part of the recording); the diagnosis needs at least {need} "
                                 "spread over the whole recording")
    return fold


def _candidates_to_try(effects, joint_names, exclude) -> list[tuple[object, int | None]]:
    """(effect, joint index) for every joint-scope effect on every joint and (effect, None) for every
    arm-scope effect, except the effects the model already contains."""
    exclude = {(n, j) for n, j in exclude}
    work = []
    for effect in effects:
        name = effect_name(effect)
        if getattr(effect, "scope", "joint") == "arm":
            if (name, None) not in exclude:
                work.append((effect, None))
        else:
            for j, joint in enumerate(joint_names):
                if (name, joint) not in exclude and (name, None) not in exclude:
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
    units = param_units(effect)
    joints = [j] if j is not None else list(range(len(joint_names)))
    reductions = {jj: fit.reduction(jj) for jj in joints}
    home = max(joints, key=lambda jj: reductions[jj])
    fold_red = fit.fold_reductions(home)
    improved = int(sum(r > 0 for r in fold_red))
    stats = jackknife(fit.fold_values) if fit.fold_values else {}
    parameters = {n: {"value": v, "std": sd, "unit": units.get(n, "")} for n, (v, sd) in stats.items()}
    red = reductions[home]
    cand = Candidate(
        joint=joint_names[home], rank=0, effect=name, title=getattr(effect, "title", name),
        scope="arm" if j is None else "joint", error_reduction=red, fold_reductions=fold_red,
        folds_improved=improved, parameters=parameters, shape=dict(fit.shape_all or {}),
        mse_before=float(fit.sse_before[home].sum() / max(fit.count[home], 1)),
        mse_after=float(fit.sse_after[home].sum() / max(fit.count[home], 1)),
        significant=is_significant(red, improved, len(fold_red), min_reduction, min_fold_fraction),
        sentence="", other_joints={joint_names[jj]: reductions[jj] for jj in joints if jj != home},
        n_parameters=complexity(effect))
    cand.sentence = candidate_sentence(effect, cand)
    return home, cand


def _assemble(ds: Dataset, residual: np.ndarray, results: dict[int, list[Candidate]],
              settings: dict) -> Diagnosis:
    """Rank each joint's candidates, number them, and add the summaries and residual correlations."""
    candidates, summary, correlations = [], {}, {}
    for j, name in enumerate(ds.joint_names):
        ranked = rank(results[j])
        for i, c in enumerate(ranked, start=1):
            c.rank = i
        candidates += ranked
        corr = residual_correlations(ds, residual, j)
        correlations[name] = corr[:6]
        summary[name] = joint_summary(name, ranked, corr)
    return Diagnosis(tuple(ds.joint_names), candidates, summary, correlations, settings)
