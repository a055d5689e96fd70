"""The real dynamixel-sdk client against the simulated servo chain, over a real pseudo-terminal and
in-process through dxlsim://, plus the control-table semantics a bus layer relies on."""

from __future__ import annotations

import time

import numpy as np
import pytest
import serial
from dynamixel_sdk import (
    COMM_RX_CORRUPT,
    COMM_RX_TIMEOUT,
    COMM_SUCCESS,
    GroupBulkRead,
    GroupBulkWrite,
    GroupSyncRead,
    GroupSyncWrite,
    PacketHandler,
    PortHandler,
)

from crane_io.dynamixel.control_table import MODE_CURRENT, MODE_POSITION
from crane_io.dynamixel.units import position_to_rad
from crane_io.sim import protocol as p
from crane_io.sim import simulated_arm
from crane_io.sim.servo import REBOOT_SILENCE_S
from crane_io.sim.transport import PtyServer

IDS = list(range(2, 10))
TORQUE, MODE, GOAL_CURRENT, GOAL_POSITION = 64, 11, 102, 116
ADDR_RDT, ADDR_WATCHDOG, ADDR_HW_ERROR = 9, 98, 70
PRESENT, PRESENT_POSITION = 126, 132
# Over a pty the server thread may wait for the CPU on a busy machine: tests wait for replies this long
# (the SDK's own timeout is ~34 ms). In-process (dxlsim://) replies are there before the SDK starts timing.
PTY_PATIENCE_S = 5.0


def wait_for(condition, timeout_s: float = 30.0, what: str = "condition") -> None:
    """Wait until `condition()` holds (never a fixed sleep that a busy machine could outlast)."""
    deadline = time.monotonic() + timeout_s
    while not condition():
        assert time.monotonic() < deadline, f"timed out after {timeout_s} s waiting for {what}"
        time.sleep(0.002)


class UrlPortHandler(PortHandler):
    """The SDK's PortHandler, opening its port through serial_for_url (so dxlsim:// works too).
    `patience_s`: the reply timeout instead of the SDK's (None: the SDK's)."""

    patience_s: float | None = None

    def setPacketTimeout(self, packet_length):  # noqa: N802 (SDK name)
        if self.patience_s is None:
            return super().setPacketTimeout(packet_length)
        return self.setPacketTimeoutMillis(self.patience_s * 1000.0)

    def setupPort(self, cflag_baud):
        if self.is_open:
            self.closePort()
        self.ser = serial.serial_for_url(self.port_name, baudrate=self.baudrate, timeout=0)
        self.is_open = True
        self.ser.reset_input_buffer()
        self.tx_time_per_byte = (1000.0 / self.baudrate) * 10.0
        return True


class Rig:
    def __init__(self, arm, port):
        self.arm, self.chain, self.port, self.ph = arm, arm.chain, port, PacketHandler(2.0)

    def s32(self, v):
        return v - (1 << 32) if v >= 1 << 31 else v

    def s16(self, v):
        return v - (1 << 16) if v >= 1 << 15 else v


def _open(kind, tmp_path, **arm_kwargs):
    arm = simulated_arm(**arm_kwargs)
    server = None
    if kind == "pty":
        server = PtyServer(arm.chain, tmp_path / "crane").start()
        port = UrlPortHandler(str(tmp_path / "crane"))
        port.patience_s = PTY_PATIENCE_S
    else:
        port = UrlPortHandler(arm.url)
    assert port.setBaudRate(3_000_000)
    return arm, server, port


def _close(arm, server, port):
    port.closePort()
    if server is not None:
        server.stop()
        assert server.error is None
    arm.close()


@pytest.fixture(params=["pty", "dxlsim"])
def rig(request, tmp_path):
    arm, server, port = _open(request.param, tmp_path, return_delay_time=0)
    yield Rig(arm, port)
    _close(arm, server, port)


@pytest.fixture
def sim(tmp_path):
    """In-process only: for semantics tests that do not depend on the transport."""
    arm, server, port = _open("dxlsim", tmp_path, return_delay_time=0)
    yield Rig(arm, port)
    _close(arm, server, port)


# ---- every instruction through the real client, over a pty and in-process -------------------------

def test_ping_reports_model_and_firmware(rig):
    assert rig.ph.ping(rig.port, 2) == (1020, COMM_SUCCESS, 0)
    assert rig.ph.ping(rig.port, 3) == (1120, COMM_SUCCESS, 0)  # joint 2 is the XM540-W270
    rig.port.patience_s = None  # silence is the answer expected next: the SDK's own short timeout
    assert rig.ph.ping(rig.port, 1)[1] == COMM_RX_TIMEOUT  # ID 1 is not on a CRANE-X7


def test_broadcast_ping_finds_every_servo(rig):
    found, result = rig.ph.broadcastPing(rig.port)
    assert result == COMM_SUCCESS
    assert sorted(found) == IDS
    assert found[3][0] == 1120 and found[2][0] == 1020


def test_read_and_write_1_2_4_bytes(rig):
    ph, port = rig.ph, rig.port
    assert ph.read1ByteTxRx(port, 5, 7) == (5, COMM_SUCCESS, 0)  # ID register
    assert ph.read2ByteTxRx(port, 3, 0) == (1120, COMM_SUCCESS, 0)  # model number
    assert ph.read4ByteTxRx(port, 4, PRESENT_POSITION) == (2048, COMM_SUCCESS, 0)
    assert ph.write1ByteTxRx(port, 4, ADDR_RDT, 7) == (COMM_SUCCESS, 0)
    assert ph.read1ByteTxRx(port, 4, ADDR_RDT)[0] == 7
    assert ph.write1ByteTxRx(port, 4, MODE, MODE_CURRENT) == (COMM_SUCCESS, 0)
    assert ph.write2ByteTxRx(port, 4, GOAL_CURRENT, (-100) & 0xFFFF) == (COMM_SUCCESS, 0)
    assert rig.s16(ph.read2ByteTxRx(port, 4, GOAL_CURRENT)[0]) == -100
    assert ph.write4ByteTxRx(port, 4, GOAL_POSITION, 1000) == (COMM_SUCCESS, 0)
    assert ph.read4ByteTxRx(port, 4, GOAL_POSITION)[0] == 1000
    assert rig.chain.servos[4].read_register("goal_current") == -100


def test_reg_write_waits_for_action(rig):
    ph, port = rig.ph, rig.port
    assert ph.regWriteTxRx(port, 6, GOAL_POSITION, 4, [0x00, 0x09, 0, 0]) == (COMM_SUCCESS, 0)
    assert ph.read1ByteTxRx(port, 6, 69)[0] == 1  # Registered Instruction
    assert ph.read4ByteTxRx(port, 6, GOAL_POSITION)[0] == 2048
    assert ph.action(port, 6) == COMM_SUCCESS
    # the SDK does not read the Action reply: wait until it has arrived, then drop it
    wait_for(lambda: port.getBytesAvailable() >= 11, what="the Action status packet")
    port.clearPort()
    assert ph.read4ByteTxRx(port, 6, GOAL_POSITION)[0] == 0x900
    assert ph.read1ByteTxRx(port, 6, 69)[0] == 0
    # Action with nothing registered is an Instruction Error (the SDK does not read Action replies)
    reply = rig.chain.feed(p.instruction_packet(6, p.INST_ACTION))
    assert reply == p.status_packet(6, p.ERR_INSTRUCTION)


def test_sync_read_plain_and_fast(rig):
    ph, port = rig.ph, rig.port
    for sid in IDS:
        ph.write1ByteTxRx(port, sid, MODE, MODE_CURRENT)
    group = GroupSyncRead(port, ph, PRESENT, 10)
    for sid in IDS:
        assert group.addParam(sid)
    assert group.txRxPacket() == COMM_SUCCESS
    assert [group.getData(s, PRESENT_POSITION, 4) for s in IDS] == [2048] * 8
    assert group.fastSyncRead() == COMM_SUCCESS
    assert [group.getData(s, PRESENT_POSITION, 4) for s in IDS] == [2048] * 8
    assert [group.getData(s, PRESENT, 2) for s in IDS] == [0] * 8


def test_sync_write_goal_current_drives_the_plant(rig):
    ph, port = rig.ph, rig.port
    for sid in IDS:
        ph.write1ByteTxRx(port, sid, MODE, MODE_CURRENT)
        ph.write1ByteTxRx(port, sid, TORQUE, 1)
    write = GroupSyncWrite(port, ph, GOAL_CURRENT, 2)
    for sid in IDS:
        write.addParam(sid, list((150 if sid == 2 else 0).to_bytes(2, "little")))
    read = GroupSyncRead(port, ph, PRESENT, 10)
    for sid in IDS:
        read.addParam(sid)
    t0 = rig.chain.time
    for _ in range(50):
        assert write.txPacket() == COMM_SUCCESS
        assert read.fastSyncRead() == COMM_SUCCESS
    assert rig.chain.time == pytest.approx(t0 + 50 * 0.002)
    assert rig.s32(read.getData(2, PRESENT_POSITION, 4)) > 2048 + 5  # joint 1 turned
    assert rig.s32(read.getData(4, PRESENT_POSITION, 4)) == 2048  # joint 3 had no current
    assert rig.s16(read.getData(2, PRESENT, 2)) == 150  # the motor draws what was commanded


def test_bulk_read_and_bulk_write(rig):
    ph, port = rig.ph, rig.port
    bw = GroupBulkWrite(port, ph)
    assert bw.addParam(2, ADDR_RDT, 1, [3])
    assert bw.addParam(3, 65, 1, [1])  # LED
    assert bw.txPacket() == COMM_SUCCESS
    br = GroupBulkRead(port, ph)
    br.addParam(2, ADDR_RDT, 1)
    br.addParam(3, 65, 1)
    br.addParam(4, PRESENT_POSITION, 4)
    assert br.txRxPacket() == COMM_SUCCESS
    assert br.getData(2, ADDR_RDT, 1) == 3
    assert br.getData(3, 65, 1) == 1
    assert br.getData(4, PRESENT_POSITION, 4) == 2048


def test_reboot_clears_a_hardware_error(rig):
    ph, port = rig.ph, rig.port
    ph.write1ByteTxRx(port, 7, TORQUE, 1)
    rig.chain.servos[7].set_hardware_error(0x20)  # overload
    value, result, error = ph.read1ByteTxRx(port, 7, ADDR_HW_ERROR)
    assert (value, result) == (0x20, COMM_SUCCESS) and error & p.ERR_ALERT
    assert ph.read1ByteTxRx(port, 7, TORQUE)[0] == 0  # the shutdown turned torque off
    assert ph.write1ByteTxRx(port, 7, TORQUE, 1)[1] & p.ERR_ALERT
    assert ph.read1ByteTxRx(port, 7, TORQUE)[0] == 0  # refused until reboot
    assert ph.reboot(port, 7) == (COMM_SUCCESS, p.ERR_ALERT)  # answered before rebooting
    rig.chain.advance(REBOOT_SILENCE_S)  # silent while it restarts
    assert ph.read1ByteTxRx(port, 7, ADDR_HW_ERROR) == (0, COMM_SUCCESS, 0)
    assert ph.write1ByteTxRx(port, 7, TORQUE, 1) == (COMM_SUCCESS, 0)


def test_factory_reset_keeps_id_and_baud_with_option_2(rig):
    ph, port = rig.ph, rig.port
    assert ph.read1ByteTxRx(port, 8, ADDR_RDT)[0] == 0
    assert ph.factoryReset(port, 8, 0x02) == (COMM_SUCCESS, 0)
    rig.chain.advance(REBOOT_SILENCE_S)  # silent while it restarts
    assert ph.read1ByteTxRx(port, 8, ADDR_RDT)[0] == 250  # back to the factory 500 us
    assert ph.read1ByteTxRx(port, 8, 8)[0] == 5  # still 3 Mbps


# ---- control-table semantics --------------------------------------------------------------------------

def test_factory_reset_variants(sim):
    ph, port, chain = sim.ph, sim.port, sim.chain
    # 0x01 keeps the ID but resets the baud rate to 57600: the servo falls silent at 3 Mbps
    assert ph.factoryReset(port, 9, 0x01) == (COMM_SUCCESS, 0)
    assert chain.servos[9].read_register("baud_rate") == 1
    assert ph.ping(port, 9)[1] == COMM_RX_TIMEOUT
    # 0xFF resets the ID to 1 as well
    assert ph.factoryReset(port, 6, 0xFF) == (COMM_SUCCESS, 0)
    assert 6 not in chain.servos and chain.servos[1].read_register("baud_rate") == 1
    # a broadcast "reset all" is not carried out
    ph.factoryReset(port, p.BROADCAST_ID, 0xFF)
    assert ph.ping(port, 2)[0] == 1020


def test_eeprom_is_locked_while_torque_is_on(sim):
    ph, port = sim.ph, sim.port
    assert ph.write1ByteTxRx(port, 2, TORQUE, 1) == (COMM_SUCCESS, 0)
    assert ph.write1ByteTxRx(port, 2, MODE, MODE_CURRENT) == (COMM_SUCCESS, p.ERR_ACCESS)
    assert ph.write2ByteTxRx(port, 2, 38, 500) == (COMM_SUCCESS, p.ERR_ACCESS)  # Current Limit
    assert ph.read1ByteTxRx(port, 2, MODE)[0] == MODE_POSITION
    ph.write1ByteTxRx(port, 2, TORQUE, 0)
    assert ph.write1ByteTxRx(port, 2, MODE, MODE_CURRENT) == (COMM_SUCCESS, 0)


def test_read_only_items_range_and_length_errors(sim):
    ph, port = sim.ph, sim.port
    assert ph.write4ByteTxRx(port, 2, PRESENT_POSITION, 5) == (COMM_SUCCESS, p.ERR_ACCESS)
    assert ph.write1ByteTxRx(port, 2, MODE, 2) == (COMM_SUCCESS, p.ERR_DATA_RANGE)  # no mode 2
    assert ph.write1ByteTxRx(port, 2, GOAL_POSITION, 5) == (COMM_SUCCESS, p.ERR_DATA_LENGTH)
    assert ph.read4ByteTxRx(port, 2, GOAL_POSITION)[0] == 2048  # nothing was written


def test_goal_current_beyond_current_limit_is_refused(sim):
    ph, port = sim.ph, sim.port
    ph.write1ByteTxRx(port, 2, MODE, MODE_CURRENT)
    assert ph.write2ByteTxRx(port, 2, GOAL_CURRENT, 5000) == (COMM_SUCCESS, p.ERR_DATA_LIMIT)
    assert ph.read2ByteTxRx(port, 2, GOAL_CURRENT)[0] == 1193  # the mode change set it to the limit
    assert ph.write2ByteTxRx(port, 2, GOAL_CURRENT, (-1193) & 0xFFFF) == (COMM_SUCCESS, 0)
    assert sim.s16(ph.read2ByteTxRx(port, 2, GOAL_CURRENT)[0]) == -1193
    ph.write2ByteTxRx(port, 2, 38, 300)  # lowering the limit clamps the goal
    assert sim.s16(ph.read2ByteTxRx(port, 2, GOAL_CURRENT)[0]) == -300
    assert sim.chain.servos[3].read_register("current_limit") == 2047  # XM540-W270 default


def test_operating_mode_change_side_effects(sim):
    ph, port = sim.ph, sim.port
    ph.write2ByteTxRx(port, 5, 84, 1500)  # Position P gain
    ph.write4ByteTxRx(port, 5, 112, 40)  # Profile Velocity
    ph.write2ByteTxRx(port, 5, 38, 800)  # Current Limit
    ph.write2ByteTxRx(port, 5, GOAL_CURRENT, 10)
    assert ph.write1ByteTxRx(port, 5, MODE, MODE_CURRENT) == (COMM_SUCCESS, 0)
    assert ph.read2ByteTxRx(port, 5, GOAL_CURRENT)[0] == 800  # := Current Limit
    assert ph.read2ByteTxRx(port, 5, 100)[0] == 885  # Goal PWM := PWM Limit
    assert ph.read4ByteTxRx(port, 5, 112)[0] == 0
    assert ph.read2ByteTxRx(port, 5, 84)[0] == 800  # gains back to defaults


def test_bus_watchdog_stops_a_silent_host(sim):
    ph, port, chain = sim.ph, sim.port, sim.chain
    ph.write1ByteTxRx(port, 2, MODE, MODE_CURRENT)
    ph.write1ByteTxRx(port, 2, ADDR_WATCHDOG, 5)  # 100 ms
    ph.write1ByteTxRx(port, 2, TORQUE, 1)
    write = GroupSyncWrite(port, ph, GOAL_CURRENT, 2)
    write.addParam(2, [50, 0])
    for _ in range(40):  # 80 ms of steady traffic: no expiry
        write.txPacket()
    assert ph.read1ByteTxRx(port, 2, ADDR_WATCHDOG)[0] == 5
    chain.advance(0.15)  # the host stalls for 150 ms
    assert ph.read1ByteTxRx(port, 2, ADDR_WATCHDOG)[0] == 0xFF  # reads -1
    assert ph.write2ByteTxRx(port, 2, GOAL_CURRENT, 0) == (COMM_SUCCESS, p.ERR_DATA_RANGE)
    assert not chain.actuator_command().torque_enabled[0]  # the plant sees the servo stopped
    chain.advance(1.0)
    assert chain.plant.dq[0] == 0.0  # no more drive: friction stopped the joint
    assert ph.write1ByteTxRx(port, 2, ADDR_WATCHDOG, 0) == (COMM_SUCCESS, 0)  # clears it
    assert ph.write2ByteTxRx(port, 2, GOAL_CURRENT, 0) == (COMM_SUCCESS, 0)


def test_position_mode_tracks_goal_position(sim):
    ph, port, chain = sim.ph, sim.port, sim.chain
    ph.write1ByteTxRx(port, 4, TORQUE, 1)
    ph.write4ByteTxRx(port, 4, GOAL_POSITION, 2048 + 300)
    chain.advance(1.0)
    q = position_to_rad(ph.read4ByteTxRx(port, 4, PRESENT_POSITION)[0])
    assert q == pytest.approx(float(position_to_rad(2348)), abs=0.02)


def _lockstep_run(seed):
    arm = simulated_arm(return_delay_time=0)
    port = UrlPortHandler(arm.url)
    port.setBaudRate(3_000_000)
    ph = PacketHandler(2.0)
    for sid in IDS:
        ph.write1ByteTxRx(port, sid, MODE, MODE_CURRENT)
        ph.write1ByteTxRx(port, sid, TORQUE, 1)
    rng = np.random.default_rng(seed)
    write = GroupSyncWrite(port, ph, GOAL_CURRENT, 2)
    read = GroupSyncRead(port, ph, PRESENT, 10)
    for sid in IDS:
        write.addParam(sid, [0, 0])
        read.addParam(sid)
    trace = []
    for _ in range(100):
        for sid in IDS:
            write.changeParam(sid, list(int(rng.integers(-200, 200)).to_bytes(2, "little", signed=True)))
        write.txPacket()
        read.fastSyncRead()
        trace.append([bytes(read.data_dict[s]) for s in IDS])
    port.closePort()
    arm.close()
    return trace


def test_lockstep_runs_are_deterministic():
    a, b = _lockstep_run(1), _lockstep_run(1)
    assert a == b
    assert a[-1] != a[0]  # and something actually moved


def test_set_clock_switches_a_running_chain_without_a_time_jump(sim):
    from crane_io.errors import ConfigError

    ph, port, chain = sim.ph, sim.port, sim.chain
    write = GroupSyncWrite(port, ph, GOAL_CURRENT, 2)
    write.addParam(2, [0, 0])
    time.sleep(0.05)  # wall time passes while in lockstep: it must not count later
    for _ in range(10):
        write.txPacket()
    assert chain.time == pytest.approx(0.02)  # ten lockstep periods of 2 ms
    before = time.monotonic()
    chain.set_clock("wall")
    chain.touch()
    since = time.monotonic() - before
    assert chain.clock == "wall" and chain.time >= 0.02
    assert chain.time - 0.02 <= since + 1e-6  # continues from 0.02: only the time since the switch counts
    time.sleep(0.05)
    while chain.touch() >= chain.max_substep_s:  # each touch steps for a bounded time: repeat
        pass
    assert chain.time >= 0.02 + 0.05 - 1e-6  # now it follows the wall clock
    chain.set_clock("lockstep")
    t = chain.time
    time.sleep(0.02)
    chain.touch()
    assert chain.time == t  # lockstep again: only goal writes advance time
    write.txPacket()
    assert chain.time == pytest.approx(t + 0.002)
    with pytest.raises(ConfigError, match="clock must be"):
        chain.set_clock("fast")


def test_fast_sync_read_can_be_unsupported(tmp_path):
    arm, server, port = _open("dxlsim", tmp_path, fast_sync_read=False)
    try:
        ph = PacketHandler(2.0)
        group = GroupSyncRead(port, ph, PRESENT, 10)
        for sid in IDS:
            group.addParam(sid)
        assert group.fastSyncRead() == COMM_RX_TIMEOUT
        assert arm.chain.stats.ignored_fast_sync_reads == 1
        assert group.txRxPacket() == COMM_SUCCESS  # the plain sync read still works
    finally:
        _close(arm, server, port)


def test_return_delay_is_honoured_on_the_wall_clock(tmp_path):
    arm, server, port = _open("pty", tmp_path, clock="wall")  # factory Return Delay Time 250 = 500 us
    try:
        ph = PacketHandler(2.0)
        group = GroupSyncRead(port, ph, PRESENT, 10)
        for sid in IDS:
            group.addParam(sid)
        assert group.txRxPacket() == COMM_SUCCESS
        start = time.perf_counter()
        assert group.txRxPacket() == COMM_SUCCESS
        assert time.perf_counter() - start >= 8 * 500e-6
        t0 = arm.chain.time
        time.sleep(0.05)
        assert ph.ping(port, 2)[1] == COMM_SUCCESS
        # the plant follows the wall clock (on a busy machine it catches up within its step budget per
        # packet or idle touch, so it may take a few more packets)
        give_up = time.monotonic() + 20.0
        while arm.chain.time - t0 < 0.05 and time.monotonic() < give_up:
            assert ph.ping(port, 2)[1] == COMM_SUCCESS
        assert arm.chain.time - t0 >= 0.05
    finally:
        _close(arm, server, port)


# ---- fault-injection hooks ---------------------------------------------------------------------------

def test_reply_filter_drop_corrupt_and_vanishing_servo(sim):
    ph, port, chain = sim.ph, sim.port, sim.chain
    chain.reply_filter = lambda chunk: None
    assert ph.ping(port, 2)[1] == COMM_RX_TIMEOUT
    assert chain.stats.replies_dropped == 1

    def flip_crc(chunk):
        return chunk[:-1] + bytes((chunk[-1] ^ 0xFF,))

    chain.reply_filter = flip_crc
    assert ph.ping(port, 2)[1] == COMM_RX_CORRUPT
    chain.reply_filter = None
    chain.remove_servo(5)
    assert ph.ping(port, 5)[1] == COMM_RX_TIMEOUT
    group = GroupSyncRead(port, ph, PRESENT, 10)
    for sid in IDS:
        group.addParam(sid)
    assert group.fastSyncRead() != COMM_SUCCESS  # the combined packet breaks at the missing servo
    assert group.txRxPacket() != COMM_SUCCESS
    chain.restore_servo(5)
    assert ph.ping(port, 5)[1] == COMM_SUCCESS
    assert chain.servos[5].read_register("torque_enable") == 0
    chain.servos[5].write_register("torque_enable", 1)
    assert ph.read1ByteTxRx(port, 5, TORQUE)[0] == 1
    assert chain.stats.packets_received > 0 and chain.stats.replies_sent > 0


def test_corrupted_instruction_is_counted_and_answered_with_crc_error(sim):
    bad = bytearray(p.instruction_packet(2, p.INST_PING))
    bad[-2] ^= 0x55
    assert sim.chain.feed(bytes(bad)) == p.status_packet(2, p.ERR_CRC)
    assert sim.chain.stats.crc_errors == 1
    assert sim.chain.feed(p.instruction_packet(2, p.INST_PING)) == p.status_packet(2, 0, bytes((0xFC, 3, 52)))


# ---- crane-collect sim-serve ---------------------------------------------------------------------------

def test_sim_serve_serves_a_pty_until_sigterm(tmp_path):
    import signal
    import subprocess
    import sys
    from pathlib import Path

    link = tmp_path / "crane_x7"
    exe = Path(sys.executable).parent / "crane-collect"
    proc = subprocess.Popen([str(exe), "sim-serve", "--link", str(link), "--plant", "simple"],
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    try:
        wait_for(lambda: link.is_symlink() or proc.poll() is not None, 120, "sim-serve to start")
        assert link.is_symlink(), proc.stderr.read() if proc.poll() is not None else "no link"
        port = UrlPortHandler(str(link))
        port.patience_s = PTY_PATIENCE_S
        assert port.openPort() and port.setBaudRate(3_000_000)
        assert PacketHandler(2.0).ping(port, 3) == (1120, COMM_SUCCESS, 0)
        port.closePort()
    finally:
        proc.send_signal(signal.SIGTERM)
        out, err = proc.communicate(timeout=120)
    assert proc.returncode == 0, err
    assert str(link) in out and "Stopped" in out
    assert "Simulated time never slipped" in out or "Simulated time slipped" in out  # the wall clock's
    assert not link.exists() and not link.is_symlink()


def test_sim_serve_serves_the_arm_plant_from_a_toml_file_to_the_bus(tmp_path):
    """`sim-serve --plant PATH.toml` end to end: the real SDK (through DynamixelBus) over the pty
    drives the pinocchio arm plant that the user's TOML file describes."""
    import signal
    import subprocess
    import sys
    from pathlib import Path

    from crane_io.dynamixel.bus import DynamixelBus

    plant = tmp_path / "my_arm.toml"
    plant.write_text('base = "crane-x7"\nname = "my-arm"\n[initial]\njoint2 = 0.3\njoint4 = -0.6\n')
    link = tmp_path / "crane_x7"
    exe = Path(sys.executable).parent / "crane-collect"
    truth = tmp_path / "truth.json"
    proc = subprocess.Popen([str(exe), "sim-serve", "--link", str(link), "--plant", str(plant),
                             "--clock", "lockstep", "--return-delay", "0", "--seed", "7",
                             "--truth", str(truth)],
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    try:
        wait_for(lambda: link.is_symlink() or proc.poll() is not None, 120, "sim-serve to start")
        assert link.is_symlink(), proc.stderr.read() if proc.poll() is not None else "no link"
        with DynamixelBus(str(link), latency_ms=PTY_PATIENCE_S * 100) as bus:  # reply timeouts ~1 s
            assert len(bus.ping_all()) == 8
            bus.configure(watchdog_s=0.5)
            bus.torque_on()
            first = bus.read_state()
            for _ in range(150):  # 0.3 s of lockstep time with zero current: gravity pulls
                state = bus.read_state()
                bus.write_goal_current(np.zeros(8))
        assert first.fast and first.position[1] == pytest.approx(0.3, abs=0.01)  # the file's pose
        assert first.position[3] == pytest.approx(-0.6, abs=0.01)
        assert state.position[3] < -0.7  # joint4 falls under gravity (the arm plant, not SimplePlant)
        assert state.position[2] == pytest.approx(0.0, abs=0.01)  # joint3 held by its position servo
    finally:
        proc.send_signal(signal.SIGTERM)
        out, err = proc.communicate(timeout=120)
    assert proc.returncode == 0, err
    assert "ArmPlant" in out and "lockstep" in out and "Stopped" in out
    assert "slipped" not in out  # lockstep time never slips
    import json

    written = json.loads(truth.read_text())  # asked for: the truth, with the seed it ran with
    assert written["plant"] == "my-arm" and written["seed"] == 7 and written["effects"]


def test_sim_serve_plant_names_pick_presets():
    from collect.sim_arms import make_plant
    from crane_io.description import default_arm
    from crane_io.errors import ConfigError
    from crane_io.sim.arm_plant import ArmPlant
    from crane_io.sim.simple_plant import SimplePlant

    arm = default_arm()
    assert isinstance(make_plant("simple", 0, arm), SimplePlant)
    assert make_plant(None, 0, arm).config.name == "crane-x7"
    for name in ("baseline", "hidden-coulomb", "hidden-payload"):
        plant = make_plant(name, 3, arm)
        assert isinstance(plant, ArmPlant) and plant.config.name == name and plant.seed == 3
    with pytest.raises(ConfigError):
        make_plant("hidden-nothing", 0, arm)


def test_sim_serve_reports_a_bad_link_in_one_sentence(tmp_path):
    from click.testing import CliRunner

    from collect.cli.sim_serve import sim_serve

    result = CliRunner().invoke(sim_serve, ["--link", str(tmp_path / "missing" / "x"), "--plant", "simple"])
    assert result.exit_code != 0
    assert result.output.startswith("Error: ") and "does not exist" in result.output
    assert "Traceback" not in result.output
    result = CliRunner().invoke(sim_serve, ["--link", str(tmp_path / "x"), "--plant", "no-such-plant"])
    assert result.exit_code != 0 and result.output.startswith("Error: ")
    result = CliRunner().invoke(sim_serve, ["--link", str(tmp_path / "x"), "--plant", "simple",
                                            "--truth", str(tmp_path / "t.json")])
    assert result.exit_code != 0 and "--truth needs an arm plant" in result.output
    result = CliRunner().invoke(sim_serve, ["--link", str(tmp_path / "x"), "--plant", "baseline",
                                            "--truth", str(tmp_path / "no" / "t.json")])
    assert result.output.startswith("Error: cannot write the truth file") and "Traceback" not in result.output


# ---- the simple plant ----------------------------------------------------------------------------------

def _command(n, mode=0, current=0.0, enabled=True, goal=0.0):
    from crane_io.sim.plant_api import ActuatorCommand

    return ActuatorCommand(
        torque_enabled=np.full(n, enabled), operating_mode=np.full(n, mode),
        goal_current=np.full(n, current), goal_position=np.full(n, goal),
        position_gains=np.tile([800.0, 0.0, 0.0], (n, 1)), current_limit=np.full(n, 3.21))


def test_simple_plant_sticks_below_coulomb_and_slides_above():
    from crane_io.sim.plant_api import Plant
    from crane_io.sim.simple_plant import SimplePlant

    plant = SimplePlant(servo_ids=(2,), inertia=0.01, viscous=0.0, coulomb=0.2, kt=2.0)
    assert isinstance(plant, Plant)
    plant.step(_command(1, current=0.09), 0.5)  # 0.18 N m < 0.2 N m
    assert plant.read().position[0] == 0.0 and plant.read().velocity[0] == 0.0
    plant.step(_command(1, current=0.15), 0.1)  # 0.3 N m: (0.3 - 0.2) / 0.01 = 10 rad/s^2
    assert plant.read().velocity[0] == pytest.approx(1.0, rel=1e-6)
    assert plant.read().current[0] == pytest.approx(0.15)
    plant.step(_command(1, enabled=False), 1.0)  # torque off: friction stops it, never reverses it
    assert plant.read().velocity[0] == 0.0 and plant.read().current[0] == 0.0
    plant.set_external_torque(np.array([-0.5]))
    plant.step(_command(1, enabled=False), 0.1)
    assert plant.read().velocity[0] < 0  # a hand pushing a limp joint moves it
    with pytest.raises(ValueError):
        plant.set_external_torque(np.zeros(3))
