"""pyserial URL handler for dxlsim://NAME: a serial port wired to a registered SimulatedChain.

pyserial finds this module because crane_io.sim.transport adds "crane_io.sim" to
serial.protocol_handler_packages; `serial.serial_for_url("dxlsim://NAME", ...)` then builds
`Serial` below. Writes are handed to the chain at once; its replies wait in the input buffer.
"""

from __future__ import annotations

import threading
import time
import urllib.parse

from serial.serialutil import PortNotOpenError, SerialBase, SerialException, to_bytes


class Serial(SerialBase):
    """A serial port whose other end is a simulated Dynamixel chain (see crane_io.sim.transport)."""

    def __init__(self, *args, **kwargs):
        self._chain = None
        self._rx = bytearray()
        # the input buffer's lock (taken directly where nobody waits or is woken: a Condition's own
        # `with` costs another Python call) and the condition readers wait on
        self._lock = threading.Lock()
        self._cond = threading.Condition(self._lock)
        self._waiting = 0  # readers waiting on _cond (write notifies only when there are any)
        super().__init__(*args, **kwargs)

    def open(self):
        from crane_io.sim import transport

        if self.is_open:
            raise SerialException("Port is already open.")
        if self._port is None:
            raise SerialException("Port must be configured before it can be used.")
        parts = urllib.parse.urlsplit(self.port)
        if parts.scheme != transport.URL_SCHEME or not parts.netloc:
            raise SerialException(f"expected a URL like dxlsim://NAME, got {self.port!r}")
        chain = transport.lookup_chain(parts.netloc)
        if chain is None:
            known = ", ".join(transport.registered_names()) or "none"
            raise SerialException(f"no simulated chain named {parts.netloc!r} (registered: {known})")
        self._chain = chain
        self._reconfigure_port()
        self._rx.clear()
        self.is_open = True

    def close(self):
        self.is_open = False
        self._chain = None
        with self._cond:
            self._cond.notify_all()
        super().close()

    def _reconfigure_port(self):
        if not isinstance(self._baudrate, int) or self._baudrate <= 0:
            raise ValueError(f"invalid baudrate: {self._baudrate!r}")

    @property
    def in_waiting(self):
        if not self.is_open:
            raise PortNotOpenError()
        return len(self._rx)

    def read(self, size=1):
        if not self.is_open:
            raise PortNotOpenError()
        with self._lock:
            if self._timeout == 0 or len(self._rx) >= size:  # nothing to wait for (the SDK polls with 0)
                data = bytes(self._rx[:size])
                del self._rx[:size]
                return data
        deadline = None if self._timeout is None else time.monotonic() + self._timeout
        with self._cond:
            self._waiting += 1
            try:
                while len(self._rx) < size and self.is_open:
                    if deadline is None:
                        self._cond.wait()
                        continue
                    left = deadline - time.monotonic()
                    if left <= 0:
                        break
                    self._cond.wait(left)
            finally:
                self._waiting -= 1
            data = bytes(self._rx[:size])
            del self._rx[:size]
        return data

    def write(self, data):
        if not self.is_open:
            raise PortNotOpenError()
        data = to_bytes(data)
        reply = self._chain.feed(data, self._baudrate)
        if reply:
            with self._lock:
                self._rx += reply
                if self._waiting:
                    self._cond.notify_all()
        return len(data)

    def servo_time(self) -> float:
        """The servos' clock in seconds (crane_io.dynamixel.bus measures host pauses with it): the chain's
        simulated time in lockstep, where no wall-clock pause can reach a servo's watchdog."""
        if not self.is_open:
            raise PortNotOpenError()
        return self._chain.servo_time()

    def flush(self):
        pass

    def reset_input_buffer(self):
        if not self.is_open:
            raise PortNotOpenError()
        with self._lock:
            self._rx.clear()

    def reset_output_buffer(self):
        if not self.is_open:
            raise PortNotOpenError()

    @property
    def out_waiting(self):
        return 0

    def _update_break_state(self):
        pass

    def _update_rts_state(self):
        pass

    def _update_dtr_state(self):
        pass

    @property
    def cts(self):
        return True

    @property
    def dsr(self):
        return True

    @property
    def ri(self):
        return False

    @property
    def cd(self):
        return True
