"""Opening a serial port for dynamixel-sdk: device paths, pty paths and `dxlsim://` URLs alike.

dynamixel-sdk's `PortHandler.setupPort` builds `serial.Serial(port_name)` directly, which only knows
device paths. `CranePortHandler` opens the port with `serial.serial_for_url` instead, so a U2D2 at
/dev/ttyUSB0, its /dev/serial/by-id/... link, a pseudo-terminal served by the simulator and the
simulator's in-process `dxlsim://NAME` URL all work with the same SDK code. Real devices are opened
exclusively (no two programs on one arm) and in low-latency mode where the OS allows it.

It also replaces the SDK's fixed 16 ms latency allowance in the reply timeout by the port's real
FTDI latency timer when it is known, so a lost reply costs ~4 ms instead of ~34 ms at 1 ms latency.
"""

from __future__ import annotations

import errno
import os
import select
import stat

import serial
from dynamixel_sdk import PortHandler

from crane_io.dynamixel.ports import read_latency_timer
from crane_io.errors import HardwareError

try:
    import termios

    _LOW_LEVEL_ERRORS: tuple = (OSError, termios.error)
except ImportError:  # pragma: no cover - not POSIX
    _LOW_LEVEL_ERRORS = (OSError,)


class PortIOError(serial.SerialException):
    """The open port stopped working (adapter unplugged, pty closed); raised from inside SDK calls."""


# The SDK's allowance for the USB adapter's latency timer, used when the real one is unknown.
SDK_LATENCY_MS = 16.0
# Longest a read waits for the port to become readable before handing control back to the SDK's poll.
WAIT_S = 0.0005


def is_url(port: str) -> bool:
    """True for pyserial URLs (dxlsim://, loop://, socket://, ...) as opposed to device paths."""
    return "://" in port


def _default_latency_ms(port: str) -> float:
    if port.startswith("dxlsim://"):
        return 4.0  # in-process simulator: replies are immediate; this only bounds a dropped reply
    if is_url(port):
        return SDK_LATENCY_MS
    timer = read_latency_timer(os.path.realpath(port))
    return float(timer) if timer is not None else SDK_LATENCY_MS


class CranePortHandler(PortHandler):
    """A dynamixel_sdk.PortHandler that opens through `serial.serial_for_url` and counts bytes."""

    def __init__(self, port_name: str, latency_ms: float | None = None):
        super().__init__(port_name)
        self.latency_ms = float(latency_ms) if latency_ms is not None else _default_latency_ms(port_name)
        self.bytes_written = 0
        self.bytes_read = 0
        self.low_latency = False
        self._fd = None

    # -- the SDK's hooks -------------------------------------------------------------------------
    def setupPort(self, cflag_baud):  # noqa: N802 (SDK name)
        if self.is_open:
            self.closePort()
        self.ser = _open_serial(self.port_name, self.baudrate)
        self.low_latency = _try_low_latency(self.ser)
        try:
            self._fd = self.ser.fileno()
        except (AttributeError, NotImplementedError, OSError, serial.SerialException):
            self._fd = None  # URL ports (dxlsim://) have no descriptor
        self.is_open = True
        self.ser.reset_input_buffer()
        self.tx_time_per_byte = (1000.0 / self.baudrate) * 10.0
        return True

    def closePort(self):  # noqa: N802
        if self.ser is not None:
            try:
                self.ser.close()
            except _LOW_LEVEL_ERRORS + (serial.SerialException,):
                pass
            finally:
                self.is_open = False

    def clearPort(self):  # noqa: N802
        try:
            self.ser.reset_input_buffer()
        except _LOW_LEVEL_ERRORS as exc:
            raise PortIOError(_io_reason(exc)) from None

    def setPacketTimeout(self, packet_length):  # noqa: N802
        self.packet_start_time = self.getCurrentTime()
        self.packet_timeout = self.tx_time_per_byte * packet_length + 2.0 * self.latency_ms + 2.0

    def readPort(self, length):  # noqa: N802
        try:
            return self._read(length)
        except _LOW_LEVEL_ERRORS as exc:
            raise PortIOError(_io_reason(exc)) from None

    def _read(self, length):
        data = self.ser.read(length)
        if not data and self._fd is not None:
            # The SDK polls with timeout 0 until its packet timeout; waiting here for the descriptor
            # to become readable (at most WAIT_S) keeps the poll from spinning a core and holding the
            # GIL, which matters with two arms in two threads.
            try:
                select.select([self._fd], [], [], WAIT_S)
            except (OSError, ValueError):
                self._fd = None
            data = self.ser.read(length)
        self.bytes_read += len(data)
        return data

    def writePort(self, packet):  # noqa: N802
        try:
            n = self.ser.write(bytes(packet))
        except _LOW_LEVEL_ERRORS as exc:
            raise PortIOError(_io_reason(exc)) from None
        self.bytes_written += n or 0
        return n


def _io_reason(exc: BaseException) -> str:
    args = getattr(exc, "args", ())
    if len(args) == 2 and isinstance(args[1], str):
        return args[1]
    return str(exc) or type(exc).__name__


def _open_serial(port: str, baudrate: int):
    url = is_url(port)
    if port.startswith("dxlsim://"):
        from crane_io.sim import transport  # noqa: F401 - registers the dxlsim:// URL handler with pyserial
    if not url and not os.path.exists(port):
        raise HardwareError(f"port {port} does not exist (is the U2D2 plugged in? see `crane-collect ports`)")
    if not url and not stat.S_ISCHR(os.stat(port).st_mode):
        what = "a folder" if os.path.isdir(port) else "a regular file"
        raise HardwareError(f"{port} is {what}, not a serial port (a U2D2 is a device such as /dev/ttyUSB0; "
                            "see `crane-collect ports`)")
    try:
        ser = serial.serial_for_url(port, do_not_open=True)
    except ValueError as exc:  # unknown URL scheme
        raise HardwareError(f"cannot open {port}: {exc}") from None
    ser.baudrate = baudrate
    ser.bytesize = serial.EIGHTBITS
    ser.timeout = 0
    if not url and hasattr(ser, "exclusive"):
        ser.exclusive = True
    try:
        ser.open()
    except (serial.SerialException, OSError) as exc:
        raise HardwareError(_open_failure(port, exc)) from None
    return ser


def _open_failure(port: str, exc: Exception) -> str:
    code = getattr(exc, "errno", None)
    text = str(exc)
    if code == errno.ENOENT:
        return f"port {port} does not exist (is the U2D2 plugged in? see `crane-collect ports`)"
    if code == errno.EACCES:
        return (f"no permission to open {port} (add yourself to the dialout group: "
                "`sudo usermod -aG dialout $USER`, then log in again; or install udev/99-crane-x7.rules)")
    if code == errno.ENOTTY or f"({errno.ENOTTY}," in text:
        return (f"{port} is not a serial port (a U2D2 is a device such as /dev/ttyUSB0; "
                "see `crane-collect ports`)")
    if code == errno.EBUSY or "exclusively lock" in text or "busy" in text.lower():
        return f"port {port} is busy: another program (another crane-collect?) has it open; close that first"
    return f"cannot open {port}: {text}"


def _try_low_latency(ser) -> bool:
    """Ask the kernel for ASYNC_LOW_LATENCY; ptys, URLs and non-Linux systems do not support it."""
    setter = getattr(ser, "set_low_latency_mode", None)
    if setter is None:
        return False
    try:
        setter(True)
        return True
    except (OSError, ValueError, NotImplementedError, serial.SerialException):
        return False


def open_port(url_or_path: str, baudrate: int = 3_000_000, *, latency_ms: float | None = None
              ) -> CranePortHandler:
    """Open `url_or_path` at `baudrate` and return the SDK port handler (raises HardwareError)."""
    handler = CranePortHandler(url_or_path, latency_ms=latency_ms)
    if handler.getCFlagBaud(baudrate) <= 0:
        raise HardwareError(f"baud rate {baudrate} is not one a Dynamixel/U2D2 supports (use 3000000)")
    handler.baudrate = baudrate
    handler.setupPort(baudrate)
    return handler
