"""Where simulated arms announce their serial links, so `crane-collect ports` can list them beside the
U2D2 adapters.

`crane-collect sim-serve` writes one small JSON file per link into the user's runtime directory
(`$XDG_RUNTIME_DIR/crane-x7/links`, else `/tmp/crane-x7-<uid>/links`; `CRANE_X7_RUNTIME_DIR` overrides
the root) and removes it on exit. A file whose process is gone, or whose link no longer leads to a
pseudo-terminal (the server was killed with SIGKILL, the machine rebooted), is stale, and one that is
not a valid entry is malformed: `live_links` ignores both and removes them. Entries are read without
blocking and without following links, regular files only; the folders must be this user's and
writable by no one else (`registry_problem`), else the registry is ignored.

    entry = announce(SimLink(link="/tmp/leader", pty="/dev/pts/3", arm="leader", plant="crane-x7",
                             clock="wall", hand=True, pid=os.getpid()))
    ...
    withdraw(entry)
"""

from __future__ import annotations

import hashlib
import json
import math
import os
import stat
import tempfile
import time
from dataclasses import asdict, dataclass, field, fields
from pathlib import Path

RUNTIME_ENV = "CRANE_X7_RUNTIME_DIR"


@dataclass(frozen=True)
class SimLink:
    link: str  # the path a client opens, e.g. /tmp/crane_x7_leader
    pty: str  # the pseudo-terminal it links to, e.g. /dev/pts/3
    arm: str  # "leader", "follower" or "arm" (a single sim-serve)
    plant: str  # the plant preset or TOML behind the servos
    clock: str  # "wall" or "lockstep"
    hand: bool  # a simulated operator's hand is on this arm
    pid: int  # the serving process
    started: float = field(default_factory=time.time)  # Unix time the link was announced


ARMS = ("leader", "follower", "arm")
CLOCKS = ("wall", "lockstep")
MAX_PID = 1 << 22  # Linux's largest pid_max
MAX_ENTRY_BYTES = 1 << 16  # an entry is a few hundred bytes


def registry_dir() -> Path:
    """The folder of link files (not created)."""
    return _root() / "links"


def _root() -> Path:
    root = os.environ.get(RUNTIME_ENV) or os.environ.get("XDG_RUNTIME_DIR")
    if root:
        return Path(root) / "crane-x7"
    return Path(tempfile.gettempdir()) / f"crane-x7-{os.getuid()}"


def registry_problem() -> str | None:
    """Why the registry's folders cannot be trusted (one sentence), or None: each of them that exists
    must be a real folder (not a link) owned by this user and writable by no one else, since another
    user could otherwise plant entries (a shared /tmp)."""
    for folder in (_root(), registry_dir()):
        try:
            st = os.lstat(folder)
        except FileNotFoundError:
            return None
        except OSError as exc:
            return f"the simulated-link folder {folder} cannot be checked ({exc.strerror or exc}); ignored"
        if not stat.S_ISDIR(st.st_mode):
            return f"the simulated-link folder {folder} is not a folder (a link or a file); ignored"
        if st.st_uid != os.getuid():
            return f"the simulated-link folder {folder} belongs to another user; ignored"
        if st.st_mode & 0o022:
            return f"the simulated-link folder {folder} is writable by other users; ignored"
    return None


def _entry_path(link: SimLink) -> Path:
    tag = hashlib.sha1(os.path.abspath(link.link).encode()).hexdigest()[:12]
    return registry_dir() / f"{link.pid}-{tag}.json"


def announce(link: SimLink) -> Path | None:
    """Write the link's file (atomically); its path, or None when the runtime directory is not writable
    or cannot be trusted (registry_problem; announcing is a convenience: serving goes on without it)."""
    path = _entry_path(link)
    try:
        _root().mkdir(parents=True, exist_ok=True, mode=0o700)  # each folder of its own: no one else's
        path.parent.mkdir(exist_ok=True, mode=0o700)
        if registry_problem() is not None:
            return None
        tmp = path.with_suffix(".tmp")
        tmp.write_text(json.dumps(asdict(link)))
        os.replace(tmp, path)
    except OSError:
        return None
    return path


def withdraw(path: Path | None) -> None:
    """Remove an announced link's file (nothing if it is gone already)."""
    if path is None:
        return
    try:
        path.unlink()
    except OSError:  # gone already, or not ours to remove: nothing to do
        pass


def _process_alive(pid: int) -> bool:
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except PermissionError:  # alive, someone else's
        return True
    return True


def _is_live(entry: SimLink) -> bool:
    if not _process_alive(entry.pid):
        return False
    try:
        return os.path.realpath(entry.link) == entry.pty and Path(entry.pty).exists()
    except (OSError, ValueError):
        return False


def _text(value) -> bool:
    return isinstance(value, str) and 0 < len(value) <= 4096 and "\0" not in value


def parse_entry(data) -> SimLink | None:
    """The SimLink an entry's JSON document describes, or None when it is not one: every field of its
    type (a pid 1 .. MAX_PID, an arm and a clock of their names, a finite start time) and nothing else."""
    if not isinstance(data, dict) or set(data) != {f.name for f in fields(SimLink)}:
        return None
    pid, started = data["pid"], data["started"]
    ok = (all(_text(data[k]) for k in ("link", "pty", "plant")) and data["arm"] in ARMS
          and data["clock"] in CLOCKS and isinstance(data["hand"], bool)
          and isinstance(pid, int) and not isinstance(pid, bool) and 0 < pid <= MAX_PID
          and isinstance(started, (int, float)) and not isinstance(started, bool) and math.isfinite(started))
    return SimLink(**data) if ok else None


def _read_entry(path: Path) -> tuple[bool, SimLink | None]:
    """(whether `path` is a regular file, the entry in it or None). Opened without following a link and
    without blocking (a FIFO is never waited on), only read when it is a regular file of sane size."""
    try:
        fd = os.open(path, os.O_RDONLY | os.O_NONBLOCK | os.O_NOFOLLOW | getattr(os, "O_CLOEXEC", 0))
    except OSError:
        return False, None
    try:
        st = os.fstat(fd)
        if not stat.S_ISREG(st.st_mode):
            return False, None
        if st.st_size > MAX_ENTRY_BYTES:
            return True, None
        return True, parse_entry(json.loads(os.read(fd, MAX_ENTRY_BYTES)))
    except (OSError, ValueError, RecursionError):
        return True, None
    finally:
        os.close(fd)


def live_links(*, clean: bool = True) -> list[SimLink]:
    """The announced links that still lead to a live simulator, sorted by link path. Stale and malformed
    entries are skipped, and removed when `clean` (only regular files in the registry's own folder);
    anything else there (a FIFO, a link) is skipped and left alone. A folder registry_problem() refuses
    gives no links."""
    if registry_problem() is not None:
        return []
    folder = registry_dir()
    try:
        files = sorted(folder.glob("*.json"))
    except OSError:
        return []
    found = []
    for path in files:
        regular, entry = _read_entry(path)
        if entry is not None and _is_live(entry):
            found.append(entry)
        elif clean and regular:
            withdraw(path)
    return sorted(found, key=lambda e: e.link)
