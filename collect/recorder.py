"""Crash-safe HDF5 session recording (format "crane-session", documented in the README).

All datasets are created up front (chunked, resizable along N, gzip level 1 + shuffle) and all
metadata is written as root attributes; then the file switches to SWMR mode (`libver="latest"`) so a
reader can follow it live and a crash leaves a file that opens. Rows are buffered in memory and
appended when half a second of samples has accumulated or half a second of wall time has passed,
whichever comes first, so a crash (even SIGKILL) loses at most the last second. Events are written
at once. On close the file is reopened normally to set `complete = True`, the achieved rate and the
loop's timing summary; a crashed recording keeps `complete = False`.
"""

from __future__ import annotations

import time
from pathlib import Path

import h5py
import numpy as np

from crane_io.errors import SessionFileError

FORMAT = "crane-session"
FORMAT_VERSION = 1

# per-arm members: name -> (dtype, per-joint columns?)
ARM_MEMBERS = {
    "t": (np.float64, False),
    "q": (np.float64, True),
    "tau": (np.float64, True),
    "dq_servo": (np.float32, True),
    "current": (np.float32, True),
    "goal_current": (np.float32, True),
    "dq": (np.float32, True),
    "tau_dis": (np.float32, True),
    "tau_res": (np.float32, True),
    "q_goal": (np.float32, True),
}
TIMING_MEMBERS = {
    "cycle_start": np.float64,
    "period": np.float32,
    "bus_time_leader": np.float32,
    "bus_time_follower": np.float32,
    "compute_time": np.float32,
    "overrun": np.bool_,
}
EVENT_DTYPE = np.dtype([("t", "<f8"), ("kind", "S24"), ("joint", "S16"), ("message", "S240")])


def _enc(text: str, size: int) -> bytes:
    raw = str(text).encode("utf-8")[:size]
    return raw.decode("utf-8", "ignore").encode("utf-8")


class SessionRecorder:
    """Write one session. `append(row)` once per cycle with a dict "arm/member" or "timing/member"
    -> value; `event(t, kind, message, joint="")`; `close(...)`. A context manager."""

    def __init__(self, path: str | Path, *, joint_names, rate_hz: float, source: str,
                 attrs: dict | None = None, arms=("leader", "follower"), force: bool = False,
                 flush_interval_s: float = 0.5, chunk_rows: int = 1024, clock=time.monotonic):
        self.path = Path(path)
        if self.path.exists():
            if not force:
                raise SessionFileError(f"{self.path} already exists; pass --force to overwrite it")
            if self.path.is_dir():
                raise SessionFileError(f"{self.path} is a directory, not a session file")
            self.path.unlink()
        try:
            self.path.parent.mkdir(parents=True, exist_ok=True)
            self._f = h5py.File(self.path, "w", libver="latest")
        except OSError as exc:
            raise SessionFileError(f"cannot create session file {self.path} ({exc})") from None
        self.joint_names = [str(n) for n in joint_names]
        J = len(self.joint_names)
        self.rate_hz = float(rate_hz)
        self._clock = clock
        self.flush_interval_s = flush_interval_s
        self._cap = max(1, int(round(rate_hz * flush_interval_s)))
        self._n = 0  # rows in the file
        self._k = 0  # rows in the buffer
        self._last_flush = clock()
        self.closed = False
        f = self._f
        f.attrs["format"] = FORMAT
        f.attrs["format_version"] = FORMAT_VERSION
        f.attrs["rate_hz"] = self.rate_hz
        f.attrs["joint_names"] = np.array(self.joint_names, dtype=h5py.string_dtype())
        f.attrs["source"] = str(source)
        f.attrs["complete"] = False
        for key, value in (attrs or {}).items():
            f.attrs[key] = _attr(value)
        self._ds: dict[str, h5py.Dataset] = {}
        self._buf: dict[str, np.ndarray] = {}
        gz = {"compression": "gzip", "compression_opts": 1, "shuffle": True}
        for arm in arms:
            g = f.create_group(arm)
            for name, (dtype, per_joint) in ARM_MEMBERS.items():
                shape = (0, J) if per_joint else (0,)
                self._add(f"{arm}/{name}", g.create_dataset(
                    name, shape=shape, maxshape=(None,) + shape[1:], dtype=dtype,
                    chunks=(chunk_rows,) + shape[1:], **gz))
        g = f.create_group("timing")
        for name, dtype in TIMING_MEMBERS.items():
            self._add(f"timing/{name}", g.create_dataset(
                name, shape=(0,), maxshape=(None,), dtype=dtype, chunks=(chunk_rows * 4,), **gz))
        self._events = f.create_dataset("events", shape=(0,), maxshape=(None,), dtype=EVENT_DTYPE,
                                        chunks=(64,))
        f.swmr_mode = True
        f.flush()

    def _add(self, key: str, ds: h5py.Dataset) -> None:
        self._ds[key] = ds
        fill = np.nan if np.issubdtype(ds.dtype, np.floating) else 0
        self._buf[key] = np.full((self._cap,) + ds.shape[1:], fill, dtype=ds.dtype)

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
        self._k = k + 1
        if self._k >= self._cap or self._clock() - self._last_flush >= self.flush_interval_s:
            self.flush()

    def flush(self) -> None:
        k = self._k
        if k:
            n0, n1 = self._n, self._n + k
            for key, ds in self._ds.items():
                ds.resize(n1, axis=0)
                b = self._buf[key]
                ds[n0:n1] = b[:k]
                if b.dtype.kind == "f":
                    b[:k] = np.nan  # a member not given in some row stays NaN, never stale
            self._n = n1
            self._k = 0
        self._f.flush()
        self._last_flush = self._clock()

    def event(self, t: float, kind: str, message: str, joint: str = "") -> None:
        rec = np.array([(float(t), _enc(kind, 24), _enc(joint, 16), _enc(message, 240))], dtype=EVENT_DTYPE)
        n = self._events.shape[0]
        self._events.resize(n + 1, axis=0)
        self._events[n] = rec[0]
        self._events.flush()

    def close(self, *, complete: bool = True, attrs: dict | None = None,
              group_attrs: dict[str, dict] | None = None) -> None:
        """Write what is buffered and close. With complete=True the file is reopened to mark it
        complete and to store `attrs` (root) and `group_attrs` ({"timing": {...}})."""
        if self.closed:
            return
        self.closed = True
        try:
            self.flush()
        finally:
            self._f.close()
        if complete:
            with h5py.File(self.path, "r+", libver="latest") as f:
                for key, value in (attrs or {}).items():
                    f.attrs[key] = _attr(value)
                for group, values in (group_attrs or {}).items():
                    for key, value in values.items():
                        f[group].attrs[key] = _attr(value)
                f.attrs["complete"] = True

    def __enter__(self):
        return self

    def __exit__(self, exc_type, exc, tb):
        self.close(complete=exc_type is None)
        return False


def _attr(value):
    if isinstance(value, str):
        return value
    if isinstance(value, (list, tuple)) and value and all(isinstance(v, str) for v in value):
        return np.array(value, dtype=h5py.string_dtype())
    if isinstance(value, dict):
        raise TypeError("dict attributes are not supported; flatten them")
    return value


def read_events(f: h5py.File) -> list[dict]:
    """The events of an open session as dicts with str fields (helper for tests and tools)."""
    if "events" not in f:
        return []
    out = []
    for rec in f["events"][()]:
        out.append({"t": float(rec["t"]), "kind": rec["kind"].decode(), "joint": rec["joint"].decode(),
                    "message": rec["message"].decode()})
    return out
