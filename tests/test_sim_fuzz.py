"""Property-based fuzzing of the simulator's packet parser and chain: any bytes, truncated packets
and corrupted packets never crash them or hang the client."""

from __future__ import annotations

import time

import serial
from dynamixel_sdk import COMM_RX_CORRUPT, COMM_RX_TIMEOUT, COMM_SUCCESS, PacketHandler, PortHandler
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from crane_io.sim import protocol as p
from crane_io.sim import simulated_arm
from crane_io.sim.chain import SimulatedChain
from crane_io.sim.simple_plant import SimplePlant

INSTRUCTIONS = [p.INST_PING, p.INST_READ, p.INST_WRITE, p.INST_REG_WRITE, p.INST_ACTION, p.INST_FACTORY_RESET,
                p.INST_REBOOT, p.INST_CLEAR, p.INST_STATUS, p.INST_SYNC_READ, p.INST_SYNC_WRITE,
                p.INST_FAST_SYNC_READ, p.INST_BULK_READ, p.INST_BULK_WRITE, p.INST_FAST_BULK_READ]

valid_packets = st.builds(
    p.instruction_packet,
    st.sampled_from([2, 3, 9, 1, 0xFE, 0xFD]),
    st.one_of(st.sampled_from(INSTRUCTIONS), st.integers(0, 255)),
    st.binary(max_size=60),
)


def _chain():
    return SimulatedChain(SimplePlant(), {3: "XM540-W270"}, return_delay_time=0)


@settings(max_examples=300, deadline=None)
@given(st.lists(st.binary(max_size=80), max_size=8))
def test_parser_survives_random_bytes(chunks):
    parser = p.PacketParser()
    for i, chunk in enumerate(chunks):
        parser.feed(chunk, now=i * 0.001)
    assert parser.crc_errors >= 0


@settings(max_examples=200, deadline=None)
@given(st.binary(max_size=120), valid_packets)
def test_parser_recovers_after_garbage(garbage, packet):
    parser = p.PacketParser(stale_after_s=0.02)
    parser.feed(garbage, now=0.0)
    got = parser.feed(packet, now=1.0)  # the host's retry comes after the receive timeout
    assert got and got[-1].raw == packet


@settings(max_examples=200, deadline=None)
@given(valid_packets, st.data())
def test_truncated_and_flipped_packets(packet, data):
    cut = data.draw(st.integers(0, len(packet) - 1))
    parser = p.PacketParser(stale_after_s=0.02)
    assert parser.feed(packet[:cut], now=0.0) == []  # a truncated packet is never delivered
    flipped = bytearray(packet)
    pos = data.draw(st.integers(0, len(packet) - 1))
    flipped[pos] ^= data.draw(st.integers(1, 255))
    for g in parser.feed(bytes(flipped), now=1.0):  # whatever gets through has a valid CRC
        assert p.crc16(g.raw[:-2]) == g.raw[-2] | g.raw[-1] << 8
    got = parser.feed(packet, now=2.0)
    assert got and got[-1].raw == packet


@settings(max_examples=150, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(st.lists(st.one_of(valid_packets, st.binary(max_size=40)), max_size=6))
def test_chain_never_raises_on_any_input(items):
    chain = _chain()
    for item in items:
        reply = chain.feed(item)
        assert isinstance(reply, bytes)
        # every reply is made of well-formed status packets
        parsed = p.PacketParser().feed(reply)
        assert all(q.instruction == p.INST_STATUS for q in parsed)
    assert chain.stats.packets_received >= 0


class _UrlPort(PortHandler):
    def setupPort(self, cflag_baud):
        self.ser = serial.serial_for_url(self.port_name, baudrate=self.baudrate, timeout=0)
        self.is_open = True
        self.tx_time_per_byte = (1000.0 / self.baudrate) * 10.0
        return True


@settings(max_examples=12, deadline=None)
@given(st.binary(min_size=1, max_size=60))
def test_sdk_call_after_garbage_returns_an_error_code_not_a_hang(garbage):
    with simulated_arm(return_delay_time=0) as arm:
        port = _UrlPort(arm.url)
        port.setBaudRate(3_000_000)
        ph = PacketHandler(2.0)
        port.ser.write(b"\xff\xff\xfd\x00" + garbage)  # line noise that looks like a packet start
        start = time.monotonic()
        value, result, error = ph.read4ByteTxRx(port, 2, 132)
        assert time.monotonic() - start < 60.0  # returns (an error code), however busy the machine
        assert result in (COMM_SUCCESS, COMM_RX_TIMEOUT, COMM_RX_CORRUPT)
        time.sleep(0.03)  # after the servos' receive timeout the bus works again
        assert ph.read4ByteTxRx(port, 2, 132) == (2048, COMM_SUCCESS, 0)
        port.closePort()
