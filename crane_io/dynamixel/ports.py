"""Finding the U2D2 adapters and checking their FTDI latency timer.

A U2D2 is an FTDI FT232H (USB vendor 0x0403, product 0x6014). Each arm has its own, told apart by its
USB serial number ("FT6Z5Q1I"). Linux names it /dev/ttyUSBn (the number depends on plug order) plus a
stable /dev/serial/by-id/... link; udev/99-crane-x7.rules adds /dev/crane_x7_leader and _follower.

The FTDI driver buffers replies for `latency_timer` ms (16 by default), which caps a read-write cycle
near 60 Hz; 1 ms is needed for a 500 Hz loop. These helpers are pure functions over
`serial.tools.list_ports` and sysfs, with the roots injectable so tests use a fake tree.
"""

from __future__ import annotations

import os
from dataclasses import dataclass
from pathlib import Path

U2D2_VID = 0x0403
U2D2_PID = 0x6014
WANTED_LATENCY_MS = 1
SYSFS_ROOT = "/sys"
DEV_ROOT = "/dev"

UDEV_FIX = ("install udev/99-crane-x7.rules (see udev/README.md), or for now: "
            "echo 1 | sudo tee /sys/bus/usb-serial/devices/{tty}/latency_timer")


@dataclass(frozen=True)
class U2D2Port:
    device: str  # /dev/ttyUSB0
    by_id: str | None  # /dev/serial/by-id/usb-FTDI_..._FT6Z5Q1I-if00-port0, if such a link exists
    serial_number: str | None  # the U2D2's USB serial, e.g. FT6Z5Q1I
    description: str
    latency_timer_ms: int | None  # None when sysfs does not say (not an FTDI tty, other OS)
    warning: str | None  # one sentence when the latency timer is not 1 ms


def latency_timer_path(device: str, sysfs_root: str = SYSFS_ROOT) -> Path:
    tty = os.path.basename(device)
    return Path(sysfs_root) / "bus" / "usb-serial" / "devices" / tty / "latency_timer"


def read_latency_timer(device: str, sysfs_root: str = SYSFS_ROOT) -> int | None:
    """The FTDI latency timer of `device` in ms, or None when it cannot be read."""
    try:
        return int(latency_timer_path(device, sysfs_root).read_text().strip())
    except (OSError, ValueError):
        return None


def latency_warning(device: str, latency_ms: int | None) -> str | None:
    """A sentence telling the user to fix the latency timer, or None when it is fine or unknown."""
    if latency_ms is None or latency_ms == WANTED_LATENCY_MS:
        return None
    tty = os.path.basename(device)
    return (f"{device} has an FTDI latency timer of {latency_ms} ms, which limits the loop to about "
            f"{1000 // (latency_ms + 1)} Hz; set it to 1 ms: " + UDEV_FIX.format(tty=tty))


def by_id_links(dev_root: str = DEV_ROOT) -> dict[str, str]:
    """Resolved device path -> /dev/serial/by-id link (the stable name of each adapter)."""
    folder = Path(dev_root) / "serial" / "by-id"
    links = {}
    try:
        entries = sorted(folder.iterdir())
    except OSError:
        return links
    for link in entries:
        target = os.path.realpath(link)
        if os.path.basename(target) and target not in links:
            links[os.path.join(dev_root, os.path.basename(target))] = str(link)
    return links


def list_u2d2_ports(comports=None, *, sysfs_root: str = SYSFS_ROOT, dev_root: str = DEV_ROOT,
                    all_ports: bool = False) -> list[U2D2Port]:
    """Candidate U2D2 ports, sorted by device. `comports` defaults to serial.tools.list_ports.comports();
    `all_ports=True` also lists serial ports that are not FTDI FT232H (other adapters)."""
    if comports is None:
        from serial.tools import list_ports

        comports = list_ports.comports()
    links = by_id_links(dev_root)
    found = []
    for info in comports:
        is_u2d2 = info.vid == U2D2_VID and info.pid == U2D2_PID
        if not (is_u2d2 or all_ports):
            continue
        latency = read_latency_timer(info.device, sysfs_root)
        found.append(U2D2Port(
            device=info.device,
            by_id=links.get(info.device),
            serial_number=info.serial_number,
            description=info.description or "",
            latency_timer_ms=latency,
            warning=latency_warning(info.device, latency),
        ))
    return sorted(found, key=lambda p: p.device)


def port_warnings(device: str, *, sysfs_root: str = SYSFS_ROOT) -> list[str]:
    """Warnings worth printing before driving an arm on `device` (empty when all is well)."""
    real = os.path.realpath(device)
    warning = latency_warning(device, read_latency_timer(real, sysfs_root))
    return [warning] if warning else []
