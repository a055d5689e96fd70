"""crane_io.dynamixel.crc remembers the CRCs of recent packets (issue 13): a receiver checking the bytes
its sender just framed, or the control loop's unchanging Sync Read, looks the CRC up. The memo is keyed
by the exact bytes, so it can never vouch for a changed byte, and the CRCs it files equal dynamixel-sdk's
own."""

from __future__ import annotations

import random

from dynamixel_sdk.protocol2_packet_handler import Protocol2PacketHandler

from crane_io.dynamixel import crc as crc_mod
from crane_io.dynamixel.crc import crc16
from crane_io.sim import protocol as p

_SDK = Protocol2PacketHandler()  # the SDK's own byte-wise CRC, independent of crane_io.dynamixel.crc


def _sdk_crc(data: bytes) -> int:
    return _SDK.updateCRC(0, list(data), len(data))


def test_a_changed_byte_is_computed_not_looked_up():
    rng = random.Random(1)
    packet = p.instruction_packet(0xFE, p.INST_SYNC_WRITE, bytes([102, 0, 2, 0, 2, 10, 0, 3, 20, 0]))
    body = packet[:-2]
    assert crc16(body) == _sdk_crc(body) == crc16(body)  # computed, then looked up: the same
    for _ in range(200):
        bad = bytearray(body)
        bad[rng.randrange(len(bad))] ^= 1 << rng.randrange(8)
        assert crc16(bytes(bad)) == _sdk_crc(bytes(bad)) != crc16(body)


def test_the_fast_status_packet_files_the_crc_the_sdk_computes():
    rng = random.Random(2)
    for _ in range(50):
        blocks = [(rng.choice((0, 0x80)), sid, bytes(rng.choice((0xFF, 0xFD, rng.randrange(256)))
                                                    for _ in range(10))) for sid in range(2, 10)]
        pkt = p.fast_status_packet(blocks)
        assert _sdk_crc(pkt[:-2]) == pkt[-2] | pkt[-1] << 8
        assert crc16(pkt[:-2]) == pkt[-2] | pkt[-1] << 8


def test_the_memo_stays_small():
    for k in range(1000):
        crc16(k.to_bytes(4, "little"))
    assert len(crc_mod._MEMO) <= crc_mod._MEMO_SIZE


def test_continuing_a_crc_never_uses_the_memo():
    data = bytes(range(40))
    assert crc16(data[20:], crc16(data[:20])) == _sdk_crc(data)
