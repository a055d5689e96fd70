"""Test-only fakes built on the simulated servo chain (crane_io.sim): fault injectors that corrupt or
drop replies, make a servo vanish, or raise hardware-error bits. See faults.py."""

from .faults import DropReplies, FlipCrcByte, HardwareErrorBits, OverloadBit, VanishingServo

__all__ = ["DropReplies", "FlipCrcByte", "HardwareErrorBits", "OverloadBit", "VanishingServo"]
