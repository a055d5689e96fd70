"""Fault injectors for a `crane_io.sim` servo chain.

Each injector is a context manager (or call `install()` / `remove()`): it changes what the simulated
servos put on the wire, so the real dynamixel-sdk client and `DynamixelBus` see exactly what a bad
cable, a loose connector or an overloaded motor would show them.

    with FlipCrcByte(chain, every=3):     # every 3rd reply has a corrupted CRC
        bus.read_state()

Reply filters stack: installing one keeps the chain's previous `reply_filter` and passes the reply on
to it, and removing restores it. Each injector counts what it did in `.hits`.
"""

from __future__ import annotations

BROADCAST_ID = 0xFE
PKT_ID = 4


def _packet_id(chunk: bytes) -> int | None:
    return chunk[PKT_ID] if len(chunk) > PKT_ID else None


class _ReplyFilter:
    """Base: a reply_filter installed on the chain, chained to the one that was there before."""

    def __init__(self, chain, servo_id: int | None = None):
        self.chain = chain
        self.servo_id = servo_id  # only replies from this servo (a fast sync read reply matches any)
        self.hits = 0
        self.seen = 0
        self._previous = None
        self._installed = False

    def matches(self, chunk: bytes) -> bool:
        pid = _packet_id(chunk)
        return self.servo_id is None or pid in (self.servo_id, BROADCAST_ID)

    def apply(self, chunk: bytes) -> bytes | None:
        raise NotImplementedError

    def __call__(self, chunk: bytes) -> bytes | None:
        if self.matches(chunk):
            self.seen += 1
            chunk = self.apply(chunk)
            if chunk is None:
                return None
        return self._previous(chunk) if self._previous is not None else chunk

    def install(self):
        if not self._installed:
            self._previous = self.chain.reply_filter
            self.chain.reply_filter = self
            self._installed = True
        return self

    def remove(self) -> None:
        if self._installed:
            self.chain.reply_filter = self._previous
            self._installed = False

    def __enter__(self):
        return self.install()

    def __exit__(self, *exc):
        self.remove()


class FlipCrcByte(_ReplyFilter):
    """Corrupt the CRC of replies: every `every`-th matching reply (every=1: all of them), or only
    the first one when once=True."""

    def __init__(self, chain, every: int = 1, *, once: bool = False, servo_id: int | None = None):
        super().__init__(chain, servo_id)
        if every < 1:
            raise ValueError("every must be >= 1")
        self.every = every
        self.once = once

    def apply(self, chunk):
        if self.once and self.hits:
            return chunk
        if self.seen % self.every:
            return chunk
        self.hits += 1
        return chunk[:-1] + bytes([chunk[-1] ^ 0xFF])


class DropReplies(_ReplyFilter):
    """Drop the next `count` matching replies (count=None: all of them while installed)."""

    def __init__(self, chain, count: int | None = 1, *, servo_id: int | None = None):
        super().__init__(chain, servo_id)
        self.count = count

    def apply(self, chunk):
        if self.count is not None and self.hits >= self.count:
            return chunk
        self.hits += 1
        return None


class VanishingServo(_ReplyFilter):
    """Servo `servo_id` answers `after_cycles` more reads that include it, then disappears from the
    bus (it neither hears nor answers, like a pulled connector). Removing the injector puts it back."""

    def __init__(self, chain, servo_id: int, after_cycles: int = 0):
        super().__init__(chain, servo_id)
        self.after_cycles = after_cycles
        self.vanished = False
        if after_cycles <= 0:
            self._vanish()

    def _vanish(self):
        self.chain.remove_servo(self.servo_id)
        self.vanished = True
        self.hits += 1

    def apply(self, chunk):
        if not self.vanished and self.seen >= self.after_cycles:
            self._vanish()
        return chunk

    def install(self):
        super().install()
        if self.vanished:
            self.chain.remove_servo(self.servo_id)
        return self

    def remove(self):
        super().remove()
        self.chain.restore_servo(self.servo_id)


class HardwareErrorBits:
    """Latch Hardware Error Status `bits` on one servo (torque goes off if they are in its Shutdown
    mask, as on a real servo); removing clears them (what a reboot would do)."""

    def __init__(self, chain, servo_id: int, bits: int):
        self.chain = chain
        self.servo_id = servo_id
        self.bits = bits

    def install(self):
        self.chain.servos[self.servo_id].set_hardware_error(self.bits)
        return self

    def remove(self):
        self.chain.servos[self.servo_id].set_hardware_error(0)

    def __enter__(self):
        return self.install()

    def __exit__(self, *exc):
        self.remove()


class OverloadBit(HardwareErrorBits):
    """The overload bit (5) on one servo: the motor was loaded beyond its rating for too long."""

    def __init__(self, chain, servo_id: int):
        super().__init__(chain, servo_id, 1 << 5)
