"""The rerun view: `crane-collect run --view-save` and `crane-train view --view-save` write .rrd files that
hold the logged entities (read back with rerun's own reader); a view failure never stops the recording;
without rerun both commands refuse in one sentence before anything starts."""

from __future__ import annotations

import collections
import io
import sys

import h5py
import numpy as np
import pytest
from click.testing import CliRunner

from collect.live_view import LiveView
from collect.recorder import read_events
from collect.runner import RunOptions, run_session
from crane_io.view import INSTALL_HINT
from tests.sessions import write_minimal_session

rerun = pytest.importorskip("rerun")
from rerun.chunk import RrdReader  # noqa: E402

# a short alignment (the simple plant starts at 0) and no status line
TEST_CONFIG = """
[loop]
status_hz = 0
[operator.start_deg]
joint2 = 0.0
joint4 = -20.0
"""
SERIES = [f"/{arm}/{sig}" for arm in ("leader", "follower") for sig in ("q", "tau", "tau_dis", "tau_res")]
ENTITIES = SERIES + ["/loop/tracking_error", "/loop/period", "/arms/leader", "/arms/follower"]


def rrd_rows(path) -> dict[str, int]:
    """Entity path -> rows logged on the session_time timeline (static rows left out)."""
    rows = collections.Counter()
    for chunk in RrdReader(str(path)).stream():
        batch = chunk.to_record_batch()
        if "session_time" in batch.schema.names:
            rows[batch.schema.metadata[b"rerun:entity_path"].decode()] += batch.num_rows
    return dict(rows)


def _batches(path, entity: str, column: str):
    for chunk in RrdReader(str(path)).stream():
        batch = chunk.to_record_batch()
        if batch.schema.metadata[b"rerun:entity_path"].decode() == entity and column in batch.schema.names:
            yield batch


def rrd_times(path, entity: str) -> np.ndarray:
    out = []
    for batch in _batches(path, entity, "session_time"):
        out.extend(batch.column("session_time").cast("int64").to_pylist())
    return np.sort(np.asarray(out, dtype=float)) / 1e9


def rrd_scalars(path, entity: str) -> np.ndarray:
    rows = []
    for batch in _batches(path, entity, "Scalars:scalars"):
        if "session_time" in batch.schema.names:
            t = batch.column("session_time").cast("int64").to_pylist()
            rows.extend(zip(t, batch.column("Scalars:scalars").to_pylist()))
    rows.sort(key=lambda r: r[0])
    return np.array([r[1] for r in rows], dtype=float)


@pytest.fixture(scope="module")
def recorded(tmp_path_factory):
    """One short simulated run with --view-save: (session path, rrd path, command output)."""
    from collect.cli import main

    d = tmp_path_factory.mktemp("view")
    cfg = d / "test.toml"
    cfg.write_text(TEST_CONFIG)
    out, rrd = d / "s.h5", d / "live.rrd"
    r = CliRunner().invoke(main, ["run", "--sim", "--plant", "simple", "--duration", "0.6", "--seed", "3",
                                  "--config", str(cfg), "-o", str(out), "--view-save", str(rrd), "--quiet"])
    assert r.exit_code == 0, r.output
    return out, rrd, r.output


def test_run_view_save_holds_the_logged_entities(recorded):
    out, rrd, _ = recorded
    assert rrd.stat().st_size > 0
    rows = rrd_rows(rrd)
    with h5py.File(out, "r") as f:
        n = len(f["follower/t"])
        assert f.attrs["complete"]
        t = f["follower/t"][:]
        q_f = f["follower/q"][:]
    assert n == 300
    for entity in ENTITIES:  # a sample every 10th cycle: 30 of them; a skipped part never loses a sample
        assert 25 <= rows.get(entity, 0) <= 30, (entity, rows)
    # the samples sit on the session's time axis and carry the recorded angles
    times = rrd_times(rrd, "/follower/q")
    assert np.allclose(times, t[::10][:len(times)], atol=1e-9)
    q = rrd_scalars(rrd, "/follower/q")
    assert q.shape[1] == 8 and np.allclose(q, q_f[::10][:len(q)])
    assert rrd_scalars(rrd, "/leader/tau_res").shape[1] == 3  # the bilateral joints only


def test_crane_train_view_replays_a_session(recorded, tmp_path):
    from train.cli import main

    out, _, _ = recorded
    rrd = tmp_path / "replay.rrd"
    r = CliRunner().invoke(main, ["view", str(out), "--view-save", str(rrd)])
    assert r.exit_code == 0, r.output
    assert "30 of 300 samples" in r.output
    rows = rrd_rows(rrd)
    assert all(rows.get(e) == 30 for e in ENTITIES), rows
    with h5py.File(out, "r") as f:
        t, q = f["follower/t"][:], f["follower/q"][:]
        err = f["leader/q"][:] - q
    assert np.allclose(rrd_times(rrd, "/arms/follower"), t[::10])
    assert np.allclose(rrd_scalars(rrd, "/follower/q"), q[::10])
    assert np.allclose(rrd_scalars(rrd, "/loop/tracking_error"), err[::10][:, [0, 1, 3]])


def test_view_replays_a_minimal_session_and_refuses_a_bad_one(tmp_path):
    from train.cli import main

    n = 200
    t = np.arange(n) / 100.0
    q = np.column_stack([np.sin(t), 0.5 * np.cos(t), -np.ones(n)])
    path = write_minimal_session(tmp_path / "m.h5", t, q, 0.1 * q, ("joint1", "joint2", "joint4"), 100)
    rrd = tmp_path / "m.rrd"
    r = CliRunner().invoke(main, ["view", str(path), "--view-save", str(rrd), "--every", "1"])
    assert r.exit_code == 0, r.output
    rows = rrd_rows(rrd)
    assert rows == {"/follower/q": n, "/follower/tau": n, "/arms/follower": n}, rows
    bad = tmp_path / "bad.h5"
    bad.write_text("not a session")
    r = CliRunner().invoke(main, ["view", str(bad), "--view-save", str(tmp_path / "b.rrd")])
    assert r.exit_code == 2 and r.output.count("\n") == 1 and "HDF5" in r.output, r.output


def test_without_rerun_both_commands_refuse_in_one_sentence(tmp_path, monkeypatch):
    from collect.cli import main as collect_main
    from train.cli import main as train_main

    monkeypatch.setitem(sys.modules, "rerun", None)  # `import rerun` raises ImportError
    out = tmp_path / "s.h5"
    for args in (["--view"], ["--view-save", str(tmp_path / "x.rrd")]):
        r = CliRunner().invoke(collect_main, ["run", "--sim", "--plant", "simple", "--duration", "0.1",
                                              "-o", str(out), *args])
        assert r.exit_code == 2, r.output
        assert r.output.strip().count("\n") == 0 and INSTALL_HINT in r.output, r.output
    assert not out.exists() and not (tmp_path / "x.rrd").exists()
    session = write_minimal_session(tmp_path / "m.h5", np.arange(100) / 100, np.zeros((100, 1)),
                                    np.zeros((100, 1)), ("joint1",), 100)
    r = CliRunner().invoke(train_main, ["view", str(session)])
    assert r.exit_code == 2 and INSTALL_HINT in r.output and r.output.strip().count("\n") == 0, r.output
    # the library refuses too (a run started from Python), before any torque is on
    from crane_io.view import ViewUnavailableError

    with pytest.raises(ViewUnavailableError, match="crane-x7\\[view\\]"):
        run_session(RunOptions(output=out, sim=True, plant="simple", duration=0.1, view=True, status=False))
    assert not out.exists()


def test_a_view_failure_warns_once_and_the_recording_goes_on(tmp_path, monkeypatch):
    from crane_io import view as view_mod
    calls = []

    def broken(self, key, t, sample):
        calls.append(key)
        raise RuntimeError("viewer gone")

    monkeypatch.setattr(view_mod.SessionView, "log_part", broken)
    cfg = tmp_path / "test.toml"
    cfg.write_text(TEST_CONFIG)
    out = tmp_path / "s.h5"
    stream = io.StringIO()
    result = run_session(RunOptions(output=out, sim=True, plant="simple", duration=0.4, config=cfg,
                                    view_save=tmp_path / "x.rrd", status=True, stream=stream))
    assert result.end_reason == "duration" and result.cycles == 200
    assert len(calls) == 1  # tried once, then off
    with h5py.File(out, "r") as f:
        warnings = [e for e in read_events(f) if e["kind"] == "warning" and "live view" in e["message"]]
    assert len(warnings) == 1 and "recording goes on" in warnings[0]["message"]
    assert stream.getvalue().count("the live view stopped") == 1


class _CountingView:
    """A stand-in for SessionView: counts the parts logged per call of log_cycle."""

    def __init__(self, j=8):
        self.joint_names = tuple(f"joint{i}" for i in range(1, j + 1))
        self.bil_cols = np.array([0, 1, 3])
        self.keys = [f"{a}/{s}" for a in ("leader", "follower") for s in ("q", "tau", "tau_dis", "tau_res")]
        self.keys += ["loop/tracking_error", "loop/period"]
        self.arm_keys = ["arms/leader", "arms/follower"]
        self.logged = []

    def log_part(self, key, t, sample):
        self.logged.append((key, t, sample[key].copy() if key in sample else None))


class _Timer:
    """The two things LiveView.idle reads of a CycleTimer, on a fake clock."""

    def __init__(self, lockstep, clock=None, deadline=0.0):
        self.lockstep, self.spin_s, self._deadline = lockstep, 2e-4, deadline


def test_lockstep_spreads_a_sample_over_cycles():
    v = _CountingView()
    live = LiveView(v, every=10, parts_per_cycle=2)
    timer = _Timer(lockstep=True)
    est = type("E", (), {"tau_dis": np.zeros(8), "tau_res": np.ones(8)})()
    per_cycle = []
    for k in range(100):
        before = len(v.logged)
        q = np.full(8, float(k))
        live.log_cycle(k * 0.002, q, q - 0.5, q, q, est, est, 0.002 + (0.001 if k == 13 else 0.0))
        assert len(v.logged) == before  # log_cycle only copies the sample
        live.idle(timer)
        per_cycle.append(len(v.logged) - before)
    assert max(per_cycle) == 2 and live.samples == 10 and live.skipped_parts == 0
    assert len(v.logged) == 10 * 12
    times = sorted({t for _, t, _ in v.logged})
    assert np.allclose(times, np.arange(0, 100, 10) * 0.002)
    # each part carries its sample's values, not a later cycle's
    q_rows = [(t, x) for key, t, x in v.logged if key == "leader/q"]
    assert all(np.all(x == round(t / 0.002)) for t, x in q_rows)
    err = [x for key, _, x in v.logged if key == "loop/tracking_error"]
    assert all(np.allclose(e, 0.5) for e in err)
    periods = [x for key, _, x in v.logged if key == "loop/period"]
    assert periods[1][1] == pytest.approx(0.002)
    assert periods[2][1] == pytest.approx(0.003)  # the longest period since the previous sample (k = 13)
    assert periods[2][0] == pytest.approx(0.002)  # the period at the sample (k = 20)


def test_paced_loop_logs_only_in_the_time_left_to_the_deadline():
    """A fake clock: every part takes 0.1 ms; the view logs only while the deadline stays 0.2 ms (margin)
    + the part's recent cost away, so it never runs into the next cycle."""
    now = [0.0]

    class SlowView(_CountingView):
        def log_part(self, key, t, sample):
            super().log_part(key, t, sample)
            now[0] += 1e-4

    v = SlowView()
    live = LiveView(v, every=10, clock=lambda: now[0], margin_s=2e-4)
    est = type("E", (), {"tau_dis": np.zeros(8), "tau_res": np.ones(8)})()
    z = np.zeros(8)
    live.log_cycle(0.0, z, z, z, z, est, est, 0.002)
    live.idle(_Timer(lockstep=False, deadline=0.6e-3))  # 0.6 ms left, first guess 0.5 ms a part: none fits
    assert v.logged == []
    live.idle(_Timer(lockstep=False, deadline=1.5e-3))  # parts while 0.2 ms + their cost fit
    assert len(v.logged) > 0 and now[0] <= 1.5e-3 - 2e-4 + 1e-12
    n = len(v.logged)
    live.idle(_Timer(lockstep=False, deadline=now[0] + 1e-2))  # plenty of time: the rest of the sample
    assert len(v.logged) == 12 and n < 12
    # a machine without slack: samples are skipped, never logged late
    v2 = _CountingView()
    live2 = LiveView(v2, every=2, clock=lambda: 0.0, margin_s=2e-4)
    for k in range(20):
        live2.log_cycle(k * 0.002, z, z, z, z, est, est, 0.002)
        live2.idle(_Timer(lockstep=False, deadline=2e-4))
    assert v2.logged == [] and live2.skipped_parts == 9 * 12


def test_close_without_a_recording_removes_the_rrd(tmp_path):
    from crane_io.view import SessionView

    rrd = tmp_path / "x.rrd"
    view = SessionView(("joint1", "joint2"), ("joint1",), save=rrd)
    view.open()
    live = LiveView(view)
    assert rrd.exists()
    live.close()  # the run ended before recording started
    assert not rrd.exists()
