"""The bus codec's two implementations (crane_io/dynamixel/codec.py: CompiledCodec, whose calls are
cycle_kernel's, against PlainCodec, the reference): the Goal Current Sync Write (the same packet bytes and
commanded amps, bit for bit, rounding ties and clamps included) and the Fast Sync Read reply of the Present
block (the same verdict on every kind of bad reply, the same floats)."""

from __future__ import annotations

import numpy as np
import pytest
from fakes import FlipCrcByte

from crane_io.dynamixel import cycle_kernel, units
from crane_io.dynamixel.bus import CommandError
from crane_io.dynamixel.codec import CompiledCodec, PlainCodec
from crane_io.dynamixel.packets import CranePacketHandler
from crane_io.sim import simulated_arm
from crane_io.sim.protocol import fast_status_packet
from tests.sim_bus import capture_writes, open_bus

LSB = units.AMPERE_PER_CURRENT_LSB
KERNELS = cycle_kernel.compiled()
needs_numba = pytest.mark.skipif(KERNELS is None, reason="numba is not installed")


@pytest.fixture
def sim():
    arm = simulated_arm()
    yield arm
    arm.close()


def _plain_codec(bus) -> None:
    """Make `bus` read and write with the plain codec from now on."""
    bus.use_codec(PlainCodec(bus._ph, len(bus.ids)))


def _amps(rng, bus) -> np.ndarray:
    """Commands of every kind: ordinary, beyond the limits, on the limits, ties of the rounding, -0.0."""
    lim = bus.current_limits
    amps = rng.uniform(-1.2, 1.2, 8) * lim
    kinds = rng.integers(0, 6, 8)
    amps = np.where(kinds == 1, (rng.integers(-400, 400, 8) + 0.5) * LSB, amps)  # a half step
    amps = np.where(kinds == 2, np.sign(rng.normal(size=8)) * lim, amps)
    amps = np.where(kinds == 3, -0.0, amps)
    amps = np.where(kinds == 4, rng.choice([-1e9, 1e9], 8), amps)
    return amps


@needs_numba
@pytest.mark.parametrize("seed", [0, 1])
def test_the_compiled_goal_current_write_sends_what_the_python_path_sends(sim, seed):
    rng = np.random.default_rng(seed)
    commands = None
    results = []
    for compiled in (True, False):
        with open_bus(sim) as bus:
            if not compiled:
                _plain_codec(bus)
            if commands is None:
                commands = [_amps(rng, bus) for _ in range(200)]
            sent = capture_writes(bus)
            returned = [bus.write_goal_current(a) for a in commands]
            assert isinstance(bus._codec, CompiledCodec) == compiled
            results.append((list(sent), returned))  # (not the stop's write when the bus closes)
    (sent_k, ret_k), (sent_p, ret_p) = results
    sent_k, sent_p = ([p for p in sent if p[7] == 0x83] for sent in (sent_k, sent_p))  # the Sync Writes
    assert sent_k == sent_p and len(sent_k) == len(commands)
    for a, b in zip(ret_k, ret_p):
        assert a.dtype == b.dtype == np.float64 and a.tobytes() == b.tobytes()


@needs_numba
def test_a_command_that_is_not_finite_is_refused_before_anything_is_sent(sim):
    with open_bus(sim) as bus:
        sent = capture_writes(bus)
        j = bus.current_joints[1]
        for bad in (np.nan, np.inf, -np.inf):
            amps = np.zeros(8)
            amps[j] = bad
            with pytest.raises(CommandError, match=bus.joint_names[j]):
                bus.write_goal_current(amps)
        with pytest.raises(CommandError, match="shape"):
            bus.write_goal_current(np.zeros(7))
        assert not [p for p in sent if p[7] == 0x83]
        amps = np.zeros(8)
        if bus.position_joints:  # a held joint's entry is ignored, whatever it is
            amps[bus.position_joints[0]] = np.nan
        assert np.array_equal(bus.write_goal_current(amps), np.zeros(8))
        assert len([p for p in sent if p[7] == 0x83]) == 1
        assert bus.write_goal_current([0.1] * 8)[bus.current_joints[0]] == round(0.1 / LSB) * LSB


@needs_numba
def test_a_packet_that_would_need_byte_stuffing_is_left_to_the_python_path():
    """ID 0xFD after a joint commanded -1 step (bytes FF FF) would read FF FF FD: the kernel refuses,
    as the packet handler does; without it the kernel's packet is the handler's."""
    ph = CranePacketHandler()
    head = ph.sync_write_header(102, 2, 6)
    kernel = KERNELS[0]
    for ids, raw, refused in (([2, 0xFD], [-1, 5], True), ([2, 3], [-1, 5], False)):
        buf = np.zeros(12 + 6 + 2, dtype=np.uint8)
        buf[:12] = np.frombuffer(head, dtype=np.uint8)
        sent = np.zeros(2)
        size = kernel(np.array(raw) * LSB, np.arange(2), np.array(ids), np.full(2, 5.0), np.full(2, 1800),
                      LSB, buf, sent, cycle_kernel.TABLE)
        params = [b for sid, r in zip(ids, raw) for b in (sid, r & 0xFF, (r >> 8) & 0xFF)]
        expected = ph.sync_write_packet(102, 2, params)
        if refused:
            assert size == -2 and expected is None
        else:
            assert size == len(buf) and buf.tobytes() == expected


def _present(current: int, velocity: int, position: int) -> bytes:
    return (current & 0xFFFF).to_bytes(2, "little") + (velocity & 0xFFFFFFFF).to_bytes(4, "little") \
        + (position & 0xFFFFFFFF).to_bytes(4, "little")


@needs_numba
@pytest.mark.parametrize("seed", [0, 1])
def test_the_compiled_reply_check_and_conversion_equal_the_plain_ones(sim, seed):
    rng = np.random.default_rng(seed)
    with open_bus(sim) as bus:
        bus.read_state()
        compiled = bus._codec
        assert isinstance(compiled, CompiledCodec)
        plain = PlainCodec(bus._ph, len(bus.ids))
        bus._reader.use_codec(plain)  # the reader's expected reply, told to the plain codec too
        verdicts = set()
        for k in range(60):
            raws = [(int(rng.integers(-32768, 32768)), int(rng.integers(-2 ** 31, 2 ** 31)),
                     int(rng.integers(-2 ** 31, 2 ** 31))) for _ in bus.ids]
            if k % 6 == 1:  # a reading that contains FF FF FD FD: the reply is stuffed
                raws[3] = (0, -0x202_0001, 0)
            records = [(0, sid, _present(*r)) for sid, r in zip(bus.ids, raws)]
            if k % 6 == 2:
                i = int(rng.integers(8))
                records[i] = (0x80,) + records[i][1:]  # an alert bit
            if k % 6 == 3:
                records[0], records[1] = records[1], records[0]  # servos out of order
            data = bytearray(fast_status_packet(records))
            if k % 6 == 4:
                data[int(rng.integers(8, len(data)))] ^= 0x10  # a corrupted byte
            if k % 6 == 5:
                data = data[:-1]
            data = bytes(data)
            out, out_plain = np.full((3, 8), np.nan), np.full((3, 8), np.nan)
            accepted = compiled.present_state(data, out)
            assert accepted == plain.present_state(data, out_plain), k
            verdicts.add(accepted)
            if accepted:
                assert out.tobytes() == out_plain.tobytes()
        assert verdicts == {True, False}


def test_a_bus_without_numba_reads_and_writes_the_same(sim, monkeypatch):
    results = []
    for compiled in (True, False):
        if not compiled:
            monkeypatch.setattr(cycle_kernel, "compiled", lambda: None)
        with open_bus(sim) as bus:
            assert isinstance(bus._codec, CompiledCodec) == (compiled and KERNELS is not None)
            sent = capture_writes(bus)
            states = []
            for k in range(5):
                s = bus.read_state()
                states.append(np.concatenate([s.position, s.velocity, s.current]).tobytes())
                bus.write_goal_current(np.full(8, 0.05 * k))
            results.append((states, list(sent)))
    writes = [[p for p in sent if p[7] == 0x83] for _states, sent in results]
    assert writes[0] == writes[1] and len(writes[0]) == 5
    assert len(results[0][0]) == len(results[1][0]) == 5


@needs_numba
def test_each_read_gives_new_arrays_and_a_bad_reply_is_still_retried(sim):
    with open_bus(sim) as bus:
        a, b = bus.read_state(), bus.read_state()
        assert a.fast and b.fast and bus._reader.decoded
        assert not np.shares_memory(a.position, b.position)
        assert not np.shares_memory(a.velocity, b.current)
        retries = bus.stats.retries
        with FlipCrcByte(sim.chain, once=True) as flip:
            c = bus.read_state()
        assert flip.hits == 1 and bus.stats.retries == retries + 1 and c.position.shape == (8,)
