"""Whole chunks of a session's datasets filtered as HDF5 stores them (`FILTERS`: shuffle, deflate,
Fletcher-32), so that the recorder can write a chunk never written before with `write_direct_chunk`, past
HDF5's chunk cache (collect/recorder.py). Used only where `filters_match_hdf5` found the bytes to be
HDF5's own, byte for byte, on a file in memory."""

from __future__ import annotations

import zlib

import h5py
import numpy as np

from crane_io import session_format as sf
from crane_io.h5check import fletcher32
from crane_io.session_format import FILTERS


def chunk_bytes(data: np.ndarray) -> bytes:
    """One chunk as the datasets' filter pipeline stores it (`FILTERS`: shuffle, deflate, fletcher32, in
    HDF5's order): the bytes regrouped by significance (byte 0 of every value, then byte 1, ...), zlib at
    FILTERS' level, then the Fletcher-32 checksum of that (HDF5's variant) as 4 bytes, little-endian."""
    return _checksummed(zlib.compress(_shuffled(data), FILTERS["compression_opts"]))


def _shuffled(data: np.ndarray) -> bytes:
    a = np.ascontiguousarray(data)
    return a.view(np.uint8).reshape(-1, a.itemsize).T.tobytes() if a.itemsize > 1 else a.tobytes()


def _checksummed(packed: bytes) -> bytes:
    return packed + fletcher32(packed).to_bytes(4, "little")


FILTER_CHECKS: dict[tuple, bool] = {}


def filters_match_hdf5(members: tuple, rows: int) -> bool:
    """Does `chunk_bytes` give, byte for byte, the chunks HDF5 stores for datasets of these (dtype, row
    shape) members with `FILTERS` and `rows`-row chunks? Tried once per process on a file in memory, with
    values like a session's (quantised, NaN); False also when anything about it fails."""
    key = (tuple(sorted(set(members))), rows)
    known = FILTER_CHECKS.get(key)
    if known is not None:
        return known
    ok = FILTERS == {"compression": "gzip", "compression_opts": 1, "shuffle": True, "fletcher32": True}
    rng = np.random.default_rng(0)
    try:
        with h5py.File(f"crane-filter-check-{id(key)}", "w", driver="core", backing_store=False) as f:
            for i, (dtype, row_shape) in enumerate(key[0] if ok else ()):
                shape = (rows,) + tuple(row_shape)
                data = (np.round(rng.normal(0, 500, shape)) * 1.5e-3).astype(dtype)
                if data.dtype.kind == "f":
                    data.flat[::7] = np.nan
                ds = f.create_dataset(str(i), shape=shape, dtype=dtype, chunks=shape,
                                      fillvalue=sf.fill_value(np.dtype(dtype)), **FILTERS)
                ds[...] = data
                f.flush()
                _mask, stored = ds.id.read_direct_chunk((0,) * len(shape))
                ok = ok and _mask == 0 and stored == chunk_bytes(data)
    except Exception:  # noqa: BLE001 - then HDF5 filters every chunk itself, as it always did
        ok = False
    FILTER_CHECKS[key] = ok
    return ok


def chunk_size(ds: h5py.Dataset, row: int) -> int:
    """Stored bytes of the chunk starting at `row` (0 if it is not on disk)."""
    try:
        info = ds.id.get_chunk_info_by_coord((row,) + (0,) * (ds.ndim - 1))
    except (OSError, ValueError, AttributeError):
        return 0
    return int(info.size or 0) if info.byte_offset is not None else 0
