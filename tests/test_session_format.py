"""The docs test of the session format: docs/file-formats.md, section "The session file", lists exactly what
crane_io/session_format.py declares (both ways: a member added to the module and not documented fails,
and so does one documented and not declared), and the recorder writes what the module declares."""

from __future__ import annotations

import re
from pathlib import Path

import h5py
import numpy as np
import pytest

from crane_io import session_format as sf

FORMATS = Path(__file__).parents[1] / "docs" / "file-formats.md"
TICKED = re.compile(r"`([A-Za-z_][A-Za-z0-9_]*)`")  # `name` (not `"value"`, not `/path`)


def _section() -> str:
    text = FORMATS.read_text()
    start = text.index("## The session file")
    end = text.index("\n## ", start + 1)
    return text[start:end]


def _between(text: str, start: str, end: str) -> str:
    a = text.index(start)
    return text[a:text.index(end, a + len(start))]


def _table(text: str) -> list[list[str]]:
    """The rows of the first markdown table in `text` (header and rule left out), cells stripped."""
    lines = [ln for ln in text.splitlines() if ln.startswith("|")]
    rows = [[c.strip() for c in ln.strip("|").split("|")] for ln in lines]
    body, seen_rule = [], False
    for row in rows:
        if all(set(c) <= set("-: ") for c in row):
            seen_rule = True
            continue
        if seen_rule:
            body.append(row)
    return body


def _name(cell: str) -> str:
    assert cell.startswith("`") and cell.endswith("`"), cell
    return cell.strip("`")


@pytest.fixture(scope="module")
def doc() -> str:
    return _section()


@pytest.fixture(scope="module")
def optional(doc) -> str:
    return _between(doc, "### Optional", "### Writing rules")


def test_heading_names_the_format_and_version(doc):
    assert doc.splitlines()[0] == (f'## The session file (HDF5, format "{sf.FORMAT}", '
                                   f"format_version {sf.FORMAT_VERSION})")


def test_required_attributes_table_is_the_modules(doc):
    rows = _table(_between(doc, "Root attributes:", "Datasets:"))
    assert [_name(r[0]) for r in rows] == list(sf.REQUIRED_ATTRS)
    assert [r[1] for r in rows] == [a.kind for a in sf.REQUIRED_ROOT]
    assert rows[0][2] == f'`"{sf.FORMAT}"`' and rows[1][2] == f"`{sf.FORMAT_VERSION}`"


def test_required_datasets_table_is_the_modules(doc):
    rows = _table(_between(doc, "Datasets:", "### Optional"))
    assert [_name(r[0]) for r in rows] == [f"/{sf.arm_path(sf.REQUIRED_ARM, m)}" for m in sf.REQUIRED_MEMBERS]
    for path, shape, unit, _meaning in rows:
        m = sf.ARM_MEMBER[_name(path).rsplit("/", 1)[-1]]
        assert (shape, unit) == (m.shape, m.unit), path


def test_per_arm_table_is_the_modules(optional):
    intro = "Per arm (" + " and ".join(f"`/{a}/...`" for a in reversed(sf.ARMS))
    assert intro in optional
    rows = _table(_between(optional, "Per arm (", "`/timing/`"))
    assert [_name(r[0]) for r in rows] == [m.name for m in sf.ARM_MEMBERS]
    for name, shape, unit, _meaning in rows:
        m = sf.ARM_MEMBER[_name(name)]
        assert (shape, unit) == (m.shape, m.unit), name


def test_dtypes_are_the_modules(optional):
    notes = _between(optional, "Notes on values:", "\n\n")
    wide = notes[:notes.index("are float64")]
    assert set(TICKED.findall(wide)) == {m.name for m in sf.ARM_MEMBERS if m.dtype is np.float64}
    assert {m.dtype for m in sf.ARM_MEMBERS if m.dtype is not np.float64} == {np.float32}
    assert {m.dtype for m in sf.TIMING_MEMBERS if m.unit == "s" and m.name != sf.CYCLE_START} == {np.float32}
    assert sf.TIMING_MEMBER[sf.CYCLE_START].dtype is np.float64


def test_timing_datasets_are_the_modules(optional):
    text = _between(optional, "`/timing/` (N,) datasets:", "\n\n")
    assert TICKED.findall(text) == [m.name for m in sf.TIMING_MEMBERS]
    assert "(bool" in text.split(f"`{sf.TIMING_MEMBERS[-1].name}`")[1]
    assert sf.TIMING_MEMBERS[-1].dtype is np.bool_


def test_events_are_the_modules(optional):
    text = _between(optional, "`/events`:", "\n\n")
    fields = re.search(r"compound type \((.*?)\)", text, re.S)[1]
    assert TICKED.findall(fields) == list(sf.EVENT_DTYPE.names)
    widths = [f"S{sf.EVENT_WIDTHS[n]}" for n in ("kind", "joint", "message")]
    assert re.search(r"\((`S\d+`, `S\d+`, `S\d+`)", text)[1] == ", ".join(f"`{w}`" for w in widths)
    assert [sf.EVENT_DTYPE[n].str for n in ("kind", "joint", "message")] == ["|" + w for w in widths]
    kinds = TICKED.findall(text[text.index("Kinds written"):])
    assert kinds == list(sf.EVENT_KINDS)


def test_optional_root_attributes_are_the_modules(optional):
    """Every optional root attribute the module declares is documented, and every attribute name the
    documentation's optional part gives is declared (or is a documented key inside a JSON attribute)."""
    listed = _between(optional, "Root attributes:", "Per arm (")
    further = _between(optional, "Further optional members", "`/timing` attributes")
    documented = set(TICKED.findall(listed)) | set(TICKED.findall(further))
    json_keys = {k for a in sf.OPTIONAL_ROOT for k in a.json_keys}
    declared = set(sf.OPTIONAL_ATTRS)
    assert declared - documented == set(), "declared, not documented"
    members = {m.name for m in sf.ARM_MEMBERS}  # datasets the attributes' meanings refer to
    assert documented - declared - json_keys - members == set(), "in docs/file-formats.md, not in the module"
    assert not set(sf.REQUIRED_ATTRS) & declared
    for value in sf.TAU_SOURCES:
        assert f'`"{value}"`' in listed
    for value in sf.END_REASONS:
        assert f'`"{value}"`' in further


def test_timing_attributes_are_the_modules(optional):
    text = optional[optional.index("`/timing` attributes"):optional.index("Notes on values:")]
    declared = {*sf.TIMING_SUMMARY_ATTRS, *sf.TIMING_REALTIME_ATTRS, sf.TIMING_LOCKSTEP}
    assert set(TICKED.findall(text)) == declared


def test_writing_rules_are_the_modules(doc):
    rules = " ".join(doc[doc.index("### Writing rules"):].split())
    assert "fletcher32" in rules and sf.FILTERS["fletcher32"]
    assert f"{sf.FILTERS['compression']} level {sf.FILTERS['compression_opts']} with shuffle" in rules
    assert sf.FILTERS["shuffle"]
    assert f"chunks of {sf.CHUNK_S:g} s of rows ({int(500 * sf.CHUNK_S)} rows at 500 Hz)" in rules
    assert f"{sf.MAX_UNSAVED_S:g} s old" in rules
    assert f"exceed {sf.COMPACT_ABOVE * 100:g} % of the file" in rules


def test_the_recorder_writes_what_the_module_declares(tmp_path):
    from collect.recorder import DEFAULT_END_ATTRS, SessionRecorder

    joints = ("joint1", "joint2")
    with SessionRecorder(tmp_path / "s.h5", joint_names=joints, rate_hz=100, source="sim",
                         lockstep=True) as rec:
        for k in range(3):
            rec.append({sf.arm_path(a, sf.T): k / 100 for a in sf.ARMS})
        rec.event(0.0, "start", "test")
    with h5py.File(tmp_path / "s.h5", "r") as f:
        datasets = {}

        def visit(name, obj):
            if isinstance(obj, h5py.Dataset):
                datasets[name] = obj.dtype

        f.visititems(visit)
        expected = {sf.arm_path(a, m.name): np.dtype(m.dtype) for a in sf.ARMS for m in sf.ARM_MEMBERS}
        expected.update({f"{sf.TIMING}/{m.name}": np.dtype(m.dtype) for m in sf.TIMING_MEMBERS})
        expected[sf.EVENTS] = sf.EVENT_DTYPE
        assert datasets == expected
        for a in sf.ARMS:
            for m in sf.ARM_MEMBERS:
                ds = f[sf.arm_path(a, m.name)]
                assert ds.shape == (3, *m.row_shape(len(joints))), ds.name
                assert (ds.compression, ds.compression_opts, ds.shuffle, ds.fletcher32) == tuple(
                    sf.FILTERS[k] for k in ("compression", "compression_opts", "shuffle", "fletcher32"))
        assert set(sf.REQUIRED_ATTRS) <= set(f.attrs)
        assert f.attrs[sf.FORMAT_ATTR] == sf.FORMAT and f.attrs[sf.VERSION_ATTR] == sf.FORMAT_VERSION
        assert set(f.attrs) - set(sf.REQUIRED_ATTRS) <= set(sf.OPTIONAL_ATTRS)
        assert set(f[sf.TIMING].attrs) == set(DEFAULT_END_ATTRS[sf.TIMING])


def test_the_loop_timer_and_realtime_attributes_are_the_modules():
    from collect.pacing import SECTIONS, CycleTimer
    from collect.realtime import RealtimeConfig, RealtimeState

    assert SECTIONS == sf.TIMING_SECTIONS
    timer = CycleTimer(100.0, lockstep=True)
    assert set(timer.summary()) == set(sf.TIMING_SUMMARY_ATTRS)
    assert tuple(RealtimeState(RealtimeConfig()).attrs()) == sf.TIMING_REALTIME_ATTRS


def test_readers_and_writers_take_the_names_from_the_module():
    import collect.recorder as recorder
    import collect.recovery as recovery
    import collect.truth_trace as truth_trace
    import train.data.session as session
    import train.evaluation.fidelity as fidelity

    assert recorder.FORMAT is sf.FORMAT and session.FORMAT is sf.FORMAT and recovery.FORMAT is sf.FORMAT
    assert session.REQUIRED_ATTRS is sf.REQUIRED_ATTRS and session.ARMS is sf.ARMS
    assert recorder.EVENT_DTYPE is sf.EVENT_DTYPE and recorder.SUMMARY_KEYS is sf.TIMING_SUMMARY_ATTRS
    assert truth_trace.FORMAT is sf.TRUTH_TRACE_FORMAT and fidelity.TRUTH_FORMAT is sf.TRUTH_TRACE_FORMAT
