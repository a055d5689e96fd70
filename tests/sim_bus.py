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


def capture_writes(bus: DynamixelBus) -> list[bytes]:
    """Every packet `bus` writes from now on, appended to the returned list (and still sent)."""
    sent: list[bytes] = []
    write = bus._port.writePort

    def capture(packet):
        sent.append(bytes(packet))
        return write(packet)

    bus._port.writePort = capture
    return sent
