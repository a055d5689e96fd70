"""The X-series control table as data: addresses the bus relies on, EEPROM flags, model numbers."""

import pytest

from crane_io.dynamixel import control_table as ct


@pytest.mark.parametrize("model", list(ct.MODELS.values()), ids=list(ct.MODELS))
def test_registers_the_bus_uses_are_where_the_emanual_puts_them(model):
    expect = {"model_number": (0, 2), "firmware_version": (6, 1), "return_delay_time": (9, 1),
              "drive_mode": (10, 1), "operating_mode": (11, 1), "current_limit": (38, 2),
              "torque_enable": (64, 1), "hardware_error_status": (70, 1), "bus_watchdog": (98, 1),
              "goal_current": (102, 2), "goal_position": (116, 4), "present_current": (126, 2),
              "present_velocity": (128, 4), "present_position": (132, 4), "present_input_voltage": (144, 2),
              "present_temperature": (146, 1)}
    for name, (address, size) in expect.items():
        reg = model.register(name)
        assert (reg.address, reg.size) == (address, size), name


def test_present_block_is_contiguous_current_velocity_position():
    m = ct.XM430_W350
    regs = [m.register(n) for n in ("present_current", "present_velocity", "present_position")]
    assert regs[0].address == ct.PRESENT_BLOCK_ADDRESS
    assert sum(r.size for r in regs) == ct.PRESENT_BLOCK_SIZE == 10
    assert regs[1].address == regs[0].address + regs[0].size
    assert regs[2].address == regs[1].address + regs[1].size
    assert all(r.signed for r in regs)


def test_eeprom_flag_follows_address_64():
    m = ct.XM540_W270
    assert m.register("operating_mode").eeprom and m.register("current_limit").eeprom
    assert not m.register("torque_enable").eeprom and not m.register("goal_current").eeprom


def test_registers_do_not_overlap():
    regs = sorted(ct.XM430_W350.registers.values(), key=lambda r: r.address)
    for a, b in zip(regs, regs[1:]):
        assert a.address + a.size <= b.address, (a.name, b.name)


def test_model_numbers_and_defaults():
    assert ct.model_by_number(1020) is ct.XM430_W350
    assert ct.model_by_number(1120) is ct.XM540_W270
    assert ct.model_by_number(1060) is None
    assert ct.XM430_W350.defaults()["current_limit"] == 1193
    assert ct.XM540_W270.defaults()["current_limit"] == 2047
    assert ct.XM430_W350.defaults()["operating_mode"] == ct.MODE_POSITION


def test_unknown_register_name_is_a_clear_error():
    with pytest.raises(KeyError, match="no control-table item named 'goal_torque'"):
        ct.XM430_W350.register("goal_torque")


def test_hardware_error_bits():
    assert ct.HARDWARE_ERROR_BITS[5] == "overload"
    assert set(ct.HARDWARE_ERROR_BITS) == {0, 2, 3, 4, 5}
