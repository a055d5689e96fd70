"""A bus opened on an in-process simulated arm the way the loop uses one: every servo pinged, the
watchdog configured, torque on (the bus fast-path tests)."""

from __future__ import annotations

from crane_io.dynamixel.bus import DynamixelBus


def open_bus(sim, watchdog_s: float = 0.1) -> DynamixelBus:
    bus = DynamixelBus(sim.url).open()
    bus.ping_all()
    bus.configure(watchdog_s=watchdog_s)
    bus.torque_on()
    return bus
