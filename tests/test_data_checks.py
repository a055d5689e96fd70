"""The data checks applied when sessions load (train.data.data_checks): a copy under another name refused
in one sentence; repeated segments, time-reversed stretches and jumps found with their file and time range
and dropped; a fit on too few rows warned about; the project's own simulated sessions pass clean."""

from __future__ import annotations

import json

import h5py
import numpy as np
import pytest
from click.testing import CliRunner

from crane_io.errors import SessionFileError
from tests.sessions import ALL_JOINTS, LEARN, stroke_trajectory
from train.cli import main
from train.data import data_checks as dc
from train.data.preprocess import PreprocessConfig, preprocess, read_preprocessed
from train.data.session import read_sessions

RATE = 500.0
DURATION_S = 40.0
STEP = 2 * np.pi / 4096  # the servos' position quantum, rad


def _signals(seed: int = 0, duration_s: float = DURATION_S):
    """(t, q, dq_servo, tau) of an 8-column arm: joints 1, 2, 4 move in strokes, the rest are held;
    quantised angle, a noisy recorded velocity, a torque from the motion plus noise."""
    rng = np.random.default_rng(seed)
    n = int(duration_s * RATE)
    t = np.arange(n) / RATE
    q = np.zeros((n, len(ALL_JOINTS)))
    dq = np.zeros_like(q)
    tau = rng.normal(0, 0.01, q.shape)
    for j, name in enumerate(LEARN):
        c = ALL_JOINTS.index(name)
        qj, dqj, ddqj = stroke_trajectory(duration_s, RATE, rng, center=0.3 * j)
        q[:, c], dq[:, c] = qj, dqj
        tau[:, c] += 0.05 * ddqj + 0.2 * np.sin(qj) + 0.15 * np.sign(dqj) + 0.05 * dqj
    for c, name in enumerate(ALL_JOINTS):
        if name not in LEARN:
            q[:, c] = 0.1 * c
    q = np.round(q / STEP) * STEP
    dq = dq + rng.normal(0, 0.02, dq.shape)
    return t, q, dq, tau


def _write(path, t, q, tau, dq=None):
    with h5py.File(path, "w") as f:
        f.attrs.update({"format": "crane-session", "format_version": 1, "rate_hz": RATE, "source": "sim"})
        f.attrs["joint_names"] = np.array(list(ALL_JOINTS), dtype=h5py.string_dtype())
        g = f.create_group("follower")
        for name, a in (("t", t), ("q", q), ("tau", tau), ("dq_servo", dq)):
            if a is not None:
                g.create_dataset(name, data=a)
    return str(path)


def _rows(rows_t: tuple[float, float]) -> slice:
    return slice(int(rows_t[0] * RATE), int(rows_t[1] * RATE))


@pytest.fixture(scope="module")
def clean(tmp_path_factory):
    d = tmp_path_factory.mktemp("checks")
    return d, _signals(0)


def _variant(d, name, change, velocity=True):
    t, q, dq, tau = (a.copy() for a in change())
    return _write(d / f"{name}.h5", t, q, tau, dq if velocity else None)


def _findings(path, check):
    return [f for s in read_sessions([path]) for f in s.findings if f.check == check]


def test_clean_sessions_have_no_findings(clean):
    d, sig = clean
    path = _write(d / "clean.h5", *sig[:2], sig[3], sig[2])
    other = _write(d / "other.h5", *(lambda s: (s[0], s[1], s[3], s[2]))(_signals(1)))
    sessions = read_sessions([path, other])
    assert [f.message for s in sessions for f in s.findings] == []
    assert sessions[0].dq is not None and len(sessions[0]) == len(sig[0])


def test_a_copy_under_another_name_is_refused_in_one_sentence(clean, tmp_path):
    d, (t, q, dq, tau) = clean
    a = _write(tmp_path / "a.h5", t, q, tau, dq)
    b = _write(tmp_path / "b.h5", t, q, tau, dq)
    with pytest.raises(SessionFileError, match="same data as"):
        read_sessions([a, b])
    result = CliRunner().invoke(main, ["info", a, b])
    assert result.exit_code != 0 and "Traceback" not in result.output
    assert result.output.count("\n") == 1 and "b.h5 holds the same data as" in result.output


def _with_duplicate(sig):
    """Rows 5-10 s copied over 25-30 s (a repeated segment with times of its own)."""
    t, q, dq, tau = (a.copy() for a in sig)
    for a in (q, dq, tau):
        a[_rows((25, 30))] = a[_rows((5, 10))]
    return t, q, dq, tau


def test_a_repeated_segment_is_found_with_its_place_and_dropped(clean):
    d, sig = clean
    path = _variant(d, "dup", lambda: _with_duplicate(sig))
    (s,) = read_sessions([path])
    found = [f for f in s.findings if f.check == "repeated"]
    assert len(found) == 1
    f = found[0]
    assert f.path == path and abs(f.t0 - 25) < 0.05 and abs(f.t1 - 30) < 0.05 and f.rows > 0.98 * 5 * RATE
    assert "5.00-" in f.message and "earlier in the same file" in f.message and "dup.h5: 25.0" in f.message
    assert not ((s.t >= 25) & (s.t < 30)).any()  # dropped (the joins at 25 and 30 s are jumps too)
    ds = preprocess([s], PreprocessConfig())
    assert not ((ds.t > 25.2) & (ds.t < 29.9)).any() and len(np.unique(ds.segment)) >= 2


def test_a_segment_repeated_across_files_names_both(clean, tmp_path):
    d, sig = clean
    t, q, dq, tau = _signals(2)
    for a, b in ((q, sig[1]), (dq, sig[2]), (tau, sig[3])):
        a[_rows((10, 14))] = b[_rows((20, 24))]
    first = _write(tmp_path / "first.h5", sig[0], sig[1], sig[3], sig[2])
    second = _write(tmp_path / "second.h5", t, q, tau, dq)
    findings = [f for s in read_sessions([first, second]) for f in s.findings]
    assert len(findings) >= 1
    rep = [f for f in findings if f.check == "repeated"]
    assert len(rep) == 1 and rep[0].path == second and "in " + first in rep[0].message
    assert abs(rep[0].t0 - 10) < 0.05 and abs(rep[0].t1 - 14) < 0.05


def test_a_time_reversed_stretch_is_found(clean):
    d, sig = clean

    def reverse():
        t, q, dq, tau = (a.copy() for a in sig)
        for a in (q, dq, tau):  # every recorded signal played backwards over 12-20 s
            a[_rows((12, 20))] = a[_rows((12, 20))][::-1]
        return t, q, dq, tau

    found = _findings(_variant(d, "rev", reverse), "reversed")
    assert len(found) == 1
    f = found[0]
    assert 11.7 < f.t0 < 12.3 and 19.5 < f.t1 < 20.3, f.message
    # without a recorded velocity the check cannot run: nothing is claimed
    assert _findings(_variant(d, "rev-noveloc", reverse, velocity=False), "reversed") == []


@pytest.mark.parametrize("velocity", [True, False])
def test_a_jump_between_joined_segments_is_masked_and_cut(clean, velocity):
    d, sig = clean

    def join():  # 0-15 s joined to 22-40 s: joint2 jumps by several tenths of a radian
        return tuple(np.concatenate([a[:_rows((0, 15)).stop], a[_rows((22, 40))]]) if a.ndim > 1 else
                     a[:len(a) - int(7 * RATE)] for a in sig)

    path = _variant(d, f"jump-{velocity}", join, velocity)
    (s,) = read_sessions([path])
    jumps = [f for f in s.findings if f.check == "jump"]
    assert len(jumps) == 1 and "jump of" in jumps[0].message and jumps[0].rows > 0
    assert jumps[0].t0 < 15 < jumps[0].t1 + 0.01
    assert len(s.breaks) == 1 and abs(s.t[s.breaks[0]] - 15) < 0.1
    assert [f.check for f in s.findings] == ["jump"]


def test_fit_on_too_few_rows_is_warned_about():
    moving = np.ones((60, 3), bool)
    f = dc.fit_rows_finding("rigid-body", moving)
    assert f is not None and "60 rows" in f.message and str(dc.MIN_FIT_ROWS["rigid-body"]) in f.message
    assert dc.fit_rows_finding("rigid-body", np.ones((200, 3), bool)) is None
    few_masked = np.ones((2000, 3), bool)
    few_masked[100:, 2] = False  # joint4 moves in 100 rows only
    assert "100 rows" in dc.fit_rows_finding("mlp-masked", few_masked).message
    assert dc.fit_rows_finding("mlp-masked", np.ones((600, 3), bool)) is None


def test_loading_warns_and_info_lists_the_findings(clean):
    d, sig = clean
    path = _variant(d, "dup-cli", lambda: _with_duplicate(sig))
    with pytest.warns(dc.DataCheckWarning, match="repeated segment"):
        ds = read_preprocessed([path], PreprocessConfig())
    assert "repeated" in [c["check"] for c in ds.meta["data_checks"]]
    result = CliRunner().invoke(main, ["info", path, "--json"])
    assert result.exit_code == 0, result.output
    doc = json.loads(result.output)
    assert [c["check"] for c in doc["data_checks"]] == ["jump", "repeated", "jump"]  # joins at 25 and 30 s
    text = CliRunner().invoke(main, ["info", path]).output
    assert "data checks: 3 finding(s)" in text and "dup-cli.h5: 25.00-" in text


def test_the_project_simulated_session_passes_clean(tmp_path):
    from collect.run_options import RunOptions
    from collect.runner import run_session

    cfg = tmp_path / "fast.toml"
    cfg.write_text("[safety]\nhoming_speed = 1.0\n")
    out = tmp_path / "sim.h5"
    run_session(RunOptions(output=out, sim=True, seed=3, duration=4.0, status=False, config=str(cfg)))
    for arm in ("follower", "leader"):
        sessions = read_sessions([out], arm)
        assert sessions[0].dq is not None
        assert [f.message for s in sessions for f in s.findings] == []
