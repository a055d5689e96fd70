"""Read crane-session HDF5 files (format declared in crane_io/session_format.py, documented in the README)
into plain numpy arrays.

Only the contract minimum is needed: root attributes `format`, `format_version`, `rate_hz`,
`joint_names`, `source`, and `/<arm>/t`, `/<arm>/q`, `/<arm>/tau`. Files are opened read-only (SWMR
read when the file was written in SWMR mode, so a recording in progress can be read too); the input
is never modified. Everything is checked before it is used (train.data.session_check: the attributes'
kinds, the datasets' types and shapes, links that would leave the file, what fits in memory, rate_hz
against t, finite values, t strictly increasing). Every problem is a `SessionFileError` whose one
sentence names the file and the attribute or dataset; stored data that fail their fletcher32 checksum
(written by crane-collect) name the damaged dataset (`SessionDamagedError`).

The arm's recorded velocity (`dq_servo`, else `dq`) is read when present, for the data checks
(train.data.data_checks), which `read_sessions` applies: a copy of one file under another name is
refused, repeated, time-reversed and jump rows are dropped, each finding kept in `RawSession.findings`.

Either arm's group can be read (`arm`, "follower" by default). The optional root attribute `hand_on`
("leader", the default when it is absent, or "follower") says which arm the operator's hand moved: that
arm's torque holds the hand's force besides its own dynamics, so it is no inverse-dynamics data
(`read_sessions(..., hand_free=True)` refuses it with a `HandOnArmError`).
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING

import h5py
import numpy as np

from crane_io.errors import SessionFileError
from crane_io.h5check import member
from crane_io.session_format import (  # noqa: F401 - FORMAT_VERSION: the newest version this reader understands
    ARMS,
    DEFAULT_HAND_ON,
    DQ,
    DQ_SERVO,
    FORMAT,
    FORMAT_ATTR,
    FORMAT_VERSION,
    HAND_ON,
    REQUIRED_ATTRS,
    TAU,
    VERSION_ATTR,
    Q,
    T,
)

from .data_checks import apply_checks
from .session_check import (
    check_declared,
    check_fits,
    check_format_attr,
    check_joint_names,
    check_rate,
    check_rate_matches,
    check_source,
    dataset,
    open_checked,
    read_attrs,
    read_rows,
)
from .session_check import decode as _decode  # noqa: F401 - the readers of other files decode with it

if TYPE_CHECKING:
    from collections.abc import Sequence
    from os import PathLike

MIN_SAMPLES = 100  # fewer raw samples than this cannot be filtered and split meaningfully


@dataclass
class RawSession:
    """One arm's recorded signals, SI units, as stored (no filtering)."""

    t: np.ndarray  # (N,) s
    q: np.ndarray  # (N, J) rad
    tau: np.ndarray  # (N, J) N m
    rate_hz: float
    joint_names: tuple[str, ...]
    source: str
    path: str = ""
    attrs: dict = field(default_factory=dict)  # every root attribute, decoded to plain Python
    truncated: bool = False  # datasets had different lengths (a crashed recording); cut to the shortest
    arm: str = "follower"  # the group the signals were read from
    dq: np.ndarray | None = None  # (N, J) rad/s, the recorded velocity (dq_servo, else dq) when there is one
    breaks: np.ndarray = field(default_factory=lambda: np.zeros(0, int))  # rows starting a new piece
    findings: list = field(default_factory=list)  # the data checks' findings (train.data.data_checks)

    @property
    def duration_s(self) -> float:
        return float(self.t[-1] - self.t[0]) if len(self.t) > 1 else 0.0

    def __len__(self) -> int:
        return len(self.t)


class HandOnArmError(SessionFileError):
    """A session whose requested arm was moved by the operator's hand (root attribute `hand_on`)."""

    def __init__(self, message: str, path: str = "", arm: str = ""):
        super().__init__(message)
        self.path, self.arm = path, arm


def hand_on(attrs: dict, path: Path | str = "the session") -> str:
    """Which arm the operator's hand moved ("leader" or "follower"), from a session's root attributes;
    "leader" when `hand_on` is absent. Any other value is a SessionFileError."""
    value = attrs.get(HAND_ON, DEFAULT_HAND_ON)
    if value not in ARMS:
        raise SessionFileError(f"{path} has {HAND_ON} = {value!r}; expected 'leader' or 'follower'")
    return value


def check_hand_free(session: RawSession) -> None:
    """Refuse (HandOnArmError) a session whose arm the operator's hand moved."""
    if hand_on(session.attrs, session.path) == session.arm:
        raise HandOnArmError(f"{session.path}: the operator's hand moved the {session.arm} in this session "
                             f"({HAND_ON} = {session.arm}), so its torque holds the hand's force, not only "
                             f"the arm's own dynamics", session.path, session.arm)


def _open(path: Path) -> h5py.File:
    return open_checked(path, "session file", "a crane-session")


def _read(path: Path, ds: h5py.Dataset, n: int) -> np.ndarray:
    """The first n rows of a checked dataset as float (train.data.session_check.read_rows)."""
    return read_rows(path, ds, n)


def check_version(path: Path, attrs: dict, fmt: str, newest: int) -> int:
    """The file's format_version; one sentence (SessionFileError) when it is unreadable or newer than
    `newest`, the version this reader understands."""
    version = attrs.get(VERSION_ATTR)
    if isinstance(version, bool) or not isinstance(version, int) or version < 1:
        shown = repr(version) if len(repr(version)) <= 60 else repr(version)[:57] + "..."
        raise SessionFileError(f"{path} has an unreadable {VERSION_ATTR} {shown}; it must be a whole number "
                               f"from 1 to {newest}")
    if version > newest:
        raise SessionFileError(f"{path} is {fmt} {VERSION_ATTR} {version}, newer than this reader's version "
                               f"{newest}; update crane-x7")
    return version


def read_session(path: str | PathLike[str], arm: str = "follower") -> RawSession:
    """Read and validate one session file; see the module docstring for what is checked."""
    path = Path(path)
    with _open(path) as f:
        attrs = read_attrs(path, f)
        check_format_attr(path, attrs, FORMAT)
        missing = [a for a in REQUIRED_ATTRS if a not in attrs]
        if missing:
            raise SessionFileError(f"{path} lacks the required attribute(s) {', '.join(missing)}")
        check_version(path, attrs, FORMAT, FORMAT_VERSION)
        rate = check_rate(path, attrs)
        names = check_joint_names(path, attrs)
        source = check_source(path, attrs)
        check_declared(path, attrs)
        hand_on(attrs, path)
        if member(path, f, arm, h5py.Group) is None:
            raise SessionFileError(f"{path} has no /{arm} group")
        dt = dataset(path, f, f"{arm}/{T}")
        dq, dtau = (dataset(path, f, f"{arm}/{key}", len(names)) for key in (Q, TAU))
        n = min(dt.shape[0], dq.shape[0], dtau.shape[0])
        truncated = len({dt.shape[0], dq.shape[0], dtau.shape[0]}) > 1
        check_fits(path, arm, n, 1 + 2 * len(names))
        if n < MIN_SAMPLES:
            raise SessionFileError(f"{path} has only {n} samples; at least {MIN_SAMPLES} are needed")
        t, q, tau = (_read(path, d, n) for d in (dt, dq, dtau))
        velocity = _recorded_velocity(path, f, arm, len(names), n)
    for name, arr in ((T, t), (Q, q), (TAU, tau)):
        bad = ~np.isfinite(arr)
        if bad.any():
            row = int(np.argwhere(bad)[0][0])
            raise SessionFileError(f"{path}: /{arm}/{name} contains NaN or infinite values "
                                   f"({int(bad.sum())} of them, first in sample {row})")
    if np.any(np.diff(t) <= 0):
        row = int(np.argmax(np.diff(t) <= 0))
        raise SessionFileError(f"{path}: /{arm}/t is not strictly increasing (at sample {row + 1})")
    check_rate_matches(path, arm, t, rate)
    return RawSession(t=t, q=q, tau=tau, rate_hz=rate, joint_names=names, source=source,
                      path=str(path), attrs=attrs, truncated=truncated, arm=arm, dq=velocity)


def _recorded_velocity(path: Path, f: h5py.File, arm: str, joints: int, n: int) -> np.ndarray | None:
    """The arm's recorded velocity (rad/s): `dq_servo`, else `dq`, when one has n finite rows; else None
    (the data checks then do without it)."""
    for key in (DQ_SERVO, DQ):
        try:
            ds = dataset(path, f, f"{arm}/{key}", joints, required=False)
            v = _read(path, ds, n) if ds is not None and ds.shape[0] >= n else None
        except SessionFileError:  # optional and never modelled: a damaged one is only not used
            continue
        if v is not None and np.isfinite(v).all():
            return v
    return None


def read_sessions(paths: Path | str | Sequence[str | PathLike[str]], arm: str = "follower",
                  hand_free: bool = False, checks: bool = True) -> list[RawSession]:
    """Read several session files; they must name the same joints. With `hand_free`, a session whose
    `arm` the operator's hand moved is refused (check_hand_free). With `checks` (the default) the data
    checks apply (train.data.data_checks: a copy under another name refused, repeated, time-reversed and
    jump rows dropped, each session carrying its `findings`)."""
    paths = [paths] if isinstance(paths, (str, Path)) else list(paths)
    if not paths:
        raise SessionFileError("no session files were given")
    seen = {}
    for p in paths:  # the same recording twice would put copies of test samples into the training data
        key = Path(p).resolve()
        if key in seen:
            raise SessionFileError(f"{p} is given twice (as {seen[key]} and {p}); name each session once")
        seen[key] = p
    sessions = [read_session(p, arm) for p in paths]
    if hand_free:
        for s in sessions:
            check_hand_free(s)
    first = sessions[0]
    for s in sessions[1:]:
        if s.joint_names != first.joint_names:
            raise SessionFileError(f"{s.path} has joints {', '.join(s.joint_names)} but {first.path} has "
                                   f"{', '.join(first.joint_names)}; sessions must record the same joints")
    return apply_checks(sessions) if checks else sessions
