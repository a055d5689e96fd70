"""Which candidates count and which comes first (train/diagnosis/diagnose.py, steps 3 and 5): the significance
rule, the parsimony ranking per joint, and the forward (nested) selection that keeps only what stays
significant once the effects found before it are in the model."""

from __future__ import annotations

import math
from dataclasses import replace
from typing import TYPE_CHECKING

import numpy as np

from .cv import CVFit, Engine, cross_validate, interval, interval_factor, jackknife
from .effects import param_units
from .result import Candidate
from .text import candidate_text, spill_over_sentence

if TYPE_CHECKING:
    from collections.abc import Sequence

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


MAX_SELECTED = 6  # forward selection stops after this many effects


def fit_parameters(effect, fit: CVFit) -> tuple[dict[str, dict], list[str]]:
    """(parameters {name: {"value", "std", "unit", "ci95"}}, the linear coefficients that cannot be told
    apart from the basis) of a candidate's cross-validated fit: the mean over folds, its jackknife
    standard error and the 95 % interval value +- t_{K-1} x std (`interval`);
    no value for a candidate that is not identifiable, nor for a coefficient the basis can trade with."""
    units = param_units(effect)
    stats = jackknife(fit.fold_values) if fit.fold_values else {}
    factor = interval_factor(len(fit.fold_values))
    parameters = {n: {"value": v, "std": sd, "unit": units.get(n, ""), "ci95": interval(v, sd, factor)}
                  for n, (v, sd) in stats.items()}
    if not fit.identifiable:
        parameters = {}  # any value fits as well: printing one (with a tiny spread) would mislead
    loose = list(fit.collinear)
    if loose:  # coefficients the others (and the model's own) can trade with: no value is meaningful
        loose = [p.name for p in getattr(effect, "linear_params", ())] or loose
        for n in loose:
            parameters.pop(n, None)
    return parameters, loose


def _take_nested_values(c: Candidate, effect, fit: CVFit) -> None:
    """A pick judged on top of the earlier picks reports that model's values: its parameters and shape
    from `fit` (cross-validated with the earlier picks in the basis); its values alone stay in
    `parameters_alone`."""
    c.parameters_alone = c.parameters
    c.parameters, c.unidentifiable_parameters = fit_parameters(effect, fit)
    c.shape = dict(fit.shape_all or {})
    c.identifiable = fit.identifiable
    c.sentence = candidate_text(effect, c)


def _label(c: Candidate) -> str:
    return f"{c.effect} on {c.joint}"


def _pick_leader(pool: list[Candidate], fits: dict[int, CVFit], joint_names) -> Candidate:
    """The next effect of the forward selection: per joint the candidate `rank` puts first (parsimony
    rule) on the reductions measured against the current model; among those, the one that removes the
    most held-out squared error over all joints (N m^2, not a fraction)."""
    tops = []
    for joint in dict.fromkeys(c.joint for c in pool):
        here = [c for c in pool if c.joint == joint]
        home = list(joint_names).index(joint)
        proxies = [replace(c, error_reduction=fits[id(c)].reduction(home),
                           fold_reductions=fits[id(c)].fold_reductions(home)) for c in here]
        first = rank(proxies)[0]
        tops.append(here[proxies.index(first)])
    return max(tops, key=lambda c: float((fits[id(c)].sse_before - fits[id(c)].sse_after).sum()))


def forward_selection(engine: Engine, joint_names: Sequence[str], results: dict[int, list[Candidate]],
                      tried: dict[int, tuple], min_reduction: float,
                      min_fold_fraction: float) -> tuple[list[Candidate], Engine]:
    """Nested forward selection (SINDy's sequential idea): what is significant is judged on top of what
    was already found, never every candidate against the same baseline. Candidates often mimic part of
    another effect (stiction or asymmetric Coulomb contain Coulomb; a ripple or a spring bends to fit a
    step) or, on another joint, buy back what a missing effect cost the rigid-body parameters the joints
    share (spill-over); against the same baseline they all look significant.

    Start from the candidates significant on their own. Put the leader (`_pick_leader`) into the model,
    cross-validate every remaining one again on top of it (the leader's columns join the basis and are
    refitted per fold), keep those still significant, and repeat. The selected candidates get
    `selection_step` 1, 2, ...; one that no longer passes is demoted: `significant` false, `explained_by`
    the effect whose addition took its significance, `reduction_given_leader` its reduction then, and a
    sentence saying to add that effect first and diagnose again.

    A pick after the first reports its parameters (and shape) from its fit on top of the picks before it,
    the model it joins, not from its fit alone (kept in `parameters_alone`).

    `tried` maps id(candidate) -> (effect, columns_by_shape, its CVFit, columns_at) (a nested pick's: the
    fit its values come from); candidates are
    changed in place. Candidates not significant on their own are not tried again (one that only
    becomes significant once another effect is in shows when diagnosing the refitted model).
    Returns the selected candidates and the engine whose basis holds all of them."""
    pool = [c for cands in results.values() for c in cands if c.significant]
    fits = {id(c): tried[id(c)][2] for c in pool}
    selected: list[Candidate] = []
    eng = engine
    while pool and len(selected) < MAX_SELECTED:
        leader = _pick_leader(pool, fits, joint_names)
        pool.remove(leader)
        selected.append(leader)
        leader.selection_step = len(selected)
        if leader.given:  # judged again with the earlier picks in: its values are from that model
            _take_nested_values(leader, tried[id(leader)][0], fits[id(leader)])
            effect, cols, _, cols_at = tried[id(leader)]
            tried[id(leader)] = (effect, cols, fits[id(leader)], cols_at)  # the fit its values are from
        eng = eng.extended(fits[id(leader)].columns_all)
        if not pool:
            break
        baseline = eng.baseline()
        given = [_label(c) for c in selected]
        still = []
        for c in pool:
            effect, cols, _, cols_at = tried[id(c)]
            fit = cross_validate(eng, effect, cols, baseline, cols_at)
            home = list(joint_names).index(c.joint)
            red = fit.reduction(home)
            improved = sum(r > 0 for r in fit.fold_reductions(home))
            fits[id(c)] = fit
            c.reduction_given_leader = red
            c.given = list(given)
            if is_significant(red, improved, engine.K, min_reduction, min_fold_fraction):
                still.append(c)
                continue
            c.significant = False
            c.explained_by = _label(leader)
            c.sentence = spill_over_sentence(c, red, leader)
        pool = still
    return selected, eng
