"""The per-servo diagnostics report behind `crane-collect check` and the stop's torque read-back.

    from crane_io.dynamixel.servo_report import servo_report
    rows = servo_report(bus)                 # one dict per servo, in arm.joints order
    rows = servo_report(bus, late_listen_s=LATE_REPLY_LISTEN_S)   # a check: give a silent servo a second look

It reads the control table of each servo in one read (addresses 0..146) and converts what a person
checks (model, firmware, mode, torque, limits, watchdog, errors, voltage, temperature, angle) to SI
units. It is no part of the control cycle: it uses the bus's public reads (`read_block`, `reply_timeout_s`,
`late_reply_s`: the bus's own transfers, retries, counters, port errors) but may wait far longer than a cycle
may (`late_listen_s`). `DynamixelBus.servo_report`
calls it.
"""

from __future__ import annotations

from typing import TYPE_CHECKING

from crane_io.dynamixel import units
from crane_io.dynamixel.control_table import X_SERIES, model_by_number, span
from crane_io.dynamixel.faults import CommunicationError, decode_hardware_error

if TYPE_CHECKING:
    from crane_io.dynamixel.bus import DynamixelBus

LATE_REPLY_LISTEN_S = 0.5  # what `crane-collect check` gives a servo that missed every try
# addresses 0..146 (Model Number .. Present Temperature): everything the report shows, one read per servo
REPORT_ADDRESS, REPORT_SIZE = span("model_number", "present_temperature")
# the second look at a servo that did not answer in time (see servo_report)
_PROBE = X_SERIES["model_number"]


def servo_report(bus: DynamixelBus, late_listen_s: float = 0.0) -> list[dict]:
    """One dict per servo: id, joint, expected_model, answering, model_number, model, firmware,
    operating_mode, torque_enabled, return_delay_s, drive_mode, current_limit_a, velocity_limit_rads,
    min/max_position_rad, bus_watchdog_s, watchdog_expired, hardware_errors, voltage_v, temperature_c,
    position_rad.

    A servo that does not answer in time gets `answering` False, `tries`, `timeout_s` (the reply
    timeout of each try), `listen_s` and `late_reply_s`. With `late_listen_s` > 0 (a check, never a
    stop that must be quick) it is asked once more and given that long to answer: `late_reply_s`
    is the seconds its reply took, or None when nothing came (silence; also without a second look)."""
    bus.require_open()
    rows = []
    for j, (joint, sid) in enumerate(zip(bus.joint_names, bus.ids)):
        row = {"id": sid, "joint": joint, "expected_model": bus.arm.joints[j].model}
        try:
            block = bus.read_block(sid, REPORT_ADDRESS, REPORT_SIZE, joint)
        except CommunicationError:
            # a second look: a read of Model Number (2 bytes), whose short reply cannot be mistaken for a
            # late reply to the report's own reads
            late = None
            if late_listen_s > 0:
                late = bus.late_reply_s(sid, _PROBE.address, _PROBE.size, late_listen_s)
            row.update(answering=False, tries=1 + bus.retries, timeout_s=bus.reply_timeout_s(REPORT_SIZE),
                       listen_s=late_listen_s, late_reply_s=late)
            rows.append(row)
            continue
        model = model_by_number(_value(block, _PROBE))
        table = model or bus.arm.joints[j].servo_model

        def reg(name, _block=block, _table=table):
            return _value(_block, _table.register(name))

        row.update(
            answering=True,
            model_number=reg("model_number"),
            model=model.name if model else f"unknown model {reg('model_number')}",
            firmware=reg("firmware_version"),
            operating_mode=reg("operating_mode"),
            torque_enabled=bool(reg("torque_enable")),
            return_delay_s=reg("return_delay_time") * units.SECONDS_PER_RETURN_DELAY_LSB,
            drive_mode=reg("drive_mode"),
            current_limit_a=float(units.current_to_ampere(reg("current_limit"))),
            velocity_limit_rads=float(units.velocity_to_rads(reg("velocity_limit"))),
            min_position_rad=float(units.position_to_rad(reg("min_position_limit"))),
            max_position_rad=float(units.position_to_rad(reg("max_position_limit"))),
            bus_watchdog_s=(float(units.watchdog_to_seconds(reg("bus_watchdog")))
                            if reg("bus_watchdog") >= 0 else None),
            watchdog_expired=reg("bus_watchdog") < 0,
            hardware_errors=decode_hardware_error(reg("hardware_error_status")),
            voltage_v=float(units.voltage_to_volt(reg("present_input_voltage"))),
            temperature_c=float(reg("present_temperature")),
            position_rad=float(units.position_to_rad(reg("present_position"))),
        )
        rows.append(row)
    return rows


def _value(block: bytes, r) -> int:
    """Register `r` out of a block read from address REPORT_ADDRESS."""
    start = r.address - REPORT_ADDRESS
    return int.from_bytes(block[start:start + r.size], "little", signed=r.signed)
