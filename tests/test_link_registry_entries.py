"""The simulated-link registry (crane_io.dynamixel.link_registry) reads what it finds in its folder as
untrusted input: malformed and stale entries are removed, a FIFO is never waited on, a folder another
user could write to is ignored with a warning, and names reach the terminal escaped."""

import json
import os
import threading

import pytest
from click.testing import CliRunner
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from collect.cli import main as collect_main
from crane_io.dynamixel import link_registry as reg

GOOD = {"link": "/tmp/crane_x7_leader", "pty": "/dev/pts/3", "arm": "leader", "plant": "crane-x7",
        "clock": "wall", "hand": True, "pid": 1, "started": 1.0}


@pytest.fixture
def folder():
    path = reg.registry_dir()
    path.mkdir(parents=True, mode=0o700)
    os.chmod(path.parent, 0o700)
    return path


def _ports():
    out = CliRunner().invoke(collect_main, ["ports"])
    assert out.exit_code == 0, out.output
    assert out.exception is None or isinstance(out.exception, SystemExit)
    return out.output


@pytest.mark.parametrize("change", [
    {"pid": "12"}, {"pid": 2**70}, {"pid": 0}, {"pid": -1}, {"pid": True}, {"link": None}, {"link": 5},
    {"arm": "x"}, {"started": "yesterday"}, {"extra": 1},
])
def test_a_malformed_entry_is_removed_without_a_traceback(folder, change):
    entry = folder / "123-0123456789ab.json"
    entry.write_text(json.dumps({**GOOD, **change}))
    assert "no simulated arm is being served" in _ports()
    assert not entry.exists()
    assert "no simulated arm is being served" in _ports()  # and on the next call too


def test_a_fifo_named_like_an_entry_is_skipped_and_left_alone(folder):
    fifo = folder / "9-0123456789ab.json"
    os.mkfifo(fifo)
    done = threading.Event()
    result = {}

    def list_links():
        result["links"] = reg.live_links()
        done.set()

    threading.Thread(target=list_links, daemon=True).start()
    assert done.wait(30), "live_links waited on a FIFO"
    assert result["links"] == [] and fifo.exists()


def test_a_link_named_like_an_entry_is_not_followed(folder, tmp_path):
    target = tmp_path / "precious.json"
    target.write_text(json.dumps(GOOD))
    (folder / "1-0123456789ab.json").symlink_to(target)
    assert reg.live_links() == []
    assert target.read_text() == json.dumps(GOOD)


def test_a_folder_others_can_write_to_is_ignored_with_a_warning(folder):
    entry = folder / "123-0123456789ab.json"
    entry.write_text(json.dumps(GOOD))
    os.chmod(folder, 0o777)
    try:
        out = CliRunner().invoke(collect_main, ["ports"])
        assert out.exit_code == 0
        assert "writable by other users; ignored" in out.output
        assert reg.live_links() == [] and entry.exists()  # nothing read, nothing removed
        assert reg.announce(reg.SimLink(**{**GOOD, "pid": os.getpid()})) is None
    finally:
        os.chmod(folder, 0o700)


def test_a_live_entry_with_escape_codes_is_printed_escaped(folder, tmp_path):
    pty = tmp_path / "pts"
    pty.write_text("")
    link = tmp_path / "arm\x1b[31m\nred"
    link.symlink_to(pty)
    path = reg.announce(reg.SimLink(**{**GOOD, "link": str(link), "pty": str(pty), "plant": "p\x07",
                                       "pid": os.getpid()}))
    assert path is not None
    out = _ports()
    assert "\x1b" not in out and "\x07" not in out
    assert "arm\\x1b[31m\\nred  simulated leader (p\\x07, wall clock, hand on it)" in out


@settings(max_examples=40, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(data=st.binary(max_size=300) | st.builds(
    lambda d: json.dumps({**d, "pty": "/nonexistent/pts/3"} if "pty" in d else d).encode(),  # never live
    st.dictionaries(st.sampled_from(sorted(GOOD) + ["x"]), st.none() | st.booleans() | st.floats()
                    | st.integers(-2**80, 2**80) | st.text(max_size=20), max_size=9)))
def test_random_entries_never_raise_and_are_removed(folder, data):
    entry = folder / "5-0123456789ab.json"
    entry.write_bytes(data)
    assert reg.live_links() == []
    assert not entry.exists()
