"""Session reader, preprocessing, masks, splits and losses of crane-train."""

from __future__ import annotations

import hashlib

import h5py
import numpy as np
import pytest
import torch
from click.testing import CliRunner

from crane_io.errors import CraneError, SessionFileError
from tests.sessions import write_synthetic_session
from train.cli import main
from train.data.dataset import Dataset
from train.data.filters import lowpass, pseudo_diff
from train.data.masks import dead_zone_mask, moving_fractions
from train.data.preprocess import PreprocessConfig, filter_signals, preprocess
from train.data.session import read_session, read_sessions
from train.data.splits import SplitConfig, SplitError, make_splits
from train.models.losses import masked_loss, mse_loss


def _digest(path):
    return hashlib.sha256(open(path, "rb").read()).hexdigest()


@pytest.fixture(scope="module")
def session_path(tmp_path_factory):
    path, _ = write_synthetic_session(tmp_path_factory.mktemp("s") / "s.h5", 120, seed=3)
    return path


def _copy(session_path, tmp_path, edit):
    dst = tmp_path / "bad.h5"
    dst.write_bytes(session_path.read_bytes())
    with h5py.File(dst, "a") as f:
        edit(f)
    return dst


def _replace(name, fn):
    def edit(f):
        data = fn(f[name][()])
        del f[name]
        f.create_dataset(name, data=data)
    return edit


BAD_FILES = {
    "foreign": (lambda f: f.attrs.__setitem__("format", "other-thing"), "not a crane-session"),
    "no format": (lambda f: f.attrs.__delitem__("format"), "no 'format' attribute"),
    "newer": (lambda f: f.attrs.__setitem__("format_version", 7), "newer than"),
    "no tau": (lambda f: f["follower"].__delitem__("tau"), "/follower/tau"),
    "shape": (_replace("follower/q", lambda a: a[:, :3]), "expected (N, 8)"),
    "nan": (_replace("follower/tau", lambda a: np.where(np.arange(len(a))[:, None] == 50, np.nan, a)),
            "NaN"),
    "short": (lambda f: [_replace(k, lambda a: a[:20])(f) for k in ("follower/t", "follower/q",
                                                                      "follower/tau")], "only 20 samples"),
}


@pytest.mark.parametrize("case", sorted(BAD_FILES))
def test_bad_session_files_give_one_sentence_and_stay_untouched(session_path, tmp_path, case):
    edit, fragment = BAD_FILES[case]
    bad = _copy(session_path, tmp_path, edit)
    before = _digest(bad)
    with pytest.raises(SessionFileError) as exc:
        read_session(bad)
    msg = str(exc.value)
    assert fragment in msg and str(bad) in msg and "\n" not in msg
    result = CliRunner().invoke(main, ["info", str(bad)])
    assert result.exit_code != 0
    assert result.output.startswith("Error: ") and "Traceback" not in result.output
    assert _digest(bad) == before


def test_missing_and_non_hdf5_files(tmp_path):
    with pytest.raises(SessionFileError, match="does not exist"):
        read_session(tmp_path / "nope.h5")
    text = tmp_path / "notes.h5"
    text.write_text("hello")
    with pytest.raises(SessionFileError, match="not an HDF5 file"):
        read_session(text)


def test_truncated_recording_uses_shortest_common_length(session_path, tmp_path):
    bad = _copy(session_path, tmp_path, _replace("follower/tau", lambda a: a[:-777]))
    s = read_session(bad)
    assert s.truncated and len(s.t) == len(s.q) == len(s.tau) == 60000 - 777


def test_reader_returns_si_arrays(session_path):
    (s,) = read_sessions([session_path])
    assert s.rate_hz == 500 and s.q.shape == (60000, 8) and s.joint_names[3] == "joint4"
    assert s.source == "sim" and s.duration_s == pytest.approx(120, abs=0.01)


def test_filters_give_q_dq_ddq_tau_the_same_delay():
    rate, w = 500.0, 6.0  # a 6 rad/s sine, well inside the 25 rad/s band
    t = np.arange(0, 20, 1 / rate)
    x = np.sin(w * t)[:, None]
    q, dq, ddq, tau = filter_signals(x, x.copy(), rate, PreprocessConfig())
    keep = t > 5
    basis = np.stack([np.sin(w * t), np.cos(w * t)], axis=1)[keep]

    def phase(sig, scale):
        a, b = np.linalg.lstsq(basis, sig[keep, 0] / scale, rcond=None)[0]
        return np.arctan2(b, a), np.hypot(a, b)

    ph_q, amp_q = phase(q, 1.0)
    ph_tau, _ = phase(tau, 1.0)
    ph_dq, amp_dq = phase(dq, w)  # d/dt sin = w cos: shift back by +90 deg
    ph_ddq, amp_ddq = phase(ddq, -(w ** 2))
    delay = -ph_q / w
    assert delay > 0.05  # two 25 rad/s lags delay by about 2/25 s
    for ph in (ph_tau, ph_dq - np.pi / 2, ph_ddq):
        assert np.angle(np.exp(1j * (ph - ph_q))) == pytest.approx(0, abs=2e-3)
    assert amp_dq == pytest.approx(amp_q, rel=2e-3) and amp_ddq == pytest.approx(amp_q, rel=2e-3)


def test_zero_phase_option_has_no_delay():
    rate, w = 500.0, 6.0
    t = np.arange(0, 20, 1 / rate)
    x = np.sin(w * t)
    keep = (t > 2) & (t < 18)
    assert np.abs(lowpass(x, 25, rate, zero_phase=True) - x / (1 + (w / 25) ** 2))[keep].max() < 1e-3
    dx = pseudo_diff(x, 25, rate, zero_phase=True)
    assert np.abs(dx - w * np.cos(w * t) / (1 + (w / 25) ** 2))[keep].max() < 5e-3
    assert np.abs(pseudo_diff(x, 25, rate) - w * np.cos(w * t))[keep].max() > 0.5  # the causal one lags


def test_preprocess_downsamples_selects_joints_and_keeps_segments(session_path, tmp_path):
    copy, _ = write_synthetic_session(tmp_path / "other.h5", 30, seed=4)  # a second recording
    sessions = read_sessions([session_path, copy])
    ds = preprocess(sessions, PreprocessConfig(joints=("joint4", "joint1")))
    assert ds.joint_names == ("joint4", "joint1") and ds.rate_hz == 50
    assert set(np.unique(ds.segment)) == {0, 1}
    assert np.all(np.diff(ds.t[ds.segment == 0]) == pytest.approx(0.02))
    assert ds.meta["preprocessing"]["joints"] == ["joint4", "joint1"] and len(ds.meta["sigma"]) == 2
    with pytest.raises(CraneError, match="no joint"):
        preprocess(sessions, PreprocessConfig(joints=("joint9",)))


def test_preprocessed_signals_match_the_true_motion(session_path):
    path, truth = write_synthetic_session(session_path.parent / "truth.h5", 30, seed=4)
    ds = preprocess(read_sessions([path]), PreprocessConfig(zero_phase=True))
    rows = np.searchsorted(truth["t"], ds.t)
    for name, tol in (("q", 0.01), ("dq", 0.1)):
        err = np.abs(getattr(ds, name) - truth[name][rows])
        assert np.median(err) < tol


def test_masks_and_fractions():
    dq = np.array([[0.0, 1.0], [2.0, 0.0], [2.0, 1.0], [-2.0, -1.0]])
    moving, sigma = dead_zone_mask(dq, alpha=0.1)
    assert sigma == pytest.approx(dq.std(axis=0))
    assert moving.tolist() == [[False, True], [True, False], [True, True], [True, True]]
    fr = moving_fractions(moving, ["a", "b"])
    assert fr == {"per_joint": {"a": 0.75, "b": 0.75}, "all_joints": 0.5}
    with pytest.raises(CraneError, match="joint b never moves"):
        dead_zone_mask(np.array([[0.0, 0.0], [1.0, 0.0]]), joint_names=["a", "b"])


def test_never_moving_joint_is_reported_through_the_cli(tmp_path):
    path, _ = write_synthetic_session(tmp_path / "still.h5", 20, seed=1)
    with h5py.File(path, "a") as f:
        q = f["follower/q"][()]
        q[:, 3] = 0.25
        f["follower/q"][...] = q
    result = CliRunner().invoke(main, ["info", str(path)])
    assert result.exit_code != 0 and "joint4 never moves" in result.output


def test_synthetic_session_usable_fractions_look_like_the_papers(session_path):
    fr = preprocess(read_sessions([session_path])).meta["usable_fraction"]
    assert all(0.5 < v < 0.85 for v in fr["per_joint"].values())
    assert 0.15 < fr["all_joints"] < 0.5


def _dataset(n, rate=50.0, seed=0, moving_p=0.8, segments=1):
    rng = np.random.default_rng(seed)
    z = rng.normal(size=(n, 3))
    moving = rng.random((n, 3)) < moving_p
    seg = np.repeat(np.arange(segments), int(np.ceil(n / segments)))[:n]
    return Dataset(("a", "b", "c"), np.arange(n) / rate, z, z, z, z, moving, rate, seg)


def test_splits_are_disjoint_sized_and_seeded():
    ds = _dataset(20000, segments=2)
    sp = make_splits(ds, seed=5)
    idx = sp.index
    assert (len(idx["pool"]), len(idx["val"]), len(idx["test"]), len(idx["window"])) == (6000, 500, 500, 150)
    sets = [set(v.tolist()) for v in idx.values()]
    assert sum(len(s) for s in sets) == len(set().union(*sets))
    assert sp.val.all_moving.all() and sp.test.all_moving.all()
    assert np.all(np.diff(idx["window"]) == 1) and len(set(ds.segment[idx["window"]])) == 1
    # no set is closer than the gap to another one (contiguous blocks with gaps)
    owner = np.full(len(ds), -1)
    for k, v in enumerate(idx.values()):
        owner[v] = k
    used = np.flatnonzero(owner >= 0)
    change = np.flatnonzero(np.diff(owner[used]) != 0)
    assert np.all(used[change + 1] - used[change] > 10)
    assert np.array_equal(make_splits(ds, seed=5).index["val"], idx["val"])
    assert not np.array_equal(make_splits(ds, seed=6).index["val"], idx["val"])


def test_splits_say_how_much_data_is_needed_or_scale_down_when_asked():
    ds = _dataset(4000)
    with pytest.raises(SplitError, match=r"need about \d+ samples .* has 4000"):
        make_splits(ds)
    sp = make_splits(ds, scale_to_data=True)
    assert sp.scale < 1 and len(sp.index["pool"]) == sp.config.n_pool < 6000
    small = make_splits(ds, SplitConfig(n_pool=1000, n_val=100, n_test=100))
    assert len(small.index["pool"]) == 1000


def test_masked_loss_is_mse_when_all_move_and_ignores_masked_joints():
    g = torch.Generator().manual_seed(0)
    pred, target = torch.randn(40, 3, generator=g), torch.randn(40, 3, generator=g)
    ones = torch.ones(40, 3, dtype=torch.bool)
    assert masked_loss(pred, target, ones).item() == pytest.approx(mse_loss(pred, target).item())
    mask = ones.clone()
    mask[:, 1] = False
    changed = target.clone()
    changed[:, 1] += 100.0  # whatever happens on a masked joint does not matter
    assert masked_loss(pred, changed, mask).item() == pytest.approx(masked_loss(pred, target, mask).item())
    # normalised by J (=3), not by the number of moving joints
    expected = ((pred - target) ** 2)[:, [0, 2]].sum() / (40 * 3)
    assert masked_loss(pred, target, mask).item() == pytest.approx(expected.item())


def _swmr_session(path, n=20000, rate=500.0):
    """A session written the way crane-collect writes one (libver latest, SWMR mode), cleanly closed."""
    t = np.arange(n) / rate
    q = np.stack([np.sin(0.7 * t + j) for j in range(3)], axis=1)
    with h5py.File(path, "w", libver="latest") as f:
        f.attrs.update({"format": "crane-session", "format_version": 1, "rate_hz": rate, "source": "sim"})
        f.attrs["joint_names"] = np.array(["joint1", "joint2", "joint4"], dtype=h5py.string_dtype())
        g = f.create_group("follower")
        for name, data in (("t", t), ("q", q), ("tau", 0.3 * q)):
            g.create_dataset(name, data=data, maxshape=(None,) + data.shape[1:], chunks=True)
        f.swmr_mode = True
    return path


def test_cut_off_copy_of_a_session_is_one_sentence_not_a_hang(tmp_path):
    # `head -c` of a recording (an interrupted copy): an SWMR read skips HDF5's length check and then
    # retries its checksums for many minutes; the reader must say at once that the file is cut off.
    whole = _swmr_session(tmp_path / "whole.h5")
    assert read_session(whole).q.shape == (20000, 3)
    half = tmp_path / "half.h5"
    half.write_bytes(whole.read_bytes()[: whole.stat().st_size // 2])
    before = _digest(half)
    with pytest.raises(SessionFileError, match=r"half\.h5 is cut off: it has \d+ bytes but its HDF5 header"):
        read_session(half)
    result = CliRunner().invoke(main, ["info", str(half)])
    assert result.exit_code == 2 and result.output.startswith("Error: ") and "cut off" in result.output
    assert _digest(half) == before
