"""Which calibration each arm of a run uses (crane_io.dynamixel.calibration), said once and recorded in
the session.

Hardware ports: the stored calibration of each arm's adapter (by its USB serial, or a simulated link's
name), unless `--no-calibration`; `--leader-calibration FILE` / `--follower-calibration FILE` name one
explicitly (also for `--sim`, whose in-process arms otherwise have none).
"""

from __future__ import annotations

import json

from crane_io import session_format as sf
from crane_io.dynamixel.calibration import Calibration, find_calibration, load_calibration

from .arm_pair import ARMS


def resolve_calibrations(ports: dict, files: dict, *, lookup: bool) -> dict[str, Calibration | None]:
    """{arm: Calibration or None}: files[arm] when given, else (when `lookup`) the one stored for the
    adapter behind ports[arm]. CalibrationError (one sentence) for a file that cannot be used."""
    out = {}
    for name in ARMS:
        path = files.get(name)
        if path is not None:
            out[name] = load_calibration(path)
        elif lookup and ports.get(name):
            out[name] = find_calibration(ports[name])
        else:
            out[name] = None
    return out


def calibration_offsets(cals: dict, joint_names) -> dict:
    """{arm: (n,) rad offsets} for the arms that have a calibration."""
    return {name: cal.offsets(joint_names) for name, cal in cals.items() if cal is not None}


def calibration_sentence(cals: dict) -> str:
    """One line: which calibration each arm uses."""
    parts = []
    for name in ARMS:
        cal = cals.get(name)
        parts.append(f"{name}: {cal.describe()}" if cal is not None
                     else f"{name}: no calibration (angles as the servos read them)")
    return "; ".join(parts)


def calibration_attrs(cals: dict) -> dict:
    """Session attributes `leader_calibration` / `follower_calibration`: JSON, "" for none."""
    return {sf.calibration_attr(name): json.dumps(cals[name].as_attrs()) if cals.get(name) is not None else ""
            for name in ARMS}
