"""The final check of `crane-train diagnose --discover` (train/diagnosis/discovery.py): time blocks that the
selection never sees, the held-out veto on what it selected, and the coefficients with their
delete-a-block jackknife standard errors.

The recording is cut into `folds` + HOLDOUT_BLOCKS contiguous time blocks (train.diagnosis.cv.fold_ids);
HOLDOUT_BLOCKS of them, spread over the recording (`block_layout`), are held out. Selection, model order
and pruning run on the others only. Then, with the base and the selected terms fitted on the selection
blocks and scored on the held-out ones (`heldout_check`):

- a term whose removal does not raise the joint's held-out error is dropped (the least useful first, the
  rest refitted), so every term that is proposed lowers the held-out error;
- the refit with what is left must not make any joint's held-out error worse: a rigid-body base is
  shared by the joints, and a term that buys one joint's fit with another's is not a discovery. Worse
  means larger summed over the held-out blocks (beyond WORSE_TOLERANCE, the fit's rounding), larger in
  at least half of them, and larger by more than one standard error of that sum (sqrt(B) x the spread
  of the B per-block changes): refitting the shared parameters with one more column moves a joint's
  small error up in one block and down in the next, and a change the blocks do not agree on is that
  noise, not a trade.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from .cv import Engine, jackknife

HOLDOUT_BLOCKS = 3
WORSE_TOLERANCE = 1e-3  # relative: a held-out error larger by less than this is the fit's rounding


def block_layout(folds: int, holdout: int = HOLDOUT_BLOCKS) -> tuple[int, list[int], list[int]]:
    """(number of blocks, selection blocks, held-out blocks): `folds` selection blocks and `holdout`
    held-out ones spread evenly over the recording (none with holdout = 0)."""
    total = folds + holdout
    held = sorted({min(int((i + 0.5) * total / holdout), total - 1) for i in range(holdout)})
    return total, [k for k in range(total) if k not in held], held


def placed(cols: np.ndarray, j: int, n_joints: int) -> np.ndarray:
    """(N, J, c) columns acting on joint index j only."""
    C = np.zeros((cols.shape[0], n_joints, cols.shape[1]))
    C[:, j, :] = cols
    return C


def heldout_sse(engine: Engine, C: np.ndarray | None, train: list[int], held: list[int]) -> np.ndarray:
    """(J,) squared error on the `held` blocks of the base (and C) fitted on the `train` blocks."""
    return block_sse(engine, C, train, held).sum(axis=0)


def block_sse(engine: Engine, C: np.ndarray | None, train: list[int], held: list[int]) -> np.ndarray:
    """(len(held), J) squared error on each of the `held` blocks of the base (and C) fitted on `train`."""
    th_x, th_c, _ = engine.fit(C, train)
    return np.array([engine.heldout_sse(C, th_x, th_c if C is not None else None, k) for k in held])


@dataclass
class HeldOut:
    kept: list[int]  # the terms (columns of T) that each lower joint j's held-out error
    dropped: list[int]  # the terms that did not
    before: np.ndarray  # (J,) held-out SSE of the base alone
    after: np.ndarray  # (J,) with the kept terms
    blocks_worse: np.ndarray  # (J,) held-out blocks in which the error with the kept terms is larger
    worse: list[int] = field(default_factory=list)  # joints whose held-out error the refit makes worse

    def reduction(self, j: int) -> float:
        return 0.0 if self.before[j] <= 0 else float(1 - self.after[j] / self.before[j])


def _without(engine: Engine, T: np.ndarray, S: list[int], i: int, j: int, train, held) -> float:
    rest = S[:i] + S[i + 1:]
    C = placed(T[:, rest], j, engine.y.shape[1]) if rest else None
    return float(heldout_sse(engine, C, train, held)[j])


def heldout_check(engine: Engine, T: np.ndarray, S: list[int], j: int, train: list[int],
                  held: list[int]) -> HeldOut:
    """The held-out veto (module docstring) on the terms S (columns of T) of joint index j."""
    n_joints = engine.y.shape[1]
    before = heldout_sse(engine, None, train, held)
    S, dropped = list(S), []
    after = before
    while S:
        after = heldout_sse(engine, placed(T[:, S], j, n_joints), train, held)
        gains = [_without(engine, T, S, i, j, train, held) - after[j] for i in range(len(S))]
        worst = int(np.argmin(gains))
        if gains[worst] > 0:
            break
        dropped.append(S.pop(worst))
        after = before
    count, worse = np.zeros(n_joints), []
    if S:
        alone = block_sse(engine, None, train, held)
        change = block_sse(engine, placed(T[:, S], j, n_joints), train, held) - alone
        count = (change > WORSE_TOLERANCE * alone).sum(axis=0)
        spread = np.sqrt(len(held)) * change.std(axis=0, ddof=1) if len(held) > 1 else np.zeros(n_joints)
        worse = [k for k in range(n_joints) if after[k] > before[k] * (1 + WORSE_TOLERANCE)
                 and 2 * count[k] >= len(held) and after[k] - before[k] > spread[k]]
    return HeldOut(S, dropped, before, after, count, worse)


def coefficients(engine: Engine, C: np.ndarray, blocks: list[int]) -> tuple[np.ndarray, np.ndarray]:
    """(coefficients of the columns C refitted with the base on `blocks`, their delete-a-block jackknife
    standard errors: train.diagnosis.cv.jackknife of the refits without each block)."""
    full = engine.fit(C, blocks)[1]
    if len(blocks) < 2:
        return full, np.full(len(full), np.inf)
    names = [str(i) for i in range(len(full))]
    per_block = [dict(zip(names, engine.fit(C, [b for b in blocks if b != k])[1])) for k in blocks]
    spread = jackknife(per_block)
    return full, np.array([spread[n][1] for n in names])
