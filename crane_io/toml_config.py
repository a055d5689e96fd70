"""TOML configuration files to checked Python values: the part every loader of the project shares.

Loaders: collect/config.py (bilateral.toml), crane_io/sim/plant_config.py (plant presets),
crane_io/description.py (the arm description), train/cli_options.py (train.toml) and
crane_io/dynamixel/calibration.py (calibration files). Each problem is a `ConfigError`, one sentence
naming the file and the key:

    data = read_toml(path, what="plant configuration")  # missing, not a file, not UTF-8, invalid TOML (line)
    merge_defaults(defaults, data, where)               # user keys onto the complete default document
    cfg = from_table(SensorConfig, data.get("sensor"), where, "[sensor]")  # a dataclass, type-checked
    expect(0 < frac <= 1, "'safety.current_fraction' in c.toml", "in (0, 1]", frac)  # "... must be ..."
    text = dump_toml(document)                          # back to TOML (tables, scalars, flat lists)

What stays in a loader, and why: collect converts `_deg` keys to radians under other names, checks values
against each other and keeps the merged document (stored in every session), so it builds its dataclasses
by hand from the type-checked merge; the plant's `base` presets, effect entries (checked by the effect
library) and joint tables are its own; the arm description keeps its sentences for unknown joints and
keys, calibration files their "cannot read the calibration" (the tests and the users know them).
"""

from __future__ import annotations

import dataclasses
import difflib
import math
import operator
import sys
import types
import typing
from pathlib import Path

from crane_io.errors import ConfigError

if sys.version_info >= (3, 11):
    import tomllib
else:  # pragma: no cover
    import tomli as tomllib


def read_toml(path: str | Path | None = None, *, text: str | None = None, what: str = "configuration file",
              where: str | None = None) -> dict:
    """The TOML document in the file at `path` (or in `text`, described as `where`) as a dict.

    `what` names the kind of file in the sentences ("configuration file", "plant configuration", ...).
    ConfigError: "<what> <path> does not exist", "... is not a file", "... cannot be read (<why>)",
    "... is not valid TOML: <what is wrong> (at line L, column C)"."""
    if text is None:
        if path is None:
            raise TypeError("read_toml needs a path or text")
        path = Path(path)
        where = where or str(path)
        if not path.exists():
            raise ConfigError(f"{what} {path} does not exist")
        if not path.is_file():
            raise ConfigError(f"{what} {path} is not a file")
        try:
            text = path.read_text(encoding="utf-8")
        except UnicodeDecodeError:
            raise ConfigError(f"{what} {path} cannot be read (not UTF-8 text)") from None
        except OSError as exc:
            raise ConfigError(f"{what} {path} cannot be read ({exc.strerror or exc})") from None
    where = where or "the text"
    try:
        return tomllib.loads(text)
    except tomllib.TOMLDecodeError as exc:
        # the decoder's message ends "(at line L, column C)": the place of the mistake
        raise ConfigError(f"{what} {where} is not valid TOML: {exc}") from None


def expect(ok: bool, subject: str, what: str, value) -> None:
    """ConfigError "<subject> must be <what>, got <value!r>" unless `ok`."""
    if not ok:
        raise ConfigError(f"{subject} must be {what}, got {value!r}")


def is_number(value) -> bool:
    """An int or a float (not a bool), finite."""
    return isinstance(value, (int, float)) and not isinstance(value, bool) and math.isfinite(value)


SEED_MAX = 2**32 - 1  # seeds are 0 .. 2**32 - 1: what every random generator of the toolkit takes


def check_seed(seed, subject: str = "`seed`") -> int:
    """`seed` as an int if it is an integer (numpy's too, not a bool) in 0 .. SEED_MAX, else ConfigError
    naming `subject`."""
    try:
        value = None if isinstance(seed, bool) else operator.index(seed)
    except TypeError:
        value = None
    expect(value is not None and 0 <= value <= SEED_MAX, subject, f"an integer between 0 and {SEED_MAX}",
           seed)
    return value


def check_keys(table: dict, known, where: str, prefix: str = "") -> None:
    """ConfigError for the first key of `table` (in sorted order) that is not in `known`: "unknown key
    '<prefix><key>' in <where>", the closest known key when one is close, and the known keys."""
    unknown, known = sorted(set(table) - set(known)), sorted(known)
    if unknown:
        close = difflib.get_close_matches(unknown[0], known, n=1)
        hint = f"; did you mean {prefix + close[0]!r}?" if close else ""
        raise ConfigError(f"unknown key {prefix + unknown[0]!r} in {where}{hint} "
                          f"(known here: {', '.join(known)})")


_WHAT = {bool: "true or false", int: "an integer", float: "a number", str: "a string", list: "a list",
         dict: "a table"}


def merge_defaults(base: dict, user: dict, where: str, prefix: str = "") -> None:
    """Overlay the document `user` onto the complete default document `base`, in place.

    Every key of `user` must be in `base` (else ConfigError naming 'table.key' in `where`); a value takes
    the default's type: a table stays a table, true/false a bool, an integer an int, a number a float (an
    integer is converted), text a str; a default list accepts a list or a string (a list given as text,
    e.g. "all")."""
    check_keys(user, base, where, prefix)
    for key, value in user.items():
        name, default = f"{prefix}{key}", base[key]
        if isinstance(default, dict):
            expect(isinstance(value, dict), f"{name!r} in {where}", "a table", value)
            merge_defaults(default, value, where, prefix=f"{name}.")
            continue
        if isinstance(default, bool):
            ok = isinstance(value, bool)
        elif isinstance(default, (int, float)):
            ok = isinstance(value, (int, float)) and not isinstance(value, bool)
            ok = ok and (isinstance(value, int) or isinstance(default, float))
            value = float(value) if ok and isinstance(default, float) else value
        elif isinstance(default, list):
            ok = isinstance(value, (list, str))
        else:
            ok = isinstance(value, type(default))
        expect(ok, f"{name!r} in {where}", _WHAT.get(type(default), f"a {type(default).__name__}"), value)
        base[key] = value


def from_table(cls, table, where: str, name: str = "", base=None):
    """An instance of the dataclass `cls` from the TOML table `table` (None: empty).

    Keys are the field names; each value is checked against the field's annotation and converted
    (a number for a float field becomes a float, a list for a tuple field a tuple). A field left out
    keeps its default, or its value in `base` (an instance of `cls`) when given; a field without either
    must be there. `name` is how the sentences call the table ("[sensor]", "joint joint1"); they read
    "<where>: <name> <key> must be ...". ConfigError for a table that is not a table, an unknown key
    ("<where>: unknown key(s) ... in <name>", the closest field and the fields), a missing key, a value of the
    wrong type; the dataclass's own checks (__post_init__) run as usual."""
    table = {} if table is None else table
    at = f"{where}: {name}" if name else where
    expect(isinstance(table, dict), f"{where}: {name.strip('[]')}" if name else where,
           f"a table ({name})" if name else "a table", table)
    hints = typing.get_type_hints(cls)
    fields = {f.name: f for f in dataclasses.fields(cls) if f.init}
    unknown = sorted(set(table) - set(fields))
    if unknown:
        close = difflib.get_close_matches(unknown[0], fields, n=1)
        hint = f"; did you mean {close[0]!r}?" if close else ""
        table_name = f" in {name}" if name else ""
        raise ConfigError(f"{where}: unknown key(s) {', '.join(unknown)}{table_name}{hint} "
                          f"(known: {', '.join(fields)})")
    for key, f in fields.items():
        required = f.default is dataclasses.MISSING and f.default_factory is dataclasses.MISSING
        if required and base is None and key not in table:
            raise ConfigError(f"{at} needs {key}")
    values = {k: _checked(v, hints[k], f"{at} {k}" if name else f"{at}: {k}") for k, v in table.items()}
    return dataclasses.replace(base, **values) if base is not None else cls(**values)


def _checked(value, tp, subject: str):
    """`value` checked against the annotation `tp` (see from_table), converted; else ConfigError."""
    origin, args = typing.get_origin(tp), typing.get_args(tp)
    if origin in (typing.Union, types.UnionType):
        options = [a for a in args if a is not type(None)]
        if len(options) == 1:
            return _checked(value, options[0], subject)
        return value
    if origin is typing.Literal:
        expect(value in args, subject, "one of " + ", ".join(map(repr, args)), value)
        return value
    if dataclasses.is_dataclass(tp):
        return from_table(tp, value, subject, "")
    if tp in (bool, int, float, str):
        return _checked_scalar(value, tp, subject)
    if origin in (tuple, list) or tp in (tuple, list):
        return _checked_list(value, tp, subject)
    if origin is dict or tp is dict:
        expect(isinstance(value, dict), subject, "a table", value)
    return value


def _checked_scalar(value, tp: type, subject: str):
    """`value` checked as a bool, int, float (converted) or str."""
    if tp is bool:
        expect(isinstance(value, bool), subject, "true or false", value)
    elif tp is int:
        expect(isinstance(value, int) and not isinstance(value, bool), subject, "an integer", value)
    elif tp is float:
        expect(is_number(value), subject, "a finite number", value)
        return float(value)
    else:
        expect(isinstance(value, str), subject, "a string", value)
    return value


def _checked_list(value, tp, subject: str):
    """`value` checked as the list or tuple annotation `tp` (a fixed-length tuple item by item)."""
    origin, args = typing.get_origin(tp), typing.get_args(tp)
    expect(isinstance(value, (list, tuple)), subject, "a list", value)
    if origin is tuple and args and args[-1] is not Ellipsis:
        expect(len(value) == len(args), subject, f"a list of {len(args)} values", value)
        items = [_checked(v, a, subject) for v, a in zip(value, args)]
    else:
        items = [_checked(v, args[0], subject) for v in value] if args else list(value)
    return tuple(items) if (origin or tp) is tuple else items


def _toml_value(value) -> str:
    if isinstance(value, bool):
        return "true" if value else "false"
    if isinstance(value, (int, float)):
        return repr(value)
    if isinstance(value, str):
        return '"' + value.replace("\\", "\\\\").replace('"', '\\"') + '"'
    if isinstance(value, (list, tuple)):
        return "[" + ", ".join(_toml_value(v) for v in value) + "]"
    raise TypeError(f"cannot write {value!r} as TOML")


def dump_toml(values: dict) -> str:
    """`values` (nested dicts of bools, numbers, strings and flat lists) as TOML text: tomllib reads the
    same document back."""
    lines: list[str] = []

    def table(d: dict, path: str) -> None:
        scalars = {k: v for k, v in d.items() if not isinstance(v, dict)}
        if path and (scalars or not d):
            lines.append(f"[{path}]")
        lines.extend(f"{k} = {_toml_value(v)}" for k, v in scalars.items())
        for k, v in d.items():
            if isinstance(v, dict):
                table(v, f"{path}.{k}" if path else k)

    table(values, "")
    return "\n".join(lines) + "\n"
