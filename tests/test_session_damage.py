"""Damaged and foreign session files: every reader refuses them in one sentence (a CraneError), never
with another exception, and never changes the file's bytes (train.data.session, train.data.session_check,
crane_io.h5check.member)."""

from __future__ import annotations

import hashlib
import shutil
import tempfile
from pathlib import Path

import h5py
import numpy as np
import pytest
from click.testing import CliRunner
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st
from sessions import write_minimal_session

from crane_io.errors import CraneError, SessionFileError
from train.cli import main
from train.data.session import read_session
from train.replay import read_replay

N, RATE = 240, 500.0
NAMES = ("joint1", "joint2")
FUZZ = settings(max_examples=40, deadline=None, suppress_health_check=[HealthCheck.too_slow])


@pytest.fixture(scope="module")
def base(tmp_path_factory) -> Path:
    rng = np.random.default_rng(3)
    t = np.arange(N) / RATE
    q, tau = rng.normal(size=(N, 2)), rng.normal(size=(N, 2))
    path = tmp_path_factory.mktemp("base") / "base.h5"
    write_minimal_session(path, t, q, tau, NAMES, RATE, attrs={"hand_on": "leader"})
    with h5py.File(path, "a") as f:  # both arms and a period, as the viewer reads them
        g = f.create_group("leader")
        for key in ("t", "q", "tau"):
            g.create_dataset(key, data=f["follower"][key][()])
        f.create_dataset("timing/period", data=np.full(N, 1 / RATE))
    return path


def _digest(path: Path) -> str:
    return hashlib.sha256(path.read_bytes()).hexdigest()


def _outcome(path: Path):
    """Run every session reader on `path`: None when all accept it, else the CraneError's sentence;
    any other exception fails the test, as does a change to the file's bytes."""
    before = _digest(path)
    try:
        read_session(path)
        read_replay(path)
        message = None
    except CraneError as exc:
        message = str(exc)
        assert message and "\n" not in message, message
    assert _digest(path) == before, "a reader changed the file"
    return message


def _damaged(base: Path, damage) -> Path:
    folder = Path(tempfile.mkdtemp(prefix="damaged-", dir=base.parent))  # inside pytest's folder
    path = folder / "s.h5"
    shutil.copy(base, path)
    damage(path)
    return path


# -- wrong values for attributes and datasets --------------------------------------------------------------
WRONG_VALUES = st.one_of(
    st.integers(-2 ** 63, 2 ** 63 - 1), st.floats(allow_nan=True, allow_infinity=True), st.booleans(),
    st.text(max_size=12).filter(lambda s: "\x00" not in s),  # h5py cannot store a NUL in a string
    st.just(np.array([1, 2])), st.just(np.array([b"a", b"b"])),
    st.just(np.array(["joint1", "joint1"], dtype=h5py.string_dtype())), st.just(h5py.Empty("f8")),
    st.just(np.zeros((2, 2))), st.just(np.array(["joint1\x1b[2J", "joint2"], dtype=h5py.string_dtype())))
ATTRS = st.sampled_from(["format", "format_version", "rate_hz", "joint_names", "source", "complete", "seed",
                         "hand_on", "bilateral_joints", "torque_constants", "start_time"])


def _strings(n):
    return np.array([["x"] * 2] * n, dtype=h5py.string_dtype())


REPLACEMENT_LIST = [
    ("strings", lambda n: np.array([[b"ab", b"cd"]] * n)),
    ("objects", _strings),
    ("records", lambda n: np.zeros(n, dtype=[("a", "f8"), ("b", "f8")])),
    ("flags", lambda n: np.zeros((n, 2), bool)),
    ("complex", lambda n: np.zeros((n, 2), complex)),
    ("one column", lambda n: np.zeros(n)),
    ("three columns", lambda n: np.zeros((n, 3))),
    ("three dimensions", lambda n: np.zeros((n, 2, 2))),
    ("scalar", lambda n: np.float64(1.0)),
    ("empty", lambda n: h5py.Empty("f8")),
    ("no rows", lambda n: np.zeros((0, 2))),
    ("few rows", lambda n: np.zeros((5, 2))),
    ("NaN", lambda n: np.full((n, 2), np.nan)),
    ("huge", lambda n: 1e308 * np.ones((n, 2))),
    ("group", None), ("loop", None), ("dangling", None), ("external", None), ("virtual", None),
]
REPLACEMENTS = st.sampled_from(REPLACEMENT_LIST)
DATASETS = st.sampled_from(["follower/t", "follower/q", "follower/tau", "follower", "leader/q",
                            "timing/period", "timing"])


def _replace(path: Path, name: str, kind: str, make):
    with h5py.File(path, "a") as f:
        n = N
        del f[name]
        if kind == "group":
            f.create_group(name)
        elif kind == "loop":
            f[name] = h5py.SoftLink("/" + name)
        elif kind == "dangling":
            f[name] = h5py.SoftLink("/nowhere/at/all")
        elif kind == "external":
            f[name] = h5py.ExternalLink(str(path), "/follower/q")
        elif kind == "virtual":
            layout = h5py.VirtualLayout(shape=(n, 2), dtype="f8")
            layout[:] = h5py.VirtualSource(str(path), "follower/q", shape=(n, 2))
            f.create_virtual_dataset(name, layout)
        else:
            value = make(n)
            if name in ("follower/t", "timing/period") and getattr(value, "ndim", 0) == 2 and kind in (
                    "NaN", "huge"):
                value = value[:, 0]
            f.create_dataset(name, data=value)


@FUZZ
@given(attr=ATTRS, value=WRONG_VALUES)
def test_a_root_attribute_of_any_wrong_type_is_one_sentence(base, attr, value):
    def damage(path):
        with h5py.File(path, "a") as f:
            f.attrs[attr] = value
    _outcome(_damaged(base, damage))


@FUZZ
@given(name=DATASETS, replacement=REPLACEMENTS)
def test_a_dataset_replaced_by_anything_is_one_sentence(base, name, replacement):
    kind, make = replacement
    _outcome(_damaged(base, lambda path: _replace(path, name, kind, make)))


@FUZZ
@given(data=st.data())
def test_flipped_or_cut_bytes_are_one_sentence(base, data):
    raw = bytearray(base.read_bytes())
    if data.draw(st.booleans(), "cut"):
        raw = raw[:data.draw(st.integers(0, len(raw) - 1), "length")]
    else:
        for _ in range(data.draw(st.integers(1, 4), "flips")):
            i = data.draw(st.integers(0, len(raw) - 1), "at")
            raw[i] ^= 1 << data.draw(st.integers(0, 7), "bit")

    def damage(path):
        path.write_bytes(bytes(raw))
    _outcome(_damaged(base, damage))


# -- the cases named in the toolkit's documentation, each with its sentence --------------------------------
@pytest.mark.parametrize("attr, value, words", [
    ("joint_names", np.array([1, 2]), "invalid joint_names"),
    ("joint_names", np.array(["a", "a"], dtype=h5py.string_dtype()), "names the joint a twice"),
    ("rate_hz", "500", "invalid rate_hz"),
    ("rate_hz", 1e308, "invalid rate_hz"),
    ("rate_hz", 50.0, "one of them is wrong"),
    ("format_version", 99, "newer than this reader"),
    ("format_version", 1.5, "unreadable format_version"),
    ("source", 7, "invalid source"),
    ("complete", "yes", "not of its kind"),
])
def test_attribute_refusals_name_the_file_and_the_attribute(base, attr, value, words):
    def damage(path):
        with h5py.File(path, "a") as f:
            f.attrs[attr] = value
    path = _damaged(base, damage)
    with pytest.raises(SessionFileError, match=words) as info:
        read_session(path)
    assert str(path) in str(info.value) and attr in str(info.value)


@pytest.mark.parametrize("name, kind, words", [
    ("follower/q", "strings", "holds byte strings, not numbers"),
    ("follower/q", "objects", "not numbers"),
    ("follower/q", "records", "compound"),
    ("follower/q", "three columns", "expected (N, 2)"),
    ("follower/q", "group", "is a group, not a dataset"),
    ("follower", "scalar", "is a dataset, not a group"),
    ("follower/q", "loop", "loop of links"),
    ("follower/tau", "dangling", "which does not exist"),
    ("follower/q", "external", "external link"),
    ("follower/t", "virtual", "other files"),
])
def test_dataset_refusals_name_the_file_and_the_dataset(base, name, kind, words):
    make = dict(REPLACEMENT_LIST)[kind]
    path = _damaged(base, lambda p: _replace(p, name, kind, make))
    before = _digest(path)
    with pytest.raises(SessionFileError) as info:
        read_session(path)
    assert words in str(info.value) and str(path) in str(info.value)
    assert f"/{name}" in str(info.value)
    assert _digest(path) == before


def test_an_external_link_to_good_data_is_refused_not_followed(base, tmp_path):
    other = tmp_path / "other.h5"
    shutil.copy(base, other)  # following the link would read a perfectly good /follower/q

    def damage(path):
        with h5py.File(path, "a") as f:
            del f["follower/q"]
            f["follower/q"] = h5py.ExternalLink(str(other), "/follower/q")
    path = _damaged(base, damage)
    with h5py.File(path, "r") as f:
        assert f["follower/q"].shape == (N, 2)  # what h5py itself would do
    with pytest.raises(SessionFileError, match=f"external link to {other}"):
        read_session(path)


def test_a_soft_link_inside_the_file_is_followed(base):
    def damage(path):
        with h5py.File(path, "a") as f:
            f.move("follower/tau", "stored_tau")
            f["follower/tau"] = h5py.SoftLink("/stored_tau")
    session = read_session(_damaged(base, damage))
    assert session.tau.shape == (N, 2)


def test_an_unreadable_session_is_one_sentence(base, tmp_path):
    folder = tmp_path / "folder.h5"
    folder.mkdir()
    with pytest.raises(SessionFileError, match="is not a file"):
        read_session(folder)


# -- the command lines -------------------------------------------------------------------------------------
@pytest.mark.parametrize("damage", ["names", "strings", "loop"])
def test_crane_train_info_on_a_damaged_session_prints_one_error_line_and_exits_2(base, damage):
    if damage == "names":
        def edit(path):
            with h5py.File(path, "a") as f:
                f.attrs["joint_names"] = np.array([1, 2])
    elif damage == "strings":
        def edit(path):
            _replace(path, "follower/q", "strings", lambda n: np.array([[b"ab", b"cd"]] * n))
    else:
        def edit(path):
            _replace(path, "follower/q", "loop", None)
    path = _damaged(base, edit)
    before = _digest(path)
    result = CliRunner().invoke(main, ["info", str(path), "--joints", "joint1,joint2"])
    assert result.exit_code == 2, result.output
    lines = result.output.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith("Error: ") and str(path) in lines[0], result.output
    assert _digest(path) == before


def test_datasets_larger_than_the_memory_are_refused_before_they_are_read(base):
    def damage(path):
        with h5py.File(path, "a") as f:
            for name, shape in (("t", (10 ** 12,)), ("q", (10 ** 12, 2)), ("tau", (10 ** 12, 2))):
                del f[f"follower/{name}"]
                f.create_dataset(f"follower/{name}", shape=shape, dtype="f8", chunks=(1000,) + shape[1:])
    path = _damaged(base, damage)
    assert path.stat().st_size < 10 ** 6  # declared, never stored
    with pytest.raises(SessionFileError, match="more than this computer's memory can read"):
        read_session(path)


@pytest.mark.parametrize("kind, words", [("external", "external link"), ("strings", "not numbers"),
                                         ("loop", "loop of links"), ("group", "not a dataset")])
def test_a_damaged_truth_trace_is_one_sentence(tmp_path, kind, words):
    from train.evaluation.fidelity import _read_trace

    path = tmp_path / "trace.h5"
    with h5py.File(path, "w") as f:
        f.attrs.update({"format": "crane-truth-trace", "format_version": 1,
                        "joint_names": np.array(NAMES, dtype=h5py.string_dtype())})
        f["t"] = np.arange(N) / RATE
        f["in_contact"] = np.zeros(N, bool)
        f["tau_ext"] = np.zeros((N, 2))
    make = dict(REPLACEMENT_LIST)[kind]
    _replace(path, "tau_ext", kind, make)
    before = _digest(path)
    with pytest.raises(SessionFileError, match=words) as info:
        _read_trace(path, NAMES)
    assert "/tau_ext" in str(info.value) and _digest(path) == before


def test_a_string_heap_object_whose_size_is_damaged_is_one_sentence_not_a_hang(base):
    """HDF5 reads a variable-length string's heap object by the size stored beside it; a flipped bit
    there made the read hang or take all the memory. The reader checks the heap before any string."""
    import struct

    raw = bytearray(base.read_bytes())
    at = raw.find(b"GCOL")
    assert at > 0
    size_at = at + 16 + 8  # the first object's size field, after the collection's and its own header
    (size,) = struct.unpack_from("<Q", raw, size_at)
    struct.pack_into("<Q", raw, size_at, size + 2048)

    def damage(path):
        path.write_bytes(bytes(raw))
    message = _outcome(_damaged(base, damage))
    assert message and "string storage" in message and "damaged" in message
