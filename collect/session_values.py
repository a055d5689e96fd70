"""The values a session file holds besides its rows: `/events` records, and the attributes written
with their types (the placeholders created before the SWMR switch and their end-of-run values, written
in place). Used by the recorder (collect/recorder.py) and recovery."""

from __future__ import annotations

import h5py
import numpy as np

from crane_io import session_format as sf
from crane_io.session_format import EVENT_DTYPE


def _enc(text: str, size: int) -> bytes:
    raw = str(text).encode("utf-8")[:size]
    return raw.decode("utf-8", "ignore").encode("utf-8")


def event_row(t: float, kind: str, message: str, joint: str = "") -> np.void:
    """One record of `/events` (strings cut to their fixed widths on a UTF-8 character boundary)."""
    w = sf.EVENT_WIDTHS
    return np.array([(float(t), _enc(kind, w["kind"]), _enc(joint, w["joint"]), _enc(message, w["message"]))],
                    dtype=EVENT_DTYPE)[0]


def placeholder(kind):
    if kind is bool:
        return False
    if kind is int:
        return np.int64(-1)
    if kind is str:
        return ""
    return np.nan


def _fits(dtype: np.dtype, value) -> bool:
    """Can `value` be written into an existing scalar attribute of `dtype` without changing its type?"""
    if h5py.check_string_dtype(dtype) is not None:
        return isinstance(value, str)
    if isinstance(value, (bool, np.bool_)):
        return dtype.kind == "b"
    if isinstance(value, (int, np.integer)):
        return dtype.kind in "iuf"
    if isinstance(value, (float, np.floating)):
        return dtype.kind == "f"
    return False


def set_end_attr(obj, key: str, value) -> None:
    value = attr_value(value)
    if key in obj.attrs:
        current = obj.attrs.get_id(key)
        if current.shape == () and _fits(current.dtype, value):
            obj.attrs.modify(key, value)  # in place: allowed while the file is in SWMR mode
            return
    obj.attrs[key] = value


def attr_value(value):
    if isinstance(value, str):
        return value
    if isinstance(value, (list, tuple)) and value and all(isinstance(v, str) for v in value):
        return np.array(value, dtype=h5py.string_dtype())
    if isinstance(value, dict):
        raise TypeError("dict attributes are not supported; flatten them")
    return value


def read_events(f: h5py.File) -> list[dict]:
    """The events of an open session as dicts with str fields (helper for tests and tools)."""
    if sf.EVENTS not in f:
        return []
    out = []
    for rec in f[sf.EVENTS][()]:
        out.append({"t": float(rec["t"]), "kind": rec["kind"].decode(), "joint": rec["joint"].decode(),
                    "message": rec["message"].decode()})
    return out
