"""The recorder's deferred writes (collect/recorder.py, `deferred_writes`): a paced loop's full chunk is
copied aside and written one dataset at a time between cycles (`write_pending`), so no chunk is
written inside a cycle; the file ends up the same as one written at once, and a crash between two of
a chunk's datasets (each flushed on its own, the file never flushed as a whole) leaves a file that
opens and that `crane-collect recover` restores."""

from __future__ import annotations

import signal
import subprocess
import sys
from pathlib import Path

import h5py
import numpy as np

from collect.recorder import SessionRecorder
from collect.recovery import recover_session
from collect.run_options import RunOptions
from collect.runner import run_session

ROOT = Path(__file__).parents[1]
NAMES = ["joint1", "joint2", "joint4"]
RATE = 100.0  # 50-row chunks


def _rows(rec: SessionRecorder, start: int, n: int) -> None:
    for k in range(start, start + n):
        q = np.array([0.01 * k, -0.02 * k, 0.5])
        rec.append({"leader/t": k / RATE, "leader/q": q, "follower/t": k / RATE, "follower/q": -q,
                    "follower/tau_res": q * 3, "timing/cycle_start": k / RATE, "timing/overrun": k % 7 == 0})


def _contents(path: Path) -> dict:
    out = {}
    with h5py.File(path, "r") as f:
        f.visititems(lambda name, obj: out.__setitem__(name, obj[()]) if isinstance(obj, h5py.Dataset)
                     and not name.startswith("events") else None)
    return out


class StepClock:
    """A clock that moves 1 ms every time it is read."""

    def __init__(self):
        self.t = 0.0

    def __call__(self) -> float:
        self.t += 1e-3
        return self.t


def test_a_full_chunk_waits_for_write_pending_and_the_file_equals_one_written_at_once(tmp_path):
    plain = SessionRecorder(tmp_path / "plain.h5", joint_names=NAMES, rate_hz=RATE, source="sim")
    deferred = SessionRecorder(tmp_path / "deferred.h5", joint_names=NAMES, rate_hz=RATE, source="sim",
                               deferred_writes=True)
    n_datasets = len(deferred._ds)
    for rec in (plain, deferred):
        _rows(rec, 0, 50)  # one full chunk
    assert plain.pending_writes == 0 and plain._ds["follower/q"].shape[0] == 50
    # the deferred recorder wrote nothing yet: every dataset is pending
    assert deferred.pending_writes == n_datasets
    assert all(ds.shape[0] == 0 for ds in deferred._ds.values())
    assert deferred.rows == 50
    # a deadline already past: nothing is written
    assert deferred.write_pending(deadline=-1.0, clock=lambda: 0.0) == n_datasets
    # a deadline a few steps away: some written, not all
    clock = StepClock()
    left = deferred.write_pending(deadline=clock.t + 8e-3, clock=clock)
    assert 0 < left < n_datasets
    written = sum(ds.shape[0] == 50 for ds in deferred._ds.values())
    assert written == n_datasets - left
    # the rows given later land in the right place while earlier ones are still pending
    for rec in (plain, deferred):
        _rows(rec, 50, 30)
    assert deferred.pending_writes == left
    assert deferred.write_pending() == 0
    for rec in (plain, deferred):
        _rows(rec, 80, 50)  # a second chunk due (with 30 rows of the third buffered)
    assert deferred.pending_writes == n_datasets
    plain.close()
    deferred.close()  # writes what is pending and buffered
    a, b = _contents(tmp_path / "plain.h5"), _contents(tmp_path / "deferred.h5")
    assert a.keys() == b.keys()
    for key in a:
        if key.startswith("timing/") and key != "timing/overrun" and key != "timing/cycle_start":
            continue
        np.testing.assert_array_equal(a[key], b[key], err_msg=key)
    assert b["follower/q"].shape[0] == 130


def test_a_chunk_due_while_the_last_is_pending_writes_the_last_first(tmp_path):
    rec = SessionRecorder(tmp_path / "s.h5", joint_names=NAMES, rate_hz=RATE, source="sim",
                          deferred_writes=True)
    _rows(rec, 0, 50)
    _rows(rec, 50, 50)  # nobody called write_pending: the first chunk is written before the second waits
    assert rec._ds["leader/q"].shape[0] == 50
    assert rec.pending_writes == len(rec._ds)
    rec.close()
    with h5py.File(tmp_path / "s.h5", "r") as f:
        np.testing.assert_array_equal(f["leader/t"][()], np.arange(100) / RATE)


WRITER = """
import sys, time
import numpy as np
from collect.recorder import SessionRecorder
rec = SessionRecorder(sys.argv[1], joint_names=["joint1", "joint2", "joint4"], rate_hz=100, source="sim",
                      deferred_writes=True)
for k in range(100):
    q = np.array([0.01 * k, -0.02 * k, 0.5])
    rec.append({"leader/t": k / 100, "leader/q": q, "follower/t": k / 100, "follower/q": -q,
                "timing/cycle_start": k / 100})
steps = iter(range(1000))
rec.write_pending(deadline=6.5, clock=lambda: float(next(steps)))  # a few of the second chunk's datasets
print("ready", rec.pending_writes, flush=True)
time.sleep(300)
"""


def test_a_crash_between_a_chunks_datasets_leaves_a_file_recover_restores(tmp_path):
    path = tmp_path / "crash.h5"
    proc = subprocess.Popen([sys.executable, "-c", WRITER, str(path)], stdout=subprocess.PIPE,
                            stderr=subprocess.PIPE, text=True, cwd=ROOT)
    try:
        line = proc.stdout.readline().split()
        assert line[:1] == ["ready"], proc.stderr.read()
        assert int(line[1]) > 0  # the crash comes with writes still pending
    finally:
        proc.send_signal(signal.SIGKILL)
        proc.wait()
    with h5py.File(path, "r", swmr=True) as f:
        lengths = {d.shape[0] for d in (f["leader/q"], f["follower/q"], f["timing/period"])}
    assert lengths == {50, 100} or lengths == {50} or lengths == {100}
    report = recover_session(path, tmp_path / "recovered.h5")
    assert report.rows in (50, 100)
    with h5py.File(tmp_path / "recovered.h5", "r") as f:
        assert f["leader/t"].shape[0] == report.rows
        np.testing.assert_array_equal(f["leader/t"][()], np.arange(report.rows) / 100)


CONFIG = """
[loop]
status_hz = 0
[realtime]
scheduling = "off"
"""


def test_a_paced_run_writes_its_chunks_between_cycles(tmp_path, monkeypatch):
    """In a paced run (`--sim --realtime`) the row that fills a chunk leaves every dataset's write
    pending; the loop writes them after its cycles, with the deadline of the next cycle; the session
    holds every row, and a lockstep run defers nothing."""
    after_row, deadlines = [], []
    row_added, write_pending = SessionRecorder._row_added, SessionRecorder.write_pending

    def spy_row(self, k):  # every appended row ends here, whichever way it was appended
        row_added(self, k)
        after_row.append(self.pending_writes)

    def spy_write(self, deadline=None, clock=None):
        deadlines.append(deadline)
        return write_pending(self, deadline, clock)

    monkeypatch.setattr(SessionRecorder, "_row_added", spy_row)
    monkeypatch.setattr(SessionRecorder, "write_pending", spy_write)
    cfg = tmp_path / "rt.toml"
    cfg.write_text(CONFIG)
    out = tmp_path / "rt.h5"
    run_session(RunOptions(output=out, sim=True, realtime=True, duration=1.2, seed=5, status=False,
                           config=cfg))
    n_datasets = 2 * 10 + 6
    assert len(after_row) == 600
    # rows 250 and 500 fill the 0.5 s chunks: all of each is pending when its row is in
    assert after_row[249] == n_datasets and after_row[499] == n_datasets
    assert any(d is not None for d in deadlines)  # the loop's calls, with its next deadline
    with h5py.File(out, "r") as f:
        assert f.attrs["complete"]
        t = f["follower/t"][()]
        assert t.shape[0] == 600 and np.isfinite(t).all() and np.isfinite(f["leader/q"][()]).all()

    after_row.clear()
    deadlines.clear()
    run_session(RunOptions(output=tmp_path / "ls.h5", sim=True, duration=0.6, seed=5, status=False,
                           config=cfg))
    assert len(after_row) == 300 and max(after_row) == 0 and not deadlines
