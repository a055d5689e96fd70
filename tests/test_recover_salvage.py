"""`crane-collect recover` salvages damaged data: rows in a chunk that fails its fletcher32 checksum are
left out of every per-cycle dataset, every other row is kept, `/events` is cut at its first damaged row,
and the summary names the rows lost and why; with -o the input is only read."""

from __future__ import annotations

import hashlib
from pathlib import Path

import h5py
import numpy as np
import pytest
from click.testing import CliRunner

from collect.cli import main
from collect.recorder import SessionRecorder, read_events
from collect.recovery import recover_session
from collect.session_detach import detach
from crane_io.errors import NotRecoverableError
from crane_io.output_files import DiskFullError
from crane_io.session_format import EVENT_CHUNK_ROWS

NAMES = [f"joint{i}" for i in range(1, 8)] + ["gripper"]
RATE = 100  # 50-row chunks


def _record(path: Path, rows: int = 600, events: int = 3, crashed: bool = True) -> Path:
    """A session of `rows` rows (t = k / RATE, q = k + joint index); `crashed`: left in the SWMR-write
    state as by a killed writer (its HDF5 handle let go of without writing), else closed ordinarily."""
    rec = SessionRecorder(path, joint_names=NAMES, rate_hz=RATE, source="sim", lockstep=True)
    for i in range(events):
        rec.event(i / RATE, "warning", f"event {i}")
    for k in range(rows):
        q = k + np.arange(8.0)
        rec.append({"follower/t": k / RATE, "leader/t": k / RATE, "timing/cycle_start": k / RATE,
                    "follower/q": q, "leader/q": -q, "follower/tau": q / 10})
    if crashed:
        rec.flush()
        detach(rec._f)
    rec.close(attrs={"end_reason": "duration"})
    return path


def _flip(path: Path, dataset: str, chunk: int) -> None:
    """Flip 8 bytes in the middle of the stored chunk number `chunk` of `dataset`."""
    with h5py.File(path, "r", libver="latest", swmr=True) as f:
        info = f[dataset].id.get_chunk_info(chunk)
    with open(path, "r+b") as fh:
        fh.seek(info.byte_offset + info.size // 2)
        data = fh.read(8)
        fh.seek(info.byte_offset + info.size // 2)
        fh.write(bytes(b ^ 0xFF for b in data))


def _digest(path: Path) -> str:
    return hashlib.sha256(path.read_bytes()).hexdigest()


@pytest.mark.parametrize("crashed", [True, False], ids=["crashed", "closed"])
def test_a_damaged_chunk_loses_its_rows_only_and_the_summary_names_them(tmp_path, crashed):
    p = _record(tmp_path / "s.h5", crashed=crashed)
    _flip(p, "/follower/q", 3)  # rows 150..199
    _flip(p, "/leader/t", 7)  # rows 350..399: a time dataset, read to find the last complete row
    before = _digest(p)
    out = tmp_path / "out.h5"
    result = CliRunner().invoke(main, ["recover", str(p), "-o", str(out)])
    assert result.exit_code == 0, result.output
    assert "Damaged data: rows 150..199 of /follower/q failed their checksum; rows 350..399 of /leader/t " \
           "failed their checksum; those rows were left out of every dataset, keeping 500 of 600 rows." \
           in result.output
    assert _digest(p) == before and not p.with_name("s.h5.crashed").exists()
    kept = np.r_[0:150, 200:350, 400:600]
    with h5py.File(out, "r") as f:
        assert not f.attrs["complete"] and f.attrs["end_reason"] == ("crashed" if crashed else "duration")
        for key in ("follower/t", "leader/t", "timing/cycle_start"):
            np.testing.assert_array_equal(f[key][()], kept / RATE)
        np.testing.assert_array_equal(f["follower/q"][()], kept[:, None] + np.arange(8.0))
        np.testing.assert_array_equal(f["leader/q"][()], -(kept[:, None] + np.arange(8.0)))
        events = read_events(f)
    assert [e["message"] for e in events[:3]] == ["event 0", "event 1", "event 2"]
    assert events[-1]["kind"] == "recovered" and "rows 150..199 of /follower/q" in events[-1]["message"]


def test_a_damaged_event_chunk_cuts_the_events_there_and_keeps_every_row(tmp_path):
    p = _record(tmp_path / "s.h5", rows=300, events=3 * EVENT_CHUNK_ROWS)
    _flip(p, "/events", 1)
    r = recover_session(p, tmp_path / "out.h5")
    assert r.rows == 300 and not r.damaged and r.cut == {"/events": EVENT_CHUNK_ROWS}
    assert r.damage_summary() == f"row {EVENT_CHUNK_ROWS} of /events failed its checksum, so /events was " \
                                 "cut there"
    with h5py.File(tmp_path / "out.h5", "r") as f:
        events = read_events(f)
        assert f["follower/t"].shape == (300,)
    assert [e["message"] for e in events[:-1]] == [f"event {i}" for i in range(EVENT_CHUNK_ROWS)]


def test_an_undamaged_closed_session_is_still_refused(tmp_path):
    p = _record(tmp_path / "s.h5", rows=100, crashed=False)
    with pytest.raises(NotRecoverableError, match="every chunk passes its checksum"):
        recover_session(p, tmp_path / "out.h5")
    assert not (tmp_path / "out.h5").exists()


def test_a_crashed_session_without_damage_recovers_as_before(tmp_path):
    p = _record(tmp_path / "s.h5", rows=237)
    r = recover_session(p, tmp_path / "out.h5")
    assert (r.rows, r.rows_dropped, r.damaged, r.cut, r.damage_summary()) == (237, 0, [], {}, "")


@pytest.mark.parametrize("flush", [1, 2], ids=["copy", "recovered-event"])
def test_recovering_onto_a_full_disk_is_one_sentence_and_leaves_nothing(tmp_path, monkeypatch, flush):
    p = _record(tmp_path / "s.h5", rows=300)
    before = _digest(p)
    out_dir = tmp_path / "full"
    out_dir.mkdir()
    original, calls = h5py.File.flush, [0]

    def flush_on_a_full_disk(self):
        if Path(self.filename).parent == out_dir:
            calls[0] += 1
            if calls[0] == flush:
                raise RuntimeError("Unable to synchronously flush file (file write failed: errno = 28, "
                                   "error message = 'No space left on device')")
        return original(self)

    monkeypatch.setattr(h5py.File, "flush", flush_on_a_full_disk)
    with pytest.raises(DiskFullError) as err:
        recover_session(p, out_dir / "out.h5")
    msg = str(err.value)
    assert err.value.exit_code == 3 and msg.startswith(f"the disk holding {out_dir / 'out.h5'} is full")
    assert list(out_dir.iterdir()) == [] and _digest(p) == before
