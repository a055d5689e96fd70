"""Discover a missing term the effects library does not have (`crane-train diagnose --discover`).

The ranking (train/diagnosis/diagnose.py) judges a closed list of effects. When the residual of a joint stays
significant after the library's best candidate, discovery proposes *what* term would explain it: a
sparse regression of the model's held-out residual on a generated basis of physically meaningful terms
(train/diagnosis/discovery_basis.py), judged with the same honesty as the ranking.

Per joint j (only the samples where j moves, as the ranking), over `folds` + 3 contiguous time blocks of
which 3, spread over the recording, are held out of everything but the final check
(train/diagnosis/discovery_check.py):

1. The base: the model's physics basis (a rigid-body model is refitted, so a term competes with the
   rigid-body parameters it correlates with; any other model keeps its prediction and the residual is
   the target), plus the library's best candidate on j when that one is significant (discovery then
   looks for what is left after it; `--discover-all` starts from the model alone on every joint).
2. The basis (train/diagnosis/discovery_basis.py): a periodic term (harmonic n of an angle, the
   library's cogging) is a candidate only when its angle was observed over at least one period 2π/n;
   the refusal is said in one sentence.
3. Selection on the selection blocks: the terms and the target are made orthogonal to the base on
   those blocks (what the base can explain is not a discovery), standardised, and the Lasso path is
   computed (scikit-learn's `lars_path`, method "lasso": exact, knot by knot, up to `max_terms` terms).
   The expressions along the path - the empty one, then one term, two terms, ... - are scored by
   cross-validation over the blocks (leave one block out, the path recomputed without it, the path's
   terms refitted by least squares - the relaxed Lasso, so shrinkage does not decide). Parsimony: the
   expression with the fewest terms whose CV error is within one standard error of the best one is
   kept. Then, one at a time, the term whose coefficient is least certain is dropped until every
   coefficient is at least twice its delete-a-block jackknife standard error (on the joint's equation,
   then again on the refit with the base that is reported).
4. Nested error: for every selection block k the selection of step 3 runs on the other selection
   blocks only, the selected terms are refitted there together with the base, and block k's squared
   error is compared with the base's alone. `error_reduction` = 1 - SSE(with terms) / SSE(base),
   summed over the blocks.
5. The held-out check: fitted on the selection blocks, every term must lower the joint's error on the
   held-out blocks (a term that does not is dropped and said so), and the refit must not make any
   joint's held-out error worse (else nothing is claimed).
6. The reported expression: refitted on all blocks with the base; each coefficient's uncertainty is the
   delete-a-block jackknife standard error (train.diagnosis.cv.jackknife of the refits without each
   block), honest with correlated neighbouring samples.
7. Significant: something survives step 5, `error_reduction` >= `min_reduction` and the error falls in
   every selection block. On a session with nothing missing the empty expression is within one
   standard error of the best, or what is selected does not hold on the blocks it never saw.
"""

from __future__ import annotations

from dataclasses import asdict, dataclass, field
from typing import TYPE_CHECKING

import numpy as np

from crane_io.errors import CraneError
from crane_io.physics.effects.terms import joint_label

from ..data.dataset import Dataset
from .cv import Engine, fold_ids, sparse_joint
from .defaults import DEFAULT_FOLDS, DEFAULT_MIN_REDUCTION
from .discovery_basis import Term, columns, distinct, generate, periodic_refusals
from .discovery_check import block_layout, coefficients, heldout_check, placed
from .discovery_select import MAX_TERMS, select

if TYPE_CHECKING:
    from ..models.base import Model
    from .result import Diagnosis


class DiscoveryError(CraneError):
    """The data cannot support a discovery (a joint that barely moves, a model that predicts NaN)."""


@dataclass
class FoundTerm:
    term: str
    coefficient: float
    stderr: float
    unit: str = "N m"
    expr: list = field(default_factory=list, repr=False)  # basis grammar: crane_io.physics.effects.terms
    parameter: str = ""  # its name in a written effect-spec file
    family: str = ""  # "velocity sign x angle", "coupling", ... (train/diagnosis/discovery_basis.py)


@dataclass
class JointDiscovery:
    joint: str
    expression: str  # readable, e.g. "0.21·sign(dq2)·(1 + 0.8·cos(2·q2))"; "" when nothing was selected
    terms: list[FoundTerm]
    error_reduction: float  # fraction of the held-out MSE (after the base) removed, nested CV
    fold_reductions: list[float]
    significant: bool
    sentence: str
    on_top_of: str | None = None  # the library effect in the base ("coulomb"), None: the model alone
    on_top_of_shape: dict = field(default_factory=dict)
    mse_before: float = 0.0
    mse_after: float = 0.0
    fold_supports: list[list[str]] = field(default_factory=list)  # terms selected without block k
    # for the report's figure (not in JSON): time, residual the terms explain, the terms' fit
    curves: dict = field(default_factory=dict, repr=False)
    refusals: list[str] = field(default_factory=list)  # why something was not considered or not claimed
    heldout_reduction: float = 0.0  # joint's held-out error removed, on blocks the selection never saw
    heldout_ratio: dict = field(default_factory=dict)  # joint -> held-out error with the terms / without

    def to_json(self) -> dict:
        d = asdict(self)
        d.pop("curves")
        for t in d["terms"]:
            t.pop("expr")
        return d


@dataclass
class Discovery:
    joints: tuple[str, ...]
    discovered: list[JointDiscovery]
    summary: dict[str, str]
    settings: dict

    def for_joint(self, joint: str) -> JointDiscovery | None:
        return next((d for d in self.discovered if d.joint == joint), None)

    def to_json(self) -> dict:
        return {"discovered": [d.to_json() for d in self.discovered], "summary": dict(self.summary),
                "settings": dict(self.settings)}


def discover(model: Model, ds: Dataset, diagnosis: Diagnosis | None = None, *, every_joint: bool = False,
             folds: int = DEFAULT_FOLDS,
             min_reduction: float = DEFAULT_MIN_REDUCTION, max_terms: int = MAX_TERMS,
             progress: bool = False) -> Discovery:
    """Discovery for every joint of `ds` (see the module docstring). `diagnosis` (train.diagnosis.diagnose's
    result on the same data) supplies each joint's library best; with `every_joint` (or without a
    diagnosis) discovery starts from the model alone."""
    from ..models.base import predict_on
    from .diagnose import physics_basis

    residual = ds.tau - np.asarray(predict_on(model, ds), dtype=float)
    if not np.isfinite(residual).all():
        raise DiscoveryError("the model predicts NaN or infinite torque on these data")
    X = physics_basis(model, ds)
    if X is None:
        X, y, how = np.zeros(ds.tau.shape + (0,)), residual, "terms fitted to the model's residual"
    else:
        y, how = ds.tau, "the physics model refitted with the terms"
    total, _, held = block_layout(folds)
    fold = fold_ids(len(ds), total)
    _check(ds, fold, total)
    out, summary = [], {}
    work = list(enumerate(ds.joint_names))
    if progress:
        from tqdm import tqdm

        work = tqdm(work, desc="discover", unit="joint", leave=False)
    for j, name in work:
        lib = None if (every_joint or diagnosis is None) else _library_best(diagnosis, name)
        base = X
        if lib is not None:
            base = np.concatenate([X, _library_columns(lib, ds, j)], axis=2)
        found = discover_joint(ds, base, y, j, fold, total, min_reduction=min_reduction,
                               max_terms=max_terms, held=held)
        if lib is not None:
            found.on_top_of, found.on_top_of_shape = lib.effect, dict(lib.shape or {})
        found.sentence = _sentence(found)
        out.append(found)
        summary[name] = found.sentence
    settings = {"folds": folds, "min_reduction": min_reduction, "max_terms": max_terms,
                "every_joint": every_joint, "method": how, "selection": (
                    "Lasso path (scikit-learn lars_path) of the terms made orthogonal to the base; "
                    "leave-one-block-out CV of the refitted expressions; the fewest terms within one "
                    "standard error of the best; terms below twice their jackknife error dropped"),
                "error_reduction": "nested: selected and fitted without the block it is scored on",
                "heldout_blocks": held, "blocks": total,
                "heldout_check": ("fitted on the selection blocks: every term lowers the joint's error on "
                                  "the held-out blocks, no joint's held-out error gets worse"),
                "periodic_terms": "only from an angle observed over at least one period (2π/n)"}
    return Discovery(tuple(ds.joint_names), out, summary, settings)


def discover_joint(ds: Dataset, base: np.ndarray, y: np.ndarray, j: int, fold: np.ndarray, folds: int,
                   min_reduction: float = DEFAULT_MIN_REDUCTION, max_terms: int = MAX_TERMS,
                   terms: list[Term] | None = None, held: list[int] | tuple = ()) -> JointDiscovery:
    """Discovery on joint index j against the basis `base` (N, J, p) and target y (N, J); `fold` numbers
    `folds` time blocks, the `held` ones kept out of the selection for the final check."""
    name = ds.joint_names[j]
    rows = np.flatnonzero(ds.moving[:, j])
    terms = generate(ds.joint_names, j) if terms is None else terms
    keep, refused = periodic_refusals(terms, ds.q, rows, ds.joint_names)
    terms = [terms[i] for i in keep]
    T = columns(terms, ds.q, ds.dq, ds.ddq)
    keep = distinct(terms, T, rows)
    terms, T = [terms[i] for i in keep], T[:, keep]
    engine = Engine(base, y, ds.moving, fold, folds)
    held = sorted(held)
    sel = [k for k in range(folds) if k not in held]
    sse_before, sse_after, supports = _nested(engine, T, y, base, rows, fold, sel, j, max_terms)
    supports = [[terms[i].name for i in S] for S in supports]
    total = sse_before.sum()
    reduction = 0.0 if total <= 0 else float(1 - sse_after.sum() / total)
    fold_red = [float(1 - a / b) if b > 0 else 0.0 for a, b in zip(sse_after, sse_before)]
    S = _prune_refit(engine, T, select(T, y[:, j], base[:, j, :], rows, fold, sel, max_terms), j, sel)
    check = heldout_check(engine, T, S, j, sel, held) if held else None
    notes = _refusal_notes(refused, check, terms, ds.joint_names, j)
    S = check.kept if check is not None else S
    found, curves = _found_terms(engine, T, S, terms, rows, base, y, j, ds.t, list(range(folds)))
    count = max(len(rows), 1)
    significant = (bool(S) and reduction >= min_reduction and all(r > 0 for r in fold_red)
                   and (check is None or not check.worse))
    out = JointDiscovery(
        joint=name, expression=expression(found), terms=found, error_reduction=reduction,
        fold_reductions=fold_red, significant=significant, sentence="",
        mse_before=float(total / count), mse_after=float(sse_after.sum() / count),
        fold_supports=supports, curves=curves, refusals=notes)
    if check is not None:
        out.heldout_reduction = check.reduction(j)
        out.heldout_ratio = {n: (float(check.after[k] / check.before[k]) if check.before[k] > 0 else 1.0)
                             for k, n in enumerate(ds.joint_names)}
    return out


def _nested(engine: Engine, T, y, base, rows, fold, sel: list[int], j: int, max_terms: int):
    """Per selection block k: the base's held-out SSE on joint j, with the terms selected and fitted
    without block k, and those terms."""
    sse_before, sse_after, supports = np.zeros(len(sel)), np.zeros(len(sel)), []
    for i, k in enumerate(sel):
        train = [b for b in sel if b != k]
        S = _prune_refit(engine, T, select(T, y[:, j], base[:, j, :], rows, fold, train, max_terms), j, train)
        supports.append(S)
        th_x = engine.fit(None, train)[0]
        sse_before[i] = engine.heldout_sse(None, th_x, None, k)[j]
        if S:
            C = placed(T[:, S], j, y.shape[1])
            th_x, th_c, _ = engine.fit(C, train)
            sse_after[i] = engine.heldout_sse(C, th_x, th_c, k)[j]
        else:
            sse_after[i] = sse_before[i]
    return sse_before, sse_after, supports


def _found_terms(engine: Engine, T, S: list[int], terms: list[Term], rows, base, y, j: int, t,
                 blocks: list[int]) -> tuple[list[FoundTerm], dict]:
    """The selected terms refitted with the base on every block (jackknife standard errors), ordered by
    their share of the fitted torque, and the curves of the report's figure."""
    if not S:
        return [], {}
    C = placed(T[:, S], j, y.shape[1])
    th_x = engine.fit(C, blocks)[0]
    th_c, se = coefficients(engine, C, blocks)
    order = np.argsort([-abs(c) * np.std(T[rows, s]) for c, s in zip(th_c, S)])
    found = []
    for o in order:
        term = terms[S[o]]
        found.append(FoundTerm(term.name, float(th_c[o]), float(se[o]), term.unit, term.expr, term.parameter,
                               term.family))
    partial = y[:, j] - (base @ th_x)[:, j] if base.shape[2] else y[:, j]
    return found, {"t": t[rows], "residual": partial[rows], "fit": (C @ th_c)[:, j][rows]}


def _refusal_notes(refused, check, terms: list[Term], joint_names, j: int) -> list[str]:
    """One sentence per reason something was not claimed: periodic terms of the joint's own angle left
    out (the other angles' are counted), terms the held-out blocks did not confirm, joints the refit
    makes worse."""
    own = f"q{joint_label(joint_names[j], j)}"
    notes = [r.sentence() for r in refused if r.angle == own]
    others = sum(r.count for r in refused if r.angle != own)
    if others:
        notes.append(f"{others} periodic term(s) of other angles were not considered: each angle was "
                     "observed over less than one of their periods.")
    if check is not None and check.dropped:
        names = ", ".join(terms[i].name for i in check.dropped)
        notes.append(f"Not proposed: {names} (fitted without the held-out blocks, it does not lower "
                     "the error on them).")
    if check is not None and check.worse:
        worse = ", ".join(f"{joint_names[k]} (x{check.after[k] / check.before[k]:.3g}, larger in "
                          f"{int(check.blocks_worse[k])} held-out blocks)" for k in check.worse)
        notes.append(f"Not claimed: the refit with these terms makes the held-out error of {worse} worse.")
    return notes


def _prune_refit(engine: Engine, T: np.ndarray, S: list[int], j: int, train: list[int]) -> list[int]:
    """The pruning of `select` once more on the refit that is reported (the base refitted with the
    terms, not only the joint's own equation): drop the least certain term until every coefficient is
    at least twice its jackknife standard error."""
    S = list(S)
    while S:
        coef, se = coefficients(engine, placed(T[:, S], j, engine.y.shape[1]), train)
        z = np.abs(coef) / np.maximum(se, 1e-300)
        worst = int(np.argmin(z))
        if z[worst] >= 2.0:
            break
        S.pop(worst)
    return S


def _check(ds: Dataset, fold: np.ndarray, folds: int) -> None:
    sparse = sparse_joint(ds.moving, fold, folds, ds.joint_names)
    if sparse is not None:
        raise DiscoveryError(sparse.format(what="discovery"))


def _library_best(diagnosis, joint: str):
    best = diagnosis.best(joint)
    if best is None or not best.significant or best.scope != "joint":
        return None
    return best


def _library_columns(candidate, ds: Dataset, j: int) -> np.ndarray:
    from crane_io.physics.effects import get_effect

    from .effects import bind

    effect = bind(get_effect(candidate.effect), ds.joint_names)
    C = np.asarray(effect.columns(ds.q, ds.dq, ds.ddq, j, candidate.shape or None), dtype=float)
    return C if C.ndim == 3 else C[:, :, None]


def _num(x: float) -> str:
    return f"{x:.3g}"


def expression(terms: list[FoundTerm]) -> str:
    """Readable sum of the terms; factored as c·F·(1 + a·g + ...) when every term is the factor F (for
    instance sign(dq2)) times something and F alone is one of them."""
    if not terms:
        return ""
    factors = [_split(t.term) for t in terms]
    common = set(factors[0])
    for f in factors[1:]:
        common &= set(f)
    lead = next((i for i, f in enumerate(factors) if set(f) == common), None) if common else None
    if lead is not None and len(terms) > 1 and len(common) == 1 and abs(terms[lead].coefficient) > 0:
        c0 = terms[lead].coefficient
        F = next(iter(common))
        inner = ["1"]
        for i, t in enumerate(terms):
            if i == lead:
                continue
            rest = "·".join(x for x in factors[i] if x != F)
            ratio = t.coefficient / c0
            inner.append(f"{'-' if ratio < 0 else '+'} {_num(abs(ratio))}·{rest}")
        return f"{_num(c0)}·{F}·({' '.join(inner)})"
    text = ""
    for i, t in enumerate(terms):
        c = t.coefficient
        piece = _num(abs(c)) if t.term == "1" else f"{_num(abs(c))}·{t.term}"
        text += (("-" if c < 0 else "") + piece) if i == 0 else f" {'-' if c < 0 else '+'} {piece}"
    return text


def _split(name: str) -> tuple[str, ...]:
    """Top-level factors of a term name: 'sign(dq2)·cos(2·q2)' -> ('sign(dq2)', 'cos(2·q2)')."""
    parts, depth, cur = [], 0, ""
    for ch in name:
        depth += ch == "("
        depth -= ch == ")"
        if ch == "·" and depth == 0:
            parts.append(cur)
            cur = ""
        else:
            cur += ch
    return tuple(parts + [cur])


def _pct(x: float) -> str:
    return f"{100 * x:.0f}%"


def _sentence(d: JointDiscovery) -> str:
    after = f" after {d.on_top_of} (the library's best candidate)" if d.on_top_of else ""
    blocks = f"{sum(r > 0 for r in d.fold_reductions)} of {len(d.fold_reductions)} blocks"
    if not d.terms:
        notes = "".join(f" {n}" for n in d.refusals)
        if any(n.startswith("Not proposed") for n in d.refusals):
            return f"{d.joint}: discovery proposes no term for the residual{after}.{notes}"
        return (f"{d.joint}: discovery finds no term that explains the residual{after}: the empty "
                f"expression is within one standard error of the best (no significant discovery).{notes}")
    removes = (f"selected and fitted without the block it is scored on, it removes "
               f"{_pct(max(d.error_reduction, 0.0))} of the held-out error (better in {blocks})")
    notes = "".join(f" {n}" for n in d.refusals)
    if d.significant:
        return (f"{d.joint}: the residual{after} is explained by {d.expression} (N m); {removes}, "
                f"{_pct(d.heldout_reduction)} on the held-out blocks. Significant: add it as an effect "
                f"(--write-effect-file) and refit.{notes}")
    return (f"{d.joint}: the best expression discovery finds for the residual{after}, {d.expression}, "
            f"is not significant: {removes}; no term is claimed.{notes}")
