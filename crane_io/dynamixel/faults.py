"""Named servo faults and the exceptions the bus layer raises.

Two things go wrong on a Dynamixel bus:

* the servo says so: the error byte of every Protocol 2.0 status packet (bit 7 = "alert", i.e. the
  Hardware Error Status register at address 70 is non-zero; bits 0..6 = an error number about the
  instruction just processed), and the Hardware Error Status register itself (one bit per fault);
* the servo says nothing, or something corrupted: the bus retries within a bounded budget and then
  raises `CommunicationError` (or `ServoMissingError` when it can tell which servo went silent).

Every exception here is a `crane_io.errors.HardwareError`, so the command lines print its one sentence.
"""

from __future__ import annotations

from crane_io.dynamixel.control_table import HARDWARE_ERROR_BITS
from crane_io.errors import HardwareError

# Status packet error byte (Protocol 2.0): bit 7 is the alert flag, bits 0..6 hold one error number.
STATUS_ALERT_BIT = 0x80
STATUS_ERROR_NUMBERS = {
    1: "result fail",
    2: "instruction error",
    3: "CRC error",
    4: "data range error",
    5: "data length error",
    6: "data limit error",
    7: "access error",
}


def decode_hardware_error(bits: int) -> list[str]:
    """Hardware Error Status register value (address 70) -> fault names, lowest bit first.

    Unused bits (1, 6, 7) that are set anyway are reported as "unknown hardware error bit N".
    """
    bits = int(bits) & 0xFF
    names = []
    for bit in range(8):
        if bits & (1 << bit):
            names.append(HARDWARE_ERROR_BITS.get(bit, f"unknown hardware error bit {bit}"))
    return names


def encode_hardware_error(names) -> int:
    """Fault names -> Hardware Error Status bits (the inverse of `decode_hardware_error`)."""
    lookup = {name: bit for bit, name in HARDWARE_ERROR_BITS.items()}
    bits = 0
    for name in names:
        if name not in lookup:
            raise ValueError(f"unknown hardware error {name!r} (known: {', '.join(lookup)})")
        bits |= 1 << lookup[name]
    return bits


def status_alert(error: int) -> bool:
    """True when a status packet's error byte carries the alert bit (a hardware error is latched)."""
    return bool(int(error) & STATUS_ALERT_BIT)


def decode_status_error(error: int) -> list[str]:
    """Status packet error byte -> names: "alert" for bit 7, then the instruction error, if any."""
    error = int(error) & 0xFF
    names = ["alert"] if error & STATUS_ALERT_BIT else []
    number = error & 0x7F
    if number:
        names.append(STATUS_ERROR_NUMBERS.get(number, f"unknown status error {number}"))
    return names


def servo_label(joint: str, servo_id: int) -> str:
    """How a servo is named in every message: 'joint4 (ID 5)'."""
    return f"{joint} (ID {servo_id})"


class CommunicationError(HardwareError):
    """Replies stayed missing or corrupted after the bus's bounded retry budget."""


class ServoMissingError(CommunicationError):
    """An expected servo does not answer (names the joint, its ID and the port)."""

    def __init__(self, message: str, missing: dict[str, int] | None = None, port: str = ""):
        super().__init__(message)
        self.missing = dict(missing or {})  # joint -> servo ID
        self.port = port


class WrongModelError(HardwareError):
    """A servo answered with a model number other than the arm description expects."""

    def __init__(self, message: str, joint: str = "", expected: str = "", found: int = 0):
        super().__init__(message)
        self.joint = joint
        self.expected = expected
        self.found = found


class ServoFaultError(HardwareError):
    """One or more servos latched Hardware Error Status bits (overload, overheating, ...)."""

    def __init__(self, message: str, faults: dict[str, list[str]] | None = None):
        super().__init__(message)
        self.faults = dict(faults or {})  # joint -> fault names


class WatchdogExpiredError(ServoFaultError):
    """The servos' Bus Watchdog expired: the host was silent too long, and those servos stopped
    (Bus Watchdog reads -1, goal items refuse writes) until `DynamixelBus.configure` clears it."""


WATCHDOG_EXPIRED = "bus watchdog expired"  # the fault name read_hardware_errors gives an expired servo


class ServoRejectedError(HardwareError):
    """A servo answered an instruction with an error number (access, data range, ...)."""


class ConfigurationMismatchError(HardwareError):
    """A register read back after `configure` does not hold the value written."""


def describe_faults(faults: dict[str, list[str]], ids: dict[str, int]) -> str:
    """{'joint4': ['overload']} -> 'joint4 (ID 5): overload' joined with '; '."""
    return "; ".join(f"{servo_label(j, ids.get(j, -1))}: {', '.join(names)}" for j, names in faults.items())
