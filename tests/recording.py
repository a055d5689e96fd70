"""Shared test helpers for collection runs: watch a crane-collect process's session file grow (SWMR
reads); check that every simulated servo was left with torque off."""

from __future__ import annotations

import time
from pathlib import Path

import h5py

# a quiet in-process run with a short alignment (the simple plant starts at 0)
TEST_CONFIG = """
[loop]
status_hz = 0
status_log_s = 10
[operator.start_deg]
joint2 = 0.0
joint4 = -20.0
"""



def recorded_rows(out: Path) -> int:
    """Rows recorded so far in a session file being written (0 while it does not exist yet)."""
    try:
        with h5py.File(out, "r", libver="latest", swmr=True) as f:
            return f["follower/t"].shape[0]
    except (OSError, KeyError):
        return 0


def complete_rows(out: Path) -> int:
    """Rows that every per-cycle dataset of a session file being written holds so far (SWMR read). The
    recorder extends its datasets one after another, so a reader can see `follower/t` a chunk ahead of
    the others: a crash then keeps only the rows all of them hold (crane-collect recover)."""
    from collect.session_copy import row_datasets

    try:
        with h5py.File(out, "r", libver="latest", swmr=True) as f:
            data = row_datasets(f)
            return min(d.shape[0] for d in data) if data else 0
    except (OSError, KeyError):
        return 0


def wait_for_rows(proc, out: Path, rows: int, timeout: float = 900) -> None:
    """Wait until the running process `proc` has recorded `rows` rows; fail if it exits or times out.
    The timeout only keeps a hung run from holding the suite: a run that starts slowly on a loaded
    machine (its imports and start-up can take minutes) is still waited for."""
    end = time.monotonic() + timeout
    while recorded_rows(out) < rows:
        assert proc.poll() is None, proc.communicate()
        assert time.monotonic() < end, "the run did not start recording"
        time.sleep(0.1)


def torque_off_everywhere(sims: dict, min_servos: int = 16) -> bool:
    """Torque off on every simulated servo of `sims` (arm name -> SimulatedArm) still on the bus, and at
    least `min_servos` of them there (a vanished servo cannot be reached; its Bus Watchdog stops it)."""
    servos = [s for sim in sims.values() for s in sim.chain.servos.values() if s.on_bus]
    return len(servos) >= min_servos and all(s.read_register("torque_enable") == 0 for s in servos)
