"""A full disk (or a read-only one) while a command writes: one sentence, exit 3 for a full disk and 2 for
a read-only place, no traceback, no temporary file left and the file that was there before kept whole.

The full disk is a fake: the flush of every output to disk (os.fsync, which every atomic write of
crane_io.output_files runs before its rename) raises ENOSPC; a few writers also fail inside the write
itself (torch.save, h5py, Path.write_bytes, matplotlib)."""

from __future__ import annotations

import errno
import os
import shutil
from pathlib import Path

import numpy as np
import pytest
from click.testing import CliRunner

from collect.cli import main as collect_main
from crane_io.description import default_arm
from tests.sessions import write_synthetic_session
from train.cli import main as train_main

MAP = ["--map", "t=time", "--map", "joint1.q=q1,joint1.tau=tau1"]
RUN_CONFIG = "[loop]\nstatus_hz = 0\n[operator.start_deg]\njoint2 = 0.0\njoint4 = -20.0\n"


def _full(*args, **kwargs):
    raise OSError(errno.ENOSPC, "No space left on device")


@pytest.fixture(scope="module")
def lab(tmp_path_factory):
    d = tmp_path_factory.mktemp("disk")
    session, _ = write_synthetic_session(d / "s.h5", 60, seed=5)
    r = CliRunner().invoke(train_main, ["fit", str(session), "--model", "rigid-body", "--scale-to-data",
                                        "--no-progress", "-o", str(d / "model")])
    assert r.exit_code == 0, r.output
    t = np.arange(200) / 100.0
    (d / "log.csv").write_text("time,q1,tau1\n" + "".join(f"{a},{np.sin(a)},{np.cos(a)}\n" for a in t))
    (d / "run.toml").write_text(RUN_CONFIG)
    return d


def _invoke(main, args, **kw):
    return CliRunner().invoke(main, [str(a) for a in args], **kw)


def _stopped(r, code=3, words="is full"):
    """Exit `code` and one sentence, the last line (a command may have said what it started on)."""
    assert r.exit_code == code, r.output
    lines = r.output.strip().splitlines()
    assert lines[-1].startswith("Error: ") and r.output.count("Error:") == 1, r.output
    assert words in lines[-1] and "Traceback" not in r.output


def _files(folder: Path) -> dict:
    return {p.relative_to(folder): p.read_bytes() for p in sorted(folder.rglob("*")) if p.is_file()}


def _writers(lab: Path, out: Path) -> dict:
    """Each crane-train command that writes, replacing the existing output `out` (a file or folder)."""
    session, model = lab / "s.h5", lab / "model"
    return {
        "report": (["report", model, session, "-o", out / "r.html", "--no-diagnosis"], "r.html"),
        "diagnose --json-out": (["diagnose", model, session, "--json-out", out / "d.json", "--folds", "2"],
                                "d.json"),
        "compare -o": (["compare", model, "--session", session, "-o", out / "c.png"], "c.png"),
        "import -o": (["import", lab / "log.csv", "-o", out / "i.h5", *MAP], "i.h5"),
        "fit -o": (["fit", session, "--model", "rigid-body", "--scale-to-data", "-o", out / "m"], "m"),
        "sweep -o": (["sweep", session, "-o", out / "sweep", "--sizes", "50", "--trials", "2", "--methods",
                      "rigid-body", "--scale-to-data", "--no-progress"], "sweep"),
        "export": (["export", out / "m"], "m"),
        "view --view-save": (["view", session, "--view-save", out / "v.rrd", "--every", "50"], "v.rrd"),
    }


def _old_outputs(lab: Path, folder: Path) -> None:
    """What each command finds at its output: a previous version it is told (--force) to replace."""
    for name in ("r.html", "d.json", "c.png", "i.h5", "v.rrd"):
        (folder / name).write_bytes(b"the previous " + name.encode())
    shutil.copytree(lab / "model", folder / "m")
    (folder / "sweep").mkdir()
    (folder / "sweep" / "results.csv").write_text("the previous results")


@pytest.mark.parametrize("command", ["report", "diagnose --json-out", "compare -o", "import -o", "fit -o",
                                     "sweep -o", "export", "view --view-save"])
def test_a_full_disk_stops_every_train_writer_in_one_sentence_and_keeps_the_old_output(
        lab, tmp_path, monkeypatch, command):
    if command == "view --view-save":
        pytest.importorskip("rerun")
    _old_outputs(lab, tmp_path)
    before = _files(tmp_path)
    args, _ = _writers(lab, tmp_path)[command]
    monkeypatch.setattr(os, "fsync", _full)
    r = _invoke(train_main, [*args, "--force"])
    _stopped(r)
    assert _files(tmp_path) == before  # nothing half-written, no temporary file, the old output whole
    assert not any(p.name.startswith(".") for p in tmp_path.rglob("*"))


def test_a_full_disk_while_the_network_is_saved_keeps_the_old_model(lab, tmp_path, monkeypatch):
    import torch

    out = tmp_path / "m"
    shutil.copytree(lab / "model", out)
    before = _files(tmp_path)
    monkeypatch.setattr(torch, "save", _full)
    r = _invoke(train_main, ["fit", lab / "s.h5", "--model", "mlp-mse", "--epochs", "1", "--scale-to-data",
                             "--no-progress", "-o", out, "--force"])
    _stopped(r)
    assert _files(tmp_path) == before and sorted(p.name for p in tmp_path.iterdir()) == ["m"]


def test_a_writer_that_hides_the_full_disk_behind_its_own_error_is_still_a_full_disk(lab, tmp_path,
                                                                                     monkeypatch):
    import torch

    def torch_full(*args, **kwargs):
        raise RuntimeError("PytorchStreamWriter failed writing file data/0: file write failed")

    real_statvfs = os.statvfs

    def no_space(path):
        st = real_statvfs(path)
        return os.statvfs_result((st.f_bsize, st.f_frsize, st.f_blocks, 0, 0, st.f_files, st.f_ffree,
                                  st.f_favail, st.f_flag, st.f_namemax))

    monkeypatch.setattr(torch, "save", torch_full)
    monkeypatch.setattr(os, "statvfs", no_space)
    r = _invoke(train_main, ["fit", lab / "s.h5", "--model", "mlp-mse", "--epochs", "1", "--scale-to-data",
                             "--no-progress", "-o", tmp_path / "m"])
    _stopped(r)
    assert list(tmp_path.iterdir()) == []


def test_a_full_disk_inside_the_writers_own_calls(lab, tmp_path, monkeypatch):
    import h5py
    import matplotlib.figure

    cases = [
        (h5py.Group, "create_dataset", ["import", lab / "log.csv", "-o", tmp_path / "i.h5", *MAP]),
        (Path, "write_bytes", ["report", lab / "model", lab / "s.h5", "-o", tmp_path / "r.html",
                               "--no-diagnosis"]),
        (matplotlib.figure.Figure, "savefig", ["compare", lab / "model", "--session", lab / "s.h5",
                                               "-o", tmp_path / "c.png"]),
    ]
    for owner, name, args in cases:
        with monkeypatch.context() as m:
            m.setattr(owner, name, _full)
            _stopped(_invoke(train_main, args))
        assert list(tmp_path.iterdir()) == [], name


def test_a_read_only_place_is_refused_before_any_work_and_a_failed_write_is_one_sentence(
        lab, tmp_path, monkeypatch):
    real_access = os.access
    monkeypatch.setattr(os, "access", lambda p, mode, **kw: False if Path(p) == tmp_path else
                        real_access(p, mode, **kw))
    for args in (["import", lab / "log.csv", "-o", tmp_path / "i.h5", *MAP],
                 ["compare", lab / "model", "--session", lab / "s.h5", "-o", tmp_path / "c.png"]):
        _stopped(_invoke(train_main, args), 2, "is not writable")
    monkeypatch.setattr(os, "access", real_access)

    def read_only(*args, **kwargs):
        raise OSError(errno.EROFS, "Read-only file system")

    monkeypatch.setattr("tempfile.mkstemp", read_only)
    _stopped(_invoke(train_main, ["import", lab / "log.csv", "-o", tmp_path / "i.h5", *MAP]), 2,
             "Read-only file system")
    assert list(tmp_path.iterdir()) == []


def test_a_full_disk_while_writing_the_truth_stops_the_run_before_it_starts(lab, tmp_path, monkeypatch):
    truth = tmp_path / "t.json"
    truth.write_text("the previous truth")
    monkeypatch.setattr(os, "fsync", _full)
    r = _invoke(collect_main, ["run", "--sim", "--plant", "hidden-coulomb", "--duration", "0.1", "--quiet",
                               "--config", lab / "run.toml", "--truth", truth, "--force",
                               "-o", tmp_path / "s.h5"])
    _stopped(r)
    assert truth.read_text() == "the previous truth" and sorted(p.name for p in tmp_path.iterdir()) == [
        "t.json"]


def test_a_full_disk_while_recovering_leaves_the_crashed_file_and_the_old_output(tmp_path, monkeypatch):
    from tests.test_recover import _crashed

    crashed = _crashed(tmp_path / "s.h5")
    out = tmp_path / "r.h5"
    out.write_bytes(b"the previous file")
    before = _files(tmp_path)
    monkeypatch.setattr(os, "fsync", _full)
    _stopped(_invoke(collect_main, ["recover", crashed, "-o", out, "--force"]))
    _stopped(_invoke(collect_main, ["recover", crashed]))  # in place
    assert _files(tmp_path) == before


# ---- calibrate: a person confirms every step before anything is written --------------------------------

@pytest.fixture
def arm(tmp_path):
    from crane_io.sim.chain import SimulatedChain
    from crane_io.sim.simple_plant import SimplePlant
    from crane_io.sim.transport import PtyServer

    chain = SimulatedChain.for_arm(default_arm(), SimplePlant.from_arm(default_arm()), clock="wall",
                                   return_delay_time=0)
    server = PtyServer(chain, tmp_path / "arm").start()
    yield str(tmp_path / "arm")
    server.stop()


def test_calibrate_at_the_end_of_its_input_writes_nothing(arm, tmp_path):
    from crane_io.dynamixel.calibration import (
        Calibration,
        JointCalibration,
        adapter_key,
        calibration_path,
        save_calibration,
    )

    stored = save_calibration(Calibration("a", adapter_key(arm), {"joint1": JointCalibration(0.01)}),
                              calibration_path(adapter_key(arm)))
    before = stored.read_bytes()
    for person, step in (("", 1), ("\n", 2)):
        r = _invoke(collect_main, ["calibrate", "--port", arm, "--arm", "a"], input=person)
        assert r.exit_code == 2 and "Traceback" not in r.output, r.output
        assert f"Error: standard input ended before step {step} was confirmed" in r.output
        assert stored.read_bytes() == before
    r = _invoke(collect_main, ["calibrate", "--port", arm, "--arm", "a", "--no-range"], input="\n")
    assert r.exit_code == 0, r.output
    assert stored.read_bytes() != before


def test_calibrate_replaces_an_existing_output_only_with_force(arm, tmp_path):
    out = tmp_path / "c.toml"
    out.write_text("the previous calibration")
    args = ["calibrate", "--port", arm, "--arm", "a", "--no-range", "--output", out]
    r = _invoke(collect_main, args, input="\n")
    _stopped(r, 2, "already exists")
    assert out.read_text() == "the previous calibration"
    r = _invoke(collect_main, [*args, "--force"], input="\n")
    assert r.exit_code == 0, r.output
    assert "[joints.joint1]" in out.read_text()


def test_a_full_disk_while_calibrating_keeps_the_old_file(arm, tmp_path, monkeypatch):
    out = tmp_path / "c.toml"
    out.write_text("the previous calibration")
    monkeypatch.setattr(os, "fsync", _full)
    r = _invoke(collect_main, ["calibrate", "--port", arm, "--arm", "a", "--no-range", "--output", out,
                               "--force"], input="\n")
    _stopped(r)
    assert out.read_text() == "the previous calibration"
    assert sorted(p.name for p in tmp_path.iterdir() if p.name != "arm") == ["c.toml"]
