"""The simulated servos and the bus client compute their CRCs independently: each side holds its own tables
(crane_io.sim.protocol.crc16 and chain_kernel's table; crane_io.dynamixel.packets.crc16 and cycle_kernel's
table) and no side keeps CRCs for the other, so a packet framed with a damaged CRC on one side is refused
by the other side's check."""

from __future__ import annotations

import array

import numpy as np
from dynamixel_sdk.protocol2_packet_handler import Protocol2PacketHandler

from crane_io.dynamixel import cycle_kernel, packets, units
from crane_io.dynamixel.crc import Crc16
from crane_io.dynamixel.packets import CranePacketHandler
from crane_io.sim import chain_kernel, protocol

_SDK = Protocol2PacketHandler()  # the SDK's own byte-wise CRC, independent of both sides


def _sdk_crc(data: bytes) -> int:
    return _SDK.updateCRC(0, list(data), len(data))


def _crc_of(packet: bytes) -> int:
    return packet[-2] | (packet[-1] << 8)


def _damaged() -> Crc16:
    """A CRC whose tables are wrong in their lowest bit."""
    bad = Crc16()
    bad.table = [x ^ 1 for x in bad.table]
    bad.table16 = array.array("H", (x ^ 1 for x in bad.table16))
    return bad


def test_each_side_holds_its_own_crc_tables():
    assert packets.crc16 is not protocol.crc16
    assert packets.crc16.table16 is not protocol.crc16.table16
    assert not np.shares_memory(cycle_kernel.TABLE, chain_kernel.CRC_TABLE_U16)
    body = protocol.instruction_packet(1, protocol.INST_PING)[:-2]
    assert packets.crc16(body) == protocol.crc16(body) == _sdk_crc(body)


def test_a_reply_framed_with_a_damaged_simulator_crc_is_refused_by_the_host(monkeypatch):
    monkeypatch.setattr(protocol, "crc16", _damaged())
    reply = protocol.status_packet(1, 0, bytes([0x2A, 0x01, 0x00, 0x00]))
    assert _crc_of(reply) != _sdk_crc(reply[:-2])  # the simulator framed it wrong ...
    assert protocol.PacketParser().feed(reply)  # ... and its own check agrees with itself
    host = CranePacketHandler()
    assert host.updateCRC(0, list(reply), len(reply) - 2) != _crc_of(reply)  # the host's check refuses it

    blocks = [(0, sid, bytes(range(sid, sid + 10))) for sid in range(2, 10)]
    fast = protocol.fast_status_packet(blocks)
    assert _crc_of(fast) != _sdk_crc(fast[:-2])
    assert packets.crc16(fast[:-2]) != _crc_of(fast)


def test_an_instruction_framed_with_a_damaged_host_crc_is_refused_by_the_simulator(monkeypatch):
    monkeypatch.setattr(packets, "crc16", _damaged())
    ph = CranePacketHandler()  # its sync write CRC tables come from the (damaged) host CRC
    packet = ph.sync_write_packet(102, 2, [2, 10, 0, 3, 20, 0])
    assert _crc_of(packet) != _sdk_crc(packet[:-2])
    parser = protocol.PacketParser()
    assert parser.feed(packet) == [] and parser.crc_errors == 1


def _present_reply() -> bytes:
    """The simulated chain's Fast Sync Read reply of the Present block of servos 2..9 as its compiled call
    builds it (the plain source of chain_kernel.fast_status, with the simulator's table)."""
    mem = np.zeros((8, 256), dtype=np.uint8)
    mem[:, 126:136] = np.arange(80, dtype=np.uint8).reshape(8, 10)
    rows, ids = np.arange(8, dtype=np.int64), np.arange(2, 10, dtype=np.int64)
    packet, _crc = chain_kernel.fast_status(mem, rows, ids, 126, 10, 70, chain_kernel.CRC_TABLE_U16)
    return packet.tobytes()


def _host_accepts(reply: bytes) -> bool:
    """The host's check of a Fast Sync Read reply of servos 2..9 (the plain source of
    cycle_kernel.present_reply_state, with the host's table)."""
    head = np.frombuffer(reply[:8], dtype=np.uint8)
    out = np.zeros((3, 8))
    return bool(cycle_kernel.present_reply_state(
        reply, head, np.arange(2, 10, dtype=np.uint8), out, float(units.POSITION_CENTER), units.RAD_PER_PULSE,
        units.RADS_PER_VELOCITY_LSB, units.AMPERE_PER_CURRENT_LSB, cycle_kernel.TABLE))


def _goal_current_packet() -> bytes:
    """The host's Goal Current Sync Write of two servos as its compiled call builds it (the plain source of
    cycle_kernel.goal_current_packet, with the host's table)."""
    head = CranePacketHandler.sync_write_header(102, 2, 6)
    buf = np.zeros(12 + 6 + 2, dtype=np.uint8)
    buf[:12] = np.frombuffer(head, dtype=np.uint8)
    lsb = units.AMPERE_PER_CURRENT_LSB
    size = cycle_kernel.goal_current_packet(np.array([0.5, -0.25]), np.arange(2), np.array([2, 3]),
                                            np.full(2, 2.0), np.full(2, 700), lsb, buf, np.zeros(2),
                                            cycle_kernel.TABLE)
    assert size == len(buf)
    return buf.tobytes()


def test_a_damaged_simulator_table_frames_replies_the_host_refuses():
    """Damaged in place, the array the simulator's compiled calls are given: with one table shared by both
    sides the host's check would agree with the damage."""
    good = _present_reply()
    assert _host_accepts(good) and _sdk_crc(good[:-2]) == _crc_of(good)
    kept = chain_kernel.CRC_TABLE_U16.copy()
    try:
        chain_kernel.CRC_TABLE_U16[:] ^= 1
        bad = _present_reply()
        assert _crc_of(bad) != _crc_of(good) and bad[:-2] != good[:-2]  # (the running CRCs differ too)
        assert not _host_accepts(bad)
        assert packets.crc16(bad[:-2]) != _crc_of(bad)
    finally:
        chain_kernel.CRC_TABLE_U16[:] = kept
    assert _present_reply() == good


def test_a_damaged_host_table_frames_packets_the_simulator_refuses():
    good = _goal_current_packet()
    assert _sdk_crc(good[:-2]) == _crc_of(good) and protocol.PacketParser().feed(good)
    kept = cycle_kernel.TABLE.copy()
    try:
        cycle_kernel.TABLE[:] ^= 1
        bad = _goal_current_packet()
        assert bad[:-2] == good[:-2] and _crc_of(bad) != _crc_of(good)
        parser = protocol.PacketParser()
        assert parser.feed(bad) == [] and parser.crc_errors == 1
    finally:
        cycle_kernel.TABLE[:] = kept
    assert _goal_current_packet() == good
