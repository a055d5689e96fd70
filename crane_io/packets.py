"""dynamixel-sdk's Protocol 2.0 packet handler with its per-packet overheads removed.

`CranePacketHandler` is `dynamixel_sdk.Protocol2PacketHandler` (the SDK still builds, sends, receives
and checks every packet) with three of its helpers made cheaper, results unchanged:

- `updateCRC` uses the word-wise table of crane_io.crc instead of rebuilding a 256-entry list on every
  call and looping per byte;
- `addStuffing` returns the packet untouched when its instruction and parameters hold no "FF FF FD"
  (the usual case) instead of copying it through a 1024-entry scratch list;
- `removeStuffing` returns the packet untouched when it holds no stuffed "FF FF FD FD".
Packets that do need (un)stuffing go through the SDK's own code.
"""

from __future__ import annotations

from dynamixel_sdk.protocol2_packet_handler import Protocol2PacketHandler

from .crc import crc16

_LEN_L, _LEN_H = 5, 6
_STUFF = b"\xff\xff\xfd"
_STUFFED = b"\xff\xff\xfd\xfd"


class CranePacketHandler(Protocol2PacketHandler):
    """Protocol2PacketHandler with fast CRC and (un)stuffing fast paths (same bytes on the wire)."""

    def updateCRC(self, crc_accum, data_blk_ptr, data_blk_size):  # noqa: N802 (SDK name)
        if 0 <= crc_accum <= 0xFFFF:
            try:
                return crc16(bytes(data_blk_ptr[:data_blk_size]), crc_accum)
            except (TypeError, ValueError):  # not a sequence of bytes: let the SDK decide
                pass
        return super().updateCRC(crc_accum, data_blk_ptr, data_blk_size)

    def addStuffing(self, packet):  # noqa: N802
        length = packet[_LEN_L] | (packet[_LEN_H] << 8)
        try:
            # the SDK stuffs an FD at positions 7 .. 4+length preceded by FF FF (from position 5 on)
            clean = _STUFF not in bytes(packet[_LEN_L:5 + length])
        except (TypeError, ValueError):
            clean = False
        if clean and len(packet) >= 7 + length:
            return packet
        return super().addStuffing(packet)

    def removeStuffing(self, packet):  # noqa: N802
        length = packet[_LEN_L] | (packet[_LEN_H] << 8)
        try:
            clean = _STUFFED not in bytes(packet[_LEN_L:6 + length])
        except (TypeError, ValueError):
            clean = False
        if clean and len(packet) >= 7 + length:
            return packet
        return super().removeStuffing(packet)
