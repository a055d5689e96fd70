"""Shared test helper: watch a crane-collect process's session file grow (SWMR reads)."""

from __future__ import annotations

import time
from pathlib import Path

import h5py


def recorded_rows(out: Path) -> int:
    """Rows recorded so far in a session file being written (0 while it does not exist yet)."""
    try:
        with h5py.File(out, "r", libver="latest", swmr=True) as f:
            return f["follower/t"].shape[0]
    except (OSError, KeyError):
        return 0


def wait_for_rows(proc, out: Path, rows: int, timeout: float = 60) -> None:
    """Wait until the running process `proc` has recorded `rows` rows; fail if it exits or times out."""
    end = time.monotonic() + timeout
    while recorded_rows(out) < rows:
        assert proc.poll() is None, proc.communicate()
        assert time.monotonic() < end, "the run did not start recording"
        time.sleep(0.1)
