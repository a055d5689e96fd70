"""crane_io.toml_config, the TOML reading every loader shares: one sentence per problem, naming the file
and the key; dataclasses built from tables with their field types checked."""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Literal

import pytest
import tomllib

from crane_io.errors import ConfigError
from crane_io.toml_config import dump_toml, expect, from_table, merge_defaults, read_toml


@dataclass(frozen=True)
class Inner:
    gain: float = 1.0


@dataclass(frozen=True)
class Settings:
    name: str
    rate: float = 500.0
    count: int = 3
    on: bool = True
    joints: tuple[str, ...] = ("joint1",)
    betas: tuple[float, float] = (0.9, 0.999)
    side: Literal["above", "below"] = "above"
    inner: Inner = field(default_factory=Inner)


def _error(call) -> str:
    with pytest.raises(ConfigError) as info:
        call()
    msg = str(info.value)
    assert "\n" not in msg
    return msg


def test_read_toml_names_the_file_and_the_line(tmp_path):
    path = tmp_path / "c.toml"
    path.write_text("a = 1\n[loop\n")
    msg = _error(lambda: read_toml(path, what="plant configuration"))
    assert msg.startswith(f"plant configuration {path} is not valid TOML") and "line 2" in msg
    assert "does not exist" in _error(lambda: read_toml(tmp_path / "nope.toml"))
    assert "is not a file" in _error(lambda: read_toml(tmp_path))
    path.write_bytes(b"\xff\xfe")
    assert "cannot be read (not UTF-8 text)" in _error(lambda: read_toml(path))
    assert read_toml(text="x = 2", where="preset 'p'") == {"x": 2}


def test_merge_defaults_checks_keys_and_types_and_suggests_the_close_key():
    base = {"loop": {"rate_hz": 500.0, "cycles": 2, "on": True, "joints": ["joint1"]}}
    merge_defaults(base, {"loop": {"rate_hz": 250, "joints": "all"}}, "c.toml")
    assert base["loop"]["rate_hz"] == 250.0 and isinstance(base["loop"]["rate_hz"], float)
    assert base["loop"]["joints"] == "all"
    msg = _error(lambda: merge_defaults(base, {"loop": {"rate": 1}}, "c.toml"))
    assert msg.startswith("unknown key 'loop.rate' in c.toml; did you mean 'loop.rate_hz'?")
    assert "'loop.cycles' in c.toml must be an integer, got 2.5" in _error(
        lambda: merge_defaults(base, {"loop": {"cycles": 2.5}}, "c.toml"))
    assert "must be true or false" in _error(lambda: merge_defaults(base, {"loop": {"on": 1}}, "c.toml"))
    assert "must be a table" in _error(lambda: merge_defaults(base, {"loop": 3}, "c.toml"))


def test_from_table_builds_the_dataclass_and_converts():
    s = from_table(Settings, {"name": "x", "rate": 100, "joints": ["joint2", "joint4"], "betas": [0.8, 0.9],
                              "side": "below", "inner": {"gain": 2}}, "f.toml", "[s]")
    assert s == Settings("x", 100.0, 3, True, ("joint2", "joint4"), (0.8, 0.9), "below", Inner(2.0))
    assert isinstance(s.rate, float) and isinstance(s.inner.gain, float)
    again = from_table(Settings, {"count": 5}, "f.toml", "[s]", base=s)
    assert again.count == 5 and again.joints == ("joint2", "joint4")


@pytest.mark.parametrize("table, words", [
    ({"name": "x", "rat": 1.0}, "f.toml: unknown key(s) rat in [s]; did you mean 'rate'?"),
    ({}, "f.toml: [s] needs name"),
    ({"name": 3}, "f.toml: [s] name must be a string, got 3"),
    ({"name": "x", "count": 2.0}, "[s] count must be an integer"),
    ({"name": "x", "count": True}, "[s] count must be an integer"),
    ({"name": "x", "rate": float("nan")}, "[s] rate must be a finite number"),
    ({"name": "x", "on": "yes"}, "[s] on must be true or false, got 'yes'"),
    ({"name": "x", "joints": "joint1"}, "[s] joints must be a list"),
    ({"name": "x", "joints": [1]}, "[s] joints must be a string, got 1"),
    ({"name": "x", "betas": [0.9]}, "[s] betas must be a list of 2 values"),
    ({"name": "x", "side": "left"}, "[s] side must be one of 'above', 'below', got 'left'"),
    ({"name": "x", "inner": {"gain": "high"}}, "gain must be a finite number, got 'high'"),
])
def test_from_table_refuses_in_one_sentence(table, words):
    assert words in _error(lambda: from_table(Settings, table, "f.toml", "[s]"))


def test_a_table_that_is_not_a_table():
    assert _error(lambda: from_table(Inner, 3, "f.toml", "[inner]")) == \
        "f.toml: inner must be a table ([inner]), got 3"


def test_expect_is_one_sentence():
    expect(True, "x", "positive", -1)
    assert _error(lambda: expect(False, "'a.b' in c.toml", "positive", -1)) == \
        "'a.b' in c.toml must be positive, got -1"


def test_dump_toml_round_trips():
    doc = {"arm": {"name": 'a "b"\\c', "on": False, "n": 3, "x": 0.25, "joints": ["j1", "j2"]},
           "joints": {"joint1": {"offset_rad": -0.01}}, "empty": {}}
    assert tomllib.loads(dump_toml(doc)) == doc
