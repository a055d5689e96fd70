"""Per-arm calibration: where each joint's zero really is, and the range it was seen to move through.

Two CRANE-X7 arms never read the same angle at the same pose: every servo's encoder zero sits a little
off the joint's mark. `crane-collect calibrate` finds each joint's offset with the arm held at its marks
(offset = the angle the servo reads there) and records the range each joint moved through; `run` and
`check` then use calibrated angles:

    q_calibrated = q_servo - offset          (what the controller, the safety limits and the session see)
    goal_servo   = goal_calibrated + offset  (what goes to a servo in position mode)

A calibration is a TOML file per arm under the user's configuration directory
(`$XDG_CONFIG_HOME/crane-x7/calibration`, else `~/.config/crane-x7/calibration`; `CRANE_X7_CONFIG_DIR`
overrides the root), named by the key of the arm's adapter: the U2D2's USB serial number (it stays with
the arm whatever /dev/ttyUSBn it gets), or for a port without one (a simulated link) `port-` and the
port's file name.

    [arm]
    name = "follower"            # what the user called it
    key = "FT6Z5Q1I"             # the adapter it belongs to
    created = "2026-11-24T08:00:00Z"
    [joints.joint1]
    offset_rad = 0.0123          # the angle the servo read at the mark
    min_rad = -2.61              # the calibrated range seen while moving the joint (absent: not recorded)
    max_rad = 2.60
"""

from __future__ import annotations

import math
import os
import re
import stat
import time
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from crane_io.description import default_arm
from crane_io.errors import ConfigError
from crane_io.toml_config import check_keys, dump_toml, is_number, read_toml

CONFIG_ENV = "CRANE_X7_CONFIG_DIR"
MAX_OFFSET_RAD = math.radians(20.0)  # more than this at a mark: the joint was not at its mark
MAX_RANGE_RAD = 2 * math.pi  # a joint's recorded range lies within one turn either way of its zero
MAX_FILE_BYTES = 1 << 20  # a calibration is a few hundred bytes: a larger file is something else
ARM_NAME = re.compile(r"[A-Za-z0-9_.() -]{1,64}")  # what an arm may be called (check_arm_name)
KEY = re.compile(r"[A-Za-z0-9._-]{1,64}")  # an adapter's key (adapter_key makes it so)


class CalibrationError(ConfigError):
    """A calibration file that cannot be read, or a calibration that cannot be right."""


@dataclass(frozen=True)
class JointCalibration:
    offset_rad: float
    min_rad: float | None = None
    max_rad: float | None = None


@dataclass(frozen=True)
class Calibration:
    name: str  # the user's name for the arm
    key: str  # the adapter's key (USB serial or port-NAME)
    joints: dict[str, JointCalibration]
    created: str = ""
    path: str | None = None  # where it was read from / written to

    def offsets(self, joint_names) -> np.ndarray:
        """(n,) rad, in `joint_names` order (0 for a joint the calibration does not name)."""
        return np.array([self.joints[n].offset_rad if n in self.joints else 0.0 for n in joint_names])

    def describe(self) -> str:
        """One line: which calibration, from where."""
        where = f" ({self.path})" if self.path else ""
        return f"calibration {self.name!r} of adapter {self.key}{where}"

    def as_attrs(self) -> dict:
        """A JSON-able summary for a session's attributes."""
        return {"name": self.name, "key": self.key, "created": self.created, "path": self.path,
                "offsets_rad": {n: j.offset_rad for n, j in self.joints.items()}}


def config_dir() -> Path:
    """The folder calibrations live in (not created)."""
    root = os.environ.get(CONFIG_ENV)
    if root:
        return Path(root) / "calibration"
    base = os.environ.get("XDG_CONFIG_HOME") or str(Path.home() / ".config")
    return Path(base) / "crane-x7" / "calibration"


def adapter_key(port: str, comports=None) -> str:
    """The key of the adapter behind `port`: the U2D2's USB serial, else `port-` + the port's name."""
    real = os.path.realpath(port)
    if comports is None:
        try:
            from serial.tools import list_ports

            comports = list_ports.comports()
        except Exception:  # noqa: BLE001 - no port enumeration on this system: fall back to the name
            comports = []
    for info in comports:
        if os.path.realpath(info.device) == real and info.serial_number:
            return _safe(info.serial_number)
    return "port-" + _safe(os.path.basename(str(port).rstrip("/")) or "unnamed")


def _safe(text: str) -> str:
    return re.sub(r"[^A-Za-z0-9._-]", "_", text)


def calibration_path(key: str) -> Path:
    return config_dir() / f"{_safe(key)}.toml"


def find_calibration(port: str, comports=None) -> Calibration | None:
    """The stored calibration of the adapter behind `port`, or None when there is none."""
    path = calibration_path(adapter_key(port, comports))
    return load_calibration(path) if path.exists() else None


def _read_text(path: Path) -> str:
    """The file's text, read without blocking (a FIFO or a device is refused, not waited on)."""
    try:
        fd = os.open(path, os.O_RDONLY | os.O_NONBLOCK | getattr(os, "O_CLOEXEC", 0))
    except OSError as exc:
        raise CalibrationError(f"cannot read the calibration {path}: {exc.strerror or exc}") from None
    try:
        if not stat.S_ISREG(os.fstat(fd).st_mode):
            what = "a folder" if path.is_dir() else "not a regular file"
            raise CalibrationError(f"cannot read the calibration {path}: it is {what}")
        data = os.read(fd, MAX_FILE_BYTES + 1)
    except OSError as exc:
        raise CalibrationError(f"cannot read the calibration {path}: {exc.strerror or exc}") from None
    finally:
        os.close(fd)
    if len(data) > MAX_FILE_BYTES:
        raise CalibrationError(f"cannot read the calibration {path}: larger than {MAX_FILE_BYTES} bytes, "
                               "not a calibration")
    try:
        return data.decode("utf-8")
    except UnicodeDecodeError:
        raise CalibrationError(f"cannot read the calibration {path}: not UTF-8 text") from None


def check_arm_name(name) -> str:
    """`name` if it can name an arm (ARM_NAME: 1 to 64 letters, digits, spaces or . _ - ( ), not only
    spaces): it is stored in TOML files and shown on terminals. CalibrationError otherwise."""
    if not (isinstance(name, str) and ARM_NAME.fullmatch(name) and name.strip()):
        raise CalibrationError("an arm name must be 1 to 64 letters, digits, spaces or . _ - ( ), "
                               f"got {name!r}")
    return name


def _number(value, subject: str, path: Path) -> float:
    if not is_number(value):
        raise CalibrationError(f"the calibration {path}: {subject} must be a finite number, got {value!r}")
    return float(value)


def load_calibration(path: str | os.PathLike) -> Calibration:
    """Read a calibration file; CalibrationError (one sentence) when it is unreadable or wrong: not a
    regular UTF-8 TOML file, no [arm] table with a name and a key, a joint the arm does not have, an
    offset that is not a finite number within MAX_OFFSET_RAD, a range that is not two finite numbers
    with min_rad <= max_rad."""
    path = Path(path)
    try:
        data = read_toml(text=_read_text(path), what="the calibration", where=str(path))
    except CalibrationError:
        raise
    except ConfigError as exc:
        raise CalibrationError(str(exc)) from None
    try:
        check_keys(data, ("arm", "joints"), f"the calibration {path}")
    except ConfigError as exc:
        raise CalibrationError(str(exc)) from None
    table = data.get("joints")
    if table is not None and not isinstance(table, dict):
        raise CalibrationError(f"the calibration {path}: [joints] must be a table of [joints.NAME] tables")
    known = default_arm().joint_names
    joints = {name: _joint(name, entry, known, path) for name, entry in (table or {}).items()}
    if not joints:
        raise CalibrationError(f"the calibration {path} names no joint")
    name, key, created = _arm_table(data.get("arm"), path)
    return Calibration(name=name, key=key, joints=joints, created=created, path=str(path))


def _joint(name: str, entry, known: tuple[str, ...], path: Path) -> JointCalibration:
    """One [joints.NAME] table of a calibration file, checked (see load_calibration)."""
    if name not in known:
        raise CalibrationError(f"the calibration {path} names unknown joint {name!r} "
                               f"(joints: {', '.join(known)})")
    if not isinstance(entry, dict) or "offset_rad" not in entry:
        raise CalibrationError(f"the calibration {path}: joint {name} needs a number offset_rad "
                               "(and numbers for min_rad/max_rad if given)")
    unknown = sorted(set(entry) - {"offset_rad", "min_rad", "max_rad"})
    if unknown:
        raise CalibrationError(f"the calibration {path}: unknown key {unknown[0]!r} in joint {name} "
                               "(known: offset_rad, min_rad, max_rad)")
    offset = _number(entry["offset_rad"], f"joint {name}'s offset_rad", path)
    if abs(offset) > MAX_OFFSET_RAD:
        raise CalibrationError(f"the calibration {path}: joint {name}'s offset {offset} rad is not "
                               f"within ±{math.degrees(MAX_OFFSET_RAD):.0f} deg; calibrate the arm again")
    lo, hi = entry.get("min_rad"), entry.get("max_rad")
    if (lo is None) != (hi is None):
        raise CalibrationError(f"the calibration {path}: joint {name} needs both min_rad and max_rad, "
                               "or neither")
    if lo is not None:
        lo = _number(lo, f"joint {name}'s min_rad", path)
        hi = _number(hi, f"joint {name}'s max_rad", path)
        if not (-MAX_RANGE_RAD <= lo <= hi <= MAX_RANGE_RAD):
            raise CalibrationError(f"the calibration {path}: joint {name}'s range {lo:g} .. {hi:g} rad "
                                   f"must have min_rad <= max_rad, both within ±{MAX_RANGE_RAD:.4g} rad")
    return JointCalibration(offset, lo, hi)


def _arm_table(head, path: Path) -> tuple[str, str, str]:
    """The [arm] table of a calibration file, checked: (name, key, created)."""
    if not isinstance(head, dict):
        raise CalibrationError(f"the calibration {path} has no [arm] table (name, key, created); "
                               "calibrate the arm again or add one")
    for key in ("name", "key", "created"):
        if key in head and not isinstance(head[key], str):
            raise CalibrationError(f"the calibration {path}: [arm] {key} must be text, got {head[key]!r}")
    unknown = sorted(set(head) - {"name", "key", "created"})
    if unknown:
        raise CalibrationError(f"the calibration {path}: unknown key {unknown[0]!r} in [arm] "
                               "(known: name, key, created)")
    name = head.get("name", "")
    try:
        check_arm_name(name)
    except CalibrationError as exc:
        raise CalibrationError(f"the calibration {path}: [arm] name: {exc}") from None
    key = head.get("key", path.stem)
    if not KEY.fullmatch(key):
        raise CalibrationError(f"the calibration {path}: [arm] key must be 1 to 64 letters, digits or . _ -, "
                               f"got {key!r}")
    return name, key, head.get("created", "")


def save_calibration(cal: Calibration, path: str | os.PathLike | None = None) -> Path:
    """Write `cal` (atomically) to `path` or its adapter's file; returns where."""
    path = Path(path) if path is not None else calibration_path(cal.key)
    joints = {}
    for name, j in cal.joints.items():
        joints[name] = {"offset_rad": j.offset_rad}
        if j.min_rad is not None and j.max_rad is not None:
            joints[name].update(min_rad=j.min_rad, max_rad=j.max_rad)
    text = ("# crane-x7 arm calibration: q_calibrated = q_servo - offset_rad "
            "(crane_io/dynamixel/calibration.py)\n"
            + dump_toml({"arm": {"name": cal.name, "key": cal.key, "created": cal.created},
                         "joints": joints}))
    from crane_io.output_files import write_text_atomic  # a full disk: DiskFullError, nothing half-written

    return write_text_atomic(path, text, "calibration")


@dataclass
class RangeRecorder:
    """The smallest and largest calibrated angle seen per joint while the user moves the arm."""

    offsets: np.ndarray
    low: np.ndarray = field(init=False)
    high: np.ndarray = field(init=False)
    samples: int = 0

    def __post_init__(self):
        self.low = np.full(len(self.offsets), np.inf)
        self.high = np.full(len(self.offsets), -np.inf)

    def add(self, q_servo: np.ndarray) -> None:
        q = np.asarray(q_servo, dtype=float) - self.offsets
        self.low = np.minimum(self.low, q)
        self.high = np.maximum(self.high, q)
        self.samples += 1


def offsets_at_marks(q_servo: np.ndarray, joint_names) -> np.ndarray:
    """The offsets from the angles read with every joint at its mark (calibrated zero); a joint reading
    more than MAX_OFFSET_RAD there is refused (CalibrationError): it was not at its mark."""
    q = np.asarray(q_servo, dtype=float)
    far = np.flatnonzero(np.abs(q) > MAX_OFFSET_RAD)
    if far.size:
        i = int(far[0])
        raise CalibrationError(f"{joint_names[i]} reads {math.degrees(q[i]):.1f} deg at its mark, more than "
                               f"the {math.degrees(MAX_OFFSET_RAD):.0f} deg an encoder can be off; put every "
                               "joint on its mark and calibrate again")
    return q.copy()


def build_calibration(name: str, key: str, joint_names, offsets: np.ndarray,
                      ranges: RangeRecorder | None = None,
                      min_span_rad: float = math.radians(5.0)) -> Calibration:
    """A Calibration from the offsets and (optionally) the ranges seen; a joint that moved less than
    `min_span_rad` gets no range. A `name` check_arm_name refuses is CalibrationError."""
    check_arm_name(name)
    joints = {}
    for i, n in enumerate(joint_names):
        lo = hi = None
        if ranges is not None and ranges.samples and ranges.high[i] - ranges.low[i] >= min_span_rad:
            lo, hi = float(ranges.low[i]), float(ranges.high[i])
        joints[n] = JointCalibration(float(offsets[i]), lo, hi)
    return Calibration(name=name, key=key, joints=joints,
                       created=time.strftime("%Y-%m-%dT%H:%M:%SZ", time.gmtime()))
