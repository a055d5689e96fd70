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

import itertools
import math
from dataclasses import asdict, dataclass, field

import numpy as np

from crane_io.errors import CraneError

from .dataset import Dataset

DEFAULT_FOLDS = 5
DEFAULT_MIN_REDUCTION = 0.15
DEFAULT_MIN_FOLD_FRACTION = 1.0
MIN_SAMPLES_PER_JOINT = 50
PARSIMONY_TOLERANCE = 0.01  # a simpler candidate within 1 percentage point of the best one goes first


class DiagnosisError(CraneError):
    """The data cannot support a diagnosis (too few moving samples, a joint that never moves)."""


@dataclass
class Candidate:
    joint: str  # joint name as in the session (for arm-scope effects: the joint where it helps most)
    rank: int  # 1 = best on this joint
    effect: str  # library name
    title: str
    scope: str  # "joint" or "arm"
    error_reduction: float  # fraction of the held-out MSE removed (can be negative: it made things worse)
    fold_reductions: list[float]  # the same, per fold
    folds_improved: int  # folds whose held-out error fell
    parameters: dict[str, dict]  # name -> {"value", "std", "unit"}
    shape: dict  # chosen shape values (on all data)
    mse_before: float  # held-out MSE of the model's residual on this joint's moving samples, N m^2
    mse_after: float  # the same after adding the candidate
    significant: bool
    sentence: str
    other_joints: dict[str, float] = field(default_factory=dict)  # arm scope: reduction on other joints
    n_parameters: int = 1  # parameters the candidate estimates (linear + shape)
    # spill-over check: set when this candidate was significant alone but no longer is once the
    # strongest significant candidate of another joint is in the model ("coulomb on joint2")
    explained_by: str | None = None
    reduction_given_leader: float | None = None  # its error reduction with that candidate added


@dataclass
class Diagnosis:
    joints: tuple[str, ...]
    candidates: list[Candidate]  # ranked per joint (joint order, then rank)
    summary: dict[str, str]  # joint -> one or two sentences
    correlations: dict[str, list[dict]]  # joint -> [{"with": ..., "r": ...}], strongest first
    settings: dict

    def for_joint(self, joint: str) -> list[Candidate]:
        return [c for c in self.candidates if c.joint == joint]

    def best(self, joint: str) -> Candidate | None:
        ranked = self.for_joint(joint)
        return ranked[0] if ranked else None

    def to_json(self) -> dict:
        return {"joints": list(self.joints), "candidates": [asdict(c) for c in self.candidates],
                "summary": dict(self.summary), "correlations": self.correlations,
                "settings": self.settings}


# ---- helpers on the effect interface ------------------------------------------------------------------

def _shape_options(effect) -> list[dict | None]:
    if hasattr(effect, "shape_options"):
        return [o or None for o in effect.shape_options()]
    grid = dict(getattr(effect, "shape_grid", None) or {})
    if not grid:
        return [None]
    names = list(grid)
    return [dict(zip(names, values)) for values in itertools.product(*(list(grid[n]) for n in names))]


def _model_params(effect) -> list:
    """The parameters a model estimates (not the plant-only ones)."""
    return [p for p in getattr(effect, "params", ()) if getattr(p, "model", True)]


def _param_units(effect) -> dict[str, str]:
    return {p.name: getattr(p, "unit", "") for p in _model_params(effect)}


def _complexity(effect) -> int:
    """Number of estimated parameters (linear coefficients + shape parameters chosen from a grid)."""
    return max(len(_model_params(effect)), 1)


def _effect_name(effect) -> str:
    return getattr(effect, "name", type(effect).__name__)


def _fold_ids(n: int, folds: int) -> np.ndarray:
    """(n,) fold index of each row: `folds` contiguous blocks of (nearly) equal size."""
    return np.minimum((np.arange(n) * folds) // max(n, 1), folds - 1)


def _values(effect, coefs: np.ndarray, shape: dict | None) -> dict[str, float]:
    values = effect.values_from_coefficients(np.asarray(coefs, dtype=float), shape)
    keep = {p.name for p in _model_params(effect)} or set(values)
    out = {}
    for name, value in dict(values).items():
        if name not in keep:
            continue
        try:
            out[name] = float(value)
        except (TypeError, ValueError):
            continue
    if shape:
        for name, value in shape.items():
            if name in keep:
                out.setdefault(name, float(value))
    return out


def _jackknife(per_fold: list[dict[str, float]]) -> dict[str, tuple[float, float]]:
    names = [n for n in per_fold[0] if all(n in v for v in per_fold)]
    k = len(per_fold)
    out = {}
    for name in names:
        v = np.array([f[name] for f in per_fold], dtype=float)
        out[name] = (float(v.mean()), float(math.sqrt((k - 1) / k * ((v - v.mean()) ** 2).sum())))
    return out


# ---- the cross-validated fit of one candidate ----------------------------------------------------------

class _Engine:
    """Per-fold normal equations of the masked least-squares problem, so that a candidate's fit on the
    training folds is a small linear solve.

    basis X (N, J, p) (may have p = 0), target y (N, J), weights W (N, J) (the moving masks), fold (N,).
    Columns are scaled to unit RMS over the weighted rows; a tiny ridge keeps rank-deficient problems
    solvable (base parameters the data barely excite).
    """

    RIDGE = 1e-8

    def __init__(self, X: np.ndarray, y: np.ndarray, W: np.ndarray, fold: np.ndarray, folds: int):
        self.X, self.y, self.W, self.fold, self.K = X, y, W.astype(float), fold, folds
        self.p = X.shape[2]
        self.sx = self._scale(X)
        self.Xs = X / self.sx
        self.masks = [self.W * (fold == k)[:, None] for k in range(folds)]  # (N, J) per fold
        self.XX = np.stack([np.einsum("nj,nja,njb->ab", m, self.Xs, self.Xs) for m in self.masks])
        self.Xy = np.stack([np.einsum("nj,nja,nj->a", m, self.Xs, y) for m in self.masks])
        self.yy = np.array([float((m * y * y).sum()) for m in self.masks])

    def _scale(self, A):
        w = self.W[:, :, None]
        s = np.sqrt((w * A * A).sum(axis=(0, 1)) / max(w.sum(), 1.0))
        return np.where(s > 1e-12, s, 1.0)

    def _solve(self, G, b):
        n = len(b)
        if n == 0:
            return np.zeros(0)
        lam = self.RIDGE * max(float(np.trace(G)) / n, 1e-12)
        try:
            return np.linalg.solve(G + lam * np.eye(n), b)
        except np.linalg.LinAlgError:
            return np.linalg.lstsq(G, b, rcond=None)[0]

    def fit(self, C: np.ndarray | None, train: list[int]):
        """Least squares on the training folds; returns (theta_x, theta_c (unscaled), training SSE)."""
        XX, Xy, yy = self.XX[train].sum(0), self.Xy[train].sum(0), self.yy[train].sum()
        if C is None:
            th = self._solve(XX, Xy)
            sse = yy - 2 * th @ Xy + th @ XX @ th
            return th / self.sx, np.zeros(0), float(sse)
        sc = self._scale(C)
        Cs = C / sc
        mask = sum(self.masks[k] for k in train)
        XC = np.einsum("nj,nja,njb->ab", mask, self.Xs, Cs)
        CC = np.einsum("nj,nja,njb->ab", mask, Cs, Cs)
        Cy = np.einsum("nj,nja,nj->a", mask, Cs, self.y)
        G = np.block([[XX, XC], [XC.T, CC]])
        b = np.concatenate([Xy, Cy])
        th = self._solve(G, b)
        sse = yy - 2 * th @ b + th @ G @ th
        return th[:self.p] / self.sx, th[self.p:] / sc, float(sse)

    def heldout_sse(self, C, th_x, th_c, k: int) -> np.ndarray:
        """(J,) SSE of the held-out fold k per joint (weighted rows only)."""
        pred = self.X @ th_x if self.p else np.zeros_like(self.y)
        if C is not None:
            pred = pred + C @ th_c
        return ((self.y - pred) ** 2 * self.masks[k]).sum(axis=0)


@dataclass
class _Fit:
    sse_before: np.ndarray  # (J, K) held-out SSE without the candidate, per joint and fold
    sse_after: np.ndarray  # (J, K) with the candidate
    count: np.ndarray  # (J,) held-out rows per joint
    fold_values: list[dict[str, float]]
    shape_all: dict | None
    shape_index: int = 0  # index into columns_by_shape of shape_all


def _cross_validate(engine: _Engine, effect, columns_by_shape, baseline) -> _Fit:
    """baseline[k] = (theta_x, sse_before (J,)) of the refit without candidate for fold k."""
    K = engine.K
    J = engine.y.shape[1]
    sse_before = np.zeros((J, K))
    sse_after = np.zeros((J, K))
    fold_values = []
    for k in range(K):
        train = [i for i in range(K) if i != k]
        best = None
        for shape, C in columns_by_shape:
            th_x, th_c, sse = engine.fit(C, train)
            if best is None or sse < best[0]:
                best = (sse, shape, C, th_x, th_c)
        _, shape, C, th_x, th_c = best
        fold_values.append(_values(effect, th_c, shape))
        sse_before[:, k] = baseline[k]
        sse_after[:, k] = engine.heldout_sse(C, th_x, th_c, k)
    count = engine.W.sum(axis=0)
    every = list(range(K))
    shape_all = min(((engine.fit(C, every)[2], i) for i, (_, C) in enumerate(columns_by_shape)))[1]
    return _Fit(sse_before, sse_after, count, fold_values, columns_by_shape[shape_all][0], shape_all)


# ---- sentences ----------------------------------------------------------------------------------------

def _fmt(value: float) -> str:
    if value == 0 or not math.isfinite(value):
        return f"{value:g}"
    return f"{value:.2g}" if abs(value) < 100 else f"{value:.0f}"


def _unit(unit: str) -> str:
    return "" if unit in ("1", "-", None) else f" {unit}"


def _describe_parameters(effect, parameters: dict[str, dict], shape: dict | None) -> str:
    """'Coulomb friction of about 0.21 N m' for one linear parameter, else a list in brackets."""
    linear = [p.name for p in _model_params(effect) if getattr(p, "linear", True) and p.name in parameters]
    title = getattr(effect, "title", _effect_name(effect))
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


def _pct(fraction: float) -> str:
    return f"{100 * fraction:.0f}%"


# ---- what the residual looks like -------------------------------------------------------------------

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


# ---- the diagnosis -----------------------------------------------------------------------------------

def model_effects(model) -> set[tuple[str, str | None]]:
    """(effect name, joint name or None) pairs a model already contains (rigid-body / hybrid)."""
    out = set()
    for entry in (getattr(model, "options", {}) or {}).get("effects", []) or []:
        if isinstance(entry, dict):
            name, joint = entry.get("name"), entry.get("joint")
        elif isinstance(entry, str):
            name, joint = entry, None
        else:
            name, joint = entry[0], (entry[1] if len(entry) > 1 else None)
        out.add((str(name), None if joint is None else str(joint)))
    return out


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
    J = len(ds.joint_names)
    if residual.shape != ds.tau.shape:
        raise DiagnosisError(f"the residual has shape {residual.shape} but the data {ds.tau.shape}")
    if not np.isfinite(residual).all():
        raise DiagnosisError("the model predicts NaN or infinite torque on these data")
    if folds < 2:
        raise DiagnosisError(f"cross-validation needs at least 2 folds, not {folds}")
    fold = _fold_ids(len(ds), folds)
    need = max(MIN_SAMPLES_PER_JOINT, 5 * folds)
    for j in range(J):
        per_fold = np.bincount(fold[ds.moving[:, j]], minlength=folds)
        if per_fold.sum() < need or per_fold.min() == 0:
            raise DiagnosisError(f"{ds.joint_names[j]} moves in only {int(per_fold.sum())} samples (or not "
                                 f"in every part of the recording); the diagnosis needs at least {need} "
                                 "spread over the whole recording")
    if effects is None:
        effects = _library_effects()
    effects = [_bind(e, ds.joint_names) for e in effects]
    if X is None:
        X = np.zeros(ds.tau.shape + (0,))
    engine = _Engine(X, y, ds.moving, fold, folds)
    baseline = []
    for k in range(folds):
        th_x, _, _ = engine.fit(None, [i for i in range(folds) if i != k])
        baseline.append(engine.heldout_sse(None, th_x, None, k))
    exclude = {(n, j) for n, j in exclude}

    work = []
    for effect in effects:
        name = _effect_name(effect)
        if getattr(effect, "scope", "joint") == "arm":
            if (name, None) not in exclude:
                work.append((effect, None))
        else:
            for j in range(J):
                if (name, ds.joint_names[j]) not in exclude and (name, None) not in exclude:
                    work.append((effect, j))
    iterator = work
    if progress:
        from tqdm import tqdm
        iterator = tqdm(work, desc="diagnose", unit="candidate", leave=False)

    results: dict[int, list[Candidate]] = {j: [] for j in range(J)}
    kept: dict[int, tuple] = {}  # id(candidate) -> (effect, j, columns_by_shape, fit): the spill-over check
    for effect, j in iterator:
        name = _effect_name(effect)
        units = _param_units(effect)
        columns_by_shape = []
        for shape in _shape_options(effect):
            C = np.asarray(effect.columns(ds.q, ds.dq, ds.ddq, j, shape), dtype=float)
            if C.ndim == 2:
                C = C[:, :, None]
            usable = C.shape[:2] == ds.tau.shape and np.isfinite(C).all()
            if not usable or not np.any(C * ds.moving[:, :, None]):
                continue
            columns_by_shape.append((shape, C))
        if not columns_by_shape:
            continue
        fit = _cross_validate(engine, effect, columns_by_shape, baseline)
        joints = [j] if j is not None else list(range(J))
        reductions = {}
        for jj in joints:
            before = fit.sse_before[jj].sum()
            reductions[jj] = 0.0 if before == 0 else float(1.0 - fit.sse_after[jj].sum() / before)
        home = max(joints, key=lambda jj: reductions[jj])
        fold_red = [float(1 - a / b) if b > 0 else 0.0
                    for a, b in zip(fit.sse_after[home], fit.sse_before[home])]
        improved = int(sum(r > 0 for r in fold_red))
        stats = _jackknife(fit.fold_values) if fit.fold_values else {}
        parameters = {n: {"value": v, "std": sd, "unit": units.get(n, "")} for n, (v, sd) in stats.items()}
        red = reductions[home]
        significant = bool(red >= min_reduction and improved >= math.ceil(min_fold_fraction * folds))
        cand = Candidate(
            joint=ds.joint_names[home], rank=0, effect=name, title=getattr(effect, "title", name),
            scope="arm" if j is None else "joint", error_reduction=red, fold_reductions=fold_red,
            folds_improved=improved, parameters=parameters, shape=dict(fit.shape_all or {}),
            mse_before=float(fit.sse_before[home].sum() / max(fit.count[home], 1)),
            mse_after=float(fit.sse_after[home].sum() / max(fit.count[home], 1)),
            significant=significant, sentence="",
            other_joints={ds.joint_names[jj]: reductions[jj] for jj in joints if jj != home},
            n_parameters=_complexity(effect))
        cand.sentence = _candidate_sentence(effect, cand)
        results[home].append(cand)
        kept[id(cand)] = (effect, j, columns_by_shape, fit)

    _spill_over_check(engine, X, y, ds, fold, folds, results, kept, min_reduction, min_fold_fraction)

    candidates, summary, correlations = [], {}, {}
    for j in range(J):
        ranked = _rank(results[j])
        for i, c in enumerate(ranked, start=1):
            c.rank = i
        candidates += ranked
        corr = residual_correlations(ds, residual, j)
        correlations[ds.joint_names[j]] = corr[:6]
        summary[ds.joint_names[j]] = _joint_summary(ds.joint_names[j], ranked, corr)
    settings = {"folds": folds, "min_reduction": min_reduction, "min_fold_fraction": min_fold_fraction,
                "method": "refit of the physics model with each candidate" if refit else
                          "candidate fitted to the model's residual",
                "samples": len(ds), "moving_samples": {ds.joint_names[j]: int(ds.moving[:, j].sum())
                                                       for j in range(J)}}
    return Diagnosis(tuple(ds.joint_names), candidates, summary, correlations, settings)


def _spill_over_check(engine, X, y, ds, fold, folds, results, kept, min_reduction, min_fold_fraction):
    """A missing effect on one joint can make a candidate on ANOTHER joint look significant: the refit
    bends the rigid-body parameters the joints share towards the missing effect, and a column that acts
    on the other joint alone (a torque-constant error, a spring ...) buys back what that cost there.
    Forward selection, one step (SINDy's sequential idea): the significant candidate that removes the
    most held-out squared error over all joints (N m^2, not a fraction) is put into the model, and every
    significant candidate of the other joints is cross-validated again on top of it. One that is no
    longer significant is demoted, with the reason in its sentence: add the leading effect first and
    diagnose again."""
    gains = []
    for cands in results.values():
        for c in cands:
            if c.significant:
                fit = kept[id(c)][3]
                gains.append((float((fit.sse_before - fit.sse_after).sum()), c))
    if not gains:
        return
    leader = max(gains, key=lambda g: g[0])[1]
    others = [c for _, c in gains if c.joint != leader.joint]
    if not others:
        return
    _, _, lead_cols, lead_fit = kept[id(leader)]
    X2 = np.concatenate([X, lead_cols[lead_fit.shape_index][1]], axis=2)
    engine2 = _Engine(X2, y, ds.moving, fold, folds)
    baseline2 = []
    for k in range(folds):
        th_x, _, _ = engine2.fit(None, [i for i in range(folds) if i != k])
        baseline2.append(engine2.heldout_sse(None, th_x, None, k))
    label = f"{leader.effect} on {leader.joint}"
    for c in others:
        effect, j, cols, _ = kept[id(c)]
        fit = _cross_validate(engine2, effect, cols, baseline2)
        home = ds.joint_names.index(c.joint)
        before = fit.sse_before[home].sum()
        red = 0.0 if before == 0 else float(1.0 - fit.sse_after[home].sum() / before)
        improved = int(sum(a < b for a, b in zip(fit.sse_after[home], fit.sse_before[home])))
        c.reduction_given_leader = red
        if red >= min_reduction and improved >= math.ceil(min_fold_fraction * folds):
            continue
        c.significant = False
        c.explained_by = label
        c.sentence = (f"{c.joint}: {c.title} explains {_pct(c.error_reduction)} of the remaining error on "
                      f"its own but only {_pct(max(red, 0.0))} once {label} is added: most likely "
                      f"{leader.joint}'s missing effect leaking into {c.joint} through the rigid-body "
                      f"parameters the joints share; add {leader.effect} to {leader.joint} first and "
                      "diagnose again.")


def _rank(cands: list[Candidate]) -> list[Candidate]:
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


def _bind(effect, joint_names):
    """Effects computed from the rigid-body dynamics get dynamics of the data's joints."""
    absent = object()
    dyn = getattr(effect, "_dynamics", absent)
    if dyn is absent or not hasattr(effect, "bind"):
        return effect
    if dyn is not None and tuple(getattr(dyn, "joint_names", ())) == tuple(joint_names):
        return effect
    try:
        from crane_io.dynamics import ArmDynamics

        return effect.bind(ArmDynamics(joints=tuple(joint_names)))
    except CraneError as exc:
        raise DiagnosisError(f"effect {getattr(effect, 'name', effect)!r} needs the arm's dynamics for "
                             f"joints {', '.join(joint_names)}: {exc}") from None


def _candidate_sentence(effect, c: Candidate) -> str:
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


def _joint_summary(joint: str, ranked: list[Candidate], corr: list[dict]) -> str:
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


def _library_effects():
    from crane_io.effects import list_effects

    out = []
    for e in list_effects():
        out.append(e() if isinstance(e, type) else e)
    return out
