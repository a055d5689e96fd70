"""Raw register values <-> SI: the conversions every reading and command passes through."""

import math

import numpy as np
import pytest
from hypothesis import given
from hypothesis import strategies as st

from crane_io.dynamixel import units


def test_center_is_joint_zero_and_half_turn_is_pi():
    assert units.position_to_rad(2048) == 0.0
    assert units.position_to_rad(4096) == pytest.approx(math.pi)
    assert units.position_to_rad(0) == pytest.approx(-math.pi)
    assert units.rad_to_position(0.0) == 2048


def test_documented_scales():
    assert units.velocity_to_rads(1) == pytest.approx(0.229 * 2 * math.pi / 60)
    assert units.current_to_ampere(1193) == pytest.approx(3.20917)
    assert units.voltage_to_volt(120) == pytest.approx(12.0)
    assert units.watchdog_to_seconds(5) == pytest.approx(0.1)


@given(st.integers(min_value=-1_048_575, max_value=1_048_575))
def test_position_round_trip_is_exact(raw):
    assert units.rad_to_position(units.position_to_rad(raw)) == raw


@given(st.integers(min_value=-32768, max_value=32767))
def test_current_and_velocity_round_trip_are_exact(raw):
    assert units.ampere_to_current(units.current_to_ampere(raw)) == raw
    assert units.rads_to_velocity(units.velocity_to_rads(raw)) == raw


@given(st.floats(min_value=-10, max_value=10, allow_nan=False))
def test_si_round_trip_within_half_a_quantum(value):
    assert abs(units.position_to_rad(units.rad_to_position(value)) - value) <= units.RAD_PER_PULSE / 2 + 1e-12
    amp = units.current_to_ampere(units.ampere_to_current(value))
    assert abs(amp - value) <= units.AMPERE_PER_CURRENT_LSB / 2 + 1e-12


def test_arrays_convert_elementwise():
    raw = np.array([0, 2048, 4095])
    assert units.position_to_rad(raw).shape == (3,)
    np.testing.assert_array_equal(units.rad_to_position(units.position_to_rad(raw)), raw)


@pytest.mark.parametrize("value,size,signed", [(0xFFFF, 2, -1), (0x8000, 2, -32768), (0x7FFF, 2, 32767),
                                               (0xFFFFFFFF, 4, -1), (5, 1, 5), (0xFF, 1, -1)])
def test_twos_complement(value, size, signed):
    assert units.to_signed(value, size) == signed
    assert units.to_unsigned(signed, size) == value


def test_watchdog_register_is_clamped_to_its_range():
    assert units.seconds_to_watchdog(0.1) == 5
    assert units.seconds_to_watchdog(0.0) == 1
    assert units.seconds_to_watchdog(100.0) == 127
