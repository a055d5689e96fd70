"""Test-only fakes built on the simulated servo chain (crane_io.sim): fault injectors that corrupt or
drop replies, make a servo vanish, or raise hardware-error bits (faults.py); a plant too slow for real
time, a pty whose replies arrive late and a clock that ticks only when read (timing.py)."""

from .faults import DropReplies, FlipCrcByte, HardwareErrorBits, OverloadBit, VanishingServo
from .timing import LateReplies, SlowPlant, TickingClock

__all__ = ["DropReplies", "FlipCrcByte", "HardwareErrorBits", "LateReplies", "OverloadBit", "SlowPlant",
           "TickingClock", "VanishingServo"]
