"""A compact copy of a session file, put in place atomically.

Used twice: `crane-collect recover` (a crashed session becomes an ordinary file) and the recorder's
close (a file whose partly filled chunks were rewritten gets its space back). Every group, dataset and
attribute is copied with its type; datasets keep their chunk shape and filters (gzip, shuffle,
fletcher32) and are written in one go, whole chunks at a time, so no space is left behind. Reading the
source checks its fletcher32 checksums: a damaged chunk stops the copy with the dataset's name.

The copy is written to a hidden temporary file in the destination's folder, flushed to disk and only
then renamed over the destination (one atomic step): the destination holds either its old content or
the whole copy, never a half-written file, and the source is only ever read.
"""

from __future__ import annotations

import os
import tempfile
from pathlib import Path

import h5py
import numpy as np

from crane_io.h5check import damaged_dataset

from .session_detach import written_file

BLOCK_BYTES = 8 << 20  # rows are copied in blocks of about this size (whole chunks)


def row_datasets(f: h5py.File) -> list[h5py.Dataset]:
    """The per-cycle datasets: every dataset inside a group (`/leader/*`, `/follower/*`, `/timing/*`);
    root-level datasets (`/events`) have their own length."""
    out: list[h5py.Dataset] = []

    def visit(name, obj):
        if isinstance(obj, h5py.Dataset) and "/" in name and obj.ndim >= 1:
            out.append(obj)

    f.visititems(visit)
    return out


def read_rows(ds: h5py.Dataset, start: int, stop: int, path) -> np.ndarray:
    """ds[start:stop]; a chunk that fails its checksum or cannot be decoded is one sentence naming the
    dataset (SessionDamagedError)."""
    try:
        return ds[start:stop]
    except OSError as exc:
        raise damaged_dataset(path, ds, exc) from None


def _copy_attrs(src, dst, skip=()) -> None:
    for name in src.attrs:
        if name in skip:
            continue
        dtype = src.attrs.get_id(name).dtype
        dst.attrs.create(name, src.attrs[name], dtype=dtype)


def _create_like(group: h5py.Group, name: str, ds: h5py.Dataset, rows: int) -> h5py.Dataset:
    shape = (rows,) + ds.shape[1:] if ds.ndim else ds.shape
    kw: dict = {"dtype": ds.dtype, "fillvalue": ds.fillvalue}
    if ds.chunks is not None:
        kw.update(chunks=tuple(c if m is None else max(1, min(c, s))
                               for c, s, m in zip(ds.chunks, shape, ds.maxshape)),
                  maxshape=ds.maxshape, compression=ds.compression, compression_opts=ds.compression_opts,
                  shuffle=ds.shuffle, fletcher32=ds.fletcher32)
    return group.create_dataset(name, shape=shape, **kw)


def _copy_dataset(src: h5py.Dataset, group: h5py.Group, name: str, rows: int, path, spans=None) -> None:
    """Copy rows 0..rows of `src`, or (`spans`: [(start, stop)]) those rows only, one after the other."""
    if spans is not None:
        rows = sum(b - a for a, b in spans)
    dst = _create_like(group, name, src, rows)
    _copy_attrs(src, dst)
    if src.ndim == 0:
        dst[()] = src[()]
        return
    chunk_rows = src.chunks[0] if src.chunks else 1
    row_bytes = max(1, src.dtype.itemsize * int(np.prod(src.shape[1:], dtype=np.int64)))
    step = max(chunk_rows, BLOCK_BYTES // row_bytes // chunk_rows * chunk_rows)
    out = 0
    for start, stop in [(0, rows)] if spans is None else spans:
        for a in range(start, stop, step):
            b = min(stop, a + step)
            dst[out:out + b - a] = read_rows(src, a, b, path)
            out += b - a


def write_copy(src: h5py.File, dest, *, rows: int | None = None, attrs: dict | None = None,
               drop_attrs: dict[str, set] | None = None, source_path=None, keep: list | None = None,
               cut: dict[str, int] | None = None) -> None:
    """Copy the open file `src` to `dest` (replaced atomically). `rows`: cut every per-cycle dataset
    (`row_datasets`) to this length; `keep`: copy only these rows of every per-cycle dataset, spans
    [(start, stop)] in order (rows left out close up); `cut`: dataset name ("/events") -> rows kept of
    a dataset that is not per-cycle; `attrs`: root attributes to set in the copy; `drop_attrs`: group
    path ("/" for the root) -> attribute names left out."""
    dest = Path(dest)
    path = source_path or src.filename
    drop = drop_attrs or {}
    fd, tmp = tempfile.mkstemp(prefix=f".{dest.name}.", suffix=".tmp", dir=dest.parent)
    os.close(fd)
    try:
        with written_file(tmp, "w") as out:
            def visit(name, obj):
                if isinstance(obj, h5py.Group):
                    g = out.require_group(name)
                    _copy_attrs(obj, g, set(drop.get(name, ())) | set(drop.get("/" + name, ())))
                elif isinstance(obj, h5py.Dataset):
                    parent = out.require_group(name.rpartition("/")[0] or "/")
                    n = obj.shape[0] if obj.ndim else 0
                    per_cycle = "/" in name and obj.ndim >= 1
                    if rows is not None and per_cycle:
                        n = min(n, rows)
                    if not per_cycle and obj.ndim and "/" + name in (cut or {}):
                        n = min(n, cut["/" + name])
                    _copy_dataset(obj, parent, name.rpartition("/")[2], n, path, keep if per_cycle else None)

            _copy_attrs(src, out, drop.get("/", ()))
            src.visititems(visit)
            for key, value in (attrs or {}).items():
                out.attrs[key] = value
        with open(tmp, "rb+") as fh:
            os.fsync(fh.fileno())
        os.chmod(tmp, _mode_like(Path(path)))
        os.replace(tmp, dest)
        _fsync_dir(dest.parent)
    except BaseException:
        try:
            os.unlink(tmp)
        except OSError:
            pass
        raise


def _mode_like(source: Path) -> int:
    """The copy gets the source's permissions (the temporary file was private), else the usual ones."""
    try:
        return source.stat().st_mode & 0o7777
    except OSError:
        umask = os.umask(0)
        os.umask(umask)
        return 0o666 & ~umask


def _fsync_dir(folder: Path) -> None:
    try:
        fd = os.open(folder, os.O_RDONLY)
    except OSError:
        return
    try:
        os.fsync(fd)
    except OSError:
        pass
    finally:
        os.close(fd)
