"""crane-train sweep in a log: plain progress lines at a bounded rate (bars only on a terminal), and
sizes that --scale-to-data shrank said at the start, recorded in results.json and named in the figures."""

from __future__ import annotations

import io
import json
import re

import pytest
import torch
from click.testing import CliRunner

import train.evaluation.plots
import train.progress
from tests.sessions import write_synthetic_session
from train.cli import main
from train.evaluation.sweep import scaled_sizes_sentence
from train.progress import ProgressLines, progress_lines

torch.set_num_threads(1)


class FakeClock:
    """One second passes at every reading, so rate limits show without waiting."""

    def __init__(self):
        self.now = 0.0

    def __call__(self):
        self.now += 1.0
        return self.now


class Tty(io.StringIO):
    def isatty(self):
        return True


@pytest.fixture(scope="module")
def session(tmp_path_factory):
    path, _ = write_synthetic_session(tmp_path_factory.mktemp("swp") / "s.h5", 150, seed=7)
    return path


def test_progress_lines_are_rate_limited_and_forced_lines_always_written():
    out = io.StringIO()
    clock = FakeClock()
    lines = ProgressLines("job: ", out, interval=10, clock=clock)
    written = [lines(f"step {i}") for i in range(100)]
    assert 5 <= sum(written) <= 100 // 10 + 1  # ~ one per 10 (fake) s, not one per call
    assert lines("the end", force=True)
    text = out.getvalue().splitlines()
    assert text[-1].startswith("job: the end, ") and text[-1].endswith(" s")
    stamps = [int(re.search(r"(\d+) s$", t).group(1)) for t in text[:-1]]
    assert all(b - a >= 10 for a, b in zip(stamps, stamps[1:]))


def test_progress_lines_only_when_asked_and_not_on_a_terminal():
    assert isinstance(progress_lines(True, io.StringIO()), ProgressLines)  # a log or a pipe
    assert progress_lines(True, Tty()) is None  # a terminal: the bars
    assert progress_lines(False, io.StringIO()) is None  # --no-progress


def test_sweep_writes_bounded_progress_lines_to_a_log(session, tmp_path, monkeypatch):
    monkeypatch.setattr(train.progress, "_clock", FakeClock())
    out = tmp_path / "o"
    epochs = 30
    result = CliRunner().invoke(main, ["sweep", str(session), "-o", str(out), "--sizes", "150:450:300",
                                       "--trials", "2", "--epochs", str(epochs), "--scale-to-data"])
    assert result.exit_code == 0, result.output
    lines = result.stderr.splitlines()
    assert lines and all(line.startswith("sweep: ") and re.search(r", \d+ s$", line) for line in lines)
    assert "\r" not in result.stderr  # no tqdm bar in a log
    assert lines[0].startswith("sweep: 3 methods x 2 sizes (150..450 samples) x 2 trials: "
                               "4 rigid-body fits, then 8 networks trained together for 30 epochs")
    assert any("rigid-body, size 2/2 (450 samples), 4 of 4 fits done" in line for line in lines)
    assert f"epoch {epochs}/{epochs} (trained)" in lines[-1]
    assert any(re.search(rf"epoch (\d+)/{epochs},", line) for line in lines)  # progress while training
    assert len(lines) < epochs  # bounded: not one line per epoch
    assert "scaled" not in result.stderr  # these sizes fit the pool: nothing to say
    doc = json.loads((out / "results.json").read_text())
    assert doc["sizes"] == doc["sizes_requested"] == [150, 450] and doc["sizes_scaled"] is False

    quiet = CliRunner().invoke(main, ["sweep", str(session), "-o", str(tmp_path / "q"), "--sizes", "150",
                                      "--trials", "2", "--epochs", "2", "--methods", "mlp-masked",
                                      "--scale-to-data", "--no-progress"])
    assert quiet.exit_code == 0, quiet.output
    assert quiet.stderr == ""


def test_scaled_sizes_are_said_at_the_start_recorded_and_named_in_the_figures(session, tmp_path,
                                                                               monkeypatch):
    titles = []

    def close(fig):  # what the figures say, read before they are closed
        titles.append((fig._suptitle.get_text(), fig.axes[0].get_xlabel()))

    monkeypatch.setattr(train.evaluation.plots.plt, "close", close)
    out = tmp_path / "o"
    result = CliRunner().invoke(main, ["sweep", str(session), "-o", str(out), "--sizes", "1000:6000:5000",
                                       "--trials", "2", "--epochs", "2", "--scale-to-data", "--no-progress"])
    assert result.exit_code == 0, result.output
    doc = json.loads((out / "results.json").read_text())
    assert doc["sizes_scaled"] is True and doc["sizes_requested"] == [1000, 6000]
    lo, hi = doc["sizes"]
    pool = doc["meta"]["splits"]["pool"]
    assert lo < 1000 and hi < 6000 and hi <= pool
    assert all(m["sizes"] == doc["sizes"] for m in doc["methods"].values())
    sentence = (f"the sizes were scaled to the data: {lo}..{hi} samples instead of 1000..6000 "
                f"(the training pool holds {pool} samples)")
    assert result.stderr.splitlines()[0] == f"sweep: {sentence}"  # first, before any training
    assert "T" + sentence[1:] + "." in result.stdout  # and with the table
    (mse_title, mse_xlabel), (window_title, _) = titles
    assert f"sizes scaled to the data: {lo}..{hi} instead of 1000..6000" in mse_title
    assert "scaled to the data" in mse_xlabel
    assert f"models trained on {hi} samples (the largest size, 6000 scaled to the data)" in window_title


def test_sizes_left_out_unscaled_are_said_as_such():
    doc = {"sizes": [300, 600], "sizes_requested": [300, 600, 9000], "sizes_scaled": True,
           "meta": {"splits": {"pool": 6000}, "split_scale": 1.0}}
    assert scaled_sizes_sentence(doc) == ("the sizes above the training pool of 6000 samples were left out: "
                                          "300..600 instead of 300..9000")
    assert scaled_sizes_sentence({**doc, "sizes_scaled": False}) is None
