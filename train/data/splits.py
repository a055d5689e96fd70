"""The paper's data splits: a training pool, validation and test sets of samples in which every joint
moves, and one continuous window for plots, all disjoint in time.

How (seeded): one `window_s` window is carved out first, at a random place in a random piece (segment)
long enough to hold it. What remains of every piece is cut into contiguous blocks of `block_s`
seconds, separated by `gap_s` of discarded samples, so the low-pass filters' memory (5 time constants of
25 rad/s = 0.2 s) barely leaks between sets. The blocks are shuffled; blocks go to validation until it
holds `n_val` all-moving samples, then to test likewise, and the rest to the training pool, which takes
whole blocks until it holds `n_pool` samples (the last block is cut). Validation and test keep their
first `n_val` / `n_test` all-moving samples in time order; the rest of their blocks is unused.
Contiguous blocks instead of interleaved rows: neighbouring rows are nearly copies of each other after
filtering, so interleaving would leak test data into training.

Evaluation sets at many joints (`eval_set`). The paper's validation and test samples have every joint
moving; with each joint moving ~70 % of the time that is 0.7^J of the rows: 34 % at 3 joints, 8 % at 7,
so 500 + 500 such samples need ~12 500 rows (250 s at 50 Hz) just for validation and test at 7 joints,
and a network validated on them sees a thin, atypical slice of the motion. `eval_set="per-joint"` applies
the paper's own mask to the evaluation instead: validation and test take blocks until EACH joint moves in
at least `n_val` / `n_test` of their rows, keep the rows where any joint moves, and every score on them
is per joint over the rows where that joint moves (train.evaluation.metrics with the dead-zone mask; the MLPs'
early stopping likewise). That needs ~n / min_j(moving fraction of j) rows (~715 at 70 %) instead of
n / 0.7^J. With every row all-moving the masked score is the plain one, so "all-moving" is a special
case. Default "auto": the paper's all-moving sets for up to 3 learning joints (its setting, results
unchanged), per-joint sets from 4 joints on. Val and test Datasets carry meta["eval_set"].
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from crane_io.errors import CraneError

from .dataset import Dataset


class SplitError(CraneError):
    """Not enough data for the requested splits."""


EVAL_SETS = ("auto", "all-moving", "per-joint")
AUTO_ALL_MOVING_MAX_JOINTS = 3  # "auto": the paper's all-moving sets up to this many joints


def per_joint(ds: Dataset) -> bool:
    """Whether `ds` is a per-joint evaluation set (score each joint where it moves)."""
    return ds.meta.get("eval_set") == "per-joint"


def eval_mask(ds: Dataset) -> np.ndarray | None:
    """The mask scores on `ds` use: its dead-zone mask for a per-joint set, else None (every row)."""
    return ds.moving if per_joint(ds) else None


@dataclass
class SplitConfig:
    n_pool: int = 6000  # training pool (the sweep draws its training sets from it)
    n_val: int = 500  # validation samples, every joint moving
    n_test: int = 500  # test samples, every joint moving
    window_s: float = 3.0  # continuous window for the torque plot
    block_s: float = 2.0  # length of the contiguous blocks the data is cut into
    gap_s: float = 0.2  # discarded between blocks (filter memory)
    eval_set: str = "auto"  # "all-moving" (the paper's), "per-joint" (masked), "auto": by joint count

    def __post_init__(self):
        if self.eval_set not in EVAL_SETS:
            raise SplitError(f"eval_set must be one of {', '.join(EVAL_SETS)}, got {self.eval_set!r}")

    def scaled(self, factor: float) -> SplitConfig:
        return SplitConfig(max(int(self.n_pool * factor), 10), max(int(self.n_val * factor), 10),
                           max(int(self.n_test * factor), 10), self.window_s, self.block_s, self.gap_s,
                           self.eval_set)

    def mode(self, n_joints: int) -> str:
        """The evaluation sets used for `n_joints` learning joints: "all-moving" or "per-joint"."""
        if self.eval_set != "auto":
            return self.eval_set
        return "all-moving" if n_joints <= AUTO_ALL_MOVING_MAX_JOINTS else "per-joint"


@dataclass
class Splits:
    pool: Dataset
    val: Dataset
    test: Dataset
    window: Dataset
    index: dict  # {'pool','val','test','window'}: row indices into the dataset that was split
    config: SplitConfig
    scale: float = 1.0  # < 1 when the sizes were scaled down to the data (--scale-to-data)


def _runs(segment: np.ndarray) -> list[tuple[int, int]]:
    cuts = np.flatnonzero(np.diff(segment) != 0) + 1
    bounds = [0, *cuts.tolist(), len(segment)]
    return [(a, b) for a, b in zip(bounds[:-1], bounds[1:])]


def needed_samples(config: SplitConfig, all_moving_fraction: float, rate_hz: float) -> int:
    """Rough number of rows the splits need at the measured fraction of evaluation rows (all-moving
    sets: the all-moving fraction; per-joint sets: the smallest per-joint moving fraction)."""
    block = config.block_s * rate_hz
    overhead = (block + config.gap_s * rate_hz) / block
    frac = max(all_moving_fraction, 1e-3)
    return int(np.ceil((config.n_pool + (config.n_val + config.n_test) / frac + block) * overhead
                       + (config.window_s + 2 * config.gap_s) * rate_hz))


def eval_fraction(ds: Dataset, mode: str) -> float:
    """Fraction of rows that count towards an evaluation set's size: all-moving rows, or (per-joint)
    the rows of the joint that moves least."""
    if not len(ds):
        return 0.0
    return float(ds.all_moving.mean()) if mode == "all-moving" else float(ds.moving.mean(axis=0).min())


def _free_spans(runs: list, window_run: tuple, w0: int, n_win: int, gap: int) -> list[tuple[int, int]]:
    """The continuous pieces, the plot window (and a gap each side of it) cut out of its own."""
    free = []
    for a, b in runs:
        if (a, b) == window_run:
            free += [(a, w0 - gap), (w0 + n_win + gap, b)]
        else:
            free.append((a, b))
    return free


def _blocks(free: list[tuple[int, int]], block: int, gap: int) -> list[np.ndarray]:
    """Row blocks of `block` rows (a last one of at least a quarter block) with `gap` rows between."""
    blocks = []
    for a, b in free:
        s = a
        while b - s >= max(block // 4, 1):
            e = min(s + block, b)
            blocks.append(np.arange(s, e))
            s = e + gap
    return blocks


def _deal_blocks(blocks: list, order, counts: np.ndarray,
                 config: SplitConfig) -> tuple[list, list, list] | None:
    """(val, test, pool) blocks dealt in `order` until each set holds its size; None when the blocks run
    out first. `counts`: (N, K) rows that count towards an evaluation set's size."""
    val, test, pool = [], [], []
    n_val = np.zeros(counts.shape[1], int)
    n_test = np.zeros(counts.shape[1], int)
    n_pool = 0
    for k in order:
        blk = blocks[k]
        if n_val.min() < config.n_val:
            val.append(blk)
            n_val += counts[blk].sum(axis=0)
        elif n_test.min() < config.n_test:
            test.append(blk)
            n_test += counts[blk].sum(axis=0)
        elif n_pool < config.n_pool:
            pool.append(blk)
            n_pool += len(blk)
    if n_val.min() < config.n_val or n_test.min() < config.n_test or n_pool < config.n_pool:
        return None
    return val, test, pool


def _take_moving(ds: Dataset, mode: str, blks: list, n: int) -> np.ndarray:
    """The first rows of the blocks that give an evaluation set its n counted rows."""
    rows = np.sort(np.concatenate(blks))
    if mode == "all-moving":
        return rows[ds.all_moving[rows]][:n]
    rows = rows[ds.moving[rows].any(axis=1)]  # per-joint: rows where some joint moves, until each
    reached = np.cumsum(ds.moving[rows], axis=0) >= n  # joint has n moving rows
    return rows[:int(max(np.argmax(reached[:, j]) for j in range(reached.shape[1]))) + 1]


def _try_split(ds: Dataset, config: SplitConfig, rng, mode: str = "all-moving") -> tuple[dict, str | None]:
    rate = ds.rate_hz
    n_win = int(round(config.window_s * rate))
    gap = int(round(config.gap_s * rate))
    block = max(int(round(config.block_s * rate)), 1)
    runs = _runs(ds.segment)
    long_runs = [r for r in runs if r[1] - r[0] >= n_win]
    if not long_runs:
        return {}, f"no continuous piece holds a {config.window_s:g} s plot window"
    wa, wb = long_runs[rng.integers(len(long_runs))]
    w0 = int(rng.integers(wa, wb - n_win + 1))
    window = np.arange(w0, w0 + n_win)
    blocks = _blocks(_free_spans(runs, (wa, wb), w0, n_win, gap), block, gap)
    order = rng.permutation(len(blocks))
    # rows that count towards an evaluation set: (N, 1) all-moving, or (N, J) each joint's moving rows
    counts = ds.all_moving[:, None] if mode == "all-moving" else ds.moving
    dealt = _deal_blocks(blocks, order, counts, config)
    if dealt is None:
        return {}, "short"
    val, test, pool = dealt
    pool_rows = np.concatenate(pool)[:config.n_pool]
    return {"pool": np.sort(pool_rows), "val": _take_moving(ds, mode, val, config.n_val),
            "test": _take_moving(ds, mode, test, config.n_test), "window": window}, None


def make_splits(ds: Dataset, config: SplitConfig | None = None, seed: int = 0,
                scale_to_data: bool = False) -> Splits:
    """Split `ds` as the module docstring describes; raise SplitError with the needed vs available
    amount when the data is too short (or, with scale_to_data, shrink every size until it fits)."""
    config = config or SplitConfig()
    rng_seed = np.random.SeedSequence(seed)
    mode = config.mode(len(ds.joint_names))
    frac = eval_fraction(ds, mode)
    if frac == 0:
        raise SplitError("no sample has every joint moving, so there is no validation or test data"
                         if mode == "all-moving" else
                         "some joint never moves, so there is no validation or test data for it")
    scale = 1.0
    for _attempt in range(12):
        cfg = config if scale == 1.0 else config.scaled(scale)
        index, problem = _try_split(ds, cfg, np.random.default_rng(rng_seed), mode)
        if not problem:
            parts = {k: ds.subset(v) for k, v in index.items()}
            for key in ("val", "test"):
                parts[key].meta["eval_set"] = mode
            return Splits(parts["pool"], parts["val"], parts["test"], parts["window"], index, cfg, scale)
        if problem != "short":
            raise SplitError(f"the data is too short: {problem}")
        if not scale_to_data:
            need = needed_samples(config, frac, ds.rate_hz)
            which = ("with every joint moving" if mode == "all-moving" else
                     "in which each joint moves (per-joint sets)")
            what = ("of rows have every joint moving here" if mode == "all-moving" else
                    "of rows have the least moving joint moving here")
            raise SplitError(
                f"the splits for {len(ds.joint_names)} joints need about {need} samples "
                f"({need / ds.rate_hz:.0f} s of recording at {ds.rate_hz:g} Hz: {config.n_pool} training, "
                f"{config.n_val} validation and {config.n_test} test samples {which}, {frac:.0%} {what}, "
                f"plus a {config.window_s:g} s window) but the data has {len(ds)} "
                f"({len(ds) / ds.rate_hz:.0f} s); record longer or use `scale_to_data`")
        scale *= 0.8
    raise SplitError(f"even scaled down the splits do not fit the {len(ds)} samples available")
