"""dynamixel-sdk's Protocol 2.0 packet handler with its per-packet overheads removed.

`CranePacketHandler` is `dynamixel_sdk.Protocol2PacketHandler` (the SDK still sends, receives and checks
every packet) with some of its steps made cheaper, the bytes on the wire unchanged:

- `updateCRC` uses the word-wise table of crane_io.dynamixel.crc (the client's own `crc16`) instead of
  rebuilding a 256-entry list on every call and looping per byte;
- `addStuffing` returns the packet untouched when its instruction and parameters hold no "FF FF FD"
  (the usual case) instead of copying it through a 1024-entry scratch list;
- `removeStuffing` returns the packet untouched when it holds no stuffed "FF FF FD FD".
- `syncReadTx` (Sync Read and Fast Sync Read) keeps the finished instruction packet (stuffed, with its
  CRC) per request: the control loop sends the same read every cycle;
- `syncWriteTxOnly` builds its packet as bytes from a kept header (only the parameters change) instead
  of a list the SDK then stuffs, checks and converts; `sync_write_packet` + `send_broadcast` do the same
  for a caller that has the parameters at hand (the bus's goal writes, without GroupSyncWrite); a sync
  write's CRC comes from per-position tables made once for its header and length (crc.FixedPrefixCrc);
- `sync_read_packet` + `send_packet`: the kept (Fast) Sync Read packet and its sending, for the bus's
  control-cycle read (`status_read.StatusSyncRead.fast_read`).
Packets that do need (un)stuffing go through the SDK's own code.
"""

from __future__ import annotations

from dynamixel_sdk.protocol2_packet_handler import (
    BROADCAST_ID,
    COMM_PORT_BUSY,
    COMM_SUCCESS,
    COMM_TX_FAIL,
    INST_FAST_SYNC_READ,
    INST_SYNC_READ,
    INST_SYNC_WRITE,
    TXPACKET_MAX_LEN,
    Protocol2PacketHandler,
)

from crane_io.dynamixel.crc import Crc16

_LEN_L, _LEN_H = 5, 6
_STUFF = b"\xff\xff\xfd"
_STUFFED = b"\xff\xff\xfd\xfd"
_HEADER = b"\xff\xff\xfd\x00"
_KEPT_READS = 16  # Sync Read packets kept (a bus sends two kinds: the Present block and the error poll)
_TABLED_PARAMS = 64  # sync writes with at most this many parameter bytes get their CRC from tables
# the bus client's CRC, with its own tables (the simulated servos have theirs: crane_io.sim.protocol)
crc16 = Crc16()


class CranePacketHandler(Protocol2PacketHandler):
    """Protocol2PacketHandler with fast CRC and (un)stuffing fast paths and kept instruction packets (same
    bytes on the wire)."""

    def __init__(self):
        super().__init__()
        self._sync_reads: dict[tuple, bytes] = {}  # (instruction, address, length, IDs) -> packet
        # (instruction, address, length, n params) -> (the bytes before the params, their CRC tables or None)
        self._headers: dict[tuple, tuple] = {}

    # ---- instruction packets -------------------------------------------------------------------------
    def syncReadTx(self, port, start_address, data_length, param, param_length, fast_option):  # noqa: N802
        inst = INST_FAST_SYNC_READ if fast_option else INST_SYNC_READ
        packet = self.sync_read_packet(inst, start_address, data_length, param[:param_length])
        if packet is None:  # needs byte stuffing: the SDK's own path
            return super().syncReadTx(port, start_address, data_length, param, param_length, fast_option)
        result = self._send(port, packet)
        if result == COMM_SUCCESS:
            port.setPacketTimeout((11 + data_length) * param_length)
        return result

    def sync_read_packet(self, inst: int, start_address: int, data_length: int, param) -> bytes | None:
        """The finished (Fast) Sync Read packet `syncReadTx` sends for `param` (the servo IDs), byte for
        byte; None when it needs byte stuffing (or there is no servo to ask)."""
        if not param:
            return None
        key = (inst, start_address, data_length, tuple(param))
        packet = self._sync_reads.get(key)
        if packet is None:
            packet = self._sync_packet(inst, start_address, data_length, param, len(param))
            if packet is None:
                return None
            if len(self._sync_reads) >= _KEPT_READS:
                self._sync_reads.clear()
            self._sync_reads[key] = packet
        return packet

    def send_packet(self, port, packet: bytes) -> int:
        """Send a finished instruction packet that expects a reply (the port stays taken for it), as
        `syncReadTx` sends its packet; the caller sets the packet timeout."""
        return self._send(port, packet)

    def syncWriteTxOnly(self, port, start_address, data_length, param, param_length):  # noqa: N802
        packet = self._sync_packet(INST_SYNC_WRITE, start_address, data_length, param, param_length)
        if packet is None:
            return super().syncWriteTxOnly(port, start_address, data_length, param, param_length)
        result = self._send(port, packet)
        if result == COMM_SUCCESS:
            port.is_using = False  # a broadcast: no status packet to wait for (as txRxPacket does)
        return result

    def sync_write_packet(self, start_address: int, data_length: int, param) -> bytes | None:
        """The finished Sync Write packet of `param` (ID and data bytes per servo), byte for byte what
        GroupSyncWrite.txPacket sends through `syncWriteTxOnly`; None when it needs byte stuffing."""
        return self._sync_packet(INST_SYNC_WRITE, start_address, data_length, param, len(param))

    def send_broadcast(self, port, packet: bytes) -> int:
        """Send a finished broadcast packet (from `sync_write_packet`) as `syncWriteTxOnly` sends it."""
        result = self._send(port, packet)
        if result == COMM_SUCCESS:
            port.is_using = False
        return result

    def _sync_packet(self, inst, start_address, data_length, param, param_length) -> bytes | None:
        """The finished broadcast packet INST ADDR LEN params (CRC appended), as the SDK's txPacket makes
        it; None when it needs byte stuffing."""
        key = (inst, start_address, data_length, param_length)
        kept = self._headers.get(key)
        if kept is None:
            head = _sync_header(inst, start_address, data_length, param_length)
            # a sync write's parameters change every cycle: its CRC from tables (see FixedPrefixCrc)
            tabled = inst == INST_SYNC_WRITE and param_length <= _TABLED_PARAMS
            kept = self._headers[key] = (head, crc16.fixed_prefix(head, param_length) if tabled else None)
        head, tabled = kept
        params = bytes(param[:param_length])
        packet = head + params
        if packet.find(_STUFF, 5) >= 0 or len(packet) + 2 > TXPACKET_MAX_LEN:
            return None
        crc = crc16(packet) if tabled is None else tabled(params)
        return packet + bytes((crc & 0xFF, crc >> 8))

    @staticmethod
    def sync_write_header(start_address: int, data_length: int, param_length: int) -> bytes:
        """The first 12 bytes of a Sync Write packet with `param_length` parameter bytes (its parameters and
        CRC follow), as `sync_write_packet` makes them."""
        return _sync_header(INST_SYNC_WRITE, start_address, data_length, param_length)

    @staticmethod
    def _send(port, packet: bytes) -> int:
        """txPacket's sending part for a finished packet: the port taken, its input cleared, the bytes
        written (the port stays taken for the reply, as in the SDK)."""
        if port.is_using:
            return COMM_PORT_BUSY
        port.is_using = True
        port.clearPort()
        if port.writePort(packet) != len(packet):
            port.is_using = False
            return COMM_TX_FAIL
        return COMM_SUCCESS

    # ---- the SDK's helpers -----------------------------------------------------------------------------

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


def _sync_header(inst: int, start_address: int, data_length: int, param_length: int) -> bytes:
    """A broadcast packet's bytes before its parameters: header, ID, LEN, INST, address, data length."""
    length = param_length + 7  # INST, address, data length, params, CRC
    return _HEADER + bytes((BROADCAST_ID, length & 0xFF, (length >> 8) & 0xFF, inst,
                            start_address & 0xFF, (start_address >> 8) & 0xFF,
                            data_length & 0xFF, (data_length >> 8) & 0xFF))
