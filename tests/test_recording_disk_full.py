"""A full disk while recording is a clean stop: both arms stopped (torque off), one sentence and exit 3,
no crash; the file keeps every chunk written before, stays in SWMR-write state and `crane-collect
recover -o` elsewhere makes it an ordinary file with those rows. A full disk when the session file is
made leaves no file. The faults are raised at the h5py layer; where a tmpfs can be mounted (a user
namespace), a real full file system is tried too."""

from __future__ import annotations

import errno
import hashlib
import shutil
import subprocess
import sys
from pathlib import Path

import h5py
import pytest

from collect import runner
from collect.recorder import SessionRecorder
from collect.recovery import recover_session
from collect.runner import RunOptions, run_session
from crane_io.output_files import DiskFullError
from tests.recording import TEST_CONFIG, torque_off_everywhere

ROOT = Path(__file__).parents[1]
CHUNK = 250  # rows of one chunk at 500 Hz (0.5 s)
DATASETS = 26  # per-cycle datasets written per chunk


HDF5_FULL = ("Unable to synchronously flush file (file write failed: errno = 28, error message = "
             "'No space left on device', total write size = 1695)")


@pytest.fixture
def cfg(tmp_path):
    p = tmp_path / "test.toml"
    p.write_text(TEST_CONFIG)
    return p


def _run(tmp_path, cfg, monkeypatch, **options):
    """run_session raising DiskFullError: (the error, the simulated arms)."""
    seen = {}
    make = runner.make_sim_arms

    def make_sim_arms(*args):
        seen["sims"] = make(*args)
        return seen["sims"]

    monkeypatch.setattr(runner, "make_sim_arms", make_sim_arms)
    opts = RunOptions(**{**dict(output=tmp_path / "s.h5", sim=True, plant="simple", duration=4.0, config=cfg,
                                seed=5, status=False), **options})
    with pytest.raises(DiskFullError) as err:
        run_session(opts)
    return err.value, seen["sims"]


def _fail_dataset_write(monkeypatch, at: int) -> None:
    """The `at`-th dataset write of the recorder (26 per chunk) fails as a full disk does."""
    original = SessionRecorder._write_rows
    calls = [0]

    def write(self, *args):
        calls[0] += 1
        if calls[0] > at:
            raise OSError(errno.ENOSPC, "No space left on device")
        return original(self, *args)

    monkeypatch.setattr(SessionRecorder, "_write_rows", write)


def _fail_file_flush(monkeypatch, path: Path, at: int) -> None:
    """The `at`-th flush of the session file (after the one that makes it) fails as HDF5 reports it."""
    original = h5py.File.flush
    calls = [0]

    def flush(self):
        if Path(self.filename) == path:
            calls[0] += 1
            if calls[0] > at:
                raise RuntimeError(HDF5_FULL)
        return original(self)

    monkeypatch.setattr(h5py.File, "flush", flush)


def _digest(path: Path) -> str:
    return hashlib.sha256(path.read_bytes()).hexdigest()


@pytest.mark.parametrize("fault,chunks",
                         [("dataset", 2), ("mid-chunk", 4), ("file-flush", 6), ("file-flush", 8)],
                         ids=["dataset", "mid-chunk", "file-flush", "at-close"])
def test_a_full_disk_while_recording_stops_cleanly_and_the_file_is_recoverable(tmp_path, cfg, monkeypatch,
                                                                                fault, chunks):
    out = tmp_path / "s.h5"
    if fault == "dataset":
        _fail_dataset_write(monkeypatch, chunks * DATASETS)
    elif fault == "mid-chunk":
        _fail_dataset_write(monkeypatch, chunks * DATASETS + 10)
    else:
        _fail_file_flush(monkeypatch, out.resolve(), chunks + 1)  # the file's own flush comes first
    err, sims = _run(tmp_path, cfg, monkeypatch)
    msg = str(err)
    assert err.exit_code == 3 and "\n" not in msg
    assert msg.startswith(f"the disk holding {out} is full: {chunks * CHUNK / 500:.1f} s were recorded")
    assert f"crane-collect recover {out} -o FILE" in msg
    assert torque_off_everywhere(sims)
    monkeypatch.undo()
    with h5py.File(out, "r", libver="latest", swmr=True) as f:  # left as a crashed recording
        assert not f.attrs["complete"]
        assert f["follower/t"].shape[0] >= chunks * CHUNK
    before = _digest(out)
    elsewhere = tmp_path / "other"
    elsewhere.mkdir()
    r = recover_session(out, elsewhere / "s.h5")
    assert r.rows == chunks * CHUNK and r.backup is None
    assert _digest(out) == before  # the input was only read
    with h5py.File(elsewhere / "s.h5", "r") as f:
        assert f["follower/t"].shape == (chunks * CHUNK,) and not f.attrs["complete"]
        assert f["follower/t"][-1] == pytest.approx((chunks * CHUNK - 1) / 500)


def test_a_full_disk_when_the_session_file_is_made_leaves_no_file_and_torque_off(tmp_path, cfg,
                                                                                   monkeypatch):
    out = tmp_path / "s.h5"
    _fail_file_flush(monkeypatch, out.resolve(), 0)
    err, sims = _run(tmp_path, cfg, monkeypatch)
    assert err.exit_code == 3 and "could not be created" in str(err) and "\n" not in str(err)
    assert torque_off_everywhere(sims)
    assert not out.exists() and list(tmp_path.iterdir()) == [tmp_path / "test.toml"]


def test_a_full_disk_before_the_first_chunk_leaves_no_file_and_close_raises_nothing_new(tmp_path,
                                                                                         monkeypatch):
    p = tmp_path / "s.h5"
    rec = SessionRecorder(p, joint_names=["joint1"], rate_hz=100, source="sim", lockstep=True)
    rec.event(0.0, "start", "aligned")
    _fail_dataset_write(monkeypatch, 0)
    with pytest.raises(DiskFullError, match="before the first rows were recorded: no file was left"):
        for k in range(60):
            rec.append({"follower/t": k / 100, "leader/t": k / 100})
    rec.event(0.6, "end", "dropped")  # after the stop events are dropped
    rec.close(attrs={"end_reason": "duration"})
    assert rec.closed and isinstance(rec.failed, DiskFullError) and not p.exists()
    with pytest.raises(DiskFullError):
        rec.flush()


def test_a_full_disk_under_the_truth_trace_stops_the_run_and_removes_the_trace(tmp_path, cfg, monkeypatch):
    trace = tmp_path / "truth.h5"
    _fail_file_flush(monkeypatch, trace.resolve(), 1)  # its second block (rows 1000..1999)
    err, sims = _run(tmp_path, cfg, monkeypatch, truth_trace=trace, plant="crane-x7")
    assert err.exit_code == 3 and str(err).startswith(f"the disk holding {trace} is full: the truth trace")
    assert torque_off_everywhere(sims) and not trace.exists()
    monkeypatch.undo()
    with h5py.File(tmp_path / "s.h5", "r") as f:  # the session itself was closed properly
        assert f.attrs["end_reason"] == "error" and f["follower/t"].shape[0] >= 1000


def test_a_full_disk_in_a_deferred_write_stops_the_recording_and_keeps_the_chunks_before(tmp_path,
                                                                                        monkeypatch):
    """The paced loop's deferred writes (one dataset per step): a full disk there is the same clean stop."""
    p = tmp_path / "s.h5"
    rec = SessionRecorder(p, joint_names=["joint1"], rate_hz=100, source="hardware", deferred_writes=True,
                          clock=lambda: 0.0)
    _fail_dataset_write(monkeypatch, 2 * DATASETS + 5)
    with pytest.raises(DiskFullError, match=r"is full: 1\.0 s were recorded"):
        for k in range(400):
            rec.append({"follower/t": k / 100, "leader/t": k / 100})
            rec.write_pending(None)
    rec.close()
    monkeypatch.undo()
    r = recover_session(p, tmp_path / "out.h5")
    assert r.rows == 100


REAL_DISK = """
import sys
from collect.recorder import SessionRecorder
from collect.recovery import recover_session
from crane_io.output_files import DiskFullError
path, out = sys.argv[1], sys.argv[2]
rec = SessionRecorder(path, joint_names=[f"joint{i}" for i in range(1, 8)] + ["gripper"], rate_hz=500,
                      source="sim", lockstep=True)
try:
    for k in range(10 ** 6):
        rec.append({"follower/t": k / 500, "leader/t": k / 500, "timing/cycle_start": k / 500,
                    "follower/q": [k * 1e-3] * 8, "leader/q": [k * 2e-3] * 8})
except DiskFullError as exc:
    print("stopped:", exc, flush=True)
rec.close(attrs={"end_reason": "duration"})
r = recover_session(path, out)
print("recovered", r.rows, flush=True)
"""


def _mount_tmpfs_works(folder: Path) -> bool:
    if shutil.which("unshare") is None or not sys.platform.startswith("linux"):
        return False
    try:
        probe = subprocess.run(["unshare", "-rm", "sh", "-c", f"mount -t tmpfs -o size=1m tmpfs '{folder}'"],
                               capture_output=True, timeout=20)
    except (OSError, subprocess.TimeoutExpired):
        return False
    return probe.returncode == 0


def test_a_real_full_file_system_stops_the_recording_without_a_crash(tmp_path):
    disk = tmp_path / "disk"
    disk.mkdir()
    if not _mount_tmpfs_works(disk):
        pytest.skip("no user namespace to mount a small tmpfs in")
    out = tmp_path / "recovered.h5"
    script = f"mount -t tmpfs -o size=1m tmpfs '{disk}' && exec '{sys.executable}' -c \"$0\" \"$1\" \"$2\""
    proc = subprocess.run(["unshare", "-rm", "sh", "-c", script, REAL_DISK, str(disk / "s.h5"), str(out)],
                          capture_output=True, text=True, cwd=ROOT, timeout=120)
    assert proc.returncode == 0, proc.stderr  # no segfault (139), no traceback
    lines = proc.stdout.splitlines()
    assert lines[0].startswith(f"stopped: the disk holding {disk / 's.h5'} is full: ")
    rows = int(lines[1].split()[1])
    assert rows > 0 and rows % CHUNK == 0
    with h5py.File(out, "r") as f:
        assert f["follower/t"].shape == (rows,) and f["follower/t"][-1] == (rows - 1) / 500


def test_a_full_disk_while_compacting_keeps_the_closed_file_as_it_is(tmp_path, monkeypatch):
    p = tmp_path / "s.h5"
    clock = [0.0]
    rec = SessionRecorder(p, joint_names=["joint1"], rate_hz=100, source="hardware", compact_above=0.0,
                          clock=lambda: clock[0])
    for k in range(120):  # a wall-clock flush every 0.9 s rewrites a partly filled chunk
        rec.append({"follower/t": k / 100, "leader/t": k / 100})
        clock[0] += 0.1
    assert rec.waste_bytes > 0
    original = h5py.File.flush

    def flush(self):  # the compact copy's flush (another file in the same folder) finds the disk full
        if Path(self.filename) != p:
            raise RuntimeError(HDF5_FULL)
        return original(self)

    monkeypatch.setattr(h5py.File, "flush", flush)
    rec.close(attrs={"end_reason": "duration"})
    monkeypatch.undo()
    assert not rec.compacted and sorted(tmp_path.iterdir()) == [p]
    with h5py.File(p, "r") as f:
        assert f.attrs["complete"] and f["follower/t"].shape == (120,)


def test_a_detached_file_is_never_written_again_and_closes_cleanly(tmp_path):
    from collect.session_detach import detach

    p = tmp_path / "a.h5"
    f = h5py.File(p, "w", libver="latest")
    ds = f.create_dataset("x", shape=(0,), maxshape=(None,), chunks=(10,), dtype="f8")
    f.swmr_mode = True
    ds.resize(10, axis=0)
    ds[:] = 1.0
    f.flush()
    before = _digest(p)
    assert detach(f)
    ds.resize(100, axis=0)
    ds[10:] = 2.0
    f.flush()
    assert ds[95] == 2.0  # HDF5 goes on in memory
    f.close()
    assert _digest(p) == before
    with h5py.File(p, "r", libver="latest", swmr=True) as g:
        assert g["x"].shape == (10,) and g["x"][9] == 1.0
