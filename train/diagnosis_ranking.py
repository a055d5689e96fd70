"""Which candidates count and which comes first (train/diagnose.py, steps 3 and 5): the significance
rule, the parsimony ranking per joint, and the spill-over check that demotes a candidate another joint's
missing effect explains."""

from __future__ import annotations

import math

import numpy as np

from .diagnosis_cv import CVFit, Engine, cross_validate
from .diagnosis_result import Candidate
from .diagnosis_text import spill_over_sentence

PARSIMONY_TOLERANCE = 0.01  # a simpler candidate within 1 percentage point of the best one goes first


def is_significant(reduction: float, folds_improved: int, folds: int, min_reduction: float,
                   min_fold_fraction: float) -> bool:
    """error reduction >= min_reduction AND the held-out error fell in enough folds."""
    return bool(reduction >= min_reduction and folds_improved >= math.ceil(min_fold_fraction * folds))


def rank(cands: list[Candidate]) -> list[Candidate]:
    """By error reduction, except that the simplest candidate whose held-out error is not clearly worse
    than the best one's goes first (the one-standard-error rule of cross-validation, on the paired
    per-fold differences): a candidate that contains another as a special case (asymmetric Coulomb vs
    Coulomb, stiction vs Coulomb) gains a little on noise and must not win on that alone. When the
    per-fold differences are nearly identical the standard error is tiny, so a gap below
    PARSIMONY_TOLERANCE also counts as "not clearly worse"."""
    ranked = sorted(cands, key=lambda c: -c.error_reduction)
    if len(ranked) < 2:
        return ranked
    best = ranked[0]
    k = len(best.fold_reductions)
    choice = best
    for c in ranked[1:]:
        if c.n_parameters >= choice.n_parameters:
            continue
        d = np.array(best.fold_reductions) - np.array(c.fold_reductions)
        se = float(d.std(ddof=1) / math.sqrt(k)) if k > 1 else 0.0
        gap = best.error_reduction - c.error_reduction
        if gap <= max(se, PARSIMONY_TOLERANCE) and c.error_reduction > 0:
            choice = c
    if choice is not best:
        ranked.remove(choice)
        ranked.insert(0, choice)
    return ranked


def spill_over_check(engine: Engine, joint_names, results: dict[int, list[Candidate]],
                     tried: dict[int, tuple[object, list, CVFit]], min_reduction: float,
                     min_fold_fraction: float) -> None:
    """A missing effect on one joint can make a candidate on ANOTHER joint look significant: the refit
    bends the rigid-body parameters the joints share towards the missing effect, and a column that acts
    on the other joint alone (a torque-constant error, a spring ...) buys back what that cost there.
    Forward selection, one step (SINDy's sequential idea): the significant candidate that removes the
    most held-out squared error over all joints (N m^2, not a fraction) is put into the model, and every
    significant candidate of the other joints is cross-validated again on top of it. One that is no
    longer significant is demoted, with the reason in its sentence: add the leading effect first and
    diagnose again.

    `tried` maps id(candidate) -> (effect, columns_by_shape, its CVFit); candidates are changed in place."""
    gains = []
    for cands in results.values():
        for c in cands:
            if c.significant:
                fit = tried[id(c)][2]
                gains.append((float((fit.sse_before - fit.sse_after).sum()), c))
    if not gains:
        return
    leader = max(gains, key=lambda g: g[0])[1]
    others = [c for _, c in gains if c.joint != leader.joint]
    if not others:
        return
    _, lead_cols, lead_fit = tried[id(leader)]
    engine2 = engine.extended(lead_cols[lead_fit.shape_index][1])
    baseline2 = engine2.baseline()
    for c in others:
        effect, cols, _ = tried[id(c)]
        fit = cross_validate(engine2, effect, cols, baseline2)
        home = list(joint_names).index(c.joint)
        red = fit.reduction(home)
        improved = sum(r > 0 for r in fit.fold_reductions(home))
        c.reduction_given_leader = red
        if is_significant(red, improved, engine.K, min_reduction, min_fold_fraction):
            continue
        c.significant = False
        c.explained_by = f"{leader.effect} on {leader.joint}"
        c.sentence = spill_over_sentence(c, red, leader)
