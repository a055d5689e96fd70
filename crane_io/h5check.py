"""Name the damage when an HDF5 dataset cannot be read: which dataset, which rows, and whether its
fletcher32 checksum failed (shared by crane-collect recover and crane-train's session reader).

HDF5 reports a checksum mismatch only as "filter returned failure during read". To say more, every
stored chunk of the dataset is read raw (`read_direct_chunk`, no filters) and its fletcher32 checksum
(the last four bytes of a chunk written with the filter) recomputed here, with HDF5's algorithm.
"""

from __future__ import annotations

import h5py
import numpy as np

from crane_io.errors import SessionDamagedError

FLETCHER32 = 3  # H5Z_FILTER_FLETCHER32


def _fold(x: int) -> int:
    """HDF5 reduces its sums with end-around carry: 0 stays 0, any other value maps into 1..65535."""
    return 0 if x == 0 else 1 + (x - 1) % 65535


def fletcher32(data: bytes) -> int:
    """HDF5's H5_checksum_fletcher32: big-endian 16-bit words (a last odd byte padded with zero)."""
    raw = np.frombuffer(data, dtype=np.uint8)
    if raw.size % 2:
        raw = np.append(raw, np.uint8(0))
    words = raw.view(">u2").astype(np.uint64)
    n = words.size
    s1 = int(words.sum())
    s2 = int(np.dot(np.arange(n, 0, -1, dtype=np.uint64), words)) if n else 0
    return (_fold(s2) << 16) | _fold(s1)


def chunk_checksum_ok(stored: bytes) -> bool:
    """True if a chunk stored with the fletcher32 filter matches its checksum (HDF5 also accepts the
    byte-swapped form written by versions before 1.6.3)."""
    if len(stored) < 4:
        return False
    body, tail = stored[:-4], stored[-4:]
    kept = int.from_bytes(tail, "little")
    swapped = (tail[1] << 24) | (tail[0] << 16) | (tail[3] << 8) | tail[2]
    return fletcher32(body) in (kept, swapped)


def has_fletcher32(ds: h5py.Dataset) -> bool:
    plist = ds.id.get_create_plist()
    return any(plist.get_filter(i)[0] == FLETCHER32 for i in range(plist.get_nfilters()))


def bad_checksum_rows(ds: h5py.Dataset) -> list[tuple[int, int]]:
    """(first, last) rows of every stored chunk of `ds` whose fletcher32 checksum fails (empty when
    the dataset has no such filter or all chunks match)."""
    if ds.chunks is None or not has_fletcher32(ds):
        return []
    out = []
    rows = ds.chunks[0] if ds.ndim else 1
    for i in range(ds.id.get_num_chunks()):
        info = ds.id.get_chunk_info(i)
        try:
            _, stored = ds.id.read_direct_chunk(info.chunk_offset)
        except OSError:
            stored = b""
        if not chunk_checksum_ok(stored):
            start = info.chunk_offset[0] if ds.ndim else 0
            out.append((start, min(start + rows, ds.shape[0] if ds.ndim else 1) - 1))
    return out


def damaged_dataset(path, ds: h5py.Dataset, exc: Exception) -> SessionDamagedError:
    """The one sentence for a dataset whose read failed with HDF5's OSError `exc`."""
    try:
        bad = bad_checksum_rows(ds)
    except (OSError, ValueError, AttributeError):
        bad = []
    if bad:
        spans = ", ".join(f"{a}-{b}" for a, b in bad[:3])
        spans += f" and {len(bad) - 3} more chunks" if len(bad) > 3 else ""
        what = f"fails its fletcher32 checksum in rows {spans}"
        salvage = f", or `crane-collect recover {path} -o NEW.h5` to keep every row that passes its checksum"
    else:
        what = f"cannot be read ({exc})"
        salvage = ""
    return SessionDamagedError(f"{path}: dataset {ds.name} {what}, so the file is damaged (a disk or copy "
                               f"error); use another copy of the session{salvage}")
