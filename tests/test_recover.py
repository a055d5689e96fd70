"""`crane-collect recover`: a session whose writer was SIGKILLed becomes an ordinary HDF5 file with every
complete row; files that need no recovery, or are still being written, are refused in one sentence;
the input is never damaged."""

from __future__ import annotations

import hashlib
import os
import signal
import subprocess
import sys
from pathlib import Path

import h5py
import numpy as np
import pytest
from click.testing import CliRunner

from collect.cli import main
from collect.recorder import SessionRecorder, read_events
from collect.session_lock import SUPPORTED as LOCKS_SUPPORTED
from crane_io.output_files import DiskFullError
from train.data.session import read_session

ROOT = Path(__file__).parents[1]
NAMES = [f"joint{i}" for i in range(1, 8)] + ["gripper"]

# A recorder at 100 Hz in lockstep (50-row chunks): 237 rows appended, 200 of them written; then,
# optionally, a crash in the middle of a flush (datasets extended unevenly, a time never written).
WRITER = """
import sys, time
import numpy as np
from collect.recorder import SessionRecorder
path, torn = sys.argv[1], sys.argv[2] == "torn"
rec = SessionRecorder(path, joint_names=[f"joint{i}" for i in range(1, 8)] + ["gripper"], rate_hz=100,
                      source="sim", lockstep=True, attrs={"seed": 4})
rec.event(0.0, "start", "aligned")
for k in range(237):
    q = np.full(8, 0.001 * k)
    rec.append({"follower/t": k / 100, "follower/q": q, "follower/tau": -q, "leader/t": k / 100,
                "leader/q": q, "timing/cycle_start": k / 90, "timing/overrun": False})
if torn:
    for key, ds in rec._ds.items():
        ds.resize(205, axis=0)
        if key != "follower/t":
            ds[200:205] = rec._buf[key][:5]
    rec._ds["leader/q"].resize(210, axis=0)
    rec._f.flush()
print("ready", flush=True)
time.sleep(300)
"""


def _writer(path: Path, torn: bool = False) -> subprocess.Popen:
    proc = subprocess.Popen([sys.executable, "-c", WRITER, str(path), "torn" if torn else "clean"],
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, cwd=ROOT)
    line = proc.stdout.readline()
    assert line.strip() == "ready", proc.stderr.read()
    return proc


def _crashed(path: Path, torn: bool = False) -> Path:
    proc = _writer(path, torn)
    proc.send_signal(signal.SIGKILL)
    proc.communicate(timeout=30)
    return path


def _digest(path: Path) -> str:
    return hashlib.sha256(path.read_bytes()).hexdigest()


def recover(*args):
    result = CliRunner().invoke(main, ["recover", *[str(a) for a in args]])
    assert "Traceback" not in result.output, result.output
    return result


def test_a_sigkilled_session_becomes_an_ordinary_file_with_every_written_row(tmp_path):
    p = _crashed(tmp_path / "s.h5")
    with pytest.raises(OSError):
        h5py.File(p, "r")  # the crashed state: only SWMR readers open it
    before = _digest(p)
    result = recover(p)
    assert result.exit_code == 0, result.output
    assert "recovered 200 rows" in result.output and "s.h5.crashed" in result.output
    with h5py.File(p, "r") as f:  # plain read, as h5dump and HDFView do
        assert not f.attrs["complete"] and f.attrs["end_reason"] == "crashed"
        assert f.attrs["format"] == "crane-session" and f.attrs["seed"] == 4
        assert list(f.attrs["joint_names"]) == NAMES
        rows = {}
        f.visititems(lambda n, o: rows.__setitem__(n, o.shape[0]) if isinstance(o, h5py.Dataset) else None)
        assert {n: r for n, r in rows.items() if n != "events"} == dict.fromkeys(set(rows) - {"events"}, 200)
        assert np.array_equal(f["follower/t"][()], np.arange(200) / 100)
        assert np.allclose(f["follower/q"][:, 0], 0.001 * np.arange(200))
        # the summary a crashed run never wrote is left out rather than kept as placeholders
        assert "rate_hz_achieved" not in f.attrs and not set(f["timing"].attrs)
        assert [e["kind"] for e in read_events(f)] == ["start", "recovered"]
        assert all(f[n].fletcher32 for n in rows)
    # the original is kept, byte for byte, and crane-train reads the recovered file
    assert _digest(tmp_path / "s.h5.crashed") == before
    assert (tmp_path / "s.h5.crashed").stat().st_mode == p.stat().st_mode  # same permissions
    assert len(read_session(p)) == 200


def test_a_torn_flush_is_cut_to_the_rows_every_dataset_holds(tmp_path):
    """Killed in the middle of a flush: some datasets longer than others, a time never written."""
    p = _crashed(tmp_path / "s.h5", torn=True)
    out = tmp_path / "r.h5"
    result = recover(p, "-o", out)
    assert result.exit_code == 0, result.output
    assert "recovered 200 rows" in result.output and "10 incomplete rows left out" in result.output
    with h5py.File(out, "r") as f:
        lengths = set()
        f.visititems(lambda n, o: lengths.add(o.shape[0])
                     if isinstance(o, h5py.Dataset) and "/" in n else None)
        assert lengths == {200}
        assert np.isfinite(f["follower/t"][()]).all()


def test_with_output_the_input_is_only_read(tmp_path):
    p = _crashed(tmp_path / "s.h5")
    before = _digest(p)
    out = tmp_path / "fixed.h5"
    assert recover(p, "-o", out).exit_code == 0
    assert _digest(p) == before and not (tmp_path / "s.h5.crashed").exists()
    with h5py.File(out, "r") as f:
        assert f["follower/q"].shape == (200, 8)
    again = recover(p, "-o", out)  # never overwrites
    assert again.exit_code == 2 and "already exists" in again.output


@pytest.mark.skipif(not LOCKS_SUPPORTED, reason="needs open-file-description locks (Linux)")
def test_a_session_still_being_written_is_refused_and_left_alone(tmp_path):
    p = tmp_path / "s.h5"
    proc = _writer(p)
    try:
        before = _digest(p)
        result = recover(p)
        assert result.exit_code == 2
        assert result.output.startswith("Error: ") and "still being written" in result.output
        assert result.output.count("\n") == 1
        assert _digest(p) == before and sorted(os.listdir(tmp_path)) == ["s.h5"]
    finally:
        proc.kill()
        proc.communicate(timeout=30)
    assert recover(p).exit_code == 0  # once the writer is gone, it is a crashed session


def test_files_that_need_no_recovery_are_refused_in_one_sentence(tmp_path):
    done = tmp_path / "done.h5"
    SessionRecorder(done, joint_names=NAMES, rate_hz=100, source="sim").close()
    foreign = tmp_path / "foreign.h5"
    with h5py.File(foreign, "w") as f:
        f["x"] = np.arange(3)
    text = tmp_path / "notes.h5"
    text.write_text("not hdf5")
    cases = {done: "ordinary session file already (complete)", foreign: "not a crane-session file",
             text: "not an HDF5 file", tmp_path / "missing.h5": "does not exist", tmp_path: "not a file"}
    for path, words in cases.items():
        before = _digest(path) if path.is_file() else None
        result = recover(path)
        assert result.exit_code == 2, (path, result.output)
        assert words in result.output and result.output.count("\n") == 1, result.output
        if before:
            assert _digest(path) == before
    assert not list(tmp_path.glob("*.crashed")) and not list(tmp_path.glob(".*"))


def test_an_earlier_recoverys_original_is_never_overwritten(tmp_path):
    p = _crashed(tmp_path / "s.h5")
    (tmp_path / "s.h5.crashed").write_bytes(b"kept from before")
    result = recover(p)
    assert result.exit_code == 2 and "s.h5.crashed already exists" in result.output
    assert (tmp_path / "s.h5.crashed").read_bytes() == b"kept from before"


def test_a_failure_midway_leaves_the_input_as_it_was(tmp_path, monkeypatch):
    from collect import session_copy

    p = _crashed(tmp_path / "s.h5")
    before = _digest(p)
    calls = []
    original = session_copy._copy_dataset

    def failing(*args, **kwargs):
        calls.append(1)
        if len(calls) == 5:
            raise OSError(28, "No space left on device")
        return original(*args, **kwargs)

    monkeypatch.setattr(session_copy, "_copy_dataset", failing)
    with pytest.raises(DiskFullError, match="is full: the recovered file was not written and .* as it was"):
        from collect.recovery import recover_session

        recover_session(p)
    assert _digest(p) == before
    assert sorted(os.listdir(tmp_path)) == ["s.h5"]  # no backup, no half-written copy
    monkeypatch.undo()
    assert recover(p).exit_code == 0


def test_crane_collect_killed_mid_run_is_recovered_and_trained_on(tmp_path):
    """The real thing: `crane-collect run --sim` SIGKILLed while recording, then `crane-collect recover`
    as a lab user types it; crane-train reads the result."""
    from tests.recording import complete_rows, wait_for_rows

    cli = str(Path(sys.executable).parent / "crane-collect")
    cfg = tmp_path / "c.toml"
    cfg.write_text("[loop]\nstatus_hz = 0\n[operator.start_deg]\njoint2 = 0.0\njoint4 = -20.0\n")
    out = tmp_path / "s.h5"
    proc = subprocess.Popen([cli, "run", "--sim", "--plant", "simple", "--duration", "120",
                             "--config", str(cfg), "-o", str(out)],
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    try:
        wait_for_rows(proc, out, 500)
        # what every dataset holds: a reader can see follower/t a chunk ahead of the rest, and a kill in
        # between keeps only the common rows (an under-load run saw follower/t at 500, the rest at 250)
        written = complete_rows(out)
    finally:
        proc.send_signal(signal.SIGKILL)
        proc.communicate(timeout=30)
    done = subprocess.run([cli, "recover", str(out)], capture_output=True, text=True, timeout=120)
    assert done.returncode == 0, done.stderr
    with h5py.File(out, "r") as f:
        n = f["follower/t"].shape[0]
        assert n >= written and f.attrs["end_reason"] == "crashed" and not f.attrs["complete"]
        assert all(f[f"{a}/{m}"].shape[0] == n for a in ("leader", "follower") for m in ("q", "tau", "dq"))
        assert [e["kind"] for e in read_events(f)][0] == "start"
    assert len(read_session(out)) == n
    again = subprocess.run([cli, "recover", str(out)], capture_output=True, text=True, timeout=120)
    assert again.returncode == 2 and again.stderr.startswith("Error: ") and "already" in again.stderr
