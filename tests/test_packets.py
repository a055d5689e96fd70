"""The fast paths of the CRC-16 and of CranePacketHandler give exactly what the e-manual's byte-wise
CRC and dynamixel-sdk's own packet handler give, on any bytes (stuffing patterns included)."""

from __future__ import annotations

from dynamixel_sdk.protocol2_packet_handler import Protocol2PacketHandler
from hypothesis import given, settings
from hypothesis import strategies as st

from crane_io.dynamixel.crc import Crc16
from crane_io.dynamixel.packets import CranePacketHandler

crc16 = Crc16()
CRC_TABLE, crc16_append, crc16_chain = crc16.table, crc16.append, crc16.chain

# bytes drawn mostly from FF / FD / 00 so that FF FF FD (and FF FF FD FD) occur often
_BYTE = st.one_of(st.sampled_from([0xFF, 0xFD, 0x00, 0x55]), st.integers(0, 255))
_DATA = st.lists(_BYTE, max_size=60)


def _bytewise(data, crc=0):
    for b in data:
        crc = ((crc << 8) ^ CRC_TABLE[((crc >> 8) ^ b) & 0xFF]) & 0xFFFF
    return crc


@given(_DATA, st.integers(0, 0xFFFF))
def test_word_table_crc_equals_the_bytewise_crc(data, start):
    assert crc16(bytes(data), start) == _bytewise(data, start)
    assert crc16(data, start) == _bytewise(data, start)  # a list of ints works too


def test_crc_of_the_e_manual_example_packet():
    # e-manual, Protocol 2.0: Ping to ID 1 is FF FF FD 00 01 03 00 01 19 4E
    assert crc16(bytes.fromhex("FFFFFD0001030001")) == 0x4E19


@given(st.lists(st.lists(_BYTE, max_size=14).map(bytes), max_size=9), st.lists(_BYTE, max_size=9).map(bytes))
def test_running_crcs_of_a_fast_status_packet(parts, head):
    expected, crc, packet = [], 0, bytearray(head)
    for part in parts:
        packet += part
        crc = _bytewise(packet)
        expected.append(crc)
        packet += bytes((crc & 0xFF, crc >> 8))
        assert crc16_append(crc) == _bytewise(packet)
    assert crc16_chain(head, parts) == expected


def _packet(params, packet_id, instruction):
    length = len(params) + 3
    head = [0xFF, 0xFF, 0xFD, 0x00, packet_id, length & 0xFF, length >> 8, instruction]
    return head + params + [0x12, 0x34]


@settings(max_examples=300)
@given(_DATA, st.sampled_from([1, 0xFE, 0xFF, 0xFD]), st.sampled_from([0x55, 0x83, 0xFD, 0xFF]))
def test_packet_handler_matches_the_sdk(params, packet_id, instruction):
    sdk, fast = Protocol2PacketHandler(), CranePacketHandler()
    pkt = _packet(params, packet_id, instruction)
    assert fast.addStuffing(list(pkt)) == sdk.addStuffing(list(pkt))
    assert fast.removeStuffing(list(pkt)) == sdk.removeStuffing(list(pkt))
    for n in (0, 1, len(pkt) - 2, len(pkt)):
        assert fast.updateCRC(0, pkt, n) == sdk.updateCRC(0, pkt, n)


class _RecordingPort:
    """What a packet handler does to its port: the bytes written, is_using, the packet timeout."""

    def __init__(self, busy=False):
        self.is_using = busy
        self.written: list[bytes] = []
        self.timeouts: list[int] = []
        self.cleared = 0

    def clearPort(self):  # noqa: N802 (SDK name)
        self.cleared += 1

    def writePort(self, packet):  # noqa: N802
        self.written.append(bytes(packet))
        return len(packet)

    def setPacketTimeout(self, length):  # noqa: N802
        self.timeouts.append(length)


def _port_trace(port, result):
    return result, port.written, port.timeouts, port.is_using, port.cleared


@settings(max_examples=300)
@given(st.lists(_BYTE, max_size=40), st.sampled_from([126, 70, 0xFDFF, 102, 116]), st.integers(1, 300),
       st.booleans(), st.booleans())
def test_kept_and_built_instruction_packets_equal_the_sdks(params, address, length, fast, busy):
    sdk, crane = Protocol2PacketHandler(), CranePacketHandler()
    for _ in range(2):  # the second time from the kept packet
        a, b = _RecordingPort(busy), _RecordingPort(busy)
        assert _port_trace(b, crane.syncReadTx(b, address, length, params, len(params), fast)) == \
            _port_trace(a, sdk.syncReadTx(a, address, length, params, len(params), fast))
        a, b = _RecordingPort(busy), _RecordingPort(busy)
        assert _port_trace(b, crane.syncWriteTxOnly(b, address, length, params, len(params))) == \
            _port_trace(a, sdk.syncWriteTxOnly(a, address, length, params, len(params)))
