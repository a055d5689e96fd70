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
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from crane_io.errors import CraneError

from .dataset import Dataset


class SplitError(CraneError):
    """Not enough data for the requested splits."""


@dataclass
class SplitConfig:
    n_pool: int = 6000  # training pool (the sweep draws its training sets from it)
    n_val: int = 500  # validation samples, every joint moving
    n_test: int = 500  # test samples, every joint moving
    window_s: float = 3.0  # continuous window for the torque plot
    block_s: float = 2.0  # length of the contiguous blocks the data is cut into
    gap_s: float = 0.2  # discarded between blocks (filter memory)

    def scaled(self, factor: float) -> SplitConfig:
        return SplitConfig(max(int(self.n_pool * factor), 10), max(int(self.n_val * factor), 10),
                           max(int(self.n_test * factor), 10), self.window_s, self.block_s, self.gap_s)


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
    """Rough number of rows the splits need at the measured all-moving fraction."""
    block = config.block_s * rate_hz
    overhead = (block + config.gap_s * rate_hz) / block
    frac = max(all_moving_fraction, 1e-3)
    return int(np.ceil((config.n_pool + (config.n_val + config.n_test) / frac + block) * overhead
                       + (config.window_s + 2 * config.gap_s) * rate_hz))


def _try_split(ds: Dataset, config: SplitConfig, rng) -> tuple[dict, str | None]:
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
    free = []
    for a, b in runs:
        if (a, b) == (wa, wb):
            free += [(a, w0 - gap), (w0 + n_win + gap, b)]
        else:
            free.append((a, b))
    blocks = []
    for a, b in free:
        s = a
        while b - s >= max(block // 4, 1):
            e = min(s + block, b)
            blocks.append(np.arange(s, e))
            s = e + gap
    order = rng.permutation(len(blocks))
    all_moving = ds.all_moving
    val, test, pool = [], [], []
    n_val = n_test = n_pool = 0
    for k in order:
        blk = blocks[k]
        if n_val < config.n_val:
            val.append(blk)
            n_val += int(all_moving[blk].sum())
        elif n_test < config.n_test:
            test.append(blk)
            n_test += int(all_moving[blk].sum())
        elif n_pool < config.n_pool:
            pool.append(blk)
            n_pool += len(blk)
    if n_val < config.n_val or n_test < config.n_test or n_pool < config.n_pool:
        return {}, "short"

    def take_moving(blks, n):
        rows = np.sort(np.concatenate(blks))
        return rows[all_moving[rows]][:n]

    pool_rows = np.concatenate(pool)[:config.n_pool]
    return {"pool": np.sort(pool_rows), "val": take_moving(val, config.n_val),
            "test": take_moving(test, config.n_test), "window": window}, None


def make_splits(ds: Dataset, config: SplitConfig | None = None, seed: int = 0,
                scale_to_data: bool = False) -> Splits:
    """Split `ds` as the module docstring describes; raise SplitError with the needed vs available
    amount when the data is too short (or, with scale_to_data, shrink every size until it fits)."""
    config = config or SplitConfig()
    rng_seed = np.random.SeedSequence(seed)
    frac = float(ds.all_moving.mean()) if len(ds) else 0.0
    if frac == 0:
        raise SplitError("no sample has every joint moving, so there is no validation or test data")
    scale = 1.0
    for _attempt in range(12):
        cfg = config if scale == 1.0 else config.scaled(scale)
        index, problem = _try_split(ds, cfg, np.random.default_rng(rng_seed))
        if not problem:
            parts = {k: ds.subset(v) for k, v in index.items()}
            return Splits(parts["pool"], parts["val"], parts["test"], parts["window"], index, cfg, scale)
        if problem != "short":
            raise SplitError(f"the data is too short: {problem}")
        if not scale_to_data:
            need = needed_samples(config, frac, ds.rate_hz)
            raise SplitError(
                f"the splits need about {need} samples ({need / ds.rate_hz:.0f} s at {ds.rate_hz:g} Hz: "
                f"{config.n_pool} training, {config.n_val} validation and {config.n_test} test samples with "
                f"every joint moving, {frac:.0%} of rows here, plus a {config.window_s:g} s window) but the "
                f"data has {len(ds)} ({len(ds) / ds.rate_hz:.0f} s); record longer or use --scale-to-data")
        scale *= 0.8
    raise SplitError(f"even scaled down the splits do not fit the {len(ds)} samples available")
