"""Write docs/cli.md, the command-line reference, from the click commands themselves.

    .venv/bin/python scripts/cli_reference.py          # rewrite docs/cli.md
    .venv/bin/python scripts/cli_reference.py --check  # exit 1 when docs/cli.md is not what it would write

Every option of every `crane-collect` and `crane-train` subcommand is listed once, with the same text and
default `--help` prints (click's own help records), so the reference cannot drift from the code:
tests/test_cli_reference.py fails when it does.
"""

from __future__ import annotations

import inspect
import re
import sys
from pathlib import Path

import click

ROOT = Path(__file__).resolve().parent.parent
OUTPUT = ROOT / "docs" / "cli.md"
PROGRAMS = (("crane-collect", "collect.cli"), ("crane-train", "train.cli"))
HEADER = """# Command-line reference

Generated from the commands by `scripts/cli_reference.py`; do not edit by hand (the test suite checks
that this page matches `--help`). Every command also takes `--help`. Each command's guide explains
when to use what: see [the documentation's contents](README.md).

"""


def programs() -> list[tuple[str, click.Group]]:
    """(program name, its click group) for both programs."""
    import importlib

    return [(name, importlib.import_module(module).main) for name, module in PROGRAMS]


def commands(group: click.Group) -> list[tuple[str, click.Command]]:
    """(name, command) of every subcommand, in the group's own order."""
    ctx = click.Context(group, info_name="x")
    return [(name, group.get_command(ctx, name)) for name in group.list_commands(ctx)]


def _cell(text: str) -> str:
    """One Markdown table cell: whitespace folded, pipes escaped, click's \\b markers dropped."""
    text = text.replace("\b", " ")
    return re.sub(r"\s+", " ", text).strip().replace("|", "\\|")


def _anchor(program: str, name: str) -> str:
    return f"{program} {name}".replace(" ", "-")


def option_rows(command: click.Command, ctx: click.Context) -> list[tuple[str, str]]:
    """(the option as `--help` shows it, its help with the default) for each option but `--help`."""
    rows = []
    for param in command.get_params(ctx):
        record = param.get_help_record(ctx)
        if record is not None and param is not command.get_help_option(ctx):
            rows.append((record[0], record[1]))
    return rows


def arguments(command: click.Command, ctx: click.Context) -> list[str]:
    return [p.make_metavar(ctx) for p in command.get_params(ctx) if isinstance(p, click.Argument)]


def render_command(program: str, name: str, command: click.Command) -> str:
    ctx = click.Context(command, info_name=f"{program} {name}", terminal_width=100, max_content_width=100)
    usage = " ".join([f"{program} {name}", *command.collect_usage_pieces(ctx)])
    help_text = inspect.cleandoc((command.help or "").replace("\b\n", ""))
    lines = [f"## {program} {name}", "", "```", usage, "```", ""]
    if help_text:
        lines += [help_text, ""]
    rows = option_rows(command, ctx)
    if rows:
        lines += ["| Option | What it does |", "| --- | --- |"]
        lines += [f"| `{_cell(flags)}` | {_cell(text)} |" for flags, text in rows]
        lines.append("")
    return "\n".join(lines)


def render() -> str:
    """The whole of docs/cli.md."""
    parts = [HEADER]
    toc, sections = [], []
    for program, group in programs():
        toc.append(f"- `{program}`: {_cell(group.help or '')}")
        for name, command in commands(group):
            toc.append(f"  - [`{program} {name}`](#{_anchor(program, name)}): "
                       f"{_cell(command.get_short_help_str(limit=90))}")
            sections.append(render_command(program, name, command))
    parts.append("\n".join(toc) + "\n\n")
    parts.append("\n".join(sections))
    return "".join(parts).rstrip("\n") + "\n"


def main(argv: list[str]) -> int:
    text = render()
    if "--check" in argv:
        current = OUTPUT.read_text(encoding="utf-8") if OUTPUT.exists() else ""
        if current != text:
            print(f"{OUTPUT.relative_to(ROOT)} is out of date: run python scripts/cli_reference.py",
                  file=sys.stderr)
            return 1
        return 0
    OUTPUT.write_text(text, encoding="utf-8")
    print(f"wrote {OUTPUT.relative_to(ROOT)}")
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
