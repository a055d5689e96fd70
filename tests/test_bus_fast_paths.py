"""The bus's fast packet paths give the verdicts and bytes of the dynamixel-sdk paths they
replace: the Fast Sync Read reply read whole and parsed in one step, and the Goal Current Sync Write
built directly. The reference is the SDK's own code (rxPacket and GroupSyncWrite), run on the same
bytes."""

from __future__ import annotations

import numpy as np
import pytest
from dynamixel_sdk import COMM_SUCCESS, GroupSyncWrite
from fakes import FlipCrcByte, OverloadBit

from crane_io.dynamixel import bus as bus_mod
from crane_io.dynamixel.bus import _StatusSyncRead
from crane_io.dynamixel.faults import CommunicationError, ServoFaultError
from crane_io.dynamixel.packets import CranePacketHandler, crc16
from crane_io.sim import simulated_arm
from crane_io.sim.protocol import fast_status_packet
from tests.sim_bus import capture_writes, open_bus

IDS = (2, 3, 4, 5, 6, 7, 8, 9)
N = 10  # Present block bytes per servo


class FakePort:
    """Hands out `data` in pieces of at most `piece` bytes; times out once it is used up."""

    def __init__(self, data: bytes, piece: int = 10_000):
        self.data = bytes(data)
        self.piece = piece
        self.is_using = True
        self.reads = 0
        self.empty_polls = 0

    def readPort(self, length):  # noqa: N802
        self.reads += 1
        out = self.data[:min(length, self.piece)]
        self.data = self.data[len(out):]
        return out

    def isPacketTimeout(self):  # noqa: N802
        self.empty_polls += 1
        return not self.data and self.empty_polls > 2


class SdkReader(_StatusSyncRead):
    """The reply parse as it was before the fast path: the SDK's own rxPacket, then the packet's blocks."""

    def fastSyncReadRxPacket(self):  # noqa: N802
        self.last_result = False
        self.errors = {}
        self.packet = None
        packet, result = self.ph.rxPacket(self.port, True)
        if result != COMM_SUCCESS:
            return result
        return self.take_fast_packet(packet)


def _blocks(errors=None, ids=IDS, seed=0):
    rng = np.random.default_rng(seed)
    errors = errors or {}
    return [(errors.get(i, 0), i, bytes(rng.integers(0, 256, N, dtype=np.uint8))) for i in ids]


def _reply(**kw) -> bytes:
    return fast_status_packet(_blocks(**kw))


def _with_crc(packet: bytes) -> bytes:
    body = bytes(packet[:-2])
    crc = crc16(body)
    return body + bytes((crc & 0xFF, crc >> 8))


def _run(cls, data: bytes, piece: int):
    port = FakePort(data, piece)
    reader = cls(port, CranePacketHandler(), 126, N)
    for sid in IDS:
        reader.addParam(sid)
    result = reader.fastSyncReadRxPacket()
    return (result, dict(reader.errors), {k: bytes(v) for k, v in reader.data_dict.items()},
            reader.last_result, port.is_using), reader


def _cases():
    good = _reply()
    wrong_id = bytearray(good)
    wrong_id[8 + 1] = 42  # the first servo's ID byte
    dup = bytearray(good)
    dup[8 + 14 + 1] = IDS[0]
    bad_data = bytearray(good)
    bad_data[20] ^= 0x01
    bad_crc = bytearray(good)
    bad_crc[-1] ^= 0xFF
    not_broadcast = bytearray(good)
    not_broadcast[4] = 0x01
    stuffed = fast_status_packet([(0, i, b"\xff\xff\xfd\x00\x00\x00\x00\x00\x00\x00") for i in IDS])
    return {
        "good": good,
        "alert bit": _reply(errors={5: 0x80}),
        "status error": _reply(errors={3: 0x02}),
        "servos out of order": fast_status_packet(_blocks(ids=IDS[::-1])),
        "stuffed data": stuffed,
        "wrong ID (CRC fixed)": _with_crc(wrong_id),
        "duplicate ID (CRC fixed)": _with_crc(dup),
        "wrong ID (CRC not fixed)": bytes(wrong_id),
        "corrupted data byte": bytes(bad_data),
        "CRC error": bytes(bad_crc),
        "short reply": good[:-5],
        "header only": good[:8],
        "no reply": b"",
        "junk before": b"\x00\xff\x13" + good,
        "junk after": good + b"\xff\xff",
        "not the broadcast ID (CRC fixed)": _with_crc(not_broadcast),
        "fewer servos (CRC fixed)": fast_status_packet(_blocks(ids=IDS[:-1])),
    }


@pytest.mark.parametrize("piece", [10_000, 11, 7, 1])
@pytest.mark.parametrize("name", list(_cases()))
def test_the_fast_reply_path_gives_the_sdk_paths_verdict(name, piece):
    data = _cases()[name]
    fast, reader = _run(_StatusSyncRead, data, piece)
    sdk, _ = _run(SdkReader, data, piece)
    assert fast == sdk
    if name == "good" and piece >= len(data):
        assert reader.packet == data  # the one-read fast path was taken
    if fast[0] != COMM_SUCCESS:
        assert reader.packet is None


def test_the_verdicts_cover_success_and_corruption():
    results = {name: _run(_StatusSyncRead, data, 10_000)[0][0] for name, data in _cases().items()}
    assert results["good"] == results["alert bit"] == results["servos out of order"] == COMM_SUCCESS
    assert results["stuffed data"] == COMM_SUCCESS
    for name in ("wrong ID (CRC fixed)", "corrupted data byte", "CRC error", "short reply",
                 "duplicate ID (CRC fixed)"):
        assert results[name] != COMM_SUCCESS, name


@pytest.fixture
def sim():
    arm = simulated_arm()
    yield arm
    arm.close()


def _bus(sim):
    return open_bus(sim)


def test_the_state_from_the_fast_path_equals_the_plain_sync_reads(sim):
    with _bus(sim) as bus:
        bus.write_goal_current(np.full(8, 0.2))
        sim.chain.advance(0.01)
        fast = bus.read_state()
        assert fast.fast and bus._reader.packet is not None
        plain = bus._reader.txRxPacket()
        assert plain == COMM_SUCCESS and bus._reader.packet is None
        state = bus._state_from(bus._reader, fast.t, False, True)
        for field in ("position", "velocity", "current"):
            np.testing.assert_array_equal(getattr(state, field), getattr(fast, field))


def test_a_crc_error_on_the_fast_path_is_retried_and_an_alert_bit_raises(sim):
    with _bus(sim) as bus:
        bus.read_state()
        with FlipCrcByte(sim.chain, once=True) as flip:
            bus.read_state()
        assert flip.hits == 1 and bus.stats.retries == 1
        with FlipCrcByte(sim.chain), pytest.raises(CommunicationError):
            bus.read_state()
    with _bus(sim) as bus, OverloadBit(sim.chain, 5), pytest.raises(ServoFaultError):
        bus.read_state()


def test_the_goal_current_packet_is_the_group_sync_writes(sim):
    with _bus(sim) as bus:
        sent = capture_writes(bus)
        rng = np.random.default_rng(1)
        for _ in range(20):
            amps = rng.uniform(-3, 3, 8)
            amps[rng.integers(8)] = -0.0
            bus.write_goal_current(amps)
            # the SDK's way: GroupSyncWrite with the same clamped values
            ref = GroupSyncWrite(bus._port, bus._ph, 102, 2)
            for i in bus.current_joints:
                lim = bus.current_limits[i]
                raw = round(min(max(amps[i], -lim), lim) / bus_mod.units.AMPERE_PER_CURRENT_LSB)
                lim_raw = int(np.floor(lim / bus_mod.units.AMPERE_PER_CURRENT_LSB + 1e-9))
                raw = max(-lim_raw, min(lim_raw, raw))
                ref.addParam(bus.ids[i], [raw & 0xFF, (raw >> 8) & 0xFF])
            assert ref.txPacket() == COMM_SUCCESS
            assert sent[-2] == sent[-1]


def test_a_sync_write_that_needs_stuffing_goes_the_sdks_way():
    ph = CranePacketHandler()
    assert ph.sync_write_packet(102, 2, [2, 0xFF, 0xFF, 0xFD, 0x00, 0x00]) is None
    packet = ph.sync_write_packet(102, 2, [2, 0x10, 0x00, 3, 0xF0, 0xFF])
    assert packet[:8] == bytes((0xFF, 0xFF, 0xFD, 0x00, 0xFE, 13, 0, 0x83))
    assert crc16(packet[:-2]) == packet[-2] | (packet[-1] << 8)
