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

Damaged data are salvaged, not refused: every stored chunk's fletcher32 checksum is checked first
(crane_io/h5check.py). The rows of a per-cycle chunk that fails it are left out of every per-cycle
dataset (their rows are one cycle each, so they stay aligned) and every other row is kept; a dataset
with rows of its own (`/events`) is cut at its first damaged row. `Recovery.damage_summary()` names
the rows lost and why. An ordinary (closed) session file with damaged chunks is recovered the same way.

In place (the default) the original is kept beside the result as `SESSION.h5.crashed` (a hard link
made before the recovered copy is renamed over the session's name, so the name always holds one
whole file); with `output` the input is only read. Any failure leaves the input untouched and no
partial output behind.
"""

from __future__ import annotations

import os
import shutil
import tempfile
from dataclasses import dataclass, field
from pathlib import Path

import h5py
import numpy as np

from crane_io import session_format as sf
from crane_io.errors import NotRecoverableError, SessionFileError
from crane_io.h5check import bad_checksum_rows
from crane_io.output_files import DiskFullError, is_disk_full
from crane_io.session_format import EVENT_DTYPE, FORMAT

from .session_copy import read_rows, row_datasets, write_copy
from .session_detach import written_file
from .session_lock import is_being_written
from .session_values import event_row

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
    damaged: list = field(default_factory=list)  # (dataset, first, last row) of per-cycle chunks dropped
    rows_damaged: int = 0  # rows left out of every per-cycle dataset because a chunk failed its checksum
    cut: dict = field(default_factory=dict)  # other dataset ("/events") -> its first damaged row

    def damage_summary(self) -> str:
        """One sentence on the rows lost to damaged chunks ("" when none): which rows of which dataset
        failed their checksum, and how many rows were kept."""
        if not self.damaged and not self.cut:
            return ""
        parts = [f"rows {a}..{b} of {name} failed their checksum" for name, a, b in self.damaged[:6]]
        if len(self.damaged) > 6:
            parts.append(f"{len(self.damaged) - 6} more damaged chunks")
        parts += [f"row {row} of {name} failed its checksum, so {name} was cut there"
                  for name, row in self.cut.items()]
        kept = self.rows + self.rows_damaged
        tail = (f"; those rows were left out of every dataset, keeping {self.rows} of {kept} rows"
                if self.damaged else "")
        return "; ".join(parts) + tail


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


def _refuse_ordinary(path: Path) -> bool:
    """A file that opens with a plain read needs no recovery (say what it is) unless some of its chunks
    fail their checksum: True for such a damaged ordinary file, False for a crashed one."""
    try:
        f = h5py.File(str(path), "r")
    except OSError as exc:
        if "already open for write" in str(exc) or "consistency flags" in str(exc):
            return False  # the crashed state recovery is for
        raise NotRecoverableError(f"{path} cannot be read as HDF5 ({exc})") from None
    with f:
        fmt = _text(f.attrs.get(sf.FORMAT_ATTR))
        if fmt != FORMAT:
            raise NotRecoverableError(f"{path} is not a crane-session file (format {fmt!r}), so there is "
                                      "nothing to recover")
        if any(_damage(f).values()):
            return True
        state = "complete" if bool(f.attrs.get(sf.COMPLETE_ATTR, False)) else "closed but incomplete"
        raise NotRecoverableError(f"{path} is an ordinary session file already ({state}) and every chunk "
                                  "passes its checksum; only a session whose recording crashed or whose "
                                  "data are damaged needs recovering")


def _damage(f: h5py.File) -> dict[str, list[tuple[int, int]]]:
    """Dataset name -> (first, last) rows of its stored chunks that fail their fletcher32 checksum (only
    rows inside the dataset's extent), for every dataset with rows."""
    out: dict[str, list[tuple[int, int]]] = {}

    def visit(name, obj):
        if isinstance(obj, h5py.Dataset) and obj.ndim >= 1:
            try:
                spans = bad_checksum_rows(obj)
            except (OSError, ValueError, AttributeError):
                spans = []
            out["/" + name] = sorted((a, b) for a, b in spans if a <= b)

    f.visititems(visit)
    return out


def _kept_spans(n: int, damage: dict, per_cycle: list[str]) -> tuple[list[tuple[int, int]], list, int]:
    """The rows 0..n that no per-cycle dataset has in a damaged chunk, as spans [(start, stop)]; the
    damaged chunks among them [(dataset, first, last)]; the rows left out for them."""
    bad = np.zeros(n, dtype=bool)
    damaged = []
    for name in per_cycle:
        for a, b in damage.get(name, []):
            if a < n:
                bad[a:min(b + 1, n)] = True
                damaged.append((name, a, min(b, n - 1)))
    edges = np.flatnonzero(np.diff(np.concatenate(([True], bad, [True])).astype(np.int8)))
    spans = [(int(a), int(b)) for a, b in zip(edges[::2], edges[1::2])]
    return spans, sorted(damaged, key=lambda d: (d[1], d[0])), int(bad.sum())


def _text(value) -> str | None:
    if isinstance(value, bytes):
        return value.decode("utf-8", "replace")
    return None if value is None else str(value)


def _complete_rows(f: h5py.File, path, damage: dict) -> tuple[int, int]:
    """(rows every per-cycle dataset holds completely, rows of the longest dataset). Rows in damaged
    chunks (`damage`) count as written here; they are left out separately."""
    data = row_datasets(f)
    if not data:
        return 0, 0
    lengths = [d.shape[0] for d in data]
    n = min(lengths)
    # rows are written time first; a time never written reads as the NaN fill value
    times = (sf.T, sf.CYCLE_START)
    for d in data:
        if d.ndim == 1 and d.dtype.kind == "f" and d.name.rsplit("/", 1)[-1] in times and n:
            values = np.zeros(n)
            for a, b in _kept_spans(n, damage, [d.name])[0]:
                values[a:b] = read_rows(d, a, b, path)
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


def _check_destination(path: Path, dest: Path, backup: Path | None) -> None:
    """In place: no earlier PATH.crashed in the way; to `dest`: a new file in an existing folder."""
    if backup is not None:
        if backup.exists() or backup.is_symlink():
            raise NotRecoverableError(f"{backup} already exists (the original of an earlier recovery?); move "
                                      f"it away or give -o for the recovered file")
        return
    if dest.exists() or dest.is_symlink():
        raise NotRecoverableError(f"{dest} already exists; give -o a new file name")
    if not dest.parent.is_dir():
        raise NotRecoverableError(f"cannot write {dest}: folder {dest.parent} does not exist")


def _open_crashed(path: Path, damaged_file: bool) -> h5py.File:
    try:
        return (h5py.File(str(path), "r") if damaged_file
                else h5py.File(str(path), "r", libver="latest", swmr=True))
    except (OSError, ValueError) as exc:
        raise NotRecoverableError(f"{path} cannot be opened even as a crashed recording ({exc})") from None


def _written_end_reason(src: h5py.File, path: Path) -> str:
    """The end reason the recording wrote ("" for none); NotRecoverableError for a file of another format."""
    fmt = _text(src.attrs.get(sf.FORMAT_ATTR))
    if fmt != FORMAT:
        raise NotRecoverableError(f"{path} is not a crane-session file (format {fmt!r}), so there "
                                  "is nothing to recover")
    return _text(src.attrs.get(sf.END_REASON_ATTR)) or ""


def _publish(staged: Path, dest: Path, backup: Path | None, path: Path) -> None:
    """Move the staged copy to `dest`; in place, the original is kept as `backup` first."""
    if backup is not None:
        _keep_original(path, backup)
    try:
        os.replace(staged, dest)
    except OSError:
        if backup is not None:
            backup.unlink(missing_ok=True)
        raise


def _not_recovered(exc: BaseException, path: Path, dest: Path) -> Exception:
    """The one-sentence error for a recovery that failed writing."""
    if is_disk_full(exc):
        return DiskFullError(f"the disk holding {dest} is full: the recovered file was not written and "
                             f"{path} was left as it was; free some space or give -o a file on another "
                             "disk")
    return SessionFileError(f"could not recover {path} ({exc}); the file was left as it was")


def recover_session(path, output=None) -> Recovery:
    """Recover the crashed session `path` into `output` (default: in place, keeping the original as
    PATH.crashed). Raises NotRecoverableError (one sentence) for a file that needs no recovery or must
    not be touched, SessionFileError subclasses for a damaged one."""
    path = Path(path)
    _check_source(path)
    in_place = output is None or Path(output).resolve() == path.resolve()
    dest = path if in_place else Path(output)
    backup = path.with_name(path.name + BACKUP_SUFFIX) if in_place else None
    _check_destination(path, dest, backup)
    damaged_file = _refuse_ordinary(path)
    src = _open_crashed(path, damaged_file)
    staged = None
    try:
        with src:
            written = _written_end_reason(src, path)
            end_reason = written or "crashed"
            damage = _damage(src)
            n, longest = _complete_rows(src, path, damage)
            spans, damaged, lost = _kept_spans(n, damage, [d.name for d in row_datasets(src)])
            cut = {name: spans_[0][0] for name, spans_ in damage.items()
                   if spans_ and "/" not in name.lstrip("/")}
            fd, staged = tempfile.mkstemp(prefix=f".{dest.name}.", suffix=".recovered", dir=dest.parent)
            os.close(fd)
            write_copy(src, staged, rows=n, attrs={sf.COMPLETE_ATTR: False, sf.END_REASON_ATTR: end_reason},
                       drop_attrs=_drops(src, bool(written)), source_path=path, keep=spans if lost else None,
                       cut=cut)
        result = Recovery(path, dest, backup, n - lost, longest - n, 0.0, end_reason, damaged, lost, cut)
        result.duration_s = _finish_copy(Path(staged), path, result, damaged_file)
        _publish(staged, dest, backup, path)
        staged = None
    except (OSError, RuntimeError) as exc:
        raise _not_recovered(exc, path, dest) from None
    finally:
        if staged is not None:
            Path(staged).unlink(missing_ok=True)
    return result


def _finish_copy(staged: Path, path: Path, r: Recovery, damaged_file: bool) -> float:
    """Add the `recovered` event to the fresh copy and check that it opens as an ordinary file."""
    n = r.rows
    t_path = sf.arm_path(sf.REQUIRED_ARM, sf.T)
    with written_file(staged, "r+") as f:
        t = f[t_path][max(0, n - 1):n] if t_path in f else np.zeros(0)
        t_end = float(t[-1]) if t.size and np.isfinite(t[-1]) else 0.0
        t0 = float(f[t_path][0]) if n and t_path in f else 0.0
        if sf.EVENTS in f and f[sf.EVENTS].dtype == EVENT_DTYPE:
            ev = f[sf.EVENTS]
            why = "from a file with damaged chunks" if damaged_file else "after a crash"
            msg = (f"recovered by crane-collect recover {why}: {n} rows kept"
                   + (f", {r.rows_dropped} incomplete rows left out" if r.rows_dropped else "")
                   + (f"; {r.damage_summary()}" if r.damaged or r.cut else ""))
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
