"""The simulated servo's firmware rules (docs/simulator-firmware.md), one test per rule, driven byte by byte
by the ROBOTIS dynamixel_sdk client (PacketHandler / PortHandler, no code shared with this project) through an
in-process dxlsim:// port."""

from __future__ import annotations

import numpy as np
import pytest
import serial
from dynamixel_sdk import (
    COMM_RX_TIMEOUT,
    COMM_SUCCESS,
    GroupSyncRead,
    GroupSyncWrite,
    PacketHandler,
    PortHandler,
)

from crane_io.dynamixel.control_table import MODE_CURRENT, MODE_EXTENDED_POSITION, MODE_POSITION
from crane_io.dynamixel.units import RAD_PER_PULSE
from crane_io.sim import protocol as p
from crane_io.sim import simulated_arm
from crane_io.sim.servo import REBOOT_SILENCE_S

DRIVE_MODE, MODE, HOMING, PWM_LIMIT, CURRENT_LIMIT, VELOCITY_LIMIT = 10, 11, 20, 36, 38, 44
MAX_POSITION, MIN_POSITION, TORQUE, SRL, REGISTERED, WATCHDOG = 48, 52, 64, 68, 69, 98
GOAL_PWM, GOAL_CURRENT, GOAL_VELOCITY, PROFILE_ACCELERATION, PROFILE_VELOCITY, GOAL_POSITION = (
    100, 102, 104, 108, 112, 116)
TICK, PRESENT_CURRENT, PRESENT_VELOCITY, PRESENT_POSITION = 120, 126, 128, 132
SID = 2  # an XM430-W350 of the default arm


class _UrlPort(PortHandler):
    """The SDK's PortHandler opening its port through serial_for_url (dxlsim://)."""

    def setupPort(self, cflag_baud):  # noqa: N802 (SDK name)
        if self.is_open:
            self.closePort()
        self.ser = serial.serial_for_url(self.port_name, baudrate=self.baudrate, timeout=0)
        self.is_open = True
        self.ser.reset_input_buffer()
        self.tx_time_per_byte = (1000.0 / self.baudrate) * 10.0
        return True


class Rig:
    def __init__(self):
        self.arm = simulated_arm(return_delay_time=0)
        self.chain, self.ph = self.arm.chain, PacketHandler(2.0)
        self.port = _UrlPort(self.arm.url)
        assert self.port.setBaudRate(3_000_000)

    def w(self, address, value, size, sid=SID):
        """(result, error number without the alert bit) of a Write."""
        fn = {1: self.ph.write1ByteTxRx, 2: self.ph.write2ByteTxRx, 4: self.ph.write4ByteTxRx}[size]
        result, error = fn(self.port, sid, address, value & ((1 << 8 * size) - 1))
        return result, error & 0x7F

    def r(self, address, size, sid=SID):
        fn = {1: self.ph.read1ByteTxRx, 2: self.ph.read2ByteTxRx, 4: self.ph.read4ByteTxRx}[size]
        value, result, _error = fn(self.port, sid, address)
        assert result == COMM_SUCCESS
        return value - (1 << 8 * size) if value >= 1 << (8 * size - 1) else value

    def raw(self, packet: bytes):
        """Send raw bytes; (the status packet's error byte or None when nothing came back)."""
        self.port.clearPort()
        self.port.writePort(packet)
        reply = self.port.readPort(64)
        return None if not reply else reply[8]


@pytest.fixture
def rig():
    rig = Rig()
    yield rig
    rig.port.closePort()
    rig.arm.close()


OK = (COMM_SUCCESS, p.ERR_NONE)
LIMIT = (COMM_SUCCESS, p.ERR_DATA_LIMIT)
RANGE = (COMM_SUCCESS, p.ERR_DATA_RANGE)
ACCESS = (COMM_SUCCESS, p.ERR_ACCESS)


def _rad_to_raw(rad):
    return round(rad / RAD_PER_PULSE) + 2048


# ---- Homing Offset (20) and Drive Mode (10) -----------------------------------------------------------

def test_homing_offset_shifts_present_position_and_the_goal_frame(rig):
    actual = rig.r(PRESENT_POSITION, 4)
    assert rig.w(MODE, MODE_EXTENDED_POSITION, 1) == OK
    assert rig.w(HOMING, 1000, 4) == OK
    rig.chain.advance(0.002)
    assert rig.r(PRESENT_POSITION, 4) == actual + 1000  # Present Position = actual + Homing Offset
    assert rig.w(TORQUE, 1, 1) == OK  # holds where it is: Goal Position := Present Position
    assert rig.r(GOAL_POSITION, 4) == actual + 1000
    assert rig.w(GOAL_POSITION, actual + 1000 + 100, 4) == OK
    goal_rad = rig.chain.actuator_command().goal_position[0]
    assert _rad_to_raw(goal_rad) == actual + 100  # the plant is driven to the goal minus the offset
    assert rig.w(TORQUE, 0, 1) == OK
    assert rig.w(HOMING, 1_044_480, 4) == RANGE


def test_homing_offset_beyond_1024_is_ignored_in_position_mode(rig):
    actual = rig.r(PRESENT_POSITION, 4)
    assert rig.r(MODE, 1) == MODE_POSITION
    assert rig.w(HOMING, 1025, 4) == OK
    rig.chain.advance(0.002)
    assert rig.r(PRESENT_POSITION, 4) == actual
    assert rig.w(HOMING, -1024, 4) == OK
    rig.chain.advance(0.002)
    assert rig.r(PRESENT_POSITION, 4) == actual - 1024


def test_drive_mode_reverse_bit_inverts_present_and_goal_items(rig):
    plant = rig.chain.plant
    plant.q[0], plant.dq[0] = 0.3, 0.5
    rig.chain.advance(0.002)
    pos, vel = rig.r(PRESENT_POSITION, 4), rig.r(PRESENT_VELOCITY, 4)
    assert pos > 2048 and vel > 0
    assert rig.w(DRIVE_MODE, 1, 1) == OK
    assert rig.w(HOMING, 10, 4) == OK  # the offset's sign is not reversed with the direction
    plant.q[0], plant.dq[0] = 0.3, 0.5
    rig.chain.advance(0.002)
    rev_pos, rev_vel = rig.r(PRESENT_POSITION, 4), rig.r(PRESENT_VELOCITY, 4)
    assert rev_pos - 10 - 2048 == pytest.approx(-(pos - 2048), abs=3)
    assert rev_vel == pytest.approx(-vel, abs=3)
    assert rig.w(MODE, MODE_CURRENT, 1) == OK
    assert rig.w(TORQUE, 1, 1) == OK
    assert rig.w(GOAL_CURRENT, 100, 2) == OK
    assert rig.chain.actuator_command().goal_current[0] < 0  # a positive goal drives the other way
    rig.chain.advance(0.01)
    assert rig.r(PRESENT_CURRENT, 2) > 0  # ... and reads back positive


# ---- goals beyond their limit items --------------------------------------------------------------------

def test_goal_current_beyond_current_limit_is_refused_with_data_limit_error(rig):
    assert rig.w(MODE, MODE_CURRENT, 1) == OK
    limit = rig.r(CURRENT_LIMIT, 2)
    assert rig.w(GOAL_CURRENT, 50, 2) == OK
    assert rig.w(GOAL_CURRENT, limit + 1, 2) == LIMIT
    assert rig.w(GOAL_CURRENT, -limit - 1, 2) == LIMIT
    assert rig.r(GOAL_CURRENT, 2) == 50  # the old goal stays
    assert rig.w(GOAL_CURRENT, -limit, 2) == OK
    # a Sync Write has no status packet: an out-of-limit goal silently leaves the old one
    write = GroupSyncWrite(rig.port, rig.ph, GOAL_CURRENT, 2)
    write.addParam(SID, list((limit + 5).to_bytes(2, "little")))
    assert write.txPacket() == COMM_SUCCESS
    assert rig.r(GOAL_CURRENT, 2) == -limit
    write.changeParam(SID, [20, 0])
    assert write.txPacket() == COMM_SUCCESS
    assert rig.r(GOAL_CURRENT, 2) == 20


def test_goal_position_outside_the_position_limits_is_refused_in_position_mode(rig):
    assert rig.w(MAX_POSITION, 3000, 4) == OK
    assert rig.w(MIN_POSITION, 1000, 4) == OK
    assert rig.w(GOAL_POSITION, 3001, 4) == LIMIT
    assert rig.w(GOAL_POSITION, 999, 4) == LIMIT
    assert rig.w(GOAL_POSITION, 2900, 4) == OK
    write = GroupSyncWrite(rig.port, rig.ph, GOAL_POSITION, 4)
    write.addParam(SID, list((3500).to_bytes(4, "little")))
    assert write.txPacket() == COMM_SUCCESS
    assert rig.r(GOAL_POSITION, 4) == 2900


def test_goal_position_range_of_the_extended_position_modes(rig):
    assert rig.w(MODE, MODE_EXTENDED_POSITION, 1) == OK
    assert rig.w(GOAL_POSITION, 1_048_575, 4) == OK  # the position limits are not used
    assert rig.w(GOAL_POSITION, 1_048_576, 4) == RANGE
    assert rig.w(GOAL_POSITION, -1_048_576, 4) == RANGE


def test_goal_velocity_pwm_and_profile_limits(rig):
    velocity_limit, pwm_limit = rig.r(VELOCITY_LIMIT, 4), rig.r(PWM_LIMIT, 2)
    assert rig.w(GOAL_VELOCITY, velocity_limit, 4) == OK
    assert rig.w(GOAL_VELOCITY, -velocity_limit - 1, 4) == LIMIT
    assert rig.w(GOAL_PWM, pwm_limit + 1, 2) == LIMIT
    assert rig.w(PROFILE_VELOCITY, velocity_limit + 1, 4) == LIMIT
    assert rig.w(PROFILE_VELOCITY, velocity_limit, 4) == OK
    assert rig.w(PROFILE_ACCELERATION, 32768, 4) == RANGE
    assert rig.w(DRIVE_MODE, 0x04, 1) == OK  # time-based profile: a time in ms, no velocity limit
    assert rig.w(PROFILE_VELOCITY, velocity_limit + 1, 4) == OK
    assert rig.w(PROFILE_VELOCITY, 32768, 4) == RANGE


# ---- Bus Watchdog (98) ---------------------------------------------------------------------------------

def test_goal_write_after_a_bus_watchdog_error_gets_data_range_error(rig):
    assert rig.w(MODE, MODE_CURRENT, 1) == OK
    assert rig.w(WATCHDOG, 5, 1) == OK  # 100 ms
    assert rig.w(TORQUE, 1, 1) == OK
    rig.chain.advance(0.15)
    assert rig.r(WATCHDOG, 1) == -1
    assert rig.w(GOAL_CURRENT, 0, 2) == RANGE
    assert rig.w(PROFILE_ACCELERATION, 10, 4) == OK  # not a goal item
    assert rig.w(WATCHDOG, 0, 1) == OK  # clears the error
    assert rig.w(GOAL_CURRENT, 0, 2) == OK


# ---- Reboot (0x08), Status Return Level (68), CRC Error --------------------------------------------------

def test_reboot_answers_then_the_servo_is_silent_while_it_restarts(rig):
    assert rig.w(TORQUE, 1, 1) == OK
    assert rig.w(SRL, 1, 1) == (COMM_SUCCESS, 0)
    assert rig.w(MAX_POSITION, 3000, 4)[0] == COMM_RX_TIMEOUT  # level 1: a write gets no reply...
    assert rig.w(TORQUE, 0, 1)[0] == COMM_RX_TIMEOUT
    assert rig.r(SRL, 1) == 1  # ... a read does
    assert rig.w(SRL, 2, 1)[0] == COMM_RX_TIMEOUT
    assert rig.w(TORQUE, 1, 1) == OK
    assert rig.ph.reboot(rig.port, SID) == (COMM_SUCCESS, 0)  # the status packet comes first
    assert rig.ph.ping(rig.port, SID)[1] == COMM_RX_TIMEOUT  # then silence while it restarts
    assert rig.ph.ping(rig.port, SID + 1)[1] == COMM_SUCCESS  # the others still answer
    rig.chain.advance(REBOOT_SILENCE_S - 0.01)
    assert rig.ph.ping(rig.port, SID)[1] == COMM_RX_TIMEOUT
    rig.chain.advance(0.02)
    assert rig.ph.ping(rig.port, SID)[1] == COMM_SUCCESS
    assert rig.r(TORQUE, 1) == 0  # back with the RAM defaults
    assert rig.r(MAX_POSITION, 4) == 4095  # the EEPROM kept (the write above was made)
    assert rig.r(SRL, 1) == 2


def test_status_return_level_0_answers_ping_only(rig):
    assert rig.w(SRL, 0, 1) == OK
    assert rig.ph.ping(rig.port, SID)[1] == COMM_SUCCESS
    assert rig.ph.read1ByteTxRx(rig.port, SID, SRL)[1] == COMM_RX_TIMEOUT
    assert rig.ph.write1ByteTxRx(rig.port, SID, 65, 1)[0] == COMM_RX_TIMEOUT
    assert rig.chain.servos[SID].read_register("led") == 1  # carried out all the same
    group = GroupSyncRead(rig.port, rig.ph, PRESENT_CURRENT, 10)
    group.addParam(SID + 1)
    assert group.fastSyncRead() == COMM_SUCCESS
    group.addParam(SID)
    assert group.fastSyncRead() != COMM_SUCCESS  # the combined reply breaks at the silent servo
    assert group.txRxPacket() != COMM_SUCCESS  # a Sync Read gets no reply from it either


def test_an_instruction_with_a_wrong_crc_gets_crc_error_and_is_not_carried_out(rig):
    packet = bytearray(p.instruction_packet(SID, p.INST_WRITE, bytes((65, 0, 1))))  # LED on
    packet[-1] ^= 0x5A
    assert rig.raw(bytes(packet)) == p.ERR_CRC
    assert rig.chain.servos[SID].read_register("led") == 0
    broadcast = bytearray(p.instruction_packet(p.BROADCAST_ID, p.INST_WRITE, bytes((65, 0, 1))))
    broadcast[-1] ^= 0x5A
    assert rig.raw(bytes(broadcast)) is None
    assert rig.chain.stats.crc_errors == 2


# ---- Realtime Tick, EEPROM lock, Reg Write / Action, Factory Reset ------------------------------------

def test_realtime_tick_counts_milliseconds_and_wraps_after_32767(rig):
    before = rig.r(TICK, 2)
    rig.chain.advance(0.1)
    assert rig.r(TICK, 2) == before + 100
    rig.chain.time = 32.7
    rig.chain.advance(0.02)
    assert rig.r(TICK, 2) == 32720
    rig.chain.advance(0.1)
    assert rig.r(TICK, 2) == 52  # 32.82 s: past 32767 back to 0


def test_eeprom_is_locked_with_access_error_while_torque_is_on(rig):
    assert rig.w(TORQUE, 1, 1) == OK
    for address, size in ((DRIVE_MODE, 1), (HOMING, 4), (CURRENT_LIMIT, 2), (MAX_POSITION, 4)):
        assert rig.w(address, 0, size) == ACCESS
    assert rig.r(CURRENT_LIMIT, 2) == 1193


def test_reg_write_waits_for_action_and_action_alone_is_an_instruction_error(rig):
    goal = rig.r(GOAL_POSITION, 4)
    assert rig.ph.regWriteTxRx(rig.port, SID, GOAL_POSITION, 4, list((goal + 50).to_bytes(4, "little"))) \
        == (COMM_SUCCESS, 0)
    assert rig.r(REGISTERED, 1) == 1 and rig.r(GOAL_POSITION, 4) == goal
    assert rig.ph.action(rig.port, SID) == COMM_SUCCESS
    assert rig.r(REGISTERED, 1) == 0 and rig.r(GOAL_POSITION, 4) == goal + 50
    rig.port.clearPort()
    assert rig.raw(p.instruction_packet(SID, p.INST_ACTION)) == p.ERR_INSTRUCTION
    # a Reg Write the servo would refuse is refused when it arrives
    assert rig.ph.regWriteTxRx(rig.port, SID, GOAL_POSITION, 4, list((5000).to_bytes(4, "little")))[1] \
        == p.ERR_DATA_LIMIT


def test_factory_reset_with_an_unknown_option_is_a_data_range_error(rig):
    assert rig.ph.factoryReset(rig.port, SID, 0x03) == (COMM_SUCCESS, p.ERR_DATA_RANGE)
    assert rig.ph.ping(rig.port, SID)[1] == COMM_SUCCESS  # nothing reset, no restart
    assert rig.ph.factoryReset(rig.port, SID, 0x02) == (COMM_SUCCESS, 0)
    assert rig.ph.ping(rig.port, SID)[1] == COMM_RX_TIMEOUT  # restarting, as after a Reboot
    rig.chain.advance(REBOOT_SILENCE_S + 0.01)
    assert rig.ph.ping(rig.port, SID)[1] == COMM_SUCCESS  # ID and baud rate kept


# ---- the toolkit's bus sends no goal the firmware would refuse --------------------------------------------

def test_the_bus_clamps_goals_to_the_limits_the_servos_refuse_beyond():
    from crane_io.dynamixel.bus import DynamixelBus

    arm = simulated_arm()
    try:
        held = arm.chain.servos[4]  # joint3, held in Position mode
        held.write_register("max_position_limit", 2100)  # narrower than the joint limit
        with DynamixelBus(arm.url) as bus:
            bus.ping_all()
            bus.configure(watchdog_s=None, current_limits={"joint1": 0.5})
            bus.torque_on()
            j = bus.joint_names.index("joint3")
            assert bus.upper[j] == pytest.approx((2100 - 2048) * RAD_PER_PULSE)
            bus.write_goal_position(np.full(8, 3.0))
            assert held.read_register("goal_position") == 2100  # clamped by the host, not refused
            bus.write_goal_current(np.full(8, 100.0))
            limit = arm.chain.servos[2].read_register("current_limit")
            assert arm.chain.servos[2].read_register("goal_current") == limit  # joint1 at its limit
    finally:
        arm.close()


# ---- Secondary ID (12), value ranges ---------------------------------------------------------------------

def test_secondary_id_groups_servos_without_status_packets(rig):
    for sid in (SID, SID + 1):
        assert rig.w(12, 100, 1, sid=sid) == OK
    assert rig.raw(p.instruction_packet(100, p.INST_WRITE, bytes((65, 0, 1)))) is None  # LED on, no reply
    assert [rig.chain.servos[s].read_register("led") for s in (SID, SID + 1, SID + 2)] == [1, 1, 0]
    assert rig.raw(p.instruction_packet(100, p.INST_WRITE, bytes((9, 0, 7)))) is None  # EEPROM: refused
    assert rig.r(9, 1) == 0  # Return Delay Time kept
    # the ID comes first: the servo whose ID it is answers, the group member carries it out silently
    assert rig.w(12, SID + 1, 1) == OK
    assert rig.w(65, 0, 1, sid=SID + 1) == OK
    assert [rig.chain.servos[s].read_register("led") for s in (SID, SID + 1)] == [0, 0]
    assert rig.w(12, 253, 1) == OK  # 253..255: off
    assert rig.raw(p.instruction_packet(253, p.INST_WRITE, bytes((65, 0, 1)))) is None
    assert rig.chain.servos[SID].read_register("led") == 0


def test_value_ranges_of_limit_items(rig):
    for address, size, bad in ((32, 2, 161), (34, 2, 94), (40, 4, 32768), (VELOCITY_LIMIT, 4, 1024),
                               (65, 1, 2)):
        assert rig.w(address, bad, size) == RANGE, address


# ---- Indirect Address / Indirect Data (168.., 224.., 578.., 634..) ---------------------------------------

IND_ADDRESS, IND_DATA, IND_ADDRESS_29, IND_DATA_29, LED = 168, 224, 578, 634, 65


def test_indirect_data_reads_and_writes_the_item_its_indirect_address_names(rig):
    assert rig.r(IND_ADDRESS, 2) == IND_DATA and rig.r(IND_ADDRESS_29, 2) == IND_DATA_29  # defaults: itself
    assert rig.w(IND_DATA + 27, 7, 1) == OK and rig.r(IND_DATA + 27, 1) == 7  # unmapped: a plain byte
    for k in range(4):  # Indirect Data 1..4 stand for Goal Position, 5 for the LED, 6..9 for Present Position
        assert rig.w(IND_ADDRESS + 2 * k, GOAL_POSITION + k, 2) == OK
        assert rig.w(IND_ADDRESS + 2 * (5 + k), PRESENT_POSITION + k, 2) == OK
    assert rig.w(IND_ADDRESS + 8, LED, 2) == OK
    assert rig.w(IND_DATA, 2100, 4) == OK
    assert rig.r(GOAL_POSITION, 4) == 2100 and rig.r(IND_DATA, 4) == 2100
    assert rig.w(IND_DATA + 4, 1, 1) == OK and rig.r(LED, 1) == 1
    assert rig.w(IND_DATA + 4, 2, 1) == RANGE  # the LED's range
    assert rig.w(IND_DATA, 5000, 4) == LIMIT  # Goal Position's limits (Position mode)
    assert rig.w(IND_DATA, 7, 1) == (COMM_SUCCESS, p.ERR_DATA_LENGTH)  # a part of Goal Position
    assert rig.r(GOAL_POSITION, 4) == 2100  # none of them written
    assert rig.r(IND_DATA + 5, 4) == rig.r(PRESENT_POSITION, 4)
    assert rig.w(IND_DATA + 5, 0, 4) == ACCESS  # Present Position is read-only
    # the EEPROM area cannot be mapped; the address range ends at 661
    assert rig.w(IND_ADDRESS, MAX_POSITION, 2) == RANGE and rig.w(IND_ADDRESS, 662, 2) == RANGE
    # the second set, read in one Fast Sync Read with the first
    assert rig.w(IND_ADDRESS_29, LED, 2) == OK
    assert rig.w(IND_DATA_29, 0, 1) == OK and rig.r(LED, 1) == 0
    group = GroupSyncRead(rig.port, rig.ph, IND_DATA, 9)
    group.addParam(SID)
    assert group.fastSyncRead() == COMM_SUCCESS
    assert group.getData(SID, IND_DATA, 4) == 2100
    assert group.getData(SID, IND_DATA + 4, 1) == 0


def test_a_sync_write_of_goal_position_through_indirect_data_is_the_lockstep_tick(rig):
    for k in range(4):
        assert rig.w(IND_ADDRESS + 2 * k, GOAL_POSITION + k, 2) == OK
    steps = rig.chain.stats.plant_steps
    group = GroupSyncWrite(rig.port, rig.ph, IND_DATA, 4)
    group.addParam(SID, list((2060).to_bytes(4, "little")))
    assert group.txPacket() == COMM_SUCCESS
    assert rig.r(GOAL_POSITION, 4) == 2060
    assert rig.chain.stats.plant_steps == steps + 1
    # Reg Write checks and holds it as Write would; Action carries it out
    assert rig.ph.regWriteTxRx(rig.port, SID, IND_DATA, 4, list((9000).to_bytes(4, "little")))[1] \
        == p.ERR_DATA_LIMIT
    assert rig.ph.regWriteTxRx(rig.port, SID, IND_DATA, 4, list((2070).to_bytes(4, "little"))) == OK
    assert rig.r(GOAL_POSITION, 4) == 2060
    assert rig.ph.action(rig.port, SID) == COMM_SUCCESS
    assert rig.r(GOAL_POSITION, 4) == 2070


def test_indirect_addresses_are_ram_and_return_to_their_defaults_at_reboot(rig):
    assert rig.w(IND_ADDRESS, LED, 2) == OK
    assert rig.w(IND_DATA, 1, 1) == OK
    assert rig.ph.reboot(rig.port, SID) == (COMM_SUCCESS, 0)
    rig.chain.advance(REBOOT_SILENCE_S + 0.01)
    assert rig.r(IND_ADDRESS, 2) == IND_DATA
    assert rig.r(IND_DATA, 1) == 0 and rig.r(LED, 1) == 0


def test_realtime_tick_counts_from_0_after_a_reboot(rig):
    rig.chain.advance(2.0)
    assert rig.ph.reboot(rig.port, SID) == (COMM_SUCCESS, 0)
    rig.chain.advance(REBOOT_SILENCE_S + 0.1)
    tick, other = rig.r(TICK, 2), rig.r(TICK, 2, sid=SID + 1)
    assert abs(tick - 100) <= 2  # 0.1 s after the restart
    assert abs(other - (tick + 2500)) <= 2  # a servo that did not restart goes on counting
    for _ in range(3):  # the lockstep cycle's compiled path counts it the same way
        group = GroupSyncWrite(rig.port, rig.ph, GOAL_CURRENT, 2)
        group.addParam(SID + 1, [0, 0])
        assert group.txPacket() == COMM_SUCCESS
    assert rig.r(TICK, 2) == tick + 3 * round(rig.chain.period_s * 1000)


# ---- Moving (122), Shutdown (63) -------------------------------------------------------------------------

def test_moving_is_set_while_present_velocity_exceeds_moving_threshold(rig):
    assert rig.r(24, 4) == 10  # Moving Threshold's default
    assert rig.r(PRESENT_VELOCITY, 4) == 0 and rig.r(122, 1) == 0
    assert rig.w(MODE, MODE_CURRENT, 1) == OK
    assert rig.w(TORQUE, 1, 1) == OK
    assert rig.w(GOAL_CURRENT, 150, 2) == OK
    rig.chain.advance(0.3)
    assert abs(rig.r(PRESENT_VELOCITY, 4)) > 10 and rig.r(122, 1) == 1


def test_only_the_errors_in_the_shutdown_mask_turn_torque_off(rig):
    servo = rig.chain.servos[SID]
    assert rig.w(63, 0x04, 1) == OK  # overheating only
    assert rig.w(TORQUE, 1, 1) == OK
    servo.raise_hardware_error(0x20)  # overload: not in the mask
    assert rig.r(TORQUE, 1) == 1
    servo.raise_hardware_error(0x04)
    assert rig.r(TORQUE, 1) == 0
    assert rig.ph.write1ByteTxRx(rig.port, SID, TORQUE, 1)[1] & p.ERR_ALERT  # refused until Reboot
    assert rig.r(TORQUE, 1) == 0
