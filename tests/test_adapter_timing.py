"""The U2D2 timing model (crane_io.sim.adapter_timing): bytes at the baud rate, Return Delay Times, USB
packets sent by the latency timer or a full buffer. The schedule is computed, never timed: every test
feeds times in and checks the times that come out."""

import pytest

from crane_io.description import default_arm
from crane_io.errors import ConfigError
from crane_io.sim import protocol as p
from crane_io.sim.adapter_timing import (
    AdapterLink,
    AdapterTiming,
    byte_time_s,
    reply_byte_times,
    status_packets,
)
from crane_io.sim.chain import SimulatedChain
from crane_io.sim.simple_plant import SimplePlant
from crane_io.sim.transport import PtyServer

MBPS3 = 3_000_000
BYTE = 10 / MBPS3  # s per byte at 3 Mbps: start bit, 8 data bits, stop bit
MS = 1e-3


def test_a_byte_takes_ten_bit_times():
    assert byte_time_s(MBPS3) == pytest.approx(3.333e-6, rel=1e-3)
    assert byte_time_s(57_600) == pytest.approx(10 / 57_600)
    with pytest.raises(ConfigError):
        byte_time_s(0)


def test_a_reply_waits_for_the_next_expiry_of_the_latency_timer():
    link = AdapterLink(AdapterTiming(latency_timer_s=1 * MS), t0=0.0)
    # 14 bytes out at 0.2 ms, a 120-byte reply without Return Delay: its last byte at
    # 0.2 ms + 134 byte times = 0.647 ms, in the adapter's buffer until the timer expires at 1 ms
    assert link.exchange(0.2 * MS, 14, MBPS3, [(120, 0.0, MBPS3)]) == [(pytest.approx(1 * MS), 120)]
    assert link.line_free == pytest.approx(0.2 * MS + 134 * BYTE)
    # the timer was reset at 1 ms: the next reply, ready at 1.5 ms, goes at 2 ms
    assert link.exchange(1.05 * MS, 14, MBPS3, [(120, 0.0, MBPS3)]) == [(pytest.approx(2 * MS), 120)]


def test_an_unconfigured_adapter_holds_each_read_for_most_of_16_ms():
    link = AdapterLink(AdapterTiming(latency_timer_s=16 * MS), t0=0.0)
    first = link.exchange(0.1 * MS, 14, MBPS3, [(120, 0.0, MBPS3)])
    # a host that asks again as soon as the reply is in waits a whole timer period again
    second = link.exchange(first[0][0], 14, MBPS3, [(120, 0.0, MBPS3)])
    assert [t for t, _ in first + second] == [pytest.approx(16 * MS), pytest.approx(32 * MS)]


def test_the_return_delay_time_pushes_the_end_of_the_reply_past_an_expiry():
    link = AdapterLink(AdapterTiming(latency_timer_s=1 * MS), t0=0.0)
    # Return Delay Time 250 (500 us): the reply starts at 0.2 + 0.0467 + 0.5 = 0.747 ms; the 76 bytes in
    # by 1 ms go then, the other 44 (in by 1.147 ms) at the next expiry, 2 ms
    assert link.exchange(0.2 * MS, 14, MBPS3, [(120, 500e-6, MBPS3)]) == [(pytest.approx(1 * MS), 76),
                                                                         (pytest.approx(2 * MS), 44)]


def test_sync_read_replies_follow_one_another_each_after_its_return_delay():
    arrived = reply_byte_times(1.0, [(2, 100e-6, 1_000_000), (3, 50e-6, 1_000_000)])
    b = 10e-6  # a byte at 1 Mbps
    first_end = 1.0 + 100e-6 + 2 * b
    second = first_end + 50e-6
    assert arrived == pytest.approx([1.0 + 100e-6 + b, first_end, second + b, second + 2 * b, second + 3 * b])


def test_a_full_usb_packet_goes_at_once_and_restarts_the_timer():
    link = AdapterLink(AdapterTiming(latency_timer_s=1 * MS, usb_packet_bytes=64), t0=0.0)
    quiet = 0.2 * MS + 14 * BYTE
    deliveries = link.exchange(0.2 * MS, 14, MBPS3, [(120, 0.0, MBPS3)])
    # 62 data bytes fill the 64-byte packet (2 status bytes) when the 62nd arrives; the timer restarts
    # then, and the other 58 bytes go one timer period later
    full = quiet + 62 * BYTE
    assert deliveries == [(pytest.approx(full), 62), (pytest.approx(full + 1 * MS), 58)]
    assert link.anchor == pytest.approx(full + 1 * MS)


def test_bytes_ready_on_an_expiry_go_with_it_and_later_ones_wait():
    link = AdapterLink(AdapterTiming(latency_timer_s=1 * MS), t0=0.0)
    assert link.deliveries([0.5 * MS, 1 * MS, 1.2 * MS]) == [(pytest.approx(1 * MS), 2),
                                                             (pytest.approx(2 * MS), 1)]


def test_an_instruction_waits_for_the_line():
    link = AdapterLink(AdapterTiming(), t0=0.0)
    link.line_free = 5 * MS  # the previous reply still on the line
    assert link.instruction_end(1 * MS, 30, MBPS3) == pytest.approx(5 * MS + 30 * BYTE)


def test_the_timing_refuses_meaningless_settings():
    with pytest.raises(ConfigError, match="latency_timer_s"):
        AdapterTiming(latency_timer_s=0)
    with pytest.raises(ConfigError, match="usb_packet_bytes"):
        AdapterTiming(usb_packet_bytes=2)


def test_status_packets_are_split_and_named_by_their_first_servo():
    fast = p.fast_status_packet([(0, 4, b"\x01\x02"), (0, 5, b"\x03\x04")])
    plain = p.status_packet(7, 0, b"\x05")
    assert status_packets(fast + plain) == [(len(fast), 4), (len(plain), 7)]
    # a Fast Sync Read cut short (a servo missing): the bytes there are count as one packet
    assert status_packets(fast[:12]) == [(12, 4)]
    assert status_packets(b"") == []


def test_the_pty_server_holds_replies_by_the_servos_own_settings(tmp_path):
    """The transport's schedule comes from the chain's control table: Return Delay Time and Baud Rate."""
    arm = default_arm()
    chain = SimulatedChain.for_arm(arm, SimplePlant.from_arm(arm), clock="wall", return_delay_time=250,
                                   fast=False)
    server = PtyServer(chain, tmp_path / "arm", adapter=AdapterTiming(latency_timer_s=1 * MS))
    server._adapter_link = AdapterLink(server.adapter, t0=0.0)
    reply = p.status_packet(2, 0, b"\x00" * 4) + p.status_packet(3, 0, b"\x00" * 4)
    server._schedule(0.1 * MS, 14, reply)
    # 14 bytes out, then each 15-byte reply 500 us after the line fell quiet: the first is in by 0.70 ms
    # and goes at the 1 ms expiry, the second is in by 1.25 ms and goes at 2 ms
    assert [(t, len(b)) for t, b in server._pending] == [(pytest.approx(1 * MS), 15),
                                                         (pytest.approx(2 * MS), 15)]
    assert b"".join(b for _, b in server._pending) == reply
