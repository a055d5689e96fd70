"""`crane-collect calibrate --port P --arm NAME`: find where each joint's zero really is and the range it
moves through, and store it for the arm's adapter (crane_io.dynamixel.calibration).

Torque stays off the whole time: the person moves the arm by hand.
  1. Every joint on its zero mark, Enter: the angles read there (averaged over AVERAGE_READS reads) are
     the offsets.
  2. Unless --no-range: each joint slowly through its whole range, Enter: the smallest and largest
     calibrated angle seen per joint.
`run` and `check` then use the calibration of that adapter (by its USB serial) whatever port it gets.
The calibration is written (atomically) only after the person confirmed every step: standard input at
its end (or closed) stops with one sentence and leaves any stored calibration as it was.
"""

from __future__ import annotations

import math
import sys
import threading

import click

from crane_io.cli_support import cli_errors
from crane_io.errors import CraneError

AVERAGE_READS = 25
RANGE_READ_PERIOD_S = 0.02


def _mean_position(bus, reads: int):
    import numpy as np

    return np.mean([bus.read_state(check_faults=False).position for _ in range(reads)], axis=0)


def _confirm(step: int) -> None:
    """Wait for the person to press Enter for `step`; standard input at its end or closed is no
    confirmation: CraneError, and nothing is written."""
    try:
        line = sys.stdin.readline() if sys.stdin is not None else ""
    except (OSError, ValueError):  # closed or unreadable
        line = ""
    if not line:
        raise CraneError(f"standard input ended before step {step} was confirmed (each step needs Enter "
                         "from the person at the arm); no calibration was written")


def _sample_range(bus, recorder, stop: threading.Event, errors: list, live: bool, names) -> None:
    """Read the arm until `stop`, feeding `recorder`; the first bus error ends it (kept in `errors`)."""
    try:
        while not stop.is_set():
            recorder.add(bus.read_state(check_faults=False).position)
            if live and recorder.samples % 10 == 0:
                spans = "  ".join(f"{n} {math.degrees(lo):6.1f}..{math.degrees(hi):6.1f}"
                                  for n, lo, hi in zip(names, recorder.low, recorder.high))
                click.echo("\r" + spans, nl=False, err=True)
            stop.wait(RANGE_READ_PERIOD_S)
    except Exception as exc:  # noqa: BLE001 - handed to the main thread
        errors.append(exc)


@click.command("calibrate")
@click.option("--port", required=True, metavar="PORT",
              help="Serial port of the arm's U2D2 (or a sim-serve link).")
@click.option("--arm", "arm_name", required=True, metavar="NAME",
              help="What to call this arm (e.g. leader, follower, left); stored in the file.")
@click.option("--no-range", is_flag=True, help="Only the zero marks; do not record the joints' ranges.")
@click.option("--output", type=click.Path(dir_okay=False), default=None, metavar="TOML",
              help="Write the calibration here instead of the adapter's file in the user's configuration "
                   "directory (then give it to run with --leader-calibration/--follower-calibration). "
                   "An existing file is replaced only with --force.")
@click.option("--force", is_flag=True,
              help="Replace the --output file if it exists (the adapter's stored calibration is replaced "
                   "once every step is confirmed, without --force).")
@cli_errors
def calibrate(port, arm_name, no_range, output, force):
    """Guided calibration of one arm: zero marks, then ranges; stored per adapter (USB serial)."""
    import os

    from crane_io.description import default_arm
    from crane_io.dynamixel.bus import DynamixelBus
    from crane_io.dynamixel.calibration import (
        RangeRecorder,
        adapter_key,
        build_calibration,
        calibration_path,
        check_arm_name,
        offsets_at_marks,
        save_calibration,
    )
    from crane_io.output_files import check_output

    check_arm_name(arm_name)  # stored in TOML and shown on terminals: refused before the arm is touched
    arm = default_arm()
    names = arm.joint_names
    key = adapter_key(port)
    target = calibration_path(key) if output is None else output
    # checked before the arm is touched: never the port, an existing --output only with --force
    check_output(target, inputs=[port] if os.path.exists(port) else [], force=force or output is None,
                 what="calibration", make_folders=True)
    with DynamixelBus(port, arm, name=arm_name) as bus:
        bus.ping_all()
        bus.safe_stop()  # torque off on every servo: the arm is moved by hand
        click.echo(f"Calibrating {arm_name!r} on {port} (adapter {key}). Torque is off on every joint.")
        click.echo("Step 1: put every joint on its zero mark (the arm straight up, the marks on each joint "
                   "lined up), hold it still, then press Enter.")
        _confirm(1)
        offsets = offsets_at_marks(_mean_position(bus, AVERAGE_READS), names)
        ranges = None
        if not no_range:
            click.echo("Step 2: move each joint slowly through its whole range (end to end), then press "
                       "Enter.")
            ranges = RangeRecorder(offsets)
            stop, errors = threading.Event(), []
            sampler = threading.Thread(target=_sample_range, daemon=True,
                                       args=(bus, ranges, stop, errors, sys.stderr.isatty(), names))
            sampler.start()
            try:
                _confirm(2)
            finally:
                stop.set()
                sampler.join(timeout=5.0)
            if errors:
                raise errors[0]
            click.echo("", err=sys.stderr.isatty())
    cal = build_calibration(arm_name, key, names, offsets, ranges)
    path = save_calibration(cal, target)
    click.echo(f"{'joint':<8} {'offset':>9}   range")
    for n, j in cal.joints.items():
        if j.min_rad is not None:
            span = f"{math.degrees(j.min_rad):7.1f} .. {math.degrees(j.max_rad):6.1f} deg"
        else:
            span = "not recorded (moved less than 5 deg)" if ranges is not None else "not recorded"
        click.echo(f"{n:<8} {math.degrees(j.offset_rad):+8.2f} deg   {span}")
    click.echo(f"calibration written to {path}")
    if output is None:
        click.echo(f"`crane-collect run` and `check` use it for the adapter {key}, whatever port it is "
                   "plugged into.")
