"""`crane-train compare`: the error per joint of successive models side by side, so the fall is visible.

All models are judged on the same held-out samples: the first model's preprocessing and split (seed,
sizes) define them (train.evaluation.heldout). A model whose preprocessing differs (another cut-off,
zero-phase ...) gets the sessions preprocessed its own way, and is scored on its rows at the same times (same
piece, same down-sampled instant), so every model sees inputs prepared as in its training and the comparison
is over the same moments.

Metrics per joint: MSE, RMSE and normalised MSE on the test set (every joint moves: the paper's test
set) and MSE on all held-out samples where that joint moves.

Each model is evaluated on the arm it was fitted on (its preprocessing setting `arm`; follower for
models saved before the setting existed).
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

from crane_io.errors import CraneError

from ..models.recorded_effects import effect_keys, effect_labels
from .heldout import HeldOut, evaluation_data, fit_record, model_settings
from .metrics import metrics_table, mse

if TYPE_CHECKING:
    from collections.abc import Sequence

    from ..models.base import Model


class CompareError(CraneError):
    """Models that cannot be compared (different joints, no sessions)."""


@dataclass
class ModelScore:
    directory: str
    method: str
    effects: list[str]
    test: dict  # {"mse": {joint: v}, "rmse": ..., "nmse": ...} on the test set (every joint moves)
    moving_mse: dict  # {joint: MSE on the held-out samples where that joint moves}
    n_test: int
    notes: list[str] = field(default_factory=list)
    arm: str = "follower"  # the arm the model was fitted (and is evaluated) on
    # each effect's label with the identity of its definition ('coulomb:joint=joint2@<sha256>'): effects of
    # one name but different definitions (two effect files' discovered-joint2) differ here
    effect_keys: list[str] = field(default_factory=list)

    def to_json(self) -> dict:
        return {"directory": self.directory, "method": self.method, "arm": self.arm, "effects": self.effects,
                "effect_identities": {label: key.rpartition("@")[2]
                                      for label, key in zip(self.effects, self.effect_keys)},
                "n_test": self.n_test, "test": self.test, "moving_mse": self.moving_mse, "notes": self.notes}


@dataclass
class Comparison:
    joints: tuple[str, ...]
    models: list[ModelScore]
    evaluated_on: str

    def to_json(self) -> dict:
        return {"joints": list(self.joints), "evaluated_on": self.evaluated_on,
                "models": [m.to_json() for m in self.models]}


def model_sessions(model: Model, model_dir: Path | str | None = None) -> list[str]:
    """The session files a model was trained on, as its fit record or preprocessing record names them."""
    for record in (fit_record(model_dir), getattr(model, "preprocessing", {}) or {}):
        for key in ("sources", "sessions"):
            if record.get(key):
                return [str(s) for s in record[key]]
    return []


def score(model: Model, held: HeldOut, directory: str = "") -> ModelScore:
    ds = held.data
    from ..models.base import predict_on

    pred = predict_on(model, ds)
    test = metrics_table(ds.tau[held.test], pred[held.test], ds.joint_names, held.test_mask())
    moving = mse(ds.tau, pred, ds.moving)
    return ModelScore(directory, model.method, effect_labels(model), test,
                      {j: float(v) for j, v in zip(ds.joint_names, moving)}, int(held.test.sum()),
                      effect_keys=effect_keys(model))


def _align(reference: HeldOut, other: HeldOut) -> HeldOut:
    """Rows of `other` at the same (piece, instant) as the reference's held-out rows."""
    def keys(h):
        return list(zip(h.data.segment.tolist(), np.round(h.data.t * 1000).astype(int).tolist()))

    where = {k: i for i, k in enumerate(keys(other))}
    ref_keys = keys(reference)
    rows = [where.get(k, -1) for k in ref_keys]
    found = np.array([r >= 0 for r in rows])
    rows = np.array([r for r in rows if r >= 0], int)
    return HeldOut(other.data.subset(rows), reference.test[found], reference.window[found],
                   reference.block_starts, reference.description, reference.per_joint)


def compare_models(model_dirs: Sequence[Path | str], sessions: Sequence[Path | str] | None = None,
                   progress: bool = False) -> Comparison:
    """Load each model directory and score it on the same held-out samples."""
    from ..data.preprocess import read_preprocessed
    from ..models.registry import load_model
    from .heldout import held_out

    if not model_dirs:
        raise CompareError("give at least one model directory to compare")
    models = [load_model(d) for d in model_dirs]
    joints = models[0].joint_names
    for d, m in zip(model_dirs, models):
        if tuple(m.joint_names) != tuple(joints):
            raise CompareError(f"{d} predicts joints {', '.join(m.joint_names)} but {model_dirs[0]} "
                               f"predicts {', '.join(joints)}; only models of the same joints compare")
    sessions = list(sessions or model_sessions(models[0], model_dirs[0]))
    if not sessions:
        raise CompareError("the models do not record their sessions; name them with `sessions`")
    _, splits, reference = evaluation_data(models[0], sessions, model_dir=model_dirs[0])
    ref_settings, _, ref_seed = model_settings(models[0], model_dirs[0])
    out = []
    iterator = list(zip(model_dirs, models))
    if progress:
        from tqdm import tqdm
        iterator = tqdm(iterator, desc="compare", unit="model", leave=False)
    for d, m in iterator:
        held = reference
        notes = []
        pconf, _, seed = model_settings(m, d)
        if seed != ref_seed:
            notes.append(f"trained with split seed {seed}, not {ref_seed}: some held-out samples may have "
                         "been in its training data")
        trained_on = model_sessions(m, d)
        if trained_on and not _same_files(trained_on, sessions) and _overlap(trained_on, sessions):
            notes.append(f"trained on {', '.join(Path(x).name for x in trained_on)}, not on exactly the "
                         f"evaluated sessions: its split differs, so some held-out samples may have been in "
                         f"its training data")
        if pconf != ref_settings:
            ds_m = read_preprocessed(sessions, pconf)
            held = _align(reference, held_out(ds_m, _reindex(splits, ds_m, reference)))
            mine, ref = pconf.to_dict(), ref_settings.to_dict()
            diff = ", ".join(f"{k} {mine[k]} instead of {ref[k]}" for k in mine if mine[k] != ref.get(k))
            notes.append(f"preprocessed with its own settings ({diff}); scored at the same instants")
        s = score(m, held, str(d))
        s.notes, s.arm = notes, pconf.arm
        out.append(s)
    return Comparison(tuple(joints), out, reference.description)


def _file_key(path) -> str:
    p = Path(path)
    return str(p.resolve()) if p.exists() else str(path)


def _same_files(a, b) -> bool:
    return sorted(map(_file_key, a)) == sorted(map(_file_key, b))


def _overlap(a, b) -> bool:
    return bool(set(map(_file_key, a)) & set(map(_file_key, b)))


def notes_text(c: Comparison) -> str:
    """One line per note a model carries ('' when none): what makes its score less comparable."""
    return "\n".join(f"Note on {_label(s, i)}: {note}" for i, s in enumerate(c.models) for note in s.notes)


def _reindex(splits, ds_other, reference):
    """A Splits-like object whose index addresses `ds_other` at the reference's held-out instants."""
    from copy import copy

    ref = reference.data
    key = {k: i for i, k in enumerate(zip(ds_other.segment.tolist(),
                                          np.round(ds_other.t * 1000).astype(int).tolist()))}

    def rows(mask):
        ks = zip(ref.segment[mask].tolist(), np.round(ref.t[mask] * 1000).astype(int).tolist())
        return np.array([key[k] for k in ks if k in key], int)

    s = copy(splits)
    s.index = {"pool": np.array([], int), "val": np.array([], int), "test": rows(reference.test),
               "window": rows(reference.window)}
    return s


# ---- output -----------------------------------------------------------------------------------------

def _label(s: ModelScore, i: int) -> str:
    name = Path(s.directory).name or s.directory
    return f"{i + 1}. {name}"


def _keys(s: ModelScore) -> list[str]:
    return s.effect_keys if len(s.effect_keys) == len(s.effects) else list(s.effects)


def effect_changes(s: ModelScore, first: ModelScore) -> list[tuple[str, str]]:
    """What model `s` changes against `first`, as (sign, effect label): "+" added, "-" dropped, "~" the
    same name with another definition (its spec's identity differs: crane_io.physics.effects.spec)."""
    mine = dict(zip(_keys(s), s.effects))
    theirs = dict(zip(_keys(first), first.effects))
    added = [label for key, label in mine.items() if key not in theirs]
    dropped = [label for key, label in theirs.items() if key not in mine]
    changed = [label for label in added if label in dropped]
    return ([("+", e) for e in added if e not in changed] + [("-", e) for e in dropped if e not in changed]
            + [("~", e) for e in changed])


def _what(s: ModelScore, first: ModelScore, i: int) -> str:
    """'rigid-body (6 effects)' for the first model, then what each later one adds, drops or defines
    differently ('~discovered-joint2:joint=joint2 (another definition)')."""
    if i == 0:
        return s.method + (f" ({len(s.effects)} effects)" if s.effects else "")
    changes = effect_changes(s, first)
    ids = {label: key.rpartition("@")[2][:12] for label, key in zip(s.effects, _keys(s))}
    text = s.method + "".join(f" {sign}{e}" + (f" (another definition, {ids[e]})" if sign == "~" else "")
                              for sign, e in changes)
    return text if (changes or s.method != first.method) else s.method + " (same effects as 1)"


def table_text(c: Comparison, metric: str = "mse") -> str:
    """A plain-text table: one row per model, one column per joint (test-set metric), with the change
    against the first model."""
    head = ["model", "method", *[f"{j} {metric.upper()}" for j in c.joints]]
    rows = []
    base = c.models[0].test[metric]
    for i, s in enumerate(c.models):
        cells = [_label(s, i), _what(s, c.models[0], i)]
        for j in c.joints:
            v = s.test[metric][j]
            change = "" if i == 0 or not base[j] else f" ({100 * (v / base[j] - 1):+.0f}%)"
            cells.append(f"{v:.4g}{change}")
        rows.append(cells)
    widths = [max(len(str(r[k])) for r in [head, *rows]) for k in range(len(head))]
    lines = ["  ".join(str(x).ljust(w) for x, w in zip(r, widths)) for r in [head, *rows]]
    lines.insert(1, "  ".join("-" * w for w in widths))
    unit = {"mse": "N m^2", "rmse": "N m", "nmse": "1"}[metric]
    return "\n".join(lines) + f"\n({metric.upper()} in {unit} on {c.models[0].n_test} held-out test samples)"


def plot(c: Comparison, path: Path | str, metric: str = "mse") -> Path:
    """The bar chart of the test metric per joint, one bar per model
    (train.evaluation.plots.plot_comparison)."""
    from .plots import plot_comparison

    return plot_comparison(c, path, metric)


def _short_effect(label: str) -> str:
    """'coulomb:joint=joint2' -> 'coulomb(joint2)'; 'payload' stays."""
    name, _, joint = label.partition(":joint=")
    return f"{name}({joint})" if joint else name


def _names(c: Comparison) -> list[str]:
    """Each model's directory name; its last two path parts where two models' names are the same."""
    paths = [Path(s.directory) for s in c.models]
    names = [p.name or s.directory for p, s in zip(paths, c.models)]
    return [n if names.count(n) == 1 else "/".join(p.parts[-2:]) or n for n, p in zip(names, paths)]


def _shorten(text: str, width: int, middle: bool = False) -> str:
    """`text` cut to `width` characters with an ellipsis, at its end or in its middle."""
    if len(text) <= width:
        return text
    if middle:
        head = (width - 1) // 2
        return text[:head] + "\u2026" + text[len(text) - (width - 1 - head):]
    return text[:width - 1] + "\u2026"


def legend_names(c: Comparison) -> list[str]:
    """One short name per model for a plot's legend: '1. baseline: rigid-body, 6 effects', then what
    each later model adds or drops ('2. with-coulomb: rigid-body +coulomb(joint2)'); a long directory
    name is cut in its middle (30 characters), a long description at its end (60)."""
    first = c.models[0]
    out = []
    for i, (s, name) in enumerate(zip(c.models, _names(c))):
        if i == 0:
            n = len(s.effects)
            what = s.method + (f", {n} effect{'s' if n > 1 else ''}" if n else "")
        else:
            changes = [f"{sign}{_short_effect(e)}" for sign, e in effect_changes(s, first)]
            if len(changes) > 3:  # the first two, then how many more
                changes = [*changes[:2], f"and {len(changes) - 2} more"]
            what = " ".join([s.method, *changes]) if changes else f"{s.method}, same effects as 1"
        out.append(f"{i + 1}. {_shorten(name, 30, middle=True)}: {_shorten(what, 60)}")
    return out
