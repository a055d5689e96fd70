"""Make a crashed session file an ordinary HDF5 file (`crane-collect recover`).

A recorder killed while writing (SIGKILL, power loss, a crash) leaves its file in the SWMR-write state:
every row flushed before the crash is there, but the superblock still says "open for write", so plain
`h5py.File(path, "r")`, h5dump or HDFView refuse it. HDF5 has no way to tell a live writer from a dead
one, so the recorder marks a live recording itself (collect/session_lock.py).

Recovery reads the file in SWMR mode and writes a fresh, compact copy (collect/session_copy.py):
every group, attribute and event, the per-cycle datasets cut to the rows that all of them hold (a
crash can leave one dataset a flush ahead of another, or rows whose time was never written), with
`complete = False` and `end_reason = "crashed"` (or the end reason the file already holds, if the
crash came while it was being closed) and a `recovered` event. A `/timing` summary that the run never
wrote (its placeholders) is left out, as are root attributes still holding a NaN placeholder.

In place (the default) the original is kept beside the result as `SESSION.h5.crashed` (a hard link
made before the recovered copy is renamed over the session's name, so the name always holds one
whole file); with `output` the input is only read. Any failure leaves the input untouched and no
partial output behind.
"""

from __future__ import annotations

import os
import shutil
import tempfile
from dataclasses import dataclass
from pathlib import Path

import h5py
import numpy as np

from crane_io import session_format as sf
from crane_io.errors import NotRecoverableError, SessionFileError
from crane_io.session_format import EVENT_DTYPE, FORMAT

from .recorder import event_row
from .session_copy import read_rows, row_datasets, write_copy
from .session_lock import is_being_written

BACKUP_SUFFIX = ".crashed"


@dataclass
class Recovery:
    source: Path
    output: Path
    backup: Path | None  # the original, kept (in-place recovery only)
    rows: int  # rows kept in every per-cycle dataset
    rows_dropped: int  # rows some dataset held beyond the common complete length
    duration_s: float  # follower time span of the kept rows
    end_reason: str


def _check_source(path: Path) -> None:
    if not path.exists():
        raise NotRecoverableError(f"{path} does not exist")
    if not path.is_file():
        raise NotRecoverableError(f"{path} is not a file")
    if not h5py.is_hdf5(str(path)):
        raise NotRecoverableError(f"{path} is not an HDF5 file, so it cannot be a crashed crane-session")
    if is_being_written(path):
        raise NotRecoverableError(f"{path} is still being written by a running crane-collect; it is closed "
                                  "properly when that run ends, so there is nothing to recover")


def _refuse_ordinary(path: Path) -> None:
    """A file that opens with a plain read needs no recovery: say what it is."""
    try:
        f = h5py.File(str(path), "r")
    except OSError as exc:
        if "already open for write" in str(exc) or "consistency flags" in str(exc):
            return  # the crashed state recovery is for
        raise NotRecoverableError(f"{path} cannot be read as HDF5 ({exc})") from None
    with f:
        fmt = _text(f.attrs.get(sf.FORMAT_ATTR))
        if fmt != FORMAT:
            raise NotRecoverableError(f"{path} is not a crane-session file (format {fmt!r}), so there is "
                                      "nothing to recover")
        state = "complete" if bool(f.attrs.get(sf.COMPLETE_ATTR, False)) else "closed but incomplete"
        raise NotRecoverableError(f"{path} is an ordinary session file already ({state}); only a session "
                                  "whose recording crashed needs recovering")


def _text(value) -> str | None:
    if isinstance(value, bytes):
        return value.decode("utf-8", "replace")
    return None if value is None else str(value)


def _complete_rows(f: h5py.File, path) -> tuple[int, int]:
    """(rows every per-cycle dataset holds completely, rows of the longest dataset)."""
    data = row_datasets(f)
    if not data:
        return 0, 0
    lengths = [d.shape[0] for d in data]
    n = min(lengths)
    # rows are written time first; a time never written reads as the NaN fill value
    times = (sf.T, sf.CYCLE_START)
    for d in data:
        if d.ndim == 1 and d.dtype.kind == "f" and d.name.rsplit("/", 1)[-1] in times and n:
            values = read_rows(d, 0, n, path)
            finite = np.flatnonzero(np.isfinite(values))
            if finite.size:
                n = min(n, int(finite[-1]) + 1)
    return n, max(lengths)


def _drops(f: h5py.File, end_reason_written: bool) -> dict[str, set]:
    drop: dict[str, set] = {"/": set()}
    for key, value in f.attrs.items():
        if isinstance(value, (float, np.floating)) and np.isnan(value):
            drop["/"].add(key)
    if not end_reason_written and sf.TIMING in f:
        drop[sf.TIMING] = set(f[sf.TIMING].attrs)
    return drop


def recover_session(path, output=None) -> Recovery:
    """Recover the crashed session `path` into `output` (default: in place, keeping the original as
    PATH.crashed). Raises NotRecoverableError (one sentence) for a file that needs no recovery or must
    not be touched, SessionFileError subclasses for a damaged one."""
    path = Path(path)
    _check_source(path)
    in_place = output is None or Path(output).resolve() == path.resolve()
    dest = path if in_place else Path(output)
    backup = path.with_name(path.name + BACKUP_SUFFIX) if in_place else None
    if in_place and (backup.exists() or backup.is_symlink()):
        raise NotRecoverableError(f"{backup} already exists (the original of an earlier recovery?); move it "
                                  f"away or give -o for the recovered file")
    if not in_place:
        if dest.exists() or dest.is_symlink():
            raise NotRecoverableError(f"{dest} already exists; give -o a new file name")
        if not dest.parent.is_dir():
            raise NotRecoverableError(f"cannot write {dest}: folder {dest.parent} does not exist")
    _refuse_ordinary(path)
    try:
        src = h5py.File(str(path), "r", libver="latest", swmr=True)
    except (OSError, ValueError) as exc:
        raise NotRecoverableError(f"{path} cannot be opened even as a crashed recording ({exc})") from None
    staged = None
    try:
        with src:
            fmt = _text(src.attrs.get(sf.FORMAT_ATTR))
            if fmt != FORMAT:
                raise NotRecoverableError(f"{path} is not a crane-session file (format {fmt!r}), so there "
                                          "is nothing to recover")
            written = _text(src.attrs.get(sf.END_REASON_ATTR)) or ""
            end_reason = written or "crashed"
            n, longest = _complete_rows(src, path)
            fd, staged = tempfile.mkstemp(prefix=f".{dest.name}.", suffix=".recovered", dir=dest.parent)
            os.close(fd)
            write_copy(src, staged, rows=n, attrs={sf.COMPLETE_ATTR: False, sf.END_REASON_ATTR: end_reason},
                       drop_attrs=_drops(src, bool(written)), source_path=path)
        duration = _finish_copy(Path(staged), path, n, longest)
        if in_place:
            _keep_original(path, backup)
        try:
            os.replace(staged, dest)
        except OSError:
            if in_place:
                backup.unlink(missing_ok=True)
            raise
        staged = None
    except OSError as exc:
        raise SessionFileError(f"could not recover {path} ({exc}); the file was left as it was") from None
    finally:
        if staged is not None:
            Path(staged).unlink(missing_ok=True)
    return Recovery(path, dest, backup, n, longest - n, duration, end_reason)


def _finish_copy(staged: Path, path: Path, n: int, longest: int) -> float:
    """Add the `recovered` event to the fresh copy and check that it opens as an ordinary file."""
    t_path = sf.arm_path(sf.REQUIRED_ARM, sf.T)
    with h5py.File(staged, "r+") as f:
        t = f[t_path][max(0, n - 1):n] if t_path in f else np.zeros(0)
        t_end = float(t[-1]) if t.size and np.isfinite(t[-1]) else 0.0
        t0 = float(f[t_path][0]) if n and t_path in f else 0.0
        if sf.EVENTS in f and f[sf.EVENTS].dtype == EVENT_DTYPE:
            ev = f[sf.EVENTS]
            msg = (f"recovered by crane-collect recover after a crash: {n} rows kept"
                   + (f", {longest - n} incomplete rows left out" if longest > n else ""))
            ev.resize(ev.shape[0] + 1, axis=0)
            ev[-1] = event_row(t_end, "recovered", msg)
    with h5py.File(staged, "r") as f:
        bad = [d.name for d in row_datasets(f) if d.shape[0] != n]
        if bad or f.attrs.get(sf.FORMAT_ATTR) != FORMAT:
            raise SessionFileError(f"the recovered copy of {path} did not come out whole ({', '.join(bad)}); "
                                   "the file was left as it was")
    return t_end - t0 if n else 0.0


def _keep_original(path: Path, backup: Path) -> None:
    """PATH.crashed: a hard link to the original (no copy, no moment without PATH); a copy where the
    file system has no hard links."""
    try:
        os.link(path, backup)
    except FileExistsError:
        raise NotRecoverableError(f"{backup} already exists; move it away or give -o") from None
    except OSError:
        shutil.copy2(path, backup)
