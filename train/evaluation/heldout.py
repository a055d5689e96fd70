"""The held-out data a model is judged on (report, compare, diagnose): the sessions preprocessed with
the model's own preprocessing settings and split with the model's split settings and seed (train.data.splits),
keeping only what training never saw: the test blocks and the plotting window.

The test set of train.data.splits holds only the rows of its blocks where every joint moves; the report
also needs the dead-zone rows of those blocks (to show the error there). They are recovered by filling
the rows between two test rows of the same piece when no training or validation row lies between them
and they are less than one block apart.
"""

from __future__ import annotations

import json
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

from ..data.dataset import Dataset
from ..data.preprocess import PreprocessConfig, read_preprocessed
from ..data.splits import SplitConfig, Splits, make_splits
from ..models.base import ModelFileError
from ..models.model_files import MAX_SEED

if TYPE_CHECKING:
    from collections.abc import Sequence

    from ..models.base import Model


@dataclass
class HeldOut:
    data: Dataset  # the held-out rows (test blocks, then the window), in time order within each part
    test: np.ndarray  # (n,) bool: rows of the paper's test set (every joint moves)
    window: np.ndarray  # (n,) bool: rows of the continuous plotting window
    block_starts: list[int] = field(default_factory=list)  # row where each contiguous held-out block starts
    description: str = ""
    per_joint: bool = False  # a per-joint test set (train.data.splits): each joint is scored where it moves

    def moving_rows(self, j: int) -> np.ndarray:
        return np.flatnonzero(self.data.moving[:, j])

    def test_rows(self, j: int) -> np.ndarray:
        """Rows of joint j's test samples: the test set, and for a per-joint set where j moves."""
        rows = self.test & self.data.moving[:, j] if self.per_joint else self.test
        return np.flatnonzero(rows)

    def test_mask(self) -> np.ndarray | None:
        """(n_test, J) mask of the test rows' scores (per-joint sets), or None (every row counts)."""
        return self.data.moving[self.test] if self.per_joint else None


def held_out_rows(ds: Dataset, splits: Splits) -> np.ndarray:
    """Row indices of `ds` that training and validation never used: the test blocks (with their
    dead-zone rows) and the window, sorted."""
    test = np.sort(np.asarray(splits.index["test"]))
    used = np.zeros(len(ds), bool)
    for key in ("pool", "val"):
        used[np.asarray(splits.index[key], dtype=int)] = True
    block = max(int(round(splits.config.block_s * ds.rate_hz)), 1)
    gap = int(round(splits.config.gap_s * ds.rate_hz))
    keep = np.zeros(len(ds), bool)
    keep[test] = True
    used_cum = np.r_[0, np.cumsum(used)]
    for a, b in zip(test[:-1], test[1:]):
        if b - a <= 1 or b - a > block + gap or ds.segment[a] != ds.segment[b]:
            continue
        if used_cum[b] - used_cum[a + 1] == 0:
            keep[a + 1:b] = True
    keep[np.asarray(splits.index["window"], dtype=int)] = True
    return np.flatnonzero(keep)


def held_out(ds: Dataset, splits: Splits, sessions: Sequence[Path | str] = (),
             seed: int | None = None) -> HeldOut:
    rows = held_out_rows(ds, splits)
    test_set = set(np.asarray(splits.index["test"]).tolist())
    window_set = set(np.asarray(splits.index["window"]).tolist())
    test = np.array([r in test_set for r in rows], bool)
    window = np.array([r in window_set for r in rows], bool)
    starts = [0] + (np.flatnonzero((np.diff(rows) > 1) | (np.diff(ds.segment[rows]) != 0)) + 1).tolist()
    w = np.asarray(splits.index["window"])
    per = splits.test.meta.get("eval_set") == "per-joint"
    desc = (f"Test blocks: {int(test.sum())} test samples "
            f"({'each joint scored where it moves' if per else 'every joint moves'}) and "
            f"{int((~test & ~window).sum())} more samples of the same blocks (some joint stands still), "
            f"in {len(starts) - 1} contiguous blocks; plus the continuous {splits.config.window_s:g} s "
            f"plotting window (t = {ds.t[w[0]]:.1f}–{ds.t[w[-1]]:.1f} s, piece {int(ds.segment[w[0]])}). "
            + (f"Split seed {seed}. " if seed is not None else "") +
            "None of these samples was used for training or validation.")
    if sessions:
        desc += f" Sessions: {', '.join(str(s) for s in sessions)}."
    return HeldOut(ds.subset(rows), test, window, starts, desc, per)


def fit_record(model_dir: Path | str | None) -> dict:
    """What `crane-train fit` wrote next to the model (fit_metrics.json: seed, sources ...), or {}."""
    if model_dir is None:
        return {}
    path = Path(model_dir) / "fit_metrics.json"
    try:
        doc = json.loads(path.read_text()) if path.is_file() else {}
    except (OSError, ValueError, RecursionError):
        return {}
    if not isinstance(doc, dict):
        raise ModelFileError(f"{path} is not the record crane-train fit writes (its top level is not an "
                             f"object)")
    return doc


def model_settings(model: Model, model_dir: Path | str | None = None
                   ) -> tuple[PreprocessConfig, SplitConfig, int]:
    """The preprocessing, split settings and split seed a model was trained with.

    The preprocessing is in the model itself; the seed comes from the fit record (fit_metrics.json)
    or the model's preprocessing record, else 0. The splits are always made with scale_to_data: with
    enough data that is the same split as without it, and with too little it is the scaled split
    `fit --scale-to-data` made (make_splits is deterministic either way).
    """
    prep = dict(getattr(model, "preprocessing", {}) or {})
    cfg = prep.get("preprocessing", prep)
    known = set(PreprocessConfig.__dataclass_fields__)
    pconf = PreprocessConfig.from_dict({k: v for k, v in cfg.items() if k in known})
    split = dict(prep.get("splits") or {})
    sknown = set(SplitConfig.__dataclass_fields__)
    sconf = SplitConfig(**{k: v for k, v in split.items() if k in sknown})
    record = fit_record(model_dir)
    seed = record.get("seed", prep.get("seed", 0)) or 0
    if isinstance(seed, bool) or not isinstance(seed, int) or not 0 <= seed <= MAX_SEED:
        raise ModelFileError(f"{Path(model_dir or '.') / 'fit_metrics.json'} records the seed {seed!r}, not "
                             f"a whole number from 0 to {MAX_SEED}")
    return pconf, sconf, seed


def evaluation_data(model: Model, session_paths: Sequence[Path | str], seed: int | None = None,
                    model_dir: Path | str | None = None) -> tuple[Dataset, Splits, HeldOut]:
    """Read and preprocess the sessions as the model's training did, split them the same way and
    return (all data, the splits, the held-out part), on the arm the model was fitted on (a session whose
    arm the operator's hand moved is refused: train.data.session.HandOnArmError)."""
    pconf, sconf, model_seed = model_settings(model, model_dir)
    ds = read_preprocessed(session_paths, pconf)
    seed = model_seed if seed is None else seed
    splits = make_splits(ds, sconf, seed=seed, scale_to_data=True)
    return ds, splits, held_out(ds, splits, session_paths, seed)


def diagnosis_data(model: Model, ds: Dataset, model_dir: Path | str | None = None,
                   seed: int | None = None) -> tuple[Dataset, str]:
    """The rows `crane-train diagnose` judges `model` on, and one sentence saying which.

    A physics model (rigid-body: linear in its parameters) is refitted from scratch on K-1 time blocks
    and scored on the K-th (train.diagnosis.diagnose), so its own training rows are no advantage: every row of
    the sessions is used - cross-validation proper, and the most data. Any other model (an MLP, the hybrid)
    is kept as trained and only the candidate is fitted to its residual; on the rows it was trained or
    early-stopped on (its pool and validation rows) that residual is optimistically small (the network
    may have bent itself towards the missing effect there), so those rows are left out and only rows its
    training never saw remain.
    """
    from ..diagnosis.diagnose import physics_basis

    if physics_basis(model, ds.subset(np.arange(min(len(ds), 2)))) is not None:
        return ds, (f"all {len(ds)} samples (the physics model is refitted on each fold's training blocks, "
                    "so none of them is scored by a fit that saw it)")
    _, sconf, model_seed = model_settings(model, model_dir)
    splits = make_splits(ds, sconf, seed=model_seed if seed is None else seed, scale_to_data=True)
    seen = np.zeros(len(ds), bool)
    for key in ("pool", "val"):
        seen[np.asarray(splits.index[key], dtype=int)] = True
    rows = np.flatnonzero(~seen)
    return ds.subset(rows), (f"the {len(rows)} of {len(ds)} samples the model was neither trained nor "
                             "validated on")
