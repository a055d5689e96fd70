"""A mark, visible to other processes, that a session file is being written.

HDF5 cannot tell a live SWMR writer from a dead one: both leave the same "open for write" flags in the
file's superblock, and the writer drops HDF5's own file lock when it switches to SWMR (so readers can
open the file). The recorder therefore holds an advisory write lock of its own on one byte far beyond
the end of the file for as long as it writes; the kernel releases it when the writer closes the file
or dies (even by SIGKILL). `crane-collect recover` asks for that lock before touching a file.

The lock is an open-file-description lock (Linux `F_OFD_SETLK`): it is independent of HDF5's
`flock()` (so readers are never blocked) and, unlike a classic POSIX record lock, is not dropped when
the same process opens and closes the file through another descriptor. Where OFD locks do not exist
(not Linux), no mark is made and `is_being_written` answers None ("cannot tell").
"""

from __future__ import annotations

import os
import struct

try:
    import fcntl
except ImportError:  # Windows
    fcntl = None

_OFD_SET = getattr(fcntl, "F_OFD_SETLK", None)
_OFD_GET = getattr(fcntl, "F_OFD_GETLK", None)
SUPPORTED = _OFD_SET is not None and _OFD_GET is not None
_START = 1 << 62  # a byte no session file reaches; HDF5 never locks byte ranges
# struct flock: short l_type, short l_whence, off_t l_start, off_t l_len, pid_t l_pid (native layout)
_FLOCK = "@hhqqi4x"


def _flock(kind: int) -> bytes:
    return struct.pack(_FLOCK, kind, os.SEEK_SET, _START, 1, 0)


class WriterLock:
    """Held by the recorder while it writes `path` (acquire after the file exists, release after it is
    closed). Without OFD locks (another system, a file system that refuses them) it does nothing: the
    recording goes on unmarked."""

    def __init__(self, path):
        self._fd: int | None = None
        if not SUPPORTED:
            return
        try:
            fd = os.open(path, os.O_RDWR | getattr(os, "O_CLOEXEC", 0))
        except OSError:
            return
        try:
            fcntl.fcntl(fd, _OFD_SET, _flock(fcntl.F_WRLCK))
        except OSError:  # a file system without such locks: record anyway, unmarked
            os.close(fd)
            return
        self._fd = fd

    def release(self) -> None:
        fd, self._fd = self._fd, None
        if fd is not None:
            os.close(fd)  # the lock goes with the last descriptor of its open file description


def is_being_written(path) -> bool | None:
    """True if a live process holds the recorder's write mark on `path`, False if none does, None
    where this cannot be told (no OFD locks on this system)."""
    if not SUPPORTED:
        return None
    try:
        fd = os.open(path, os.O_RDONLY | getattr(os, "O_CLOEXEC", 0))
    except OSError:
        return None
    try:
        answer = fcntl.fcntl(fd, _OFD_GET, _flock(fcntl.F_RDLCK))
    except OSError:  # a file system without such locks
        return None
    finally:
        os.close(fd)
    return struct.unpack(_FLOCK, answer)[0] != fcntl.F_UNLCK
