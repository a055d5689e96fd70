"""The simulator answers the same bytes whatever Python's string-hash seed is (lockstep runs must be
reproducible from one process to the next)."""

from __future__ import annotations

import os
import subprocess
import sys

from crane_io.sim import protocol as p
from crane_io.sim.servo import EmulatedServo

# A Write of 4 bytes at 68 covers Status Return Level (68, RW, here 5: out of range) and the read-only
# Registered Instruction and Hardware Error Status: two different errors are possible.
_PROBE = ("from crane_io.sim.servo import EmulatedServo; "
          "print(EmulatedServo(2).check_write(68, bytes([5, 0, 0, 0])))")


def test_a_write_breaking_several_rules_gets_the_error_of_its_first_item():
    servo = EmulatedServo(2)
    assert servo.check_write(68, bytes([5, 0, 0, 0])) == p.ERR_DATA_RANGE
    assert servo.write(68, bytes([5, 0, 0, 0])) == p.ERR_DATA_RANGE
    assert servo.read_register("status_return_level") == 2  # a rejected write changes nothing


def test_the_error_does_not_depend_on_the_hash_seed():
    answers = set()
    for seed in ("0", "1", "5"):  # seeds under which a set-ordered check used to answer differently
        env = dict(os.environ, PYTHONHASHSEED=seed)
        out = subprocess.run([sys.executable, "-c", _PROBE], env=env, capture_output=True, text=True,
                             check=True)
        answers.add(out.stdout.strip())
    assert answers == {str(p.ERR_DATA_RANGE)}
