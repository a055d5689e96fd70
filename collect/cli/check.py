"""`crane-collect check`: what each servo of an arm says about itself."""

from __future__ import annotations

import math

import click

from crane_io.cli_support import cli_errors
from crane_io.errors import ConfigError

_MODES = {0: "current", 1: "velocity", 3: "position", 4: "ext. position", 5: "current-based pos.", 16: "PWM"}


def _not_answering(r: dict) -> str:
    """Why a servo has no row: silence, or replies that come too late (and what to do about each)."""
    expected = r["expected_model"]
    late = r.get("late_reply_s")
    if "tries" not in r:
        return f"NOT ANSWERING (expected {expected})"
    timeout_ms = r["timeout_s"] * 1e3
    tries = r["tries"]
    reads = "a read" if tries == 1 else f"{tries} reads"
    if late is None:
        return (f"NOT ANSWERING (expected {expected}): no reply at all, to {reads} nor in the "
                f"{r['listen_s']:g} s after; check the arm's power and cable, the servo's ID "
                "and baud rate (3 Mbps)")
    if late * 1e3 <= timeout_ms:
        return (f"ANSWERS ONLY SOMETIMES (expected {expected}): no reply to {reads}, then one after "
                f"{late * 1e3:.1f} ms; check the cable and connectors, then retry")
    return (f"REPLIES TOO LATE (expected {expected}): no reply to {reads} within the {timeout_ms:.1f} ms "
            f"timeout, but a reply came after {late * 1e3:.0f} ms: the computer or the USB adapter is "
            "slow (check the adapter's latency timer with `crane-collect ports`, close busy programs) "
            "or the line is overloaded; retry")


def _row(r: dict, offset: float | None = None) -> str:
    head = f"ID {r['id']:>2} {r['joint']:<8}"
    if not r.get("answering"):
        return f"{head} {_not_answering(r)}"
    model = r["model"] + ("" if r["model"] == r["expected_model"] else f" (EXPECTED {r['expected_model']})")
    mode = _MODES.get(r["operating_mode"], str(r["operating_mode"]))
    errors = ", ".join(r["hardware_errors"]) or "none"
    torque = "on " if r["torque_enabled"] else "off"
    lo, hi = math.degrees(r["min_position_rad"]), math.degrees(r["max_position_rad"])
    return (f"{head} {model:<12} fw {r['firmware']:>3}  mode {mode:<8} torque {torque}"
            f"  limits {lo:7.1f}..{hi:6.1f} deg {r['current_limit_a']:.2f} A  errors {errors}"
            f"  {r['voltage_v']:.1f} V  {r['temperature_c']:.0f} C"
            f"  at {math.degrees(r['position_rad']):7.1f} deg"
            + ("" if offset is None else f" (calibrated {_deg(r['position_rad'] - offset):7.1f})"))


def _deg(rad: float) -> float:
    """Degrees to 0.1, never printed as -0.0."""
    return round(math.degrees(rad), 1) + 0.0


@click.command("check")
@click.option("--sim", is_flag=True, help="Check a simulated arm (in-process) instead of hardware.")
@click.option("--port", "ports", multiple=True, metavar="PORT",
              help="Serial port of an arm's U2D2; repeat for both arms.")
@click.option("--calibration", "calibration_path", type=click.Path(dir_okay=False), default=None,
              metavar="TOML", help="Show angles with this calibration (default: the one stored for each "
                                   "port's adapter by `crane-collect calibrate`, if any).")
@cli_errors
def check(sim, ports, calibration_path):
    """Per servo: ID, joint, model, firmware, mode, torque, limits, errors, voltage, temperature, angle
    (and the calibrated angle, with the calibration in use named).

    The check reads registers only; on the way out it leaves every servo with torque off."""
    from crane_io.description import default_arm
    from crane_io.dynamixel.bus import DynamixelBus
    from crane_io.dynamixel.calibration import find_calibration, load_calibration
    from crane_io.dynamixel.ports import port_warnings
    from crane_io.dynamixel.servo_report import LATE_REPLY_LISTEN_S

    arm = default_arm()
    sims = []
    if sim:
        if ports:
            raise ConfigError("--port cannot be combined with --sim")
        from crane_io.sim import simulated_arm

        sims.append(simulated_arm(arm=arm))
        ports = (sims[0].url,)
    elif not ports:
        raise ConfigError("give --port PORT for each arm (see `crane-collect ports`), or --sim")
    try:
        problems = 0
        for port in ports:
            click.echo(f"{port}:")
            if not sim:
                for w in port_warnings(port):
                    click.echo(f"  Warning: {w}")
            cal = (load_calibration(calibration_path) if calibration_path is not None
                   else None if sim else find_calibration(port))
            click.echo(f"  {cal.describe()}" if cal is not None else
                       "  no calibration (angles as the servos read them; see `crane-collect calibrate`)")
            with DynamixelBus(port, arm, name=str(port)) as bus:
                for r in bus.servo_report(late_listen_s=LATE_REPLY_LISTEN_S):
                    offset = cal.joints[r["joint"]].offset_rad if cal and r["joint"] in cal.joints else None
                    click.echo("  " + _row(r, offset))
                    bad = not r.get("answering") or r["model"] != r["expected_model"] or r["hardware_errors"]
                    problems += bool(bad)
        if problems:
            raise click.exceptions.Exit(1)
    finally:
        for s in sims:
            s.close()
