"""Where a self-test's result is kept, and the check `crane-collect run` makes of it.

The record sits beside the calibration it was made with: `KEY.selftest.toml` next to `KEY.toml` in the
calibration folder (crane_io.dynamixel.calibration), or `NAME.selftest.toml` next to a calibration file
given by name. It holds the SHA-256 of that calibration's content (arm, adapter, date, every joint's
offset and range), so a changed calibration (the arm calibrated again, the file edited) needs a new
self-test; an arm tested without a calibration records an empty digest, and only counts while it runs
without one.

    [selftest]
    arm = "follower"
    key = "FT6Z5Q1I"
    created = "2026-11-28T23:40:00Z"
    passed = true
    calibration = "/home/lab/.config/crane-x7/calibration/FT6Z5Q1I.toml"
    calibration_sha256 = "9f2c..."
    duration_s = 28.4
    [findings.f01]
    check = "identity"
    joint = "joint1"
    status = "pass"
    sentence = "ID 2 is a XM430-W350 as described, firmware v52."
"""

from __future__ import annotations

import hashlib
import json
import time
from pathlib import Path

from crane_io.errors import ConfigError
from crane_io.toml_config import dump_toml, read_toml

SUFFIX = ".selftest.toml"


class SelftestMissingError(ConfigError):
    """An arm without a passing self-test for the calibration it would run with."""


def calibration_digest(calibration) -> str:
    """SHA-256 of the calibration's content: its arm, adapter, date and every joint's offset and range
    ("" for no calibration)."""
    if calibration is None:
        return ""
    content = {"name": calibration.name, "key": calibration.key, "created": calibration.created,
               "joints": {n: [j.offset_rad, j.min_rad, j.max_rad] for n, j in calibration.joints.items()}}
    return hashlib.sha256(json.dumps(content, sort_keys=True).encode()).hexdigest()


def record_path(port: str, calibration=None, comports=None) -> Path:
    """Where the self-test of the arm behind `port` with `calibration` is kept (see the docstring)."""
    if calibration is not None and calibration.path:
        path = Path(calibration.path)
        return path.with_name(path.name[:-len(path.suffix)] + SUFFIX if path.suffix else path.name + SUFFIX)
    from crane_io.dynamixel.calibration import adapter_key, config_dir

    return config_dir() / f"{adapter_key(port, comports)}{SUFFIX}"


def save_record(result, path: Path, *, arm_name: str, key: str, calibration=None) -> Path:
    """Write the result (atomically, crane_io.output_files) to `path`; returns it."""
    from crane_io.output_files import write_text_atomic

    findings = {f"f{k + 1:02d}": {"check": f.check, "joint": f.joint, "status": f.status,
                                  "sentence": f.sentence}
                for k, f in enumerate(result.findings)}
    head = {"arm": arm_name, "key": key, "created": time.strftime("%Y-%m-%dT%H:%M:%SZ", time.gmtime()),
            "passed": bool(result.passed),
            "calibration": calibration.path if calibration is not None and calibration.path else "",
            "calibration_sha256": calibration_digest(calibration), "duration_s": round(result.duration_s, 3)}
    text = ("# crane-x7 arm self-test (crane-collect selftest; collect/selftest_record.py)\n"
            + dump_toml({"selftest": head, "findings": findings}))
    path.parent.mkdir(parents=True, exist_ok=True)
    return write_text_atomic(path, text, "self-test record")


def load_record(path: Path) -> dict | None:
    """The [selftest] table of the record at `path`; None when there is none or it cannot be read."""
    if not Path(path).is_file():
        return None
    try:
        data = read_toml(path, what="self-test record")
    except ConfigError:
        return None
    head = data.get("selftest")
    return head if isinstance(head, dict) else None


def require_selftest(arm_name: str, port: str, calibration=None, comports=None) -> None:
    """SelftestMissingError (one sentence naming the command to run) unless the arm behind `port` has a
    passing self-test recorded for `calibration`."""
    path = record_path(port, calibration, comports)
    head = load_record(path)
    command = f"`crane-collect selftest --port {port}`"
    if calibration is not None and calibration.path:
        command = f"`crane-collect selftest --port {port} --calibration {calibration.path}`"
    if head is None:
        why = "has no self-test on record"
    elif head.get("calibration_sha256") != calibration_digest(calibration):
        why = "was self-tested with another calibration than the one it runs with"
    elif head.get("passed") is not True:
        why = "failed its last self-test"
    else:
        return
    raise SelftestMissingError(f"the {arm_name} arm on {port} {why} ({path}); run {command} first, or pass "
                               "`skip_selftest` to run without one")
