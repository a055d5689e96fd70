"""The one way the toolkit writes a file a user asked for: checked against the command's inputs, never
over an existing file without `force`, and written atomically.

    out = check_output(path, inputs=[session], force=force, what="report")
    with atomic_path(out) as tmp:          # a temporary file in the target's folder
        write_something(tmp)               # an exception (or Ctrl+C) leaves the target as it was
    write_text_atomic(out, text)           # the same for a string
    check_output(model_dir, inputs=[session], force=force, directory=True)
    with atomic_directory(model_dir) as tmp_dir: ...   # a model directory, replaced whole

Rules (the same for every command):
- an output that is the same file as any input (links and `..` resolved, hard links by inode) is refused,
  as is an output inside an input directory's tree or an input directory inside the output's;
- an existing output is replaced only with `force`; two outputs of one command are never one file;
- the data go to a temporary file next to the target (same filesystem), are flushed to disk and renamed
  into place, so an interrupted or failed write never leaves half a file where a good one was;
- a write that fails says so in one sentence: a full disk raises DiskFullError (exit 3), any other
  failure OutputPathError (exit 2); the temporary file is removed.

Where: every command checks each of its outputs against all of its inputs (and its other outputs) before
any work: the command line itself, or the library function that takes the output path from its caller
and knows the inputs (train.make_report, train.api.FitResult.save, train.data.importer.import_session,
collect.run_options.check_run_outputs for `crane-collect run`). The library's writers only write, each
through atomic_path or atomic_directory (missing folders are made there when `make_folders` allowed them).
"""

from __future__ import annotations

import contextlib
import errno
import os
import shutil
import tempfile
from collections.abc import Iterable, Iterator
from pathlib import Path

from crane_io.errors import CraneError

_FULL = (errno.ENOSPC, getattr(errno, "EDQUOT", errno.ENOSPC))


class OutputPathError(CraneError):
    """An output path that must not be written: an input of the command, an existing file without
    `force`, a folder that does not exist, a read-only or forbidden place."""


class DiskFullError(CraneError):
    """The disk (or quota) holding an output is full; nothing half-written was left behind."""

    exit_code = 3


def is_disk_full(exc: BaseException) -> bool:
    """True for an OSError (or an h5py error built on one) that says the disk or the quota is full."""
    seen = 0
    while exc is not None and seen < 8:
        if isinstance(exc, OSError) and exc.errno in _FULL:
            return True
        text = str(exc)
        if "No space left on device" in text or "Disk quota exceeded" in text:
            return True
        exc = exc.__cause__ or exc.__context__
        seen += 1
    return False


class _HiddenDiskFull(OSError):
    """A writer's own error (torch's "file write failed", a RuntimeError) raised while its disk had no
    space left: the full disk it was."""

    def __init__(self, cause: BaseException):
        super().__init__(errno.ENOSPC, f"No space left on device ({cause})")


def _no_space_left(folder: Path) -> bool:
    """True when the file system holding `folder` has (almost) no space left for this user: a writer
    that hides the errno (torch, rerun) failed for it."""
    try:
        st = os.statvfs(folder)
    except OSError:
        return False
    return st.f_bavail * st.f_frsize < 64 * 1024 or (st.f_files > 0 and st.f_favail == 0)


def write_error(exc: BaseException, path, what: str = "output") -> CraneError:
    """One sentence for a failed write of `path` (DiskFullError for a full disk)."""
    if is_disk_full(exc):
        return DiskFullError(f"the disk holding {path} is full: the {what} was not written (nothing "
                             "half-written was left); free some space or write elsewhere")
    reason = getattr(exc, "strerror", None) or str(exc) or type(exc).__name__
    return OutputPathError(f"cannot write the {what} {path}: {reason}")


def _resolved(path) -> Path:
    return Path(os.path.realpath(os.path.abspath(os.fspath(path))))


def same_file(a, b) -> bool:
    """True when the two paths name one file or folder: links resolved, hard links compared by inode."""
    ra, rb = _resolved(a), _resolved(b)
    if ra == rb:
        return True
    try:
        return os.path.samefile(ra, rb)
    except OSError:
        return False


def _inside(child: Path, parent: Path) -> bool:
    try:
        child.relative_to(parent)
    except ValueError:
        return False
    return True


def check_output(path, *, inputs: Iterable = (), force: bool = False, what: str = "output",
                 others: Iterable = (), directory: bool = False, make_folders: bool = False) -> Path:
    """The output path, checked (OutputPathError otherwise): not empty, not one of `inputs` (files or
    folders, compared with links resolved), not inside an input folder nor holding one, not one of the
    command's `others` outputs, its folder exists (with `make_folders`: or can be made, the writer
    making it) and is writable, and it does not exist unless `force` (then it must be of the kind
    written: a file, or a folder when `directory`). Nothing is created."""
    raw = os.fspath(path) if path is not None else ""
    if not str(raw).strip():
        raise OutputPathError(f"the {what} path is empty")
    if "\x00" in str(raw):
        raise OutputPathError(f"the {what} path {raw!r} contains a NUL character")
    out = Path(raw)
    check_distinct(out, inputs=inputs, others=others, what=what, directory=directory)
    # the folder the new file is renamed into (the link's own, when the output is a link)
    _check_folder(out, Path(os.path.abspath(out)).parent, what, make_folders)
    if os.path.lexists(out):
        if not force:
            raise OutputPathError(f"the {what} {out} already exists; pass `force` to replace it")
        if directory and not out.is_dir():
            raise OutputPathError(f"the {what} {out} exists and is not a folder")
        if not directory and out.is_dir():
            raise OutputPathError(f"the {what} {out} is a folder, not a file")
    return out


def check_distinct(path, *, inputs: Iterable = (), others: Iterable = (), what: str = "output",
                   directory: bool = False) -> Path:
    """The part of check_output that compares paths (OutputPathError otherwise): `path` is none of
    `inputs`, not inside an input folder, does not hold an input when it is a folder (`directory`), and
    is none of the command's `others` outputs; links and `..` resolved, hard links by inode."""
    out = Path(path)
    real = _resolved(out)
    for inp in inputs:
        if inp is None:
            continue
        rin = _resolved(inp)
        if same_file(out, inp):
            raise OutputPathError(f"the {what} {out} is the same file as the input {inp}; "
                                  "write it elsewhere (an output never replaces an input)")
        if Path(inp).is_dir() and _inside(real, rin):
            raise OutputPathError(f"the {what} {out} lies inside the input {inp}; write it elsewhere")
        if directory and _inside(rin, real):
            raise OutputPathError(f"the {what} {out} holds the input {inp}; write it elsewhere")
    for other in others:
        if other is not None and same_file(out, other):
            raise OutputPathError(f"the {what} {out} is also another output of this command; give "
                                  "each output its own path")
    return out


def _check_folder(out: Path, parent: Path, what: str, make_folders: bool) -> None:
    """The output's folder exists (or, with `make_folders`, its nearest existing ancestor is a folder)
    and can be written to."""
    existing = parent
    while not os.path.lexists(existing) and existing != existing.parent:
        existing = existing.parent
    if os.path.lexists(existing) and not existing.is_dir():
        raise OutputPathError(f"cannot write {out}: {existing} is a file, not a folder")
    if existing != parent and not make_folders:
        raise OutputPathError(f"cannot write the {what} {out}: the folder {parent} does not exist")
    if not os.access(existing, os.W_OK | os.X_OK):
        raise OutputPathError(f"cannot write the {what} {out}: the folder {existing} is not writable "
                              "(read-only or forbidden)")


def _mode(target: Path, full: int) -> int:
    """The permissions a new output gets: those of the file it replaces, else `full` less the umask."""
    try:
        return os.stat(target).st_mode & 0o7777
    except OSError:
        return full & ~_umask()


def _umask() -> int:
    """The process's umask, read without changing it where Linux shows it (os.umask sets it for every
    thread meanwhile)."""
    with contextlib.suppress(OSError, ValueError):
        with open("/proc/self/status") as fh:
            for line in fh:
                if line.startswith("Umask:"):
                    return int(line.split()[1], 8)
    umask = os.umask(0o022)
    os.umask(umask)
    return umask


def _fsync_dir(folder: Path) -> None:
    with contextlib.suppress(OSError):
        fd = os.open(folder, os.O_RDONLY)
        try:
            os.fsync(fd)
        finally:
            os.close(fd)


@contextlib.contextmanager
def atomic_path(path, what: str = "output") -> Iterator[Path]:
    """Yield a temporary path in the target's folder; on a clean exit it is flushed and renamed onto
    `path` (which then holds the whole new file), on any exception it is removed and `path` is left
    as it was. OSErrors become one sentence (DiskFullError for a full disk)."""
    target = Path(path)
    folder = target.parent if str(target.parent) else Path(".")
    try:
        folder.mkdir(parents=True, exist_ok=True)  # missing folders that check_output allowed
        # the target's suffix kept last: writers that infer the format from it (savefig, np.savez) work
        fd, tmp_name = tempfile.mkstemp(prefix=f".{target.name}.", suffix=f".part{target.suffix}",
                                        dir=folder)
        os.close(fd)
    except OSError as exc:
        raise write_error(exc, target, what) from None
    tmp = Path(tmp_name)
    try:
        yield tmp
        with open(tmp, "rb+") as fh:
            os.fsync(fh.fileno())
        os.chmod(tmp, _mode(target, 0o666))  # mkstemp's file is private
        os.replace(tmp, target)
        _fsync_dir(folder)
    except BaseException as exc:
        with contextlib.suppress(OSError):
            tmp.unlink()
        _raise_write_error(exc, target, what, folder)
        raise


def _raise_write_error(exc: BaseException, target: Path, what: str, folder: Path) -> None:
    """Raise the one sentence for a failed write of `target` (an OSError, or a writer's own error that
    hides a full disk); return for anything else, which the caller re-raises as it is."""
    if isinstance(exc, OSError):
        raise write_error(exc, target, what) from None
    if isinstance(exc, Exception) and not isinstance(exc, CraneError) and (
            is_disk_full(exc) or _no_space_left(folder)):
        raise write_error(_HiddenDiskFull(exc), target, what) from None


def write_bytes_atomic(path, data: bytes, what: str = "output") -> Path:
    with atomic_path(path, what) as tmp:
        tmp.write_bytes(data)
    return Path(path)


def write_text_atomic(path, text: str, what: str = "output", encoding: str = "utf-8") -> Path:
    return write_bytes_atomic(path, text.encode(encoding), what)


@contextlib.contextmanager
def atomic_directory(path, what: str = "output folder") -> Iterator[Path]:
    """Yield a new temporary folder beside `path`; on a clean exit it replaces `path` (an existing
    folder there is moved aside first and removed after the new one is in place), on any exception it
    is removed and `path` is left as it was."""
    target = Path(path)
    folder = target.parent if str(target.parent) else Path(".")
    try:
        folder.mkdir(parents=True, exist_ok=True)
        tmp = Path(tempfile.mkdtemp(prefix=f".{target.name}.", suffix=".part", dir=folder))
    except OSError as exc:
        raise write_error(exc, target, what) from None
    old: Path | None = None
    try:
        yield tmp
        for f in tmp.rglob("*"):
            if f.is_file():
                with open(f, "rb+") as fh:
                    os.fsync(fh.fileno())
        os.chmod(tmp, _mode(target, 0o777))  # mkdtemp's folder is private
        if os.path.lexists(target):
            old = Path(tempfile.mkdtemp(prefix=f".{target.name}.", suffix=".old", dir=folder))
            os.rmdir(old)
            os.replace(target, old)
        os.replace(tmp, target)
        _fsync_dir(folder)
    except BaseException as exc:
        if old is not None and not os.path.lexists(target):
            with contextlib.suppress(OSError):
                os.replace(old, target)
            old = None
        shutil.rmtree(tmp, ignore_errors=True)
        _raise_write_error(exc, target, what, folder)
        raise
    finally:
        if old is not None:
            if old.is_dir() and not old.is_symlink():
                shutil.rmtree(old, ignore_errors=True)
            else:
                with contextlib.suppress(OSError):
                    old.unlink()
