"""Sessions from other rigs: another logger's CSV or NPZ columns written as a crane-session file (the
contract's required part, README "The session file"), so its data can be trained and diagnosed.

    spec = parse_map(["t=time", "joint1.q=q1", "joint1.current=i1", ...])
    import_session("log.csv", "session.h5", spec, ImportUnits(angle="deg", time="ms", current="mA"))

The map names what each contract signal is called in the input:

| key | meaning | unit (converted to SI) |
|---|---|---|
| `t` | time of each sample (required; strictly increasing; shifted to start at 0) | `time`: s, ms, us, ns |
| `JOINT.q` | joint angle | `angle`: rad, deg, pulse (raw Present Position, 2048 = 0 rad, 4096 a turn) |
| `JOINT.tau` | joint torque | N m |
| `JOINT.current` | motor current, times the joint's torque constant | `current`: A, mA, raw (2.69 mA/LSB) |

Torque constants (`torque_constants`, N m/A) default to the arm description's (2.20; 3.60 on joint2).

JOINT is a CRANE-X7 joint (joint1 .. joint7, gripper); every mapped joint needs its angle and either its
torque or its current. The columns are written in the arm's joint order. A column is a CSV header name
or an NPZ array name; `NAME[k]` takes column k of a 2-D NPZ array (or of a CSV header literally so
named). CSV: one header row, then numbers; the delimiter (comma, semicolon, tab, space) is detected.

What cannot be mapped is refused with one sentence (`ImportMapError`): a column that is not there, an
unknown joint or signal, a joint without its angle or torque, a time that does not increase, a value
that is not a number, NaN or infinite values. The input is only read; the output is written to a
temporary file beside it and renamed into place (an existing output only with `force`).
"""

from __future__ import annotations

import csv
import io
import json
import re
import zipfile
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

from crane_io import session_format as sf
from crane_io.description import default_arm
from crane_io.dynamixel.units import AMPERE_PER_CURRENT_LSB, POSITION_CENTER, RAD_PER_PULSE
from crane_io.errors import CraneError
from crane_io.output_files import atomic_path, check_output

from .session import MIN_SAMPLES as MIN_ROWS  # what crane-train reads
from .session_check import MAX_RATE_HZ, check_rate_matches

if TYPE_CHECKING:
    from collections.abc import Iterable, Sequence

ANGLE_UNITS = {"rad": 1.0, "deg": np.pi / 180.0, "pulse": RAD_PER_PULSE}
TIME_UNITS = {"s": 1.0, "ms": 1e-3, "us": 1e-6, "ns": 1e-9}
CURRENT_UNITS = {"A": 1.0, "mA": 1e-3, "raw": AMPERE_PER_CURRENT_LSB}
JOINT_SIGNALS = ("q", "tau", "current")
_INDEXED = re.compile(r"^(?P<name>.+)\[(?P<col>\d+)\]$")


class ImportMapError(CraneError):
    """Input columns that cannot be mapped onto the session contract (one sentence)."""


@dataclass(frozen=True)
class ImportUnits:
    angle: str = "rad"
    time: str = "s"
    current: str = "A"

    def __post_init__(self):
        for what, value, table in (("angle", self.angle, ANGLE_UNITS), ("time", self.time, TIME_UNITS),
                                   ("current", self.current, CURRENT_UNITS)):
            if value not in table:
                raise ImportMapError(f"unknown {what} unit {value!r}; use one of {', '.join(table)}")


@dataclass
class ImportMap:
    """Contract signal -> input column: `time` and, per joint, {"q": col, "tau" or "current": col}."""

    time: str
    joints: dict[str, dict[str, str]] = field(default_factory=dict)

    def columns(self) -> list[str]:
        return [self.time] + [c for sigs in self.joints.values() for c in sigs.values()]

    def to_json(self) -> str:
        return json.dumps({"t": self.time, "joints": self.joints}, sort_keys=True)


def _map_pairs(mapping: Iterable[str]):
    """(key, column) of each non-empty `KEY=COLUMN` pair, in order."""
    for item in mapping:
        for pair in str(item).split(","):
            pair = pair.strip()
            if not pair:
                continue
            key, sep, col = pair.partition("=")
            key, col = key.strip(), col.strip()
            if not sep or not key or not col:
                raise ImportMapError(f"`mapping` {pair!r} is not KEY=COLUMN (e.g. t=time, joint1.q=q1, "
                                     f"joint1.current=i1)")
            yield key, col


def _joint_signal(key: str, known: Sequence[str]) -> tuple[str, str]:
    """(joint, signal) of a `JOINT.SIGNAL` key, both checked."""
    joint, dot, sig = key.rpartition(".")
    if not dot or not joint:
        raise ImportMapError(f"`mapping` key {key!r} is neither t nor JOINT.SIGNAL (e.g. joint1.q)")
    if joint not in known:
        raise ImportMapError(f"`mapping` {key}: unknown joint {joint!r}; joints are "
                             f"{', '.join(known)}")
    if sig not in JOINT_SIGNALS:
        raise ImportMapError(f"`mapping` {key}: unknown signal {sig!r}; use q (angle), tau (torque) "
                             f"or current (made torque with the torque constant)")
    return joint, sig


def _check_joint_signals(joint: str, sigs: dict[str, str]) -> None:
    """A mapped joint has an angle and exactly one of a torque and a current."""
    if "tau" in sigs and "current" in sigs:
        raise ImportMapError(f"`mapping` gives {joint} both a torque and a current; map one of them")
    if "q" not in sigs:
        raise ImportMapError(f"`mapping` gives no angle for {joint}; add {joint}.q=COLUMN")
    if "tau" not in sigs and "current" not in sigs:
        raise ImportMapError(f"`mapping` gives no torque for {joint}; add {joint}.tau=COLUMN or "
                             f"{joint}.current=COLUMN")


def parse_map(mapping: Iterable[str], joint_names: Sequence[str] | None = None) -> ImportMap:
    """ImportMap from `KEY=COLUMN` strings (several per string, comma-separated, are allowed)."""
    known = tuple(joint_names or default_arm().joint_names)
    time_col, joints, seen = None, {}, {}
    for key, col in _map_pairs(mapping):
        if key in seen:
            raise ImportMapError(f"`mapping` names {key} twice ({seen[key]!r} and {col!r})")
        seen[key] = col
        if key == "t":
            time_col = col
            continue
        joint, sig = _joint_signal(key, known)
        joints.setdefault(joint, {})[sig] = col
    if time_col is None:
        raise ImportMapError("`mapping` names no time column; add t=COLUMN")
    if not joints:
        raise ImportMapError("`mapping` names no joint; add JOINT.q=COLUMN and JOINT.tau=COLUMN (or "
                             "JOINT.current=COLUMN) for each joint")
    for joint, sigs in joints.items():
        _check_joint_signals(joint, sigs)
    order = [n for n in known if n in joints]
    return ImportMap(time_col, {n: joints[n] for n in order})


# -- reading the input ---------------------------------------------------------------------------------
def _read_csv(path: Path, wanted: list[str]) -> dict[str, np.ndarray]:
    try:
        text = path.read_text(encoding="utf-8-sig")
    except UnicodeDecodeError:
        raise ImportMapError(f"{path} is not a text (CSV) file") from None
    except OSError as exc:
        raise ImportMapError(f"{path} cannot be read ({exc.strerror or exc})") from None
    try:
        return _csv_columns(path, text, wanted)
    except csv.Error as exc:
        raise ImportMapError(f"{path} is not a readable CSV file ({exc})") from None


def _csv_columns(path: Path, text: str, wanted: list[str]) -> dict[str, np.ndarray]:
    lines = text.splitlines()
    if not lines or not lines[0].strip():
        raise ImportMapError(f"{path} is empty or has no header row")
    try:
        dialect = csv.Sniffer().sniff(lines[0], delimiters=",;\t ")
        delimiter = dialect.delimiter
    except csv.Error:
        delimiter = ","
    reader = csv.reader(io.StringIO(text), delimiter=delimiter, skipinitialspace=True)
    header = [h.strip() for h in next(reader)]
    index = {}
    for name in wanted:
        if name in header:
            index[name] = header.index(name)
        else:
            raise ImportMapError(f"{path} has no column {name!r} (its columns: {_listing(header)})")
    rows = [r for r in reader if r and any(c.strip() for c in r)]
    out = {}
    for name, c in index.items():
        col = np.empty(len(rows))
        for i, row in enumerate(rows):
            cell = row[c].strip() if c < len(row) else ""
            try:
                col[i] = float(cell) if cell else np.nan
            except ValueError:
                raise ImportMapError(f"{path}: column {name!r} holds {cell[:30]!r} in data row {i + 1}, "
                                     f"not a number") from None
        out[name] = col
    return out


def _listing(names, limit: int = 12) -> str:
    names = list(names)
    shown = ", ".join(names[:limit])
    return shown + (f", ... ({len(names)} in all)" if len(names) > limit else "") if names else "none"


def _read_npz(path: Path, wanted: list[str]) -> dict[str, np.ndarray]:
    try:
        npz = np.load(path, allow_pickle=False)
    except (OSError, ValueError, EOFError, zipfile.BadZipFile) as exc:
        raise ImportMapError(f"{path} cannot be read as NPZ ({exc})") from None
    if not hasattr(npz, "files"):
        raise ImportMapError(f"{path} is a single .npy array, not an NPZ archive of named arrays")
    try:
        return _npz_columns(path, npz, wanted)
    except ValueError as exc:
        if "allow_pickle" in str(exc) or "Object arrays" in str(exc):
            raise ImportMapError(f"{path} holds Python objects (pickled data), which are never "
                                 f"loaded") from None
        raise ImportMapError(f"{path} cannot be read as NPZ ({exc})") from None
    except (OSError, EOFError, zipfile.BadZipFile, MemoryError, NotImplementedError, RuntimeError) as exc:
        # zipfile raises RuntimeError for a member flagged as encrypted and NotImplementedError for a
        # compression method or flag it does not know: what one flipped bit of a header makes
        raise ImportMapError(f"{path} cannot be read as NPZ ({exc})") from None


def _npz_columns(path: Path, npz, wanted: list[str]) -> dict[str, np.ndarray]:
    with npz:
        out = {}
        for name in wanted:
            m = _INDEXED.match(name)
            if name in npz.files:
                arr = npz[name]
                if arr.ndim != 1:
                    raise ImportMapError(f"{path}: array {name!r} has shape {arr.shape}; map one column of "
                                         f"it as {name}[k]")
            elif m and m["name"] in npz.files:
                arr = npz[m["name"]]
                k = int(m["col"])
                if arr.ndim != 2 or k >= arr.shape[1]:
                    raise ImportMapError(f"{path}: {name} is not a column of array {m['name']!r} (shape "
                                         f"{arr.shape})")
                arr = arr[:, k]
            else:
                raise ImportMapError(f"{path} has no array {name!r} (its arrays: {_listing(npz.files)})")
            if arr.dtype.kind not in "iuf":
                raise ImportMapError(f"{path}: array {name!r} holds {arr.dtype} values, not numbers")
            out[name] = np.asarray(arr, dtype=float)
    lengths = {len(a) for a in out.values()}
    if len(lengths) > 1:
        detail = ", ".join(f"{n} {len(a)}" for n, a in out.items())
        raise ImportMapError(f"{path}: the mapped arrays have different lengths ({detail})")
    return out


def read_columns(path: Path | str, wanted: list[str]) -> dict[str, np.ndarray]:
    """The named columns of a CSV or NPZ file as float arrays (ImportMapError for anything missing)."""
    path = Path(path)
    if not path.exists():
        raise ImportMapError(f"{path} does not exist")
    if not path.is_file():
        raise ImportMapError(f"{path} is not a file")
    try:
        with open(path, "rb") as fh:
            magic = fh.read(4)
    except OSError as exc:
        raise ImportMapError(f"{path} cannot be read ({exc.strerror or exc})") from None
    if magic == b"PK\x03\x04" or path.suffix.lower() == ".npz":
        return _read_npz(path, wanted)
    return _read_csv(path, wanted)


# -- the session -------------------------------------------------------------------------------------------
@dataclass
class ImportedSession:
    t: np.ndarray  # (N,) s from 0
    q: np.ndarray  # (N, J) rad
    tau: np.ndarray  # (N, J) N m
    joint_names: tuple[str, ...]
    rate_hz: float
    current: np.ndarray | None  # (N, J) A where a current was mapped, NaN elsewhere; None without any
    torque_constants: np.ndarray  # (J,) N m/A used (the arm description's where no current was mapped)
    tau_source: tuple[str, ...]  # per column: "imported_torque" or "imported_current"
    t_offset_s: float  # the input's first time, s (subtracted)


def _check_torque_constants(kt_given: dict[str, float], spec: ImportMap) -> None:
    """Given torque constants belong to imported joints and are positive."""
    unknown = [n for n in kt_given if n not in spec.joints]
    if unknown:
        raise ImportMapError(f"a torque constant is given for {', '.join(unknown)}, which `mapping` does not "
                             f"import")
    for name, value in kt_given.items():
        if not (np.isfinite(value) and value > 0):
            raise ImportMapError(f"the torque constant of {name} must be a positive number of N m/A, got "
                                 f"{value}")


def _check_finite(columns: dict[str, np.ndarray], spec: ImportMap, source_name: str) -> None:
    """Every mapped column holds finite numbers only."""
    for name in spec.columns():
        bad = ~np.isfinite(columns[name])
        if bad.any():
            raise ImportMapError(f"{source_name}: column {name!r} has {int(bad.sum())} missing, NaN or "
                                 f"infinite values (first in data row {int(np.argmax(bad)) + 1})")


def _checked_time(columns: dict[str, np.ndarray], spec: ImportMap, units: ImportUnits,
                  source_name: str) -> np.ndarray:
    """The time column in s: long enough and strictly increasing."""
    t_raw = columns[spec.time] * TIME_UNITS[units.time]
    n = len(t_raw)
    if n < MIN_ROWS:
        raise ImportMapError(f"{source_name} has {n} data rows; a session needs at least {MIN_ROWS}")
    step = np.diff(t_raw)
    if np.any(step <= 0):
        row = int(np.argmax(step <= 0)) + 1
        raise ImportMapError(f"{source_name}: time column {spec.time!r} does not increase at data row "
                             f"{row + 1} ({t_raw[row - 1]:.9g} s, then {t_raw[row]:.9g} s); a session needs "
                             f"strictly increasing time")
    return t_raw


def _session_rate(rate_hz: float | None, t_raw: np.ndarray, spec: ImportMap, source_name: str) -> float:
    """The given rate, checked against the time column, or the time column's own (whole Hz when it is)."""
    step = np.diff(t_raw)
    if rate_hz is None:
        rate_hz = 1.0 / float(np.median(step))
        if abs(rate_hz - round(rate_hz)) < 1e-6 * rate_hz:
            rate_hz = float(round(rate_hz))
    elif not (np.isfinite(rate_hz) and 0 < rate_hz <= MAX_RATE_HZ):
        raise ImportMapError(f"the rate must be a positive number of Hz (at most {MAX_RATE_HZ:g}), got "
                             f"{rate_hz}")
    else:  # what every session reader checks (train.data.session_check.check_rate_matches)
        try:
            check_rate_matches(source_name, "input", t_raw, float(rate_hz))
        except CraneError:
            raise ImportMapError(f"the rate {rate_hz:g} Hz disagrees with the time column {spec.time!r} of "
                                 f"{source_name}, which advances by {float(np.median(step)):.6g} s a row "
                                 f"({1 / float(np.median(step)):.6g} Hz)") from None
    return rate_hz


def _joint_angle(raw_q: np.ndarray, units: ImportUnits) -> np.ndarray:
    """An angle column in rad."""
    if units.angle == "pulse":
        return (raw_q - POSITION_CENTER) * RAD_PER_PULSE
    return raw_q * ANGLE_UNITS[units.angle]


def convert(columns: dict[str, np.ndarray], spec: ImportMap, units: ImportUnits = ImportUnits(),
            torque_constants: dict[str, float] | None = None, rate_hz: float | None = None,
            source_name: str = "the input") -> ImportedSession:
    """Input columns -> SI session arrays, checked (ImportMapError, one sentence, for what is unusable)."""
    kt_given = dict(torque_constants or {})
    _check_torque_constants(kt_given, spec)
    _check_finite(columns, spec, source_name)
    t_raw = _checked_time(columns, spec, units, source_name)
    rate_hz = _session_rate(rate_hz, t_raw, spec, source_name)
    n = len(t_raw)
    arm = default_arm()
    names = tuple(spec.joints)
    j = len(names)
    q, tau = np.empty((n, j)), np.empty((n, j))
    current = np.full((n, j), np.nan)
    kt = np.array([kt_given.get(name, arm.joint(name).torque_constant) for name in names])
    source = []
    for c, name in enumerate(names):
        sigs = spec.joints[name]
        q[:, c] = _joint_angle(columns[sigs["q"]], units)
        if "tau" in sigs:
            tau[:, c] = columns[sigs["tau"]]
            source.append("imported_torque")
        else:
            current[:, c] = columns[sigs["current"]] * CURRENT_UNITS[units.current]
            tau[:, c] = current[:, c] * kt[c]
            source.append("imported_current")
    any_current = "imported_current" in source
    return ImportedSession(t_raw - t_raw[0], q, tau, names, float(rate_hz), current if any_current else None,
                           kt, tuple(source), float(t_raw[0]))


def write_session(out: Path | str, s: ImportedSession, *, source: str = "import", attrs: dict | None = None,
                  force: bool = False) -> Path:
    """Write the contract's required part (plus `current` where mapped) to `out` (an existing file only
    with `force`), through a temporary file in the same folder renamed into place
    (crane_io.output_files: a full disk is one sentence)."""
    import h5py

    out = check_output(out, force=force, what="session file", make_folders=True)
    with atomic_path(out, "session file") as tmp, h5py.File(tmp, "w") as f:
        f.attrs[sf.FORMAT_ATTR] = sf.FORMAT
        f.attrs[sf.VERSION_ATTR] = sf.FORMAT_VERSION
        f.attrs[sf.RATE_ATTR] = float(s.rate_hz)
        f.attrs[sf.JOINT_NAMES_ATTR] = np.array(list(s.joint_names), dtype=h5py.string_dtype())
        f.attrs[sf.SOURCE_ATTR] = str(source)
        f.attrs[sf.COMPLETE_ATTR] = True
        f.attrs[sf.TAU_SOURCE_ATTR] = np.array(list(s.tau_source), dtype=h5py.string_dtype())
        f.attrs[sf.TORQUE_CONSTANTS_ATTR] = s.torque_constants
        for k, v in (attrs or {}).items():
            f.attrs[k] = v
        g = f.create_group(sf.REQUIRED_ARM)
        for name, data in ((sf.T, s.t), (sf.Q, s.q), (sf.TAU, s.tau)):
            g.create_dataset(name, data=data, **sf.FILTERS)
        if s.current is not None:
            current: np.ndarray = s.current.astype(sf.ARM_MEMBER[sf.CURRENT].dtype)
            g.create_dataset(sf.CURRENT, data=current, **sf.FILTERS)
    return out


def import_session(input_path: Path | str, out: Path | str, spec: ImportMap,
                   units: ImportUnits = ImportUnits(), *,
                   torque_constants: dict[str, float] | None = None, rate_hz: float | None = None,
                   source: str = "import", force: bool = False) -> ImportedSession:
    """Read `input_path` (CSV or NPZ), convert by `spec` and `units`, write the session `out`."""
    input_path = Path(input_path)
    # before the (possibly long) read: never the input, an existing file only with `force`
    out = check_output(out, inputs=[input_path], force=force, what="session file", make_folders=True)
    columns = read_columns(input_path, list(dict.fromkeys(spec.columns())))
    s = convert(columns, spec, units, torque_constants, rate_hz, source_name=str(input_path))
    imported_from, import_map, import_units, offset = (a.name for a in sf.IMPORT_ROOT)
    attrs = {imported_from: input_path.name, import_map: spec.to_json(),
             import_units: json.dumps({"angle": units.angle, "time": units.time, "current": units.current}),
             offset: s.t_offset_s}
    write_session(out, s, source=source, attrs=attrs, force=force)
    return s
