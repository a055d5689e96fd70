"""Crash-safe HDF5 session recording (format "crane-session": its names, dtypes and writing constants
are declared in crane_io/session_format.py and documented in the README).

All datasets are created up front (chunked, resizable along N, gzip level 1 + shuffle + fletcher32
checksums, float fill NaN) and all metadata is written as root attributes, including placeholders for
the end-of-run attributes (`end_reason`, `rate_hz_achieved`, the `/timing` summary); then the file
switches to SWMR mode (`libver="latest"`) so a reader can follow it live and a crash leaves a file that
`h5py.File(path, "r", swmr=True)` opens (`crane-collect recover` makes it an ordinary file).

Rows are buffered and written in whole chunks: a chunk holds `flush_interval_s` (0.5 s) of recorded
rows and is written once, when it is full. In real time a partly filled chunk is also written when its
oldest row is `max_unsaved_s` (0.9 s) old by the wall clock, so a crash (even SIGKILL) loses at most
the last second of recorded time; in lockstep (simulated time) only full chunks are written, which
also lose at most 0.5 s of recorded time however slowly the loop runs. A chunk written twice leaves its
first copy behind (an SWMR writer never reuses file space); the recorder counts those bytes and, when
they exceed `compact_above` of the file, rewrites the file compactly after closing it. Events are
written at once (their chunks are uncompressed, so a rewrite keeps its place).

The row buffers of the members of one dtype and row shape are columns of one block array, so that
`row_writer` copies a row's per-joint members of each block in one step. A whole chunk that was never
written before (the usual flush) is filtered here, `chunk_bytes`, and stored with `write_direct_chunk`,
past HDF5's chunk cache: about half the cost of HDF5's own path. Its bytes are HDF5's own (shuffle,
zlib, Fletcher-32, checked against HDF5 on a file in memory when a recorder is made; where they
differ, e.g. another zlib, HDF5 filters every chunk as before); every other flush goes through HDF5.

A paced loop cannot afford to write a chunk inside a cycle: writing some 26 datasets (compressed,
checksummed) and flushing the SWMR file takes 3-7 ms, most of it the file flush, longer than the 2 ms
period, so every chunk written in the cycle was a late cycle (a 10-minute real-time run: 1238 periods
more than 2 ms late). With `deferred_writes` (crane-collect sets it for every paced run) a full
chunk's rows are copied aside and written one dataset at a time by `write_pending(deadline, clock)`,
which the loop calls after each cycle's writes, with the time left before its next deadline: each step
writes one dataset and flushes that dataset alone (H5Dflush, ~0.1-0.3 ms, SWMR's own pattern), while
the next step's learned cost fits. The whole-file flush is left out: it grew with the file (0.6 ms
at the start, 6-12 ms after five minutes) and a file whose datasets were flushed one by one opens and
recovers whole after a SIGKILL (tests). So a chunk reaches the file over a few
cycles instead of in one. The rows wait at most a few cycles longer, well inside `max_unsaved_s`; a
chunk that falls due while writes are still pending first finishes them, and `flush()` and `close()`
write everything at once. A crash between two of a chunk's datasets leaves one dataset a chunk ahead of
another, which `crane-collect recover` already cuts to the rows they all hold.

Close never reopens the file (a live reader would make a second open fail): the end-of-run values are
written into the attributes created before the SWMR switch, `complete = True` last, then the file is
closed. A recorder holds an advisory lock while it writes (collect/session_lock.py) so that
`crane-collect recover` can tell a live recording from a crashed one.

A write that fails (a full disk, an I/O error) stops the recording: the recorder raises one sentence
(DiskFullError, exit 3, for a full disk) and from then on HDF5 never writes to the file again
(collect/session_detach.py: HDF5 retrying, or closing half way, crashed the process), so the file keeps
every chunk written before, in the state of a crashed recording, for `crane-collect recover -o`; events
after the stop are dropped and `close()` only lets go of the file. A file without a saved row is removed.
"""

from __future__ import annotations

import contextlib
import operator
import time
from collections.abc import Callable, Sequence
from pathlib import Path

import h5py
import numpy as np

from crane_io import session_format as sf
from crane_io.errors import CraneError, SessionCloseError, SessionFileError
from crane_io.output_files import DiskFullError, is_disk_full
from crane_io.session_format import EVENT_DTYPE, FILTERS, FORMAT, FORMAT_VERSION  # noqa: F401 - re-exported

from . import chunk_filter
from .session_detach import detach
from .session_values import attr_value, event_row, placeholder, read_events, set_end_attr  # noqa: F401

# end-of-run attributes written by close(), created with placeholders before the SWMR switch
SUMMARY_KEYS = sf.TIMING_SUMMARY_ATTRS
DEFAULT_END_ATTRS = {"/": {sf.END_REASON_ATTR: str, sf.RATE_ACHIEVED_ATTR: float},
                     sf.TIMING: {**dict.fromkeys(SUMMARY_KEYS, float), sf.TIMING_LOCKSTEP: bool}}


class SessionRecorder:
    """Write one session. `append(row)` once per cycle with a dict "arm/member" or "timing/member"
    -> value (or `append_values(columns(keys), values)`); `event(t, kind, message, joint="")`;
    `close(...)`. A context manager.

    `lockstep`: rows carry simulated time; only whole chunks are written (no wall-clock flushes).
    `end_attrs`: the end-of-run attributes `close()` will write, {group: {name: type}} with "/" for
    the root and types float, int, bool or str (default `DEFAULT_END_ATTRS`: `end_reason`,
    `rate_hz_achieved` and the keys of `CycleTimer.summary()` plus `lockstep` in `/timing`). They are
    created before the SWMR switch with placeholders (NaN, -1, False, "") and overwritten in place at
    close; a key given to close() that was not declared is created then (HDF5 accepts it, but a
    reader that has the file open sees it only after reopening; declare keys to be safe)."""

    def __init__(self, path: str | Path, *, joint_names, rate_hz: float, source: str,
                 attrs: dict | None = None, arms=sf.ARMS, force: bool = False,
                 flush_interval_s: float = sf.CHUNK_S, max_unsaved_s: float = sf.MAX_UNSAVED_S,
                 lockstep: bool = False, chunk_rows: int | None = None, end_attrs: dict | None = None,
                 compact_above: float = sf.COMPACT_ABOVE, deferred_writes: bool = False,
                 clock=time.monotonic):
        self.path = Path(path)
        self._lock = None
        if self.path.exists():
            if not force:
                raise SessionFileError(f"{self.path} already exists; pass `force` to overwrite it")
            if self.path.is_dir():
                raise SessionFileError(f"{self.path} is a directory, not a session file")
            self.path.unlink()
        try:
            self.path.parent.mkdir(parents=True, exist_ok=True)
            self._f = h5py.File(self.path, "w", libver="latest")
        except OSError as exc:
            with contextlib.suppress(OSError):
                self.path.unlink(missing_ok=True)
            if is_disk_full(exc):
                raise self._not_created() from None
            raise SessionFileError(f"cannot create session file {self.path} ({exc})") from None
        self.failed: CraneError | None = None  # the write failure that stopped the recording (file detached)
        self.closed = False
        try:
            self._create(joint_names, rate_hz, source, attrs, arms, flush_interval_s, max_unsaved_s, lockstep,
                         chunk_rows, end_attrs, compact_above, deferred_writes, clock)
        except BaseException as exc:
            self._abandon_new_file()
            if is_disk_full(exc):
                raise self._not_created() from None
            raise

    def _not_created(self) -> DiskFullError:
        return DiskFullError(f"the disk holding {self.path} is full: the session file could not be created, "
                             "nothing was recorded and no file was left; free some space or record elsewhere")

    def _abandon_new_file(self) -> None:
        """A file whose creation failed: let HDF5 go of it without writing to it again, then remove it."""
        detach(self._f)
        with contextlib.suppress(Exception):
            self._f.close()
        if self._lock is not None:
            self._lock.release()
        self.closed = True
        with contextlib.suppress(OSError):
            self.path.unlink(missing_ok=True)

    def _create(self, joint_names, rate_hz, source, attrs, arms, flush_interval_s, max_unsaved_s, lockstep,
                chunk_rows, end_attrs, compact_above, deferred_writes, clock) -> None:
        self.joint_names = [str(n) for n in joint_names]
        J = len(self.joint_names)
        self.rate_hz = float(rate_hz)
        self._clock = clock
        self.flush_interval_s = flush_interval_s
        self.max_unsaved_s = max_unsaved_s
        self.lockstep = bool(lockstep)
        self.compact_above = compact_above
        self.chunk_rows = int(chunk_rows) if chunk_rows else max(1, int(round(rate_hz * flush_interval_s)))
        self._cap = self.chunk_rows
        self._n = 0  # rows in the file
        self._k = 0  # rows in the buffer
        self._oldest = 0.0  # wall-clock time the oldest buffered row was appended
        self._saved = 0  # rows every dataset holds in the file (flushed)
        self.waste_bytes = 0  # bytes of chunks written and then superseded (never reused under SWMR)
        self.compacted = False
        # deferred writes (a paced loop): [(key, n0, n1, rows, partial)], one dataset each
        self.deferred_writes = bool(deferred_writes)
        self._pending: list[tuple] = []
        self._write_cost = _FIRST_WRITE_COST_S  # s: the learned cost of one dataset's write
        f = self._f
        # the required attributes (sf.REQUIRED_ROOT), then `complete`
        f.attrs[sf.FORMAT_ATTR] = FORMAT
        f.attrs[sf.VERSION_ATTR] = FORMAT_VERSION
        f.attrs[sf.RATE_ATTR] = self.rate_hz
        f.attrs[sf.JOINT_NAMES_ATTR] = np.array(self.joint_names, dtype=h5py.string_dtype())
        f.attrs[sf.SOURCE_ATTR] = str(source)
        f.attrs[sf.COMPLETE_ATTR] = False
        for key, value in (attrs or {}).items():
            f.attrs[key] = attr_value(value)
        self._ds: dict[str, h5py.Dataset] = {}
        members = []  # (key, group, name, dtype, row shape) in the order the datasets are created
        for arm in arms:
            g = f.create_group(arm)
            members += [(sf.arm_path(arm, m.name), g, m.name, m.dtype, m.row_shape(J))
                        for m in sf.ARM_MEMBERS]
        g = f.create_group(sf.TIMING)
        members += [(f"{sf.TIMING}/{m.name}", g, m.name, m.dtype, m.row_shape(J)) for m in sf.TIMING_MEMBERS]
        for key, group, name, dtype, row_shape in members:
            self._add(key, group, name, dtype, row_shape)
        self._buf, self._blocks = _block_buffers(members, self._cap)
        self._row_shapes = {key: tuple(row_shape) for key, _g, _n, _d, row_shape in members}
        # whole chunks filtered here when that gives HDF5's own bytes (collect/chunk_filter.py)
        kinds = tuple((np.dtype(d).str, tuple(r)) for _k, _g, _n, d, r in members)
        self._direct = chunk_filter.filters_match_hdf5(kinds, self.chunk_rows)
        self._events = f.create_dataset(sf.EVENTS, shape=(0,), maxshape=(None,), dtype=EVENT_DTYPE,
                                        chunks=(sf.EVENT_CHUNK_ROWS,), fletcher32=True)
        for group, keys in (DEFAULT_END_ATTRS if end_attrs is None else end_attrs).items():
            obj = f if group in ("/", "") else f.require_group(group)
            for key, kind in keys.items():
                if key not in obj.attrs:
                    obj.attrs[key] = placeholder(kind)
        f.swmr_mode = True
        f.flush()
        from .session_lock import WriterLock

        self._lock = WriterLock(self.path)

    def _add(self, key: str, group: h5py.Group, name: str, dtype, row_shape: tuple) -> None:
        fill = sf.fill_value(dtype)
        ds = group.create_dataset(name, shape=(0,) + row_shape, maxshape=(None,) + row_shape, dtype=dtype,
                                  chunks=(self.chunk_rows,) + row_shape, fillvalue=fill, **FILTERS)
        self._ds[key] = ds

    # ---- writing ------------------------------------------------------------------------------------
    @property
    def rows(self) -> int:
        """Rows appended so far (written or buffered)."""
        return self._n + self._k

    def append(self, row: dict) -> None:
        k = self._k
        buf = self._buf
        for key, value in row.items():
            buf[key][k] = value
        self._row_added(k + 1)

    def columns(self, keys) -> tuple:
        """The row buffers of `keys` ("arm/member", "timing/member"), for `append_values`: a caller that
        appends the same members every cycle skips building a dict per row."""
        return tuple(self._buf[key] for key in keys)

    def append_values(self, columns: tuple, values) -> None:
        """`append(dict(zip(keys, values)))` for the buffers `columns(keys)`: the same row."""
        k = self._k
        for b, value in zip(columns, values):
            b[k] = value
        self._row_added(k + 1)

    def row_writer(self, keys) -> Callable[[Sequence], None]:
        """`append_values(columns(keys), values)` as one function of `values` (in `keys` order), for a caller
        that appends the same members every cycle: the members that make up a whole block buffer (all the
        per-joint members of one dtype, or all the scalar ones) are copied into it in one step per row, the
        others one by one."""
        keys = tuple(keys)
        blocks, scalars, used = self._whole_blocks(keys)
        singles = [(self._buf[key], i) for i, key in enumerate(keys) if key not in used]
        concatenate = np.concatenate

        def append(values) -> None:
            k = self._k
            for get, rows, members in blocks:
                try:
                    concatenate(get(values), out=rows[k])
                except (ValueError, TypeError):  # a value that is not a (J,) row: member by member
                    for b, i in members:
                        b[k] = values[i]
            for get, block, members in scalars:
                try:
                    block[k] = get(values)
                except (ValueError, TypeError):  # a value that is not a scalar: member by member
                    for b, i in members:
                        b[k] = values[i]
            for b, i in singles:
                b[k] = values[i]
            self._row_added(k + 1)

        return append

    def _whole_blocks(self, keys: tuple) -> tuple[list, list, set]:
        """(per-joint blocks, scalar blocks, members in them) of the block buffers whose members `keys`
        all name: each block as (getter of its members' values, its rows, [(member buffer, index)]), the
        rows of a per-joint block as one flat view each."""
        where = {key: i for i, key in enumerate(keys)}
        blocks, used = [], set()
        scalars = []  # blocks of scalar members: a row's values go in as one tuple
        for block, members in self._blocks:
            if block.ndim in (2, 3) and len(members) > 1 and all(m in where for m in members):
                index = [where[m] for m in members]
                columns = [(self._buf[m], where[m]) for m in members]
                if block.ndim == 2:
                    scalars.append((operator.itemgetter(*index), block, columns))
                else:
                    rows = [block[r].reshape(-1) for r in range(block.shape[0])]  # one flat view per row
                    blocks.append((operator.itemgetter(*index), rows, columns))
                used.update(members)
        return blocks, scalars, used

    def _row_added(self, k: int) -> None:
        self._k = k
        if (self._n + k) % self.chunk_rows == 0:  # a chunk is full: write it whole
            self._rows_due()
        elif not self.lockstep:
            now = self._clock()
            if k == 1:
                self._oldest = now
            elif now - self._oldest >= self.max_unsaved_s:
                self._rows_due()

    def _rows_due(self) -> None:
        """The buffered rows are to be written: now, or (deferred_writes) by write_pending."""
        if not self.deferred_writes:
            self.flush()
            return
        self._write_all_pending()  # an earlier chunk first (normally long done)
        k = self._k
        n0, n1 = self._n, self._n + k
        partial = n0 % self.chunk_rows
        for key in self._ds:
            self._pending.append((key, n0, n1, self._buf[key][:k].copy(), partial))
        self._clear_rows(k)
        self._n = n1
        self._k = 0

    @property
    def pending_writes(self) -> int:
        """Deferred dataset writes not yet done."""
        return len(self._pending)

    def write_pending(self, deadline: float | None = None, clock=None) -> int:
        """Do deferred writes: all of them when `deadline` is None, otherwise while the next one's
        learned cost still ends before `deadline` (a time of `clock`, default the recorder's clock);
        at least nothing, at most everything. Returns the number of steps left."""
        if self.failed is not None:
            raise self.failed
        clock = clock or self._clock
        pending = self._pending
        try:
            while pending:
                if deadline is not None and clock() + self._write_cost > deadline:
                    break
                t0 = clock()
                key, _n0, n1 = pending[0][:3]
                self._write_rows(*pending.pop(0))
                self._ds[key].id.flush()  # H5Dflush: this dataset's chunk and index reach the file now
                self._saved = pending[0][1] if pending else n1
                took = clock() - t0
                # a slow step raises the estimate at once; capped, so one stall cannot stop the writes
                self._write_cost = min(max(took, self._write_cost * _COST_DECAY), _MAX_WRITE_COST_S)
        except (OSError, RuntimeError) as exc:
            raise self._write_failed(exc) from None
        return self.pending_writes

    def _write_all_pending(self) -> None:
        if self._pending:
            self.write_pending(None)

    def _write_rows(self, key: str, n0: int, n1: int, rows: np.ndarray, partial: int) -> None:
        """Rows n0..n1 of one dataset (`partial`: rows of its last chunk already in the file). A whole
        chunk never written before is filtered here (`chunk_bytes`: HDF5's bytes, checked when the
        recorder was made) and written as it is, past HDF5's chunk cache and filter calls (about half
        the time); anything else, or a chunk HDF5 refuses, goes through HDF5."""
        ds = self._ds[key]
        if self._direct and not partial and n1 - n0 == self.chunk_rows:
            row_shape = self._row_shapes[key]
            try:
                ds.id.set_extent((n1,) + row_shape)
                ds.id.write_direct_chunk((n0,) + (0,) * len(row_shape), chunk_filter.chunk_bytes(rows))
                return
            except Exception as exc:  # noqa: BLE001 - HDF5 refused a chunk: it writes them itself from now on
                if is_disk_full(exc):
                    raise
                self._direct = False
        if partial:  # the chunk on disk is superseded by the one written now
            self.waste_bytes += chunk_filter.chunk_size(ds, n0 - partial)
        ds.resize(n1, axis=0)
        ds[n0:n1] = np.ascontiguousarray(rows)

    def _clear_rows(self, k: int) -> None:
        """Refill the first k buffered rows: a member not given in some row stays NaN, never stale."""
        for block, _members in self._blocks:
            if block.dtype.kind == "f":
                block[:k] = np.nan

    def flush(self) -> None:
        """Write the deferred and the buffered rows now (whole chunks where they fall on chunk
        boundaries), and flush the file. A failed write stops the recording (`_write_failed`)."""
        if self.failed is not None:
            raise self.failed
        self._write_all_pending()
        try:
            k = self._k
            if k:
                n0, n1 = self._n, self._n + k
                partial = n0 % self.chunk_rows
                for key in self._ds:
                    self._write_rows(key, n0, n1, self._buf[key][:k], partial)
                self._clear_rows(k)
                self._n = n1
                self._k = 0
            self._f.flush()
        except (OSError, RuntimeError) as exc:
            raise self._write_failed(exc) from None
        self._saved = self._n

    def event(self, t: float, kind: str, message: str, joint: str = "") -> None:
        """Record an event at once. After a failed write (`failed`) events are dropped: the recording
        has stopped and its failure was raised already."""
        if self.failed is not None:
            return
        try:
            n = self._events.shape[0]
            self._events.resize(n + 1, axis=0)
            self._events[n] = event_row(t, kind, message, joint)
            self._events.flush()
        except (OSError, RuntimeError) as exc:
            raise self._write_failed(exc) from None

    def _write_failed(self, exc: BaseException) -> CraneError:
        """A write to the file failed (a full disk, an I/O error): the recording stops here. The file is
        let go of without HDF5 writing to it again (collect/session_detach.py), so it stays as the last
        successful write left it: every chunk written before, in SWMR-write state, for `crane-collect
        recover`; a file without a recorded row is removed. Returns the one-sentence error (DiskFullError
        for a full disk), kept in `failed`."""
        if self.failed is not None:
            return self.failed
        detach(self._f)
        full = is_disk_full(exc)
        if full:
            what = f"the disk holding {self.path} is full"
        else:
            what = f"writing {self.path} failed ({' '.join(str(exc).split())[:200] or type(exc).__name__})"
        if self._saved:
            self.failed = (DiskFullError if full else SessionFileError)(
                f"{what}: {self._saved / self.rate_hz:.1f} s were recorded, and the file keeps every chunk "
                f"written before; `crane-collect recover {self.path} -o FILE`, with FILE on another disk, "
                "makes it an ordinary file")
        else:  # nothing recorded yet: nothing worth keeping either
            with contextlib.suppress(OSError):
                self.path.unlink()
            self.failed = (DiskFullError if full else SessionFileError)(
                f"{what} before the first rows were recorded: no file was left; free some space or record "
                "elsewhere")
        return self.failed

    # ---- the end ------------------------------------------------------------------------------------
    def close(self, *, complete: bool = True, attrs: dict | None = None,
              group_attrs: dict[str, dict] | None = None) -> None:
        """Write what is buffered, the end-of-run attributes (`attrs` at the root, `group_attrs`
        {"timing": {...}}) and, if `complete`, `complete = True`; then close the file. No second open:
        readers may keep the file open meanwhile. Raises SessionCloseError (one sentence) if any of
        it could not be written; the rows already written stay in the file. A write that fails for the
        disk (full, I/O error) raises `failed` instead, once: after it the file is only let go of."""
        if self.closed:
            return
        self.closed = True
        reported = self.failed  # a failure raised already is not raised again
        failed: list[str] = []
        try:
            lost = self._write_end(complete, attrs, group_attrs, failed)
        finally:
            closed = self._let_go()
        if self.failed is not None:
            if reported is None:
                raise self.failed
            return
        if not closed:
            raise SessionCloseError(f"session file {self.path} could not be closed; {lost}the rows written "
                                    f"before are kept: run `crane-collect recover {self.path}` to make it "
                                    "an ordinary file")
        if failed:
            names = ", ".join(n for n in failed if n != "rows") or "none"
            raise SessionCloseError(f"session file {self.path} was closed but {lost}its end-of-run "
                                    f"attributes ({names}) could not be written, so it stays "
                                    f"complete = False; its {self._n} rows are kept")
        self._compact()

    def _write_end(self, complete: bool, attrs: dict | None, group_attrs: dict | None,
                   failed: list[str]) -> str:
        """Write the buffered rows and the end-of-run attributes; the names of those that could not be
        written go in `failed`, and the returned words say which rows were lost ("" for none)."""
        lost = ""
        try:
            self.flush()
        except CraneError:
            pass  # `failed`: raised by close
        except Exception as exc:  # noqa: BLE001 - reported by close, the rest must still run
            lost = f"the last {self._k} rows could not be written ({exc}); "
            failed.append("rows")
        if self.failed is None:
            self._end_attrs(attrs, group_attrs, failed)
            if complete and not failed:
                self._f.attrs.modify(sf.COMPLETE_ATTR, True)
            try:  # everything written now, so that closing has nothing left to write
                self._f.flush()
            except (OSError, RuntimeError) as exc:
                self._write_failed(exc)
        return lost

    def _let_go(self) -> bool:
        """Close the file and release its lock; whether the file closed."""
        closed = True
        try:
            self._f.close()
        except Exception:  # noqa: BLE001
            closed = False
        if self._lock is not None:
            self._lock.release()
        return closed

    def _end_attrs(self, attrs: dict | None, group_attrs: dict | None, failed: list[str]) -> None:
        """The end-of-run attributes written in place; the names of those that could not be, in `failed`."""
        values = {"/": dict(attrs or {})}
        for group, items in (group_attrs or {}).items():
            values.setdefault(group.strip("/") or "/", {}).update(items)
        for group, items in values.items():
            for key, value in items.items():
                try:
                    set_end_attr(self._f if group == "/" else self._f[group], key, value)
                except Exception:  # noqa: BLE001 - named in the sentence below
                    failed.append(f"{group.rstrip('/')}/{key}".lstrip("/") if group != "/" else key)

    def _compact(self) -> None:
        """Rewrite the closed file compactly if superseded chunks waste more than `compact_above` of it.
        A failure keeps the (valid, larger) file as it is."""
        try:
            size = self.path.stat().st_size
        except OSError:
            return
        if not size or self.waste_bytes <= self.compact_above * size:
            return
        from .session_copy import write_copy

        try:
            with h5py.File(self.path, "r") as src:
                write_copy(src, self.path, source_path=self.path)
        except (OSError, RuntimeError, SessionFileError):  # a full disk too: the file stays as it is
            return
        self.compacted = True

    def __enter__(self):
        return self

    def __exit__(self, exc_type, exc, tb):
        self.close(complete=exc_type is None)
        return False


_FIRST_WRITE_COST_S = 4e-4  # a dataset's write + flush before any was timed (a 0.5 s chunk: ~0.1-0.3 ms)
_COST_DECAY = 0.95  # per step: a slow step raises the learned cost at once, which then decays
_MAX_WRITE_COST_S = 1e-3  # the learned cost's cap: a stall (disk) must not keep the writes waiting


def _block_buffers(members, rows: int) -> tuple[dict[str, np.ndarray], list[tuple[np.ndarray, tuple]]]:
    """The row buffers of `members` ((key, group, name, dtype, row shape)): the members of one dtype and
    row shape share one block array (rows, m) + row shape, filled with the dtype's fill value, and each
    member's buffer is its column of the block (a view). Returns ({key: buffer}, [(block, keys)])."""
    groups: dict[tuple, list[str]] = {}
    for key, _group, _name, dtype, row_shape in members:
        groups.setdefault((np.dtype(dtype), tuple(row_shape)), []).append(key)
    buffers, blocks = {}, []
    for (dtype, row_shape), keys in groups.items():
        block = np.full((rows, len(keys)) + row_shape, sf.fill_value(dtype), dtype=dtype)
        for i, key in enumerate(keys):
            buffers[key] = block[:, i]
        blocks.append((block, tuple(keys)))
    return buffers, blocks
