"""One bus cycle of DynamixelBus against the simulated CRANE-X7: a fast sync read of the 10-byte block
(Present Current, Velocity, Position) from all 8 servos plus one sync write of Goal Current.

Measured in-process (dxlsim://, no OS in the way: the cost of the Python client plus the emulator) and
over a pseudo-terminal (the same bytes through the kernel's tty layer, as with a U2D2, minus the USB
latency timer). The plain sync read path (servos without fast sync read) is measured for comparison.
Bytes on the wire per cycle are counted at the port and compared with the Protocol 2.0 minimum.
"""

from __future__ import annotations

import tempfile
import time
from pathlib import Path

import numpy as np

from crane_io.dynamixel.bus import DynamixelBus
from crane_io.sim import simulated_arm
from crane_io.sim.transport import PtyServer

N_SERVOS = 8
BLOCK = 10  # bytes read per servo (addresses 126..135)
BAUD = 3_000_000


def protocol_minimum() -> dict[str, int]:
    """Bytes on the wire per cycle, Protocol 2.0, 8 servos (facts §6d for the plain sync read)."""
    instruction = 14 + N_SERVOS  # header 4, ID, LEN 2, INST, addr 2, len 2, IDs, CRC 2
    plain_reply = N_SERVOS * (11 + BLOCK)  # one status packet per servo
    fast_reply = 8 + N_SERVOS * (BLOCK + 4)  # one packet: header..INST, then ERR ID DATA CRC per servo
    write_all = 14 + N_SERVOS * (1 + 2)  # sync write of a 2-byte Goal Current to 8 servos
    return {"plain": instruction + plain_reply + write_all, "fast": instruction + fast_reply + write_all,
            "fast_read": instruction + fast_reply, "plain_read": instruction + plain_reply}


def _cycles(bus: DynamixelBus, n: int) -> tuple[np.ndarray, float]:
    amps = np.zeros(N_SERVOS)
    bus.read_state()
    bus.write_goal_current(amps)
    w0, r0 = bus._port.bytes_written, bus._port.bytes_read
    times = np.empty(n)
    for k in range(n):
        t0 = time.perf_counter()
        state = bus.read_state()
        amps[:] = 0.05 * np.sin(state.position)
        bus.write_goal_current(amps)
        times[k] = time.perf_counter() - t0
    wire = (bus._port.bytes_written - w0 + bus._port.bytes_read - r0) / n
    return times, wire


def _measure(url: str, n: int) -> tuple[np.ndarray, float, DynamixelBus]:
    with DynamixelBus(url) as bus:
        bus.ping_all()
        bus.configure(watchdog_s=0.5)
        bus.torque_on()
        times, wire = _cycles(bus, n)
    return times, wire, bus


def _rows(label: str, times: np.ndarray, note: str) -> list[dict]:
    return [
        {"benchmark": "bus", "metric": f"{label}: cycles/s", "value": len(times) / times.sum(), "unit": "1/s",
         "note": note},
        {"benchmark": "bus", "metric": f"{label}: median cycle", "value": float(np.median(times)) * 1e3,
         "unit": "ms", "note": f"{len(times)} cycles"},
        {"benchmark": "bus", "metric": f"{label}: p99 cycle", "value": float(np.percentile(times, 99)) * 1e3,
         "unit": "ms", "note": ""},
    ]


def run(quick: bool = False) -> list[dict]:
    n_inproc, n_pty = (200, 100) if quick else (3000, 1500)
    rows = []
    minimum = protocol_minimum()

    sim = simulated_arm()
    try:
        times, wire, bus = _measure(sim.url, n_inproc)
        assert bus.stats.fast, "fast sync read was not used"
    finally:
        sim.close()
    rows += _rows("in-process fast", times, "dxlsim://, fast sync read + sync write")
    rows += [
        {"benchmark": "bus", "metric": "wire bytes per cycle (measured)", "value": wire, "unit": "B",
         "note": f"fast read {minimum['fast_read']} B + write to the 3 current-mode servos 23 B"},
        {"benchmark": "bus", "metric": "Protocol 2.0 minimum, fast sync read", "value": minimum["fast"],
         "unit": "B", "note": f"{minimum['fast_read']} B read + 38 B write to 8 servos"},
        {"benchmark": "bus", "metric": "Protocol 2.0 minimum, plain sync read", "value": minimum["plain"],
         "unit": "B", "note": f"{minimum['plain_read']} B read + 38 B write (facts 6d)"},
        {"benchmark": "bus", "metric": "wire time per cycle at 3 Mbps", "value": wire * 10 / BAUD * 1e3,
         "unit": "ms", "note": "8N1, measured bytes; plus USB latency on hardware"},
    ]

    sim = simulated_arm(fast_sync_read=False)
    try:
        times, wire_plain, bus = _measure(sim.url, n_inproc)
        assert bus.stats.fast is False
    finally:
        sim.close()
    rows += _rows("in-process plain", times, "servos without fast sync read (fallback)")
    rows.append({"benchmark": "bus", "metric": "wire bytes per cycle, plain fallback", "value": wire_plain,
                 "unit": "B", "note": "measured"})

    sim = simulated_arm()
    try:
        with tempfile.TemporaryDirectory() as tmp, PtyServer(sim.chain, Path(tmp) / "arm") as server:
            times, _, _ = _measure(str(Path(tmp) / "arm"), n_pty)
            if server.error is not None:
                raise server.error
    finally:
        sim.close()
    rows += _rows("pty fast", times, "through a pseudo-terminal and a server thread")
    return rows


if __name__ == "__main__":
    import sys

    sys.path.insert(0, str(Path(__file__).resolve().parent))
    from run_all import table

    print(table(run(quick="--quick" in sys.argv)))
