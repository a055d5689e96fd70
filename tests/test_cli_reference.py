"""docs/cli.md, the command-line reference, is what scripts/cli_reference.py writes from the click commands,
and every option each command's `--help` prints is in that command's section, once."""

from __future__ import annotations

import importlib.util
import re
from pathlib import Path

import pytest
from click.testing import CliRunner

ROOT = Path(__file__).resolve().parent.parent
_spec = importlib.util.spec_from_file_location("cli_reference", ROOT / "scripts" / "cli_reference.py")
cli_reference = importlib.util.module_from_spec(_spec)
_spec.loader.exec_module(cli_reference)

ALL = [(program, group, name) for program, group in cli_reference.programs()
       for name, _ in cli_reference.commands(group)]


def _section(text: str, program: str, name: str) -> str:
    start = text.index(f"\n## {program} {name}\n")
    end = text.find("\n## ", start + 1)
    return text[start:] if end < 0 else text[start:end]


def test_the_reference_is_what_the_script_writes():
    assert cli_reference.OUTPUT.read_text(encoding="utf-8") == cli_reference.render(), (
        "docs/cli.md is out of date: run .venv/bin/python scripts/cli_reference.py")


def test_every_command_has_a_section_and_a_contents_line():
    text = cli_reference.OUTPUT.read_text(encoding="utf-8")
    assert len(ALL) >= 17
    for program, _, name in ALL:
        assert text.count(f"\n## {program} {name}\n") == 1
        assert f"(#{program}-{name})" in text


@pytest.mark.parametrize(("program", "group", "name"), ALL, ids=[f"{p} {n}" for p, _, n in ALL])
def test_every_option_of_help_is_documented_once(program, group, name):
    result = CliRunner().invoke(group, [name, "--help"], prog_name=program, terminal_width=200)
    assert result.exit_code == 0, result.output
    options = result.output.split("Options:", 1)[1]
    flags = set(re.findall(r"^\s{1,4}((?:-{1,2}[\w-]+)(?:, -{1,2}[\w-]+)*)", options, flags=re.M))
    flags.discard("--help")
    assert flags, result.output
    section = _section(cli_reference.OUTPUT.read_text(encoding="utf-8"), program, name)
    rows = [line for line in section.splitlines() if line.startswith("| `")]
    for flag in flags:
        hits = [row for row in rows if row.startswith(f"| `{flag} ") or row.startswith(f"| `{flag}`")]
        assert len(hits) == 1, f"{program} {name} {flag}: documented {len(hits)} times"
