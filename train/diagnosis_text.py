"""The diagnosis in plain language (train/diagnose.py): one sentence per candidate, the spill-over
demotion, a summary per joint, and what the residual correlates with when no candidate explains it."""

from __future__ import annotations

import math

import numpy as np

from .dataset import Dataset
from .diagnosis_effects import effect_name, model_params
from .diagnosis_result import Candidate


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


def candidate_sentence(effect, c: Candidate) -> str:
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


def spill_over_sentence(c: Candidate, reduction: float, leader: Candidate) -> str:
    """Why candidate c was demoted: with `leader` in the model it explains only `reduction`."""
    label = f"{leader.effect} on {leader.joint}"
    return (f"{c.joint}: {c.title} explains {_pct(c.error_reduction)} of the remaining error on "
            f"its own but only {_pct(max(reduction, 0.0))} once {label} is added: most likely "
            f"{leader.joint}'s missing effect leaking into {c.joint} through the rigid-body "
            f"parameters the joints share; add {leader.effect} to {leader.joint} first and "
            "diagnose again.")


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


def _correlation_sentence(corr: list[dict]) -> str:
    if not corr or abs(corr[0]["r"]) < 0.1:
        return ("the residual does not correlate with angle, velocity, acceleration or time (|r| < 0.1); "
                "it looks like noise")
    top = [c for c in corr[:2] if abs(c["r"]) >= 0.1]
    text = " and ".join(f"the {c['with']} (r = {c['r']:+.2f})" for c in top)
    return f"the residual correlates most with {text}"


def joint_summary(joint: str, ranked: list[Candidate], corr: list[dict]) -> str:
    """One or two sentences for a joint: its best significant candidate (and the other significant
    ones), or that none is significant and what the residual correlates with."""
    significant = [c for c in ranked if c.significant]
    if significant:
        text = significant[0].sentence
        if len(significant) > 1:
            text += (" Also significant: " + ", ".join(f"{c.effect} ({_pct(c.error_reduction)})"
                                                       for c in significant[1:4]) + ".")
        return text
    if ranked:
        best = ranked[0]
        if best.explained_by:
            lead = (f"{joint}: no candidate effect explains a significant part of the remaining error "
                    f"once {best.explained_by} is added (best: {best.effect}, "
                    f"{_pct(max(best.error_reduction, 0.0))} on its own, "
                    f"{_pct(max(best.reduction_given_leader or 0.0, 0.0))} with {best.explained_by}: "
                    f"spill-over through the shared rigid-body parameters)")
        else:
            lead = (f"{joint}: no candidate effect explains a significant part of the remaining error "
                    f"(best: {best.effect}, {_pct(max(best.error_reduction, 0.0))})")
    else:
        lead = f"{joint}: no candidate effects to try"
    return f"{lead}; {_correlation_sentence(corr)}."
