"""Checks of the data in session files, applied when sessions are loaded for modelling
(train.data.session.read_sessions; `crane-train info` lists what they find, fit, sweep, diagnose and compare
warn of it). Each finding names the file and the time range (seconds of the file's `t`):

* **the same data under another name**: two files whose t, q and tau are identical (SHA-256 over the
  arrays, `content_hash`) are one recording given twice; refused (SessionFileError), as the same path twice
  is, because its rows would land in training and test alike;
* **repeated segments** (`repeated_rows`): a run of at least REPEAT_MIN_S of rows whose q and tau (every
  column) are exact twins of an earlier run, in the same file or an earlier one, at one fixed row offset.
  Recorded signals never repeat bit for bit while the arm moves (a still arm repeats one row, at no fixed
  offset), so such a run is a copy; the later copy is dropped;
* **time-reversed stretches** (`reversed_rows`, only where the file records a velocity: `dq_servo`, else
  `dq`): the recorded velocity and the derivative of the recorded angle disagree in sign, over the joints
  that move, in more than REVERSED_FRACTION of the samples of a REVERSED_WINDOW_S window (two stretches
  are one when what lies between them holds less than half a window of agreeing samples: a pause, in
  which nothing can be compared); such rows are dropped (played backwards, friction and
  inertia have the wrong sign for the torque);
* **jumps** (`jump_rows`): a step of a joint's angle between two consecutive samples larger than its
  velocity allows (JUMP_SLACK times the larger recorded speed of the two samples plus JUMP_SPEED_RAD_S,
  times the time step; without a recorded velocity, MAX_SPEED_RAD_S times the time step; never less than
  JUMP_MIN_RAD): two recordings joined together. The samples within JUMP_MASK_S of the jump are dropped
  and the data is cut there;
* **too few rows to fit** (`fit_rows_finding`): a fit whose training rows (those its method uses) are
  fewer than MIN_FIT_ROWS[method] is warned about.

A dropped stretch cuts its file into continuous pieces (RawSession.breaks) that the preprocessing filters
separately, as it does at a gap in `t`. Findings travel in each RawSession's `findings` and the Dataset's
meta["data_checks"]; `warn` issues them as DataCheckWarning. docs/data-checks.md says what to do about each.
"""

from __future__ import annotations

import hashlib
import warnings
from dataclasses import dataclass, replace
from typing import TYPE_CHECKING

import numpy as np

from crane_io.errors import SessionFileError

if TYPE_CHECKING:
    from collections.abc import Sequence

    from .session import RawSession

REPEAT_MIN_S = 0.1  # a run of exact twins at least this long is a copied segment
REPEAT_MIN_ROWS = 10  # ... and at least this many rows
REVERSED_WINDOW_S = 0.2  # the window over which velocity signs are compared
REVERSED_FRACTION = 0.8  # of the window's compared samples disagree: a reversed stretch
REVERSED_MIN_SPEED_RAD_S = 0.05  # both velocities faster than this for a sample to be compared
JUMP_SLACK = 2.0  # a step may be this many times the recorded speed times the time step ...
JUMP_SPEED_RAD_S = 2.0  # ... plus this speed (the recorded velocity's noise and delay)
MAX_SPEED_RAD_S = 10.0  # without a recorded velocity: faster than any CRANE-X7 joint moves
JUMP_MIN_RAD = 0.1  # a smaller step is never called a jump (servo velocity lags and quantisation)
JUMP_MASK_S = 0.05  # dropped either side of a jump
# training rows below which a fit is warned about: a rigid-body model of 3 joints has some 20-25 parameters
# (150 rows: 450 equations, about 20 per parameter); a network of 64 hidden units some 4 500 weights
MIN_FIT_ROWS = {"rigid-body": 150, "hybrid": 500, "mlp-mse": 500, "mlp-masked": 500}


class DataCheckWarning(UserWarning):
    """A data check found something in the sessions (a stretch dropped, too few rows)."""


@dataclass(frozen=True)
class Finding:
    """What one check found in one file: `check` ("repeated", "reversed", "jump", "few-rows"), the file,
    the time range t0..t1 (s of the file's t), the rows concerned and what was done ("dropped", "warned")."""

    check: str
    path: str
    t0: float
    t1: float
    rows: int
    action: str
    detail: str = ""

    @property
    def message(self) -> str:
        where = f"{self.path}: " if self.path else ""
        span = f"{self.t0:.2f}-{self.t1:.2f} s: " if self.t1 >= self.t0 else ""
        done = f" ({self.rows} rows {self.action})" if self.action == "dropped" else ""
        return f"{where}{span}{self.detail}{done}"

    def to_dict(self) -> dict:
        return {"check": self.check, "path": self.path, "t0_s": self.t0, "t1_s": self.t1, "rows": self.rows,
                "action": self.action, "detail": self.detail, "message": self.message}


def content_hash(s: RawSession) -> str:
    """SHA-256 of a session's joint names and its t, q and tau arrays (float64, C order)."""
    h = hashlib.sha256("\x1f".join(s.joint_names).encode())
    for a in (s.t, s.q, s.tau):
        h.update(np.ascontiguousarray(a, dtype=np.float64).tobytes())
    return h.hexdigest()


def check_distinct(sessions: Sequence[RawSession]) -> None:
    """Refuse (SessionFileError) two sessions with identical content under different names."""
    seen: dict[str, str] = {}
    for s in sessions:
        key = content_hash(s)
        if key in seen:
            raise SessionFileError(f"{s.path} holds the same data as {seen[key]} (identical t, q and tau: a "
                                   f"copy under another name); name each recording once")
        seen[key] = s.path


def _runs(flag: np.ndarray) -> list[tuple[int, int]]:
    """[start, stop) of the runs of True in a 1-D bool array."""
    d = np.diff(np.concatenate(([0], flag.astype(np.int8), [0])))
    return list(zip(np.flatnonzero(d == 1).tolist(), np.flatnonzero(d == -1).tolist()))


def _row_keys(rows: np.ndarray) -> np.ndarray:
    """A 64-bit key per row of a float64 array (equal rows, equal keys)."""
    bits = np.ascontiguousarray(rows, dtype=np.float64).view(np.uint64)
    mult = np.random.default_rng(0x5EED).integers(1, 2 ** 63, size=bits.shape[1], dtype=np.uint64)
    mult |= np.uint64(1)
    with np.errstate(over="ignore"):
        mixed = (bits ^ (bits >> np.uint64(29))) * mult
    return np.bitwise_xor.reduce(mixed, axis=1) + mixed.sum(axis=1, dtype=np.uint64)


def repeated_rows(sessions: Sequence[RawSession]) -> tuple[list[np.ndarray], list[Finding]]:
    """Per session a (N,) bool of the rows that repeat an earlier run exactly (module docstring), with the
    findings."""
    rows = np.concatenate([np.hstack([s.q, s.tau]) for s in sessions])
    owner = np.concatenate([np.full(len(s), k) for k, s in enumerate(sessions)])
    starts = np.cumsum([0] + [len(s) for s in sessions])
    keys = _row_keys(rows)
    _, first_index, inverse = np.unique(keys, return_index=True, return_inverse=True)
    first = first_index[inverse.ravel()]
    idx = np.arange(len(rows))
    twin = (first < idx) & np.all(rows == rows[first], axis=1)
    offset = np.where(twin, idx - first, -1)
    same = np.concatenate(([False], (offset[1:] == offset[:-1]) & twin[1:] & (owner[1:] == owner[:-1])))
    # runs of twins at one offset: a run starts at a twin that does not continue the row before it
    start = twin & ~same
    run_id = np.cumsum(start) - 1
    member = twin & (start | same)
    length = np.bincount(run_id[member], minlength=int(start.sum()))
    run_start = np.flatnonzero(start)
    rate = np.array([s.rate_hz for s in sessions])[owner[run_start]]
    long = np.flatnonzero(length >= np.maximum(REPEAT_MIN_ROWS, REPEAT_MIN_S * rate))
    drop = np.zeros(len(rows), bool)
    found: list[list[int]] = []  # [a, b, src] of each copied run, neighbouring runs of one file merged
    for r in long.tolist():
        a, b = int(run_start[r]), int(run_start[r] + length[r])
        if np.ptp(rows[a:b]) == 0:
            continue
        drop[a:b] = True
        if found and owner[found[-1][1] - 1] == owner[a] and a - found[-1][1] <= REPEAT_MIN_ROWS:
            drop[found[-1][1]:a] = True
            found[-1][1] = b
        else:
            found.append([a, b, int(first[a])])
    findings = [_repeat_finding(sessions, owner, starts, (a, b), src) for a, b, src in found]
    return [drop[starts[k]:starts[k + 1]] for k in range(len(sessions))], findings


def _repeat_finding(sessions, owner, starts, run: tuple[int, int], src: int) -> Finding:
    """The finding of the rows `run` ([a, b) of all sessions' rows) repeating those from row `src` on."""
    a, b = run
    k, o = owner[a], owner[src]
    s, s_src = sessions[k], sessions[o]
    i0, i1 = a - starts[k], b - 1 - starts[k]
    j0, j1 = src - starts[o], src + (b - a) - 1 - starts[o]
    where = "earlier in the same file" if o == k else f"in {s_src.path}"
    return Finding("repeated", s.path, float(s.t[i0]), float(s.t[i1]), b - a, "dropped",
                   f"a repeated segment, q and tau exactly as at {s_src.t[j0]:.2f}-{s_src.t[j1]:.2f} s "
                   f"{where}")


def recorded_speed_ok(s: RawSession) -> bool:
    """Whether the session records a velocity the checks can use."""
    return s.dq is not None and s.dq.shape == s.q.shape


def reversed_rows(s: RawSession) -> tuple[np.ndarray, list[Finding]]:
    """(N,) bool of the rows in time-reversed stretches (module docstring), with the findings; none
    without a recorded velocity."""
    n = len(s)
    if not recorded_speed_ok(s) or n < 3:
        return np.zeros(n, bool), []
    slope = np.gradient(s.q, s.t, axis=0)
    compared = (np.abs(slope) > REVERSED_MIN_SPEED_RAD_S) & (np.abs(s.dq) > REVERSED_MIN_SPEED_RAD_S)
    against = compared & (np.sign(slope) != np.sign(s.dq))
    w = max(int(round(REVERSED_WINDOW_S * s.rate_hz)), 3)
    if n < w:
        return np.zeros(n, bool), []
    c_all = np.concatenate(([0], np.cumsum(compared.sum(axis=1))))
    c_bad = np.concatenate(([0], np.cumsum(against.sum(axis=1))))
    n_all, n_bad = c_all[w:] - c_all[:-w], c_bad[w:] - c_bad[:-w]  # per window starting at row i
    flagged = (n_all >= w // 2) & (n_bad > REVERSED_FRACTION * n_all)
    c_agree = c_all - c_bad
    drop = np.zeros(n, bool)
    last = None
    for a, b in _runs(flagged):
        if last is not None and last < a and c_agree[a] - c_agree[last] < w // 2:
            a = last  # nothing between says the time runs forward there
        drop[a:b - 1 + w] = True
        last = b - 1 + w
    findings = [Finding("reversed", s.path, float(s.t[a]), float(s.t[b - 1]), b - a, "dropped",
                        "a time-reversed stretch, the recorded velocity against the angle's derivative")
                for a, b in _runs(drop)]
    return drop, findings


def jump_rows(s: RawSession) -> tuple[np.ndarray, np.ndarray, list[Finding]]:
    """((N,) bool of the rows dropped around jumps, the rows after each jump, the findings)."""
    n = len(s)
    step = np.abs(np.diff(s.q, axis=0))
    dt = np.diff(s.t)[:, None]
    if recorded_speed_ok(s):
        speed = np.maximum(np.abs(s.dq[:-1]), np.abs(s.dq[1:]))
        allowed = np.maximum(dt * (JUMP_SLACK * speed + JUMP_SPEED_RAD_S), JUMP_MIN_RAD)
    else:
        allowed = np.broadcast_to(np.maximum(dt * MAX_SPEED_RAD_S, JUMP_MIN_RAD), step.shape)
    by = "by its recorded velocity" if recorded_speed_ok(s) else "at any speed the arm reaches"
    over = step > allowed
    at = np.flatnonzero(over.any(axis=1)) + 1  # the first row after each jump
    drop = np.zeros(n, bool)
    half = max(int(round(JUMP_MASK_S * s.rate_hz)), 1)
    findings = []
    for i in at.tolist():
        a, b = max(i - half, 0), min(i + half, n)
        drop[a:b] = True
        j = int(np.argmax(step[i - 1] - allowed[i - 1]))
        findings.append(Finding("jump", s.path, float(s.t[a]), float(s.t[b - 1]), b - a, "dropped",
                                f"a jump of {step[i - 1, j]:.3g} rad in {s.joint_names[j]} between "
                                f"{s.t[i - 1]:.3f} and {s.t[i]:.3f} s (at most {allowed[i - 1, j]:.2g} rad "
                                f"{by})"))
    return drop, at, findings


def _dropped(s: RawSession, drop: np.ndarray, cuts: np.ndarray, findings: list[Finding]) -> RawSession:
    """The session without the dropped rows, cut into pieces where rows went missing or a jump was."""
    keep = ~drop
    if keep.all() and not len(cuts):
        return replace(s, findings=list(findings))
    new_index = np.cumsum(keep) - 1  # row -> its index among the kept rows
    gone = np.flatnonzero(np.diff(np.concatenate(([1], keep.astype(np.int8)))) == 1)  # rows after a gap
    marks = np.concatenate([gone, cuts, s.breaks]).astype(int)
    marks = marks[(marks > 0) & (marks < len(s))]
    marks = marks[keep[marks]] if len(marks) else marks
    breaks = np.unique(new_index[marks]) if len(marks) else np.zeros(0, int)
    breaks = breaks[breaks > 0]
    dq = None if s.dq is None else s.dq[keep]
    return replace(s, t=s.t[keep], q=s.q[keep], tau=s.tau[keep], dq=dq, breaks=breaks,
                   findings=list(findings))


def apply_checks(sessions: Sequence[RawSession]) -> list[RawSession]:
    """The sessions checked as the module docstring says: a copy under another name refused, repeated,
    reversed and jump rows dropped, each session carrying its findings."""
    check_distinct(sessions)
    repeated, rep_findings = repeated_rows(sessions)
    out = []
    for s, rep in zip(sessions, repeated):
        rev, rev_findings = reversed_rows(s)
        jmp, cuts, jump_findings = jump_rows(s)
        findings = sorted([f for f in rep_findings if f.path == s.path] + rev_findings + jump_findings,
                          key=lambda f: f.t0)
        out.append(_dropped(s, rep | rev | jmp, cuts, findings))
    return out


def warn(findings: Sequence[Finding | dict]) -> None:
    """Issue each finding as a DataCheckWarning."""
    for f in findings:
        warnings.warn(DataCheckWarning(f["message"] if isinstance(f, dict) else f.message), stacklevel=2)


def fit_rows_finding(method: str, moving: np.ndarray, per_joint: bool = False) -> Finding | None:
    """A warning when the training rows `method` fits on are fewer than MIN_FIT_ROWS[method]; None otherwise.
    `moving`: the (N, J) dead-zone mask of the training data. The rows counted: those with every joint
    moving (mlp-mse; rigid-body unless `per_joint`), or the fewest rows in which any one joint moves
    (mlp-masked, hybrid; rigid-body fitted per joint)."""
    need = MIN_FIT_ROWS.get(method)
    if need is None:
        return None
    if method == "mlp-mse" or (method == "rigid-body" and not per_joint):
        rows, which = int(moving.all(axis=1).sum()), "rows in which every joint moves"
    else:
        rows, which = int(moving.sum(axis=0).min()), "rows in which its least moving joint moves"
    if rows >= need:
        return None
    return Finding("few-rows", "", 0.0, -1.0, rows, "warned",
                   f"{method} is fitted on {rows} {which}, fewer than the {need} it needs for estimates to "
                   f"be trusted; record more or fit a smaller model")
