"""Reading the servos' status packets: the sync reads of the bus (crane_io.dynamixel.bus) and the Fast Sync
Read reply's own receiving path, byte for byte what dynamixel-sdk accepts.

`StatusSyncRead` is dynamixel-sdk's GroupSyncRead keeping every servo's status error byte and removing
byte stuffing from Fast Sync Read replies; its `fast_read` is the control cycle's read (the kept request,
the expected reply checked whole, optionally converted by the bus codec in one call). `rx_packet` is the
SDK's rxPacket loop starting from bytes already read.
"""

from __future__ import annotations

import numpy as np
from dynamixel_sdk import COMM_RX_CORRUPT, COMM_SUCCESS, COMM_TX_FAIL, GroupSyncRead
from dynamixel_sdk.protocol2_packet_handler import INST_FAST_SYNC_READ, RXPACKET_MAX_LEN
from dynamixel_sdk.robotis_def import BROADCAST_ID, COMM_RX_TIMEOUT

from crane_io.dynamixel.control_table import PRESENT_BLOCK_SIZE
from crane_io.dynamixel.packets import crc16

_PKT_RESERVED, _PKT_ID, _PKT_LEN_L, _PKT_INSTRUCTION = 3, 4, 5, 7  # as in dynamixel-sdk's protocol 2 handler
STUFFED = b"\xff\xff\xfd\xfd"  # a stuffed FF FF FD in a packet
FIRST_PARAM = 8  # fast sync read: the first servo's error byte


class StatusSyncRead(GroupSyncRead):
    """GroupSyncRead that keeps every servo's status error byte and removes byte stuffing from fast
    sync read replies (the SDK parses the stuffed packet, which shifts the data when a reading happens
    to contain FF FF FD)."""

    def __init__(self, port, ph, start_address, data_length):
        super().__init__(port, ph, start_address, data_length)
        self.errors: dict[int, int] = {}
        self.packet: bytes | None = None  # the latest fast reply when it took the fast path (else None)
        self._fast_head: bytes | None = None  # the expected fast reply's first 8 bytes, its length, IDs
        self._fast_total = 0
        self._fast_ids: tuple = ()
        self._fast_id_bytes: bytes | None = None
        self._zero_errors: dict[int, int] = {}  # ... and its `errors`
        self._request: bytes | None = None  # fast_read's kept Fast Sync Read packet, for `param`
        self._request_param: list | None = None
        self._codec = None  # fast_read's check and conversion of the Present block's reply (`use_codec`)
        self.decoded = False  # the latest fast_read filled its `out`

    def rxPacket(self):  # noqa: N802 (SDK name)
        self.last_result = False
        self.errors = {}
        self.packet = None
        for dxl_id in self.data_dict:
            data, result, error = self.ph.readRx(self.port, dxl_id, self.data_length)
            if result != COMM_SUCCESS:
                return result
            if len(data) != self.data_length:
                return COMM_RX_CORRUPT
            self.data_dict[dxl_id] = bytearray(data)
            self.errors[dxl_id] = error
        self.last_result = True
        return COMM_SUCCESS

    def fastSyncReadRxPacket(self):  # noqa: N802
        self.last_result = False
        self.errors = {}
        self.packet = None
        self._expect_fast_reply()
        return self._take_fast_reply(self.port.readPort(self._fast_total))

    def _expect_fast_reply(self) -> None:
        """The expected fast reply's first 8 bytes, length and servo IDs for the servos of data_dict."""
        count = len(self.data_dict)
        total = 8 + (self.data_length + 4) * count  # header, ID, LEN, INST, then ERR ID DATA CRC per servo
        if self._fast_head is None or self._fast_total != total or self._fast_ids != tuple(self.data_dict):
            length = total - 7
            self._fast_head = bytes((0xFF, 0xFF, 0xFD, 0x00, BROADCAST_ID, length & 0xFF, length >> 8, 0x55))
            self._fast_total = total
            self._fast_ids = tuple(self.data_dict)
            self._fast_id_bytes = bytes(self._fast_ids) if all(i < 256 for i in self._fast_ids) else None
            self._zero_errors = dict.fromkeys(self._fast_ids, 0)
            self._tell_codec()

    def use_codec(self, codec) -> None:
        """Let fast_read check the expected reply and convert it with `codec` (crane_io.dynamixel.codec: the
        Present block only)."""
        self._codec = codec
        self._tell_codec()

    def _tell_codec(self) -> None:
        if self._codec is not None and self._fast_head is not None:
            ok = self._fast_id_bytes is not None and self.data_length == PRESENT_BLOCK_SIZE
            self._codec.expect(self._fast_head, self._fast_id_bytes if ok else None)

    def fast_read(self, out: np.ndarray | None = None) -> tuple[int, bytes | None]:
        """fastSyncRead for the control cycle, the same bytes on the wire: (result, reply). `reply` is the
        whole fast reply when the codec (`use_codec`) accepts it: the expected one with every status error
        byte 0 (the usual case); then it is converted into `out` ((3, n) floats, a new array when None:
        positions, velocities, currents in the servos' request order), `decoded` is set and only `packet`
        and `errors` are updated (not data_dict: the reply holds the data). Otherwise `reply` is None and
        the reader is left exactly as fastSyncRead leaves it."""
        self.decoded = False
        request = self._request
        if request is None or self.is_param_changed or self.param is not self._request_param:
            # first call, or other servos: the SDK's way (its packet handler keeps the packet)
            result = self.fastSyncRead()
            self._request_param = self.param
            self._request = self.ph.sync_read_packet(INST_FAST_SYNC_READ, self.start_address,
                                                     self.data_length, self.param)
            self._expect_fast_reply()
            return result, None
        port = self.port
        result = self.ph.send_packet(port, request)  # as syncReadTx sends it
        if result != COMM_SUCCESS:
            return result, None
        port.setPacketTimeout((11 + self.data_length) * len(self.param))
        self.last_result = False
        self.errors = {}
        self.packet = None
        data = port.readPort(self._fast_total)
        codec = self._codec
        if out is None:
            out = np.empty((3, len(self._fast_ids)))
        if codec is not None and codec.present_state(data, out):
            port.is_using = False
            self.packet = data
            self.errors = self._zero_errors  # shared: `errors` is always replaced, never changed in place
            self.last_result = True
            self.decoded = True
            return COMM_SUCCESS, data
        return self._take_fast_reply(data), None

    def _take_fast_reply(self, data: bytes) -> int:
        """fastSyncReadRxPacket with the first `_fast_total` bytes already read."""
        port, n = self.port, self.data_length
        chunk = n + 4
        total = self._fast_total
        # fast path: the one expected reply read whole, as dynamixel-sdk's rxPacket would accept it (its
        # header at the start, its CRC right, no byte stuffing, the servos in request order); anything
        # else goes through rxPacket's own loop with the bytes already read (`rx_packet`)
        if (len(data) == total and data.startswith(self._fast_head) and STUFFED not in data
                and crc16(data[:-2]) == (data[-2] | (data[-1] << 8))
                and data[9::chunk] == self._fast_id_bytes):
            port.is_using = False
            self.packet = data
            ids = self._fast_ids
            self.errors = dict(zip(ids, data[8::chunk]))
            dd = self.data_dict
            for k, dxl_id in enumerate(ids):
                start = 10 + k * chunk
                dd[dxl_id] = bytearray(data[start:start + n])
            self.last_result = True
            return COMM_SUCCESS
        packet, result = rx_packet(self.ph, port, data)
        if result != COMM_SUCCESS:
            return result
        return self.take_fast_packet(packet)

    def take_fast_packet(self, packet: list) -> int:
        """Take the blocks of a Fast Sync Read status packet as rxPacket returned it (a list of bytes,
        possibly stuffed): COMM_SUCCESS, or COMM_RX_CORRUPT for a packet not addressed to the broadcast
        ID, of the wrong length, or with an unknown or repeated servo ID."""
        if packet[_PKT_ID] != BROADCAST_ID:
            return COMM_RX_CORRUPT
        packet = self.ph.removeStuffing(packet)  # rxPacket's own list: unstuffed in place
        length = packet[5] | (packet[6] << 8)
        body = bytes(packet[FIRST_PARAM: 7 + length])  # [ERR ID DATA.. CRC CRC] per servo
        n = self.data_length
        chunk = n + 4
        if len(body) != chunk * len(self.data_dict):
            return COMM_RX_CORRUPT
        seen = {}
        for k in range(0, len(body), chunk):
            dxl_id = body[k + 1]
            if dxl_id not in self.data_dict or dxl_id in seen:
                return COMM_RX_CORRUPT
            seen[dxl_id] = (bytearray(body[k + 2:k + 2 + n]), body[k])
        for dxl_id, (data, error) in seen.items():
            self.data_dict[dxl_id] = data
            self.errors[dxl_id] = error
        self.last_result = True
        return COMM_SUCCESS


def rx_packet(ph, port, prefix=b""):
    """dynamixel-sdk's Protocol2PacketHandler.rxPacket(port, fast_option=True), step for step, starting
    with the bytes `prefix` already read from the port (the fast path's read). The SDK reads in pieces
    (11 bytes, then the rest of the packet); the bytes it sees, and so its verdict, are the same: only
    reads that would ask for no byte are skipped."""
    rxpacket = list(prefix)
    packet_id = BROADCAST_ID
    result = COMM_TX_FAIL
    rx_length = len(rxpacket)
    wait_length = 11  # minimum length (HEADER0..2 RESERVED ID LENGTH_L LENGTH_H INST ERROR CRC16_L CRC16_H)
    while True:
        if wait_length > rx_length:
            rxpacket.extend(port.readPort(wait_length - rx_length))
            rx_length = len(rxpacket)
        if rx_length >= wait_length:
            idx = _header_at(rxpacket, rx_length)
            if idx == 0:
                length = rxpacket[_PKT_LEN_L] | (rxpacket[_PKT_LEN_L + 1] << 8)
                if (rxpacket[_PKT_RESERVED] != 0x00 or rxpacket[_PKT_ID] > packet_id
                        or length > RXPACKET_MAX_LEN or rxpacket[_PKT_INSTRUCTION] != 0x55):
                    del rxpacket[0]  # remove the first byte in the packet
                    rx_length -= 1
                    continue
                if wait_length != length + _PKT_LEN_L + 2:
                    wait_length = length + _PKT_LEN_L + 2
                    continue
                if rx_length < wait_length:
                    if port.isPacketTimeout():
                        result = COMM_RX_TIMEOUT if rx_length == 0 else COMM_RX_CORRUPT
                        break
                    continue
                crc = rxpacket[wait_length - 2] | (rxpacket[wait_length - 1] << 8)
                ok = ph.updateCRC(0, rxpacket, wait_length - 2) == crc
                result = COMM_SUCCESS if ok else COMM_RX_CORRUPT
                break
            del rxpacket[0:idx]  # remove unnecessary packets
            rx_length -= idx
        elif port.isPacketTimeout():
            result = COMM_RX_TIMEOUT if rx_length == 0 else COMM_RX_CORRUPT
            break
    port.is_using = False
    return rxpacket, result


def _header_at(rxpacket: list, rx_length: int) -> int:
    """Where rxPacket's search finds the packet header (FF FF FD not followed by FD) among the first
    `rx_length` (at least 4) bytes: its index, or the last index searched when there is none."""
    for idx in range(0, rx_length - 3):
        if (rxpacket[idx] == 0xFF and rxpacket[idx + 1] == 0xFF and rxpacket[idx + 2] == 0xFD
                and rxpacket[idx + 3] != 0xFD):
            return idx
    return rx_length - 4

