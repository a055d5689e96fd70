"""Let go of a session file whose write failed (a full disk, an I/O error) without HDF5 touching it again.

After a failed write HDF5's own state for the file is no longer in step with the disk, and every later
call that writes (a flush, closing a dataset, closing the file, even the interpreter's exit closing what
was left open) tries again and fails again; a close that fails half way leaves identifiers that point at
freed memory, and the next one to go (Python's exit, at the latest) crashes the process (SIGSEGV, in
H5D_close). Worse, a later write that does get through (the superblock is rewritten in place, for
instance) can leave a file that opens as an ordinary one but is inconsistent.

`detach(f)` therefore points the open file's descriptor (HDF5's sec2 driver) at a private in-memory copy
of the file (`memfd_create`; a temporary file where that does not exist): from then on HDF5 reads what
it wrote before and writes into memory, so closing succeeds and frees everything, while the file on
disk stays exactly as the last successful write left it: in SWMR-write state, every chunk written
before the failure readable, recoverable with `crane-collect recover`.
"""

from __future__ import annotations

import contextlib
import os
import tempfile

import h5py

_BLOCK = 8 << 20


def detach(f: h5py.File) -> bool:
    """Redirect the open file `f` to a private copy of its bytes (see the module docstring). True when
    done; False when the file's descriptor is not reachable (another driver), and then nothing changed."""
    try:
        fd = f.id.get_vfd_handle()
    except Exception:  # noqa: BLE001 - a driver without a descriptor, or a file already closed
        return False
    if not isinstance(fd, int) or fd < 0:
        return False
    try:
        copy = _private_file()
    except Exception:  # noqa: BLE001 - never raises: it runs while another failure is being handled
        return False
    try:
        _copy_bytes(fd, copy)
        os.dup2(copy, fd)
    except Exception:  # noqa: BLE001
        return False
    finally:
        os.close(copy)
    return True


def _private_file() -> int:
    create = getattr(os, "memfd_create", None)
    if create is not None:
        with contextlib.suppress(OSError):
            return create("crane-detached-session", getattr(os, "MFD_CLOEXEC", 0))
    return os.dup(tempfile.TemporaryFile().fileno())


def _copy_bytes(src: int, dst: int) -> None:
    """The bytes of `src` into `dst` at the same offsets. Memory running out part way keeps what was
    copied: HDF5 then reads zeros beyond it, and at worst its close reports an error instead of
    finishing, which is still harmless to the file on disk."""
    offset = 0
    while True:
        try:
            data = os.pread(src, _BLOCK, offset)
        except (OSError, MemoryError):
            return
        if not data:
            return
        try:
            os.pwrite(dst, data, offset)
        except (OSError, MemoryError):
            return
        offset += len(data)


@contextlib.contextmanager
def written_file(path, mode: str = "w", **kwargs):
    """`h5py.File(path, mode)` for writing, closed safely: flushed before it is closed, so a full disk
    shows up as an exception there, and after any exception inside the block (or in that flush) let go
    of with `detach` before closing, so that HDF5 never retries its writes on the failed file."""
    f = h5py.File(path, mode, **kwargs)
    try:
        yield f
        f.flush()
    except BaseException:
        detach(f)
        with contextlib.suppress(Exception):
            f.close()
        raise
    f.close()
