"""The simulated chain's fast path (crane_io.sim.chain_kernel, SimulatedChain(fast=True)) against
its general path (fast=False, the reference): the same packet streams, faults included, give the same reply
bytes, the same control-table memories and the same plant state; and the compiled functions compute what
their Python source computes."""

from __future__ import annotations

import numpy as np
import pytest

from crane_io.dynamixel.units import RADS_PER_VELOCITY_LSB
from crane_io.sim import chain_kernel
from crane_io.sim import protocol as p
from crane_io.sim.arm_plant import ArmPlant
from crane_io.sim.chain import SimulatedChain
from crane_io.sim.simple_plant import SimplePlant

TORQUE, MODE, GOAL_CURRENT, GOAL_POSITION, ID, WATCHDOG, CURRENT_LIMIT = 64, 11, 102, 116, 7, 98, 38
PRESENT = 126


def _pair(plant_factory):
    chains = [SimulatedChain(plant_factory(), fast=fast) for fast in (True, False)]
    assert chains[0].fast and not chains[1].fast
    return chains


def _same(chains):
    fast, ref = chains
    assert np.array_equal(fast.memories, ref.memories)
    for a, b in zip(fast._order, ref._order):
        assert (a.id, a.watchdog_expired, a.last_contact, a.registered, a.on_bus) == \
               (b.id, b.watchdog_expired, b.last_contact, b.registered, b.on_bus)
    assert fast.time == ref.time and fast.stats == ref.stats
    if isinstance(fast.plant, ArmPlant):
        for name in ("q", "dq", "_held_q", "_held_dq", "_held_current", "motor_torque"):
            assert np.array_equal(getattr(fast.plant, name), getattr(ref.plant, name)), name
        assert fast.plant.rng.bit_generator.state == ref.plant.rng.bit_generator.state


def _feed(chains, data: bytes) -> bytes:
    replies = [c.feed(data) for c in chains]
    assert replies[0] == replies[1]
    _same(chains)
    return replies[0]


def _write(sid, address, value, size):
    return p.instruction_packet(sid, p.INST_WRITE, bytes((address & 0xFF, address >> 8))
                                + int(value).to_bytes(size, "little", signed=value < 0))


def _sync_write_current(ids, values):
    body = b"".join(bytes((i,)) + int(v).to_bytes(2, "little", signed=True) for i, v in zip(ids, values))
    return p.instruction_packet(p.BROADCAST_ID, p.INST_SYNC_WRITE, bytes((GOAL_CURRENT, 0, 2, 0)) + body)


def _fast_read(ids, address=PRESENT, length=10):
    return p.instruction_packet(p.BROADCAST_ID, p.INST_FAST_SYNC_READ,
                                bytes((address & 0xFF, address >> 8, length, 0)) + bytes(ids))


def _sync_write_position(ids, values):
    body = b"".join(bytes((i,)) + int(v).to_bytes(4, "little", signed=True) for i, v in zip(ids, values))
    return p.instruction_packet(p.BROADCAST_ID, p.INST_SYNC_WRITE, bytes((GOAL_POSITION, 0, 4, 0)) + body)


def _sync_write_torque(ids, value):
    body = b"".join(bytes((i, value)) for i in ids)
    return p.instruction_packet(p.BROADCAST_ID, p.INST_SYNC_WRITE, bytes((TORQUE, 0, 1, 0)) + body)


def _cycle(chains, ids, currents, read_ids=None):
    _feed(chains, _sync_write_current(ids, currents))
    return _feed(chains, _fast_read(read_ids if read_ids is not None else chains[0].plant.servo_ids))


def _bring_up(chains, current_ids):
    ids = list(chains[0].plant.servo_ids)
    for sid in current_ids:
        _feed(chains, _write(sid, MODE, 0, 1))
    _feed(chains, _sync_write_torque(ids, 1))
    return ids


@pytest.mark.parametrize("joints", ["crane-x7", "crane-x7-7dof"])
def test_the_fast_path_answers_and_steps_as_the_general_path_does_through_faults(joints):
    chains = _pair(lambda: ArmPlant(joints, seed=3))
    ids = _bring_up(chains, [2, 3, 4, 5, 6, 7, 8])
    rng = np.random.default_rng(0)
    cur_ids = [2, 3, 4, 5, 6, 7, 8]

    def run(n, read_ids=None, scale=400):
        for _ in range(n):
            _cycle(chains, cur_ids, rng.integers(-scale, scale, len(cur_ids)), read_ids)

    run(20)
    # out-of-limit goal currents: refused beyond +-Current Limit
    run(5, scale=30000)
    # CRC errors: a corrupted Sync Write and a corrupted Fast Sync Read are dropped
    bad = bytearray(_sync_write_current(cur_ids, [100] * 7))
    bad[-1] ^= 0xFF
    _feed(chains, bytes(bad))
    bad = bytearray(_fast_read(ids))
    bad[9] ^= 0x01
    assert _feed(chains, bytes(bad)) == b""
    run(3)
    # torque off on one servo, then back on
    _feed(chains, _write(4, TORQUE, 0, 1))
    run(5)
    _feed(chains, _write(4, TORQUE, 1, 1))
    run(3)
    # a latched hardware error (overload: alert bit in every status, torque off)
    for c in chains:
        c.servos[5].set_hardware_error(0x20)
    reply = _cycle(chains, cur_ids, [50] * 7)
    assert reply and reply[9 + 4 * 12] & 0x80  # the fourth block (ID 5) carries the alert bit
    run(3)
    _feed(chains, p.instruction_packet(5, p.INST_REBOOT))
    run(3)  # ID 5 restarting: silent
    for c in chains:
        c.advance(0.5)
    _feed(chains, _write(5, MODE, 0, 1))
    _feed(chains, _write(5, TORQUE, 1, 1))
    run(3)
    # watchdog: armed on ID 6, which then stops being addressed until it expires
    _feed(chains, _write(6, WATCHDOG, 1, 1))
    others = [i for i in cur_ids if i != 6]
    for _ in range(20):
        _feed(chains, _sync_write_current(others, [30] * len(others)))
        _feed(chains, _fast_read([i for i in ids if i != 6]))
    assert chains[0].servos[6].watchdog_expired
    run(3)  # goal current refused, present block still read (the general path answers)
    _feed(chains, _write(6, WATCHDOG, 0, 1))
    run(3)
    # a missing servo (the fast read's reply stops before it), an ID nobody has
    for c in chains:
        c.remove_servo(7)
    run(3)
    for c in chains:
        c.restore_servo(7)
    run(2, read_ids=ids + [99])
    run(2, read_ids=[99] + ids)
    # a servo whose firmware has no Fast Sync Read
    for c in chains:
        c.servos[3].supports_fast_sync_read = False
    run(3)
    for c in chains:
        c.servos[3].supports_fast_sync_read = True
    # mode changes: an integrated joint's servo to position mode and back; a held one to current mode
    def set_mode(sid, mode):  # the Operating Mode is EEPROM: torque off, the mode, torque on
        for address, value in ((TORQUE, 0), (MODE, mode), (TORQUE, 1)):
            _feed(chains, _write(sid, address, value, 1))

    set_mode(2, 3)
    run(5)
    set_mode(9, 0)
    run(5, read_ids=ids)
    set_mode(2, 0)
    run(3)
    # an ID change: 8 becomes 20 (EEPROM: torque off first); the old ID is gone, the new one answers
    _feed(chains, _write(8, TORQUE, 0, 1))
    _feed(chains, _write(8, ID, 20, 1))
    run(3)
    new_ids = [20 if i == 8 else i for i in ids]
    cur_ids = [20 if i == 8 else i for i in cur_ids]
    _feed(chains, _write(20, TORQUE, 1, 1))
    run(5, read_ids=new_ids)
    # duplicate IDs in a read, a read of other addresses (watchdog and goal items), a zero-length read
    run(2, read_ids=new_ids + new_ids[:2])
    _feed(chains, _fast_read(new_ids, address=WATCHDOG, length=30))
    _feed(chains, _fast_read(new_ids, address=600, length=100))
    _feed(chains, _fast_read(new_ids, address=PRESENT, length=0))
    # the present block of every servo but the ones written, and status return level 0 on one servo
    _feed(chains, _write(4, 68, 0, 1))
    run(3, read_ids=new_ids)
    # a lower Current Limit (EEPROM) refuses the goal currents written beyond it
    _feed(chains, _write(3, TORQUE, 0, 1))
    _feed(chains, _write(3, CURRENT_LIMIT, 100, 2))
    _feed(chains, _write(3, TORQUE, 1, 1))
    run(5, scale=3000)
    # a truncated Sync Write body, a Sync Write of two servos, several packets in one feed
    raw = _sync_write_current(cur_ids, [10] * len(cur_ids))
    body = raw[12:-2]
    _feed(chains, p.instruction_packet(p.BROADCAST_ID, p.INST_SYNC_WRITE, bytes((GOAL_CURRENT, 0, 2, 0))
                                       + body[:-1]))
    _feed(chains, _sync_write_current([2, 20], [7, -7]) + _fast_read(new_ids) + _fast_read(new_ids[:3]))
    run(5)
    # Drive Mode reverse and a Homing Offset on an integrated joint's servo and a held one (EEPROM)
    for sid, drive, homing in ((2, 1, 300), (9, 1, -700), (3, 0, 2000)):
        _feed(chains, _write(sid, TORQUE, 0, 1))
        _feed(chains, _write(sid, 10, drive, 1))
        _feed(chains, _write(sid, 20, homing, 4))
        _feed(chains, _write(sid, TORQUE, 1, 1))
    run(5, read_ids=new_ids)
    _feed(chains, _sync_write_position([9], [-5000]))  # outside the position limits: refused
    _feed(chains, _sync_write_position([9], [2100]))
    run(3, read_ids=new_ids)


def test_the_lockstep_cycle_takes_one_compiled_call_per_packet_and_agrees_through_odd_packets():
    """The usual Sync Write of Goal Current and Fast Sync Read skip the parser and the handlers
    (crane_io.sim.lockstep_kernel); split, stuffed, foreign-speed and other packets, and a plant whose state
    arrays were replaced, still give what the general path gives."""
    chains = _pair(lambda: ArmPlant("crane-x7", seed=5))
    ids = _bring_up(chains, [2, 3, 5])
    handled = []
    fast = chains[0]
    general_handle = fast._handle
    fast._handle = lambda *a, **k: handled.append(a[0].instruction) or general_handle(*a, **k)
    rng = np.random.default_rng(4)
    for _ in range(10):
        _cycle(chains, [2, 3, 5], rng.integers(-300, 300, 3), ids)
    assert handled == []  # every packet took the lockstep path
    assert fast.plant._stepper.views is not None and fast.plant.q is fast.plant._stepper.views[0]
    # a packet in two pieces, two packets in one piece
    pkt = _sync_write_current([2, 3, 5], [40, -40, 5])
    _feed(chains, pkt[:9])
    _feed(chains, pkt[9:])
    _feed(chains, _fast_read(ids) + _sync_write_current([2, 3, 5], [1, 2, 3]))
    # byte stuffing: a goal current of -1 (FF FF) followed by ID 253 (FD), and a read of such IDs
    _feed(chains, _sync_write_current([2, 253, 3], [-1, 7, 7]))
    _feed(chains, _fast_read([2, 0xFF, 0xFF, 0xFD]))
    # at a port speed the servos are set to, at another, at one no servo can be set to
    for baud in (3_000_000, 57_600, 12_345):
        for data in (_sync_write_current([2, 3, 5], [9, 9, 9]), _fast_read(ids)):
            replies = [c.feed(data, baudrate=baud) for c in chains]
            assert replies[0] == replies[1]
            _same(chains)
    # the plant's state set or replaced from outside between packets
    for c in chains:
        c.plant.set_state(q=np.linspace(-0.3, 0.3, 8), dq=np.full(8, 0.01))
    _cycle(chains, [2, 3, 5], [100, 100, 100])
    for c in chains:
        c.plant.q = c.plant.q.copy()
        c.plant.motor_torque = c.plant.motor_torque + 0.0
    _cycle(chains, [2, 3, 5], [-100, 50, 0])
    # Sync Writes of Goal Position (a lockstep tick too): refused outside the position limits (Position mode)
    def sync_write_position(values):
        body = b"".join(bytes((i,)) + int(v).to_bytes(4, "little", signed=True) for i, v in values)
        return p.instruction_packet(p.BROADCAST_ID, p.INST_SYNC_WRITE, bytes((GOAL_POSITION, 0, 4, 0)) + body)

    for sid, address, value in ((9, TORQUE, 0), (9, 48, 3000), (9, 52, 1000), (9, TORQUE, 1)):
        _feed(chains, _write(sid, address, value, 4 if address in (48, 52) else 1))
    for values in ([(9, 2048)], [(9, 5000), (8, -7), (6, 2**31 - 1)], [(9, -5), (4, 100)],
                   [(9, 1000), (99, 1)], [(9, 999)]):
        _feed(chains, sync_write_position(values))
        _cycle(chains, [2, 3, 5], [1, 1, 1])
    assert chains[0].servos[9].read_register("goal_position") == 1000
    # a Sync Write of another item, an instruction to one servo, a read that is not fast
    _feed(chains, p.instruction_packet(p.BROADCAST_ID, p.INST_SYNC_WRITE, bytes((116 + 4, 0, 4, 0))
                                       + bytes((9,)) + (20).to_bytes(4, "little")))
    _feed(chains, _write(2, GOAL_CURRENT, 20, 2))
    _feed(chains, p.instruction_packet(p.BROADCAST_ID, p.INST_SYNC_READ,
                                       bytes((PRESENT, 0, 10, 0)) + bytes(ids)))
    # Indirect Data 1..4 standing for Present Position: a Fast Sync Read of them declines the compiled path
    for k in range(4):
        _feed(chains, _write(2, 168 + 2 * k, PRESENT + 6 + k, 2))
    n_before = len(handled)
    reply = _feed(chains, _fast_read(ids, address=224, length=4))
    assert len(handled) == n_before + 1
    position = chains[0].servos[2].read_register("present_position")
    assert reply[10:14] == position.to_bytes(4, "little", signed=True)  # servo 2's block comes first
    # the chain's Fast Sync Read switched off, a reply filter
    for c in chains:
        c.fast_sync_read = False
    _cycle(chains, [2, 3, 5], [3, 3, 3])
    for c in chains:
        c.fast_sync_read = True
        c.reply_filter = lambda chunk: chunk
    _cycle(chains, [2, 3, 5], [4, 4, 4])
    n_general = len(handled)
    for c in chains:
        c.reply_filter = None
    _cycle(chains, [2, 3, 5], [5, 5, 5])
    assert len(handled) == n_general  # back on the lockstep path


def test_the_lockstep_cycle_with_the_plants_reference_path_and_overload():
    """A plant integrating on its reference path (kernel=False) or with the overload model: the packets take
    the compiled calls, the plant its general step."""
    import dataclasses

    def overloaded():
        plant = ArmPlant("crane-x7", seed=2)
        plant.config = dataclasses.replace(plant.config, overload=dataclasses.replace(
            plant.config.overload, enabled=True, time_s=0.01))
        return plant

    for factory in (lambda: ArmPlant("crane-x7", seed=2, kernel=False), overloaded):
        chains = _pair(factory)
        ids = _bring_up(chains, [2, 3, 5])
        for k in range(15):
            _cycle(chains, [2, 3, 5], [2000 * (-1) ** k, 30000, -50], ids)


def test_the_fast_path_on_a_plant_without_array_methods():
    """SimplePlant has no read_arrays / step_command: the chain's compiled sensors and fast reads still
    apply, the general plant calls stay."""
    chains = _pair(lambda: SimplePlant())
    ids = _bring_up(chains, [2, 3, 4])
    rng = np.random.default_rng(1)
    for _ in range(30):
        _cycle(chains, [2, 3, 4], rng.integers(-2000, 2000, 3), ids)


def test_the_general_path_is_chosen_by_the_environment(monkeypatch):
    monkeypatch.setenv("CRANE_CHAIN_FAST", "0")
    assert not SimulatedChain(SimplePlant()).fast
    monkeypatch.setenv("CRANE_CHAIN_FAST", "1")
    assert SimulatedChain(SimplePlant()).fast
    assert not SimulatedChain(SimplePlant(), fast=False).fast


# ---- the compiled functions against their Python source ---------------------------------------------

def _fns():
    fns = chain_kernel.compiled()
    assert fns is not None
    return dict(zip(("sensors_into", "commands", "fast_status", "reading"), fns))


def test_sensors_into_compiled_equals_python_and_set_sensors():
    from crane_io.dynamixel.units import AMPERE_PER_CURRENT_LSB, RAD_PER_PULSE, RADS_PER_VELOCITY_LSB
    from crane_io.sim.servo import EmulatedServo

    fn = _fns()["sensors_into"]
    rng = np.random.default_rng(5)
    n = 8
    cases = [rng.normal(0, 3, (3, n))]
    halves = np.array([0.5, 1.5, 2.5, -0.5, -1.5, -2.5, 1e12, -1e12])  # ties, clamps
    cases.append(np.stack([halves * RAD_PER_PULSE, halves * RADS_PER_VELOCITY_LSB,
                           halves * AMPERE_PER_CURRENT_LSB]))
    odd = rng.normal(0, 1, (3, n))
    odd[0, 1], odd[1, 2], odd[2, 3], odd[0, 4] = np.nan, np.inf, -np.inf, 1e300
    cases.append(odd)
    for case in cases:
        servos = [EmulatedServo(i + 1) for i in range(n)]
        for s in servos:
            s.write_register("moving_threshold", int(rng.integers(0, 20)))
            s.write_register("present_velocity", int(rng.integers(-50, 50)))
            # the servo's frame: Drive Mode reverse, a Homing Offset (ignored beyond +-1024 in Position mode)
            s.write_register("drive_mode", int(rng.integers(0, 2)))
            s.write_register("homing_offset", int(rng.choice([0, 5, -1024, 1025, -400000])))
            s.write_register("operating_mode", int(rng.choice([0, 3, 4])))
        mem = np.array([np.frombuffer(bytes(s.memory), dtype=np.uint8) for s in servos])
        mem_py = mem.copy()
        volt = np.array([120, -1, 0, 65535, 120, 121, -1, 3], dtype=np.int64)
        temp = np.array([35, -1, 255, 0, 35, -1, 40, 3], dtype=np.int64)
        args = (case[0].copy(), case[1].copy(), case[2].copy(), volt, temp, 12345, 126, 120, 144, 24)
        assert fn(mem, *args) is fn.py_func(mem_py, *args) is True
        assert np.array_equal(mem, mem_py)
        for i, s in enumerate(servos):
            s.set_sensors(case[0, i], case[1, i], case[2, i], 12.345,
                          None if volt[i] < 0 else volt[i] / 10, None if temp[i] < 0 else float(temp[i]))
            assert bytes(s.memory) == mem[i].tobytes(), i
    # a finite reading too large to quantise (set_sensors raises OverflowError): nothing written, False
    huge = np.zeros(n)
    huge[3] = 1e308
    before = mem.copy()
    assert fn(mem, huge, np.zeros(n), np.zeros(n), volt, temp, 1, 126, 120, 144, 24) is False
    with np.errstate(over="ignore"):
        assert fn.py_func(mem, huge, np.zeros(n), np.zeros(n), volt, temp, 1, 126, 120, 144, 24) is False
    assert np.array_equal(mem, before)


def test_commands_compiled_equals_python_and_command():
    from crane_io.sim.servo import EmulatedServo

    fn = _fns()["commands"]
    rng = np.random.default_rng(6)
    servos = [EmulatedServo(i + 1) for i in range(8)]
    for s in servos:
        s.write_register("torque_enable", int(rng.integers(0, 2)))
        s.write_register("operating_mode", int(rng.choice([0, 3, 5])))
        s.write_register("goal_current", int(rng.integers(-32768, 32768)))
        s.write_register("goal_position", int(rng.integers(-2**31, 2**31)))
        s.write_register("current_limit", int(rng.integers(0, 2**16)))
        s.write_register("drive_mode", int(rng.integers(0, 2)))
        s.write_register("homing_offset", int(rng.choice([0, 5, -1024, 1025, -400000])))
    servos[2].watchdog_expired = True
    expired = 1 << 2
    mem = np.array([np.frombuffer(bytes(s.memory), dtype=np.uint8) for s in servos])
    out, out_py = np.zeros((5, 8)), np.zeros((5, 8))
    args = (expired, 64, 11, 102, 116, 38)
    mask = fn(mem, args[0], out, *args[1:])
    assert mask == fn.py_func(mem, args[0], out_py, *args[1:])
    assert np.array_equal(out, out_py)
    for i, s in enumerate(servos):
        driving, mode, gc, gp, _gains, limit = s.command()
        assert tuple(out[:, i]) == (float(driving), mode, gc, gp, limit)
        assert bool(mask >> i & 1) == (driving and mode != 0)


def test_fast_status_compiled_equals_python_and_the_protocols_packet():
    fn = _fns()["fast_status"]
    rng = np.random.default_rng(7)
    for trial in range(200):
        n = int(rng.integers(1, 9))
        mem = rng.integers(0, 256, (8, 200), dtype=np.uint8)
        if trial % 2:  # byte stuffing: FF FF FD in the data, across the error/ID bytes too
            for _ in range(3):
                r, a = int(rng.integers(0, 8)), int(rng.integers(0, 197))
                mem[r, a:a + 3] = (0xFF, 0xFF, 0xFD)
            mem[:, 70] = rng.choice([0, 0xFF], 8)
        rows = rng.integers(0, 8, n).astype(np.int64)
        ids = rng.choice([0xFF, 0xFD, 1, 2, 3], n).astype(np.int64)
        address, length = int(rng.integers(100, 150)), int(rng.integers(1, 40))
        packet, crc = fn(mem, rows, ids, address, length, 70, chain_kernel.CRC_TABLE_U16)
        packet_py, crc_py = fn.py_func(mem, rows, ids, address, length, 70, chain_kernel.CRC_TABLE_U16)
        assert packet.tobytes() == packet_py.tobytes() and crc == crc_py
        blocks = [(0x80 if mem[r, 70] else 0, int(i), mem[r, address:address + length].tobytes())
                  for r, i in zip(rows, ids)]
        expected = p.fast_status_packet(blocks)
        assert packet.tobytes() == expected
        assert crc == p.crc16(expected[:-2]) == expected[-2] | expected[-1] << 8


def test_reading_compiled_equals_python_and_read_lists():
    fn = _fns()["reading"]
    for joints in ("crane-x7", "crane-x7-7dof"):
        plants = [ArmPlant(joints, seed=11) for _ in range(2)]
        command = ([True] * 8, [0] * 8, [0.1] * 8, [0.0] * 8, [(800, 0, 0)] * 8, [2.0] * 8, 0.002)
        for _ in range(5):
            plants[0].step_lists(*command)
            plants[1].step_lists(*command)
            pos, vel, cur, volt, temp = plants[0].read_arrays()
            ref = plants[1].read_lists()
            assert pos.tolist() == ref[0] and vel.tolist() == ref[1] and cur.tolist() == ref[2]
            assert (volt, temp) == (ref[3], ref[4])
    pl = plants[0]
    rng = np.random.default_rng(2)
    args = (pl.q, pl.dq, pl.motor_torque, pl._held_q, pl._held_dq, pl._held_current,
            np.array(pl._bi_l), np.array(pl._held_l), np.array(pl._kt_l), 8, 0.3)
    z = rng.standard_normal(16)
    for raw, flips, signs in ((rng.integers(0, 2**63, 12, dtype=np.uint64) * np.uint64(2), np.zeros(0),
                               np.zeros(0)),
                              (np.zeros(0, dtype=np.uint64), rng.random(8), rng.choice([-1.0, 1.0], 8))):
        for sds in ((0.1, 0.2), (0.0, 0.2), (0.1, 0.0), (0.0, 0.0)):
            a = fn(*args, raw, flips, signs, *sds, z)
            b = fn.py_func(*args, raw, flips, signs, *sds, z)
            for x, y in zip(a, b):
                assert x.tobytes() == y.tobytes()


def test_a_subclass_that_changes_read_lists_or_step_lists_is_not_bypassed():
    class Offset(ArmPlant):
        def read_lists(self):
            pos, vel, cur, volt, temp = super().read_lists()
            return [x + 0.1 for x in pos], vel, cur, volt, temp

    class Stepped(ArmPlant):
        steps = 0

        def step_lists(self, *args):
            self.steps += 1
            return super().step_lists(*args)

    offset = SimulatedChain(Offset("crane-x7", seed=0), fast=True)
    plain = SimulatedChain(ArmPlant("crane-x7", seed=0), fast=True)
    shift = (offset.servos[2].read_register("present_position")
             - plain.servos[2].read_register("present_position"))
    assert abs(shift - 0.1 / 0.0015339807878856412) <= 1.5  # the subclass's offset (0.1 rad) is there
    stepped = SimulatedChain(Stepped("crane-x7", seed=0), fast=True)
    stepped.advance(0.01)
    assert stepped.plant.steps == 5


def test_a_new_chain_has_its_kernels_compiled_before_the_first_packet():
    """Compiled lazily, the kernels were compiled (seconds on a fresh checkout) at the first packet, while a
    host on a pseudo-terminal waited for the reply and then declared the servos silent. A fresh process:
    building the chain alone leaves every kernel with its signature compiled (or loaded from the cache)."""
    import json
    import subprocess
    import sys

    probe = (
        "import json\n"
        "from crane_io.sim import chain_kernel, lockstep_kernel, plant_kernel\n"
        "from crane_io.sim.arm_plant import ArmPlant\n"
        "from crane_io.sim.chain import SimulatedChain\n"
        "chain = SimulatedChain(ArmPlant('crane-x7', seed=0), fast=True)\n"
        "fns = [*chain_kernel.compiled(), plant_kernel.compiled()[0], *lockstep_kernel.compiled()]\n"
        "print(json.dumps({f.__name__: len(f.signatures) for f in fns}))\n")
    out = subprocess.run([sys.executable, "-c", probe], capture_output=True, text=True, check=True)
    counts = json.loads(out.stdout.strip().splitlines()[-1])
    # sync_write_read calls sync_write_goal with a literal plant_on: compiling it (not loading it from the
    # cache) adds that specialisation to sync_write_goal's dispatcher, still while the chain is built
    goal = counts.pop("sync_write_goal")
    assert 1 <= goal <= 2
    assert counts == {"sensors_into": 1, "commands": 1, "fast_status": 1, "reading": 1, "step_arm": 1,
                      "sense": 1, "fast_sync_read": 1, "sync_write_read": 1}


@pytest.mark.parametrize("joints", ["crane-x7", "crane-x7-7dof"])
def test_the_one_call_cycle_draws_the_noise_the_general_path_draws(joints):
    """lockstep_kernel.sync_write_read draws the sensor noise inside the compiled call from the plant's own
    Generator: the same readings and generator state as the general path, also when something else draws
    from the generator between cycles, when the generator is replaced, when the noise settings change
    (position noise off, more position noise, no velocity noise), and for a plant with its own _noise."""
    import dataclasses

    chains = _pair(lambda: ArmPlant(joints, seed=8))
    ids = _bring_up(chains, [2, 3, 4, 5, 6, 7, 8])
    calls = []
    fns = chains[0]._lockstep_fns
    chains[0]._lockstep_fns = fns._replace(
        sync_write_read=lambda *a: calls.append(1) or fns.sync_write_read(*a))
    rng = np.random.default_rng(2)

    def run(n):
        for _ in range(n):
            _cycle(chains, [2, 3, 4, 5, 6, 7, 8], rng.integers(-300, 300, 7), ids)

    run(10)
    assert len(calls) == 10
    for c in chains:  # a 32-bit draw from elsewhere leaves half an output in the bit generator
        c.plant.rng.integers(0, 5, dtype=np.int32)
    run(5)
    for c in chains:
        c.plant.rng = np.random.default_rng(77)
    run(5)
    for sensor in ({"position_noise_probability": 0.0}, {"position_noise_probability": 0.4},
                   {"velocity_noise_lsb": 0.0}, {"current_noise_lsb": 0.0, "velocity_noise_lsb": 0.0}):
        for c in chains:
            c.plant.config = dataclasses.replace(
                c.plant.config, sensor=dataclasses.replace(c.plant.config.sensor, **sensor))
        run(4)
    assert len(calls) == 10 + 5 + 5 + 16


def test_a_plant_with_its_own_noise_is_not_bypassed():
    class Quiet(ArmPlant):
        def _noise(self):
            p, raw, flips, signs, vel_sd, cur_sd, z = super()._noise()
            return p, raw, flips, signs, vel_sd, cur_sd, z * 0.0

    chain = SimulatedChain(Quiet("crane-x7", seed=1), fast=True)
    assert chain.fast and chain.plant.kernel_cycle_args(0.002) is None
    for sid in (2, 3, 5):
        chain.feed(_write(sid, MODE, 0, 1))
    chain.feed(_sync_write_torque(list(chain.plant.servo_ids), 1))
    for _ in range(5):
        chain.feed(_sync_write_current([2, 3, 5], [200, -200, 100]))
    velocity = chain.memories[:, PRESENT + 2:PRESENT + 6].copy().view("<i4").ravel()
    true = np.zeros(8)
    true[chain.plant._bi_l], true[chain.plant._held_l] = chain.plant.dq, chain.plant._held_dq
    assert np.any(true != 0)
    assert np.array_equal(velocity, np.round(true / RADS_PER_VELOCITY_LSB).astype(int))  # noise-free
