"""The diagnosis in plain language (train/diagnosis/diagnose.py): one sentence per candidate, the spill-over
demotion, a summary per joint, and what the residual correlates with when no candidate explains it."""

from __future__ import annotations

import math
from typing import TYPE_CHECKING

import numpy as np

from ..data.dataset import Dataset
from .effects import effect_name, model_params
from .result import Candidate

if TYPE_CHECKING:
    from typing import Any


REFINED_DIGITS = 4  # significant digits of a refined shape value (sentence and command alike)


def _fmt(value: float) -> str:
    if value == 0 or not math.isfinite(value):
        return f"{value:g}"
    return f"{value:.2g}" if abs(value) < 100 else f"{value:.0f}"


def _unit(unit: str) -> str:
    return "" if unit in ("1", "-", None) else f" {unit}"


def _pct(fraction: float) -> str:
    return f"{100 * fraction:.0f}%"


def _describe_parameters(effect, parameters: dict[str, dict], shape: dict | None) -> str:
    """'Coulomb friction of about 0.21 N m' for one linear parameter, else a list in brackets."""
    linear = [p.name for p in model_params(effect) if getattr(p, "linear", True) and p.name in parameters]
    title = getattr(effect, "title", effect_name(effect))
    if len(linear) == 1 and len(parameters) == 1:
        p = parameters[linear[0]]
        return f"{title} of about {_fmt(p['value'])}{_unit(p['unit'])}"
    parts = [f"{name} ≈ {_fmt(p['value'])}{_unit(p['unit'])}" for name, p in parameters.items()]
    return f"{title} ({', '.join(parts)})" if parts else title


def _signature(effect, joint: str) -> str:
    text = str(getattr(effect, "signature", "") or "")
    try:
        text = text.format(joint=joint)
    except (KeyError, IndexError, ValueError):
        pass
    return text.rstrip(". ")


def candidate_sentence(effect: Any, c: Candidate) -> str:
    """'joint2: <signature>; Coulomb friction of about 0.21 N m explains 64% of the remaining error.'"""
    what = _describe_parameters(effect, c.parameters, c.shape)
    sig = _signature(effect, c.joint)
    if c.error_reduction <= 0:
        text = f"{c.joint}: {what} does not reduce the held-out error"
    else:
        text = f"{c.joint}: "
        if sig:
            text += f"{sig}; "
        text += f"{what} explains {_pct(c.error_reduction)} of the remaining error"
        if not c.significant:
            text += f" (not significant: it helped in {c.folds_improved} of {len(c.fold_reductions)} folds)"
    if c.scope == "arm":
        others = ", ".join(f"{_pct(v)} on {n}" for n, v in c.other_joints.items())
        text += " — an arm-wide effect, shown on the joint where it helps most"
        if others:
            text += f" (also {others})"
    return text + "."


def candidate_text(effect: Any, c: Candidate) -> str:
    """The sentence of a judged candidate: `candidate_sentence`, or why it has no value (not identifiable,
    or some coefficients that cannot be told apart from the model's own)."""
    if not c.identifiable:
        return unidentifiable_sentence(c)
    text = candidate_sentence(effect, c)
    loose = c.unidentifiable_parameters
    if loose:
        text = (text[:-1] + f" ({', '.join(loose)} cannot be told apart from the model's own parameters, "
                "so no value is given).")
    return text


def spill_over_sentence(c: Candidate, reduction: float, leader: Candidate) -> str:
    """Why candidate c was demoted: with `leader` in the model it explains only `reduction`."""
    label = f"{leader.effect} on {leader.joint}"
    if leader.joint == c.joint:
        why = f"it mostly mimics part of {label}"
    else:
        why = (f"most likely {leader.joint}'s missing effect leaking into {c.joint} through the rigid-body "
               "parameters the joints share")
    return (f"{c.joint}: {c.title} explains {_pct(c.error_reduction)} of the remaining error on "
            f"its own but only {_pct(max(reduction, 0.0))} once {label} is added: {why}; add "
            f"{leader.effect} to {leader.joint} first and diagnose again.")


def unidentifiable_sentence(c: Candidate) -> str:
    """A candidate whose columns the model's own parameters span: no value can be estimated."""
    what = ", ".join(c.unidentifiable_parameters) or "its parameters"
    return (f"{c.joint}: {c.title} cannot be identified from this model: its torque is a combination of "
            f"what the model already fits (the rigid-body base parameters or the model's own effects), so "
            f"any value of {what} fits equally well; it can only show against a model that does not fit "
            "those parameters (e.g. fixed nominal ones).")


def selected_suffix(c: Candidate) -> str:
    """' (31% of what remains once coulomb on joint2 is in the model)' for a candidate selected after
    others, '' for the first."""
    if not c.given or c.reduction_given_leader is None:
        return ""
    verb = "is" if len(c.given) == 1 else "are"
    return (f" ({_pct(max(c.reduction_given_leader, 0.0))} of what remains once {', '.join(c.given)} "
            f"{verb} in the model)")


def refinement_sentence(r: dict) -> str:
    """The model's own shape parameter is off its grid pick: what refining it removes, how to refit."""
    unit = _unit(r.get("unit", ""))
    value = f"{r['value']:.{REFINED_DIGITS}g}"  # the same value in the sentence and in the command
    return (f"{r['joint']}: the model's {r['effect']} has {r['parameter']} = {r['model_value']:g}{unit} "
            f"(picked from a grid by fit); refined to {value} ± {r['std']:.2g}{unit} it removes "
            f"{_pct(r['error_reduction'])} of the remaining error: refit with --effect "
            f"{r['effect']}:joint={r['joint']},{r['parameter']}={value}.")


def residual_correlations(ds: Dataset, residual: np.ndarray, joint: int) -> list[dict]:
    """Pearson correlation of joint `joint`'s residual (its moving samples) with the angle, velocity,
    acceleration and sign of velocity of every joint and with time; strongest first."""
    rows = np.flatnonzero(ds.moving[:, joint])
    r = residual[rows, joint]
    out = []
    if len(rows) < 3 or r.std() == 0:
        return out
    candidates = [("time", ds.t[rows])]
    for i, name in enumerate(ds.joint_names):
        candidates += [(f"angle of {name}", ds.q[rows, i]), (f"velocity of {name}", ds.dq[rows, i]),
                       (f"acceleration of {name}", ds.ddq[rows, i]),
                       (f"sign of velocity of {name}", np.sign(ds.dq[rows, i]))]
    for label, x in candidates:
        if x.std() == 0:
            continue
        out.append({"with": label, "r": float(np.corrcoef(r, x)[0, 1])})
    out.sort(key=lambda d: -abs(d["r"]))
    return out


DEPENDENCE_BINS = 8  # quantile bins of a continuous signal
DEPENDENCE_MIN_SHARE = 0.05  # held-out variance share below which a dependence is not named
REMAINING_MIN_SHARE = 0.25  # after a selected effect: name what the rest depends on from this share


def _codes(x: np.ndarray, bins: int = DEPENDENCE_BINS) -> np.ndarray:
    """(n,) bin index of each value: quantile bins of a continuous signal."""
    edges = np.unique(np.quantile(x, np.linspace(0, 1, bins + 1)[1:-1]))
    return np.searchsorted(edges, x, side="right")


def _heldout_share(r: np.ndarray, code: np.ndarray, fold: np.ndarray, folds: int) -> float:
    """Fraction of the residual's held-out variance that its mean per bin (estimated on the other
    folds) explains: 1 - SSE(binned means) / SSE(training mean); <= 0 for noise."""
    n_codes = int(code.max()) + 1
    sse_bin = sse_mean = 0.0
    for k in range(folds):
        tr, te = fold != k, fold == k
        if not te.any() or not tr.any():
            continue
        mean = float(r[tr].mean())
        counts = np.bincount(code[tr], minlength=n_codes)
        sums = np.bincount(code[tr], weights=r[tr], minlength=n_codes)
        binned = np.where(counts > 0, sums / np.maximum(counts, 1), mean)
        sse_bin += float(((r[te] - binned[code[te]]) ** 2).sum())
        sse_mean += float(((r[te] - mean) ** 2).sum())
    return 0.0 if sse_mean <= 0 else 1.0 - sse_bin / sse_mean


def residual_dependence(ds: Dataset, residual: np.ndarray, joint: int, folds: int = 5) -> list[dict]:
    """What joint `joint`'s residual (its moving samples) depends on, by a measure that sees shapes a
    linear correlation misses (a friction sign(dq) f(q) has no linear correlation with the angle): the
    share of its variance explained by its binned means, estimated on contiguous time blocks and scored
    on the held-out one, for the angle, velocity, acceleration and sign of velocity of every joint and
    for every pair (sign of velocity of one joint, angle of one joint). Strongest first:
    [{"with": label, "share": fraction, "parts": [labels]}]."""
    from .cv import fold_ids

    rows = np.flatnonzero(ds.moving[:, joint])
    if len(rows) < 10 * folds:
        return []
    r = residual[rows, joint]
    if r.std() == 0:
        return []
    fold = fold_ids(len(rows), folds)
    singles, signs, angles = [], {}, {}
    for i, name in enumerate(ds.joint_names):
        q, dq, ddq = ds.q[rows, i], ds.dq[rows, i], ds.ddq[rows, i]
        angles[name] = _codes(q)
        signs[name] = (np.sign(dq) + 1).astype(int)
        singles += [(f"angle of {name}", angles[name]), (f"velocity of {name}", _codes(dq)),
                    (f"acceleration of {name}", _codes(ddq)), (f"sign of velocity of {name}", signs[name])]
    out = [{"with": label, "share": _heldout_share(r, code, fold, folds), "parts": [label]}
           for label, code in singles if len(np.unique(code)) > 1]
    for a, sa in signs.items():
        for b, qb in angles.items():
            if len(np.unique(sa)) < 2 or len(np.unique(qb)) < 2:
                continue
            code = sa * (int(qb.max()) + 1) + qb
            la, lb = f"sign of velocity of {a}", f"angle of {b}"
            out.append({"with": f"{la} together with the {lb}", "share": _heldout_share(r, code, fold, folds),
                        "parts": [la, lb]})
    out.sort(key=lambda d: -d["share"])
    return out


def _dependence_sentence(dep: list[dict] | None, floor: float = DEPENDENCE_MIN_SHARE) -> str | None:
    if not dep or dep[0]["share"] < floor:
        return None
    alone = {d["with"]: d["share"] for d in dep if len(d["parts"]) == 1}
    for d in dep:
        if len(d["parts"]) != 2 or d["share"] < DEPENDENCE_MIN_SHARE:
            continue
        a, b = d["parts"]
        if d["share"] >= max(alone.get(a, 0.0), alone.get(b, 0.0)) + DEPENDENCE_MIN_SHARE:
            return (f"the residual depends on the {a} together with the {b}: binned by both they explain "
                    f"{_pct(d['share'])} of its held-out variance ({_pct(max(alone.get(a, 0.0), 0.0))} and "
                    f"{_pct(max(alone.get(b, 0.0), 0.0))} separately), a shape such as sign(velocity) x "
                    f"f(angle) that a linear correlation misses")
        break
    top = [d for d in dep if len(d["parts"]) == 1 and d["share"] >= DEPENDENCE_MIN_SHARE][:2]
    if not top:
        return None
    text = " and ".join(f"the {d['with']} ({_pct(d['share'])} of its held-out variance)" for d in top)
    return f"the residual depends most on {text}"


def _correlation_sentence(corr: list[dict], dep: list[dict] | None = None) -> str:
    dep_text = _dependence_sentence(dep)
    top = [c for c in corr[:2] if abs(c["r"]) >= 0.1]
    if dep_text is None and not top:
        return ("the residual does not correlate with angle, velocity, acceleration or time (|r| < 0.1) "
                "and its binned means explain little of it; it looks like noise")
    lin = " and ".join(f"the {c['with']} (r = {c['r']:+.2f})" for c in top)
    if dep_text is None:
        return f"the residual correlates most with {lin}"
    return dep_text + (f"; linearly it correlates most with {lin}" if lin else "")


def joint_summary(joint: str, ranked: list[Candidate], corr: list[dict], dependence: list[dict] | None = None,
                  refinements: list[dict] = ()) -> str:
    """One or two sentences for a joint: its selected (significant) candidates in the order of the
    forward selection, or that none is significant and what the residual depends on; a refined shape
    parameter of the model's own effects, and the candidates that cannot be identified, are added."""
    text = _joint_lead(joint, ranked, corr, dependence)
    refined = [r for r in refinements if r["joint"] == joint and r["significant"]]
    if refined:
        text = " ".join(refinement_sentence(r) for r in refined) + " " + text
    hidden = [c for c in ranked if not c.identifiable]
    if hidden:
        text += (" Not identifiable from this model (the model's own parameters absorb them, so no value "
                 "is given): " + ", ".join(c.title for c in hidden) + ".")
    return text


def _joint_lead(joint: str, ranked: list[Candidate], corr: list[dict], dependence) -> str:
    significant = sorted((c for c in ranked if c.significant), key=lambda c: c.selection_step or 0)
    if significant:
        text = significant[0].sentence
        if len(significant) > 1:
            text += (f" Also significant once {significant[0].effect} is in the model: "
                     + ", ".join(f"{c.effect} ({_pct(max(c.reduction_given_leader or 0.0, 0.0))} of what "
                                 "remains)" for c in significant[1:4]) + ".")
        rest = _dependence_sentence(dependence, REMAINING_MIN_SHARE)
        if rest:
            names = ", ".join(c.effect for c in significant[:4])
            text += f" Once {names} {'is' if len(significant) == 1 else 'are'} in the model, {rest}."
        return text
    if ranked:
        best = ranked[0]
        if best.explained_by:
            lead = (f"{joint}: no candidate effect explains a significant part of the remaining error "
                    f"once {best.explained_by} is added (best: {best.effect}, "
                    f"{_pct(max(best.error_reduction, 0.0))} on its own, "
                    f"{_pct(max(best.reduction_given_leader or 0.0, 0.0))} with {best.explained_by})")
        else:
            lead = (f"{joint}: no candidate effect explains a significant part of the remaining error "
                    f"(best: {best.effect}, {_pct(max(best.error_reduction, 0.0))})")
    else:
        lead = f"{joint}: no candidate effects to try"
    return f"{lead}; {_correlation_sentence(corr, dependence)}."
