"""Where simulated arms announce their serial links, so `crane-collect ports` can list them beside the
U2D2 adapters.

`crane-collect sim-serve` writes one small JSON file per link into the user's runtime directory
(`$XDG_RUNTIME_DIR/crane-x7/links`, else `/tmp/crane-x7-<uid>/links`; `CRANE_X7_RUNTIME_DIR` overrides
the root) and removes it on exit. A file whose process is gone, or whose link no longer leads to a
pseudo-terminal (the server was killed with SIGKILL, the machine rebooted), is stale: `live_links`
ignores it and removes it.

    entry = announce(SimLink(link="/tmp/leader", pty="/dev/pts/3", arm="leader", plant="crane-x7",
                             clock="wall", hand=True, pid=os.getpid()))
    ...
    withdraw(entry)
"""

from __future__ import annotations

import hashlib
import json
import os
import tempfile
import time
from dataclasses import asdict, dataclass, field
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


def registry_dir() -> Path:
    """The folder of link files (not created)."""
    root = os.environ.get(RUNTIME_ENV) or os.environ.get("XDG_RUNTIME_DIR")
    if root:
        return Path(root) / "crane-x7" / "links"
    return Path(tempfile.gettempdir()) / f"crane-x7-{os.getuid()}" / "links"


def _entry_path(link: SimLink) -> Path:
    tag = hashlib.sha1(os.path.abspath(link.link).encode()).hexdigest()[:12]
    return registry_dir() / f"{link.pid}-{tag}.json"


def announce(link: SimLink) -> Path | None:
    """Write the link's file (atomically); its path, or None when the runtime directory is not writable
    (announcing is a convenience: serving goes on without it)."""
    path = _entry_path(link)
    try:
        path.parent.mkdir(parents=True, exist_ok=True, mode=0o700)
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
    except OSError:
        return False


def live_links(*, clean: bool = True) -> list[SimLink]:
    """The announced links that still lead to a live simulator, sorted by link path; unreadable and
    stale files are skipped (and removed when `clean`)."""
    folder = registry_dir()
    try:
        files = sorted(folder.glob("*.json"))
    except OSError:
        return []
    found = []
    for path in files:
        try:
            entry = SimLink(**json.loads(path.read_text()))
        except (OSError, ValueError, TypeError):
            entry = None
        if entry is not None and _is_live(entry):
            found.append(entry)
        elif clean:
            withdraw(path)
    return sorted(found, key=lambda e: e.link)
