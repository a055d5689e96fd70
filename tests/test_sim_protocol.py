"""Protocol 2.0 codec of the simulator, byte for byte against the ROBOTIS e-manual examples
(docs/en/dxl/protocol2.md of ROBOTIS-GIT/emanual) and against the dynamixel-sdk's own routines."""

from __future__ import annotations

import pytest
from dynamixel_sdk import PacketHandler

from crane_io.sim import protocol as p


def h(text: str) -> bytes:
    return bytes.fromhex(text)


# (instruction packet, e-manual bytes) built with our encoder
EMANUAL_INSTRUCTIONS = [
    ("ping id 1", (1, p.INST_PING, b""), "FF FF FD 00 01 03 00 01 19 4E"),
    ("broadcast ping", (0xFE, p.INST_PING, b""), "FF FF FD 00 FE 03 00 01 31 42"),
    ("read present position", (1, p.INST_READ, h("84 00 04 00")),
     "FF FF FD 00 01 07 00 02 84 00 04 00 1D 15"),
    ("write goal position 512", (1, p.INST_WRITE, h("74 00 00 02 00 00")),
     "FF FF FD 00 01 09 00 03 74 00 00 02 00 00 CA 89"),
    ("reg write goal velocity 200", (1, p.INST_REG_WRITE, h("68 00 C8 00 00 00")),
     "FF FF FD 00 01 09 00 04 68 00 C8 00 00 00 AE 8E"),
    ("action", (1, p.INST_ACTION, b""), "FF FF FD 00 01 03 00 05 02 CE"),
    ("factory reset except id", (1, p.INST_FACTORY_RESET, h("01")), "FF FF FD 00 01 04 00 06 01 A1 E6"),
    ("reboot", (1, p.INST_REBOOT, b""), "FF FF FD 00 01 03 00 08 2F 4E"),
    ("clear multi-turn", (1, p.INST_CLEAR, h("01 44 58 4C 22")),
     "FF FF FD 00 01 08 00 10 01 44 58 4C 22 B1 DC"),
    ("sync read", (0xFE, p.INST_SYNC_READ, h("84 00 04 00 01 02")),
     "FF FF FD 00 FE 09 00 82 84 00 04 00 01 02 CE FA"),
    ("sync write", (0xFE, p.INST_SYNC_WRITE, h("74 00 04 00 01 96 00 00 00 02 AA 00 00 00")),
     "FF FF FD 00 FE 11 00 83 74 00 04 00 01 96 00 00 00 02 AA 00 00 00 82 87"),
    ("bulk read", (0xFE, p.INST_BULK_READ, h("01 90 00 02 00 02 92 00 01 00")),
     "FF FF FD 00 FE 0D 00 92 01 90 00 02 00 02 92 00 01 00 1A 05"),
    ("bulk write", (0xFE, p.INST_BULK_WRITE, h("01 20 00 02 00 A0 00 02 1F 00 01 00 50")),
     "FF FF FD 00 FE 10 00 93 01 20 00 02 00 A0 00 02 1F 00 01 00 50 B7 68"),
]

EMANUAL_STATUS = [
    ("ping reply id 1", (1, 0, h("06 04 26")), "FF FF FD 00 01 07 00 55 00 06 04 26 65 5D"),
    ("ping reply id 2", (2, 0, h("06 04 26")), "FF FF FD 00 02 07 00 55 00 06 04 26 6F 6D"),
    ("read reply 166", (1, 0, h("A6 00 00 00")), "FF FF FD 00 01 08 00 55 00 A6 00 00 00 8C C0"),
    ("sync read reply 2079", (2, 0, h("1F 08 00 00")), "FF FF FD 00 02 08 00 55 00 1F 08 00 00 BA BE"),
    ("write ack", (1, 0, b""), "FF FF FD 00 01 04 00 55 00 A1 0C"),
    ("bulk read reply voltage", (1, 0, h("77 00")), "FF FF FD 00 01 06 00 55 00 77 00 C3 69"),
    ("bulk read reply temperature", (2, 0, h("24")), "FF FF FD 00 02 05 00 55 00 24 8B A9"),
]


@pytest.mark.parametrize("name,args,wire", EMANUAL_INSTRUCTIONS, ids=[e[0] for e in EMANUAL_INSTRUCTIONS])
def test_instruction_packets_match_emanual(name, args, wire):
    assert p.instruction_packet(*args) == h(wire)


@pytest.mark.parametrize("name,args,wire", EMANUAL_STATUS, ids=[e[0] for e in EMANUAL_STATUS])
def test_status_packets_match_emanual(name, args, wire):
    assert p.status_packet(*args) == h(wire)


@pytest.mark.parametrize("name,args,wire", EMANUAL_INSTRUCTIONS, ids=[e[0] for e in EMANUAL_INSTRUCTIONS])
def test_parser_reads_emanual_packets(name, args, wire):
    parser = p.PacketParser()
    packets = parser.feed(h(wire))
    assert [(q.id, q.instruction, q.params) for q in packets] == [args]
    assert parser.crc_errors == 0 and not parser.buffer


def test_crc_matches_sdk_for_arbitrary_bytes():
    sdk = PacketHandler(2.0)
    data = bytes(range(256)) * 3
    for n in (0, 1, 7, 100, len(data)):
        assert p.crc16(data[:n]) == sdk.updateCRC(0, list(data[:n]), n)
    # continuing a CRC equals computing it in one go
    assert p.crc16(data[10:], p.crc16(data[:10])) == p.crc16(data)


def test_stuffing_adds_fd_after_header_pattern_and_round_trips():
    body = h("03 74 00 FF FF FD 00")
    assert p.stuff(body) == h("03 74 00 FF FF FD FD 00")
    assert p.unstuff(p.stuff(body)) == body
    packet = p.instruction_packet(1, p.INST_WRITE, h("74 00 FF FF FD 00"))
    # LEN counts the stuffed bytes and the CRC covers them (e-manual "Processing Order of Transmission")
    assert packet[5] == 3 + 7
    assert p.crc16(packet[:-2]) == packet[-2] | packet[-1] << 8
    sdk = PacketHandler(2.0)
    tx = [0xFF, 0xFF, 0xFD, 0x00, 1, 9, 0, p.INST_WRITE, 0x74, 0x00, 0xFF, 0xFF, 0xFD, 0x00, 0, 0]
    stuffed = sdk.addStuffing(tx)
    assert bytes(stuffed[:-2]) == packet[:-2]
    parsed = p.PacketParser().feed(packet)
    assert parsed[0].params == h("74 00 FF FF FD 00")


def test_parser_handles_split_input_garbage_and_bad_crc():
    good = p.instruction_packet(2, p.INST_PING)
    bad = bytearray(p.instruction_packet(3, p.INST_PING))
    bad[-1] ^= 0x01
    stream = b"\x00\xff\xff" + bytes(bad) + b"\x12\xfd" + good + good
    parser = p.PacketParser()
    got = []
    for i in range(len(stream)):
        got += parser.feed(stream[i:i + 1])
    assert [q.id for q in got] == [2, 2]
    assert parser.crc_errors == 1


def test_parser_abandons_a_stale_partial_packet():
    parser = p.PacketParser(stale_after_s=0.02)
    # a header announcing a huge length: a corrupted LEN field
    assert parser.feed(h("FF FF FD 00 01 F0 03"), now=0.0) == []
    good = p.instruction_packet(2, p.INST_PING)
    assert parser.feed(good, now=0.001) == []  # still waiting for the long packet
    got = parser.feed(good, now=0.5)  # the host retries after its timeout
    assert [q.id for q in got] == [2]
    assert parser.feed(good, now=0.501) == got  # and the parser is back in step


def test_fast_sync_read_packet_layout():
    blocks = [(0, 2, h("01 02")), (0x80, 3, h("03 04"))]
    pkt = p.fast_status_packet(blocks)
    assert pkt[:8] == h("FF FF FD 00 FE 0D 00 55")  # LEN = 1 + 2 * (4 + 2)
    assert len(pkt) == 7 + 13
    first = pkt[:8] + h("00 02 01 02")
    crc1 = p.crc16(first)
    assert pkt[12:14] == bytes((crc1 & 0xFF, crc1 >> 8))  # running CRC after servo 2's block
    assert pkt[14:18] == h("80 03 03 04")
    assert p.crc16(pkt[:-2]) == pkt[-2] | pkt[-1] << 8


def test_wire_sizes_match_the_facts_table():
    # shared/crane_x7_facts.md 6d: sync read 10 B of 8 servos = 22 + 8 * 21, sync write 2 B = 38
    assert p.sync_read_bytes(8, 10) == (22, 168)
    assert p.sync_write_bytes(8, 2) == 38
    assert p.sync_write_bytes(8, 4) == 54
    assert p.fast_sync_read_bytes(8, 10) == (22, 120)
    assert p.cycle_bytes(8, 10, 2, fast=True) == 180
    assert p.cycle_bytes(8, 10, 2, fast=False) == 228
    assert len(p.instruction_packet(0xFE, p.INST_SYNC_READ, bytes(4 + 8))) == 22
    assert len(p.fast_status_packet([(0, i, bytes(10)) for i in range(2, 10)])) == 120
