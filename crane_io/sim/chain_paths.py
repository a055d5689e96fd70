"""How the simulated chain (crane_io.sim.chain) reaches its plant and its compiled calls, by name:

- `PlantPaths`: the plant's optional faster methods the chain may use instead of `read` and `step` (found
  once per plant, `plant_paths`; None for each one the plant's class does not define together with the
  method it replaces, so a subclass or wrapper that changes `read` or `step` is never bypassed);
- `ChainCalls`: crane_io.sim.chain_kernel's compiled calls (the general path's fast steps);
- `LockstepCalls`: crane_io.sim.lockstep_kernel's (the lockstep cycle's usual packets whole; what they
  return is named there: DECLINED, UNHEARD, STEPPED, WRITTEN, STEPPED_UNSENSED);
- `fast_layout`: whether every servo has the items those calls read and write at the X series' addresses.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import NamedTuple

from crane_io.dynamixel.control_table import X_SERIES


class PlantPaths(NamedTuple):
    read_lists: Callable | None  # read() as lists of floats
    step_lists: Callable | None  # step() from lists
    read_arrays: Callable | None  # read() as arrays (chain_kernel.reading)
    step_command: Callable | None  # step() from the commands array (chain_kernel.commands)
    kernel_read_args: Callable | None  # lockstep_kernel.sense's arguments
    kernel_step_args: Callable | None  # lockstep_kernel.sync_write_goal's
    kernel_cycle_args: Callable | None  # lockstep_kernel.sync_write_read's (only with both above)


class ChainCalls(NamedTuple):
    sensors_into: Callable
    commands: Callable
    fast_status: Callable
    reading: Callable


class LockstepCalls(NamedTuple):
    sync_write_goal: Callable
    sense: Callable
    fast_sync_read: Callable
    sync_write_read: Callable


def plant_paths(plant) -> PlantPaths:
    """The plant's faster methods (see PlantPaths)."""
    read_args = list_method(plant, "read", "kernel_read_args")
    step_args = list_method(plant, "step", "kernel_step_args")
    # the step and the reading in one compiled call (lockstep_kernel.sync_write_read) when both fit
    both = read_args is not None and step_args is not None
    return PlantPaths(list_method(plant, "read"), list_method(plant, "step"),
                      list_method(plant, "read", "read_arrays"), list_method(plant, "step", "step_command"),
                      read_args, step_args, getattr(plant, "kernel_cycle_args", None) if both else None)


def list_method(plant, name: str, variant: str | None = None):
    """`plant.<name>_lists` (the same call with lists instead of arrays; or the method named `variant`) when
    the class whose `name` method the plant uses defines it too, else None: a subclass or a wrapper that
    changes `read` or `step` (sensor offsets, a delegating __getattr__; or, for a variant, `<name>_lists`)
    is never bypassed."""
    lists = f"{name}_lists"
    if variant is None:
        for klass in type(plant).__mro__:
            if name in vars(klass):
                return getattr(plant, lists) if lists in vars(klass) else None
        return None
    # the fast path's variant: the first class defining any of the three must define all three
    for klass in type(plant).__mro__:
        found = [m in vars(klass) for m in (name, lists, variant)]
        if any(found):
            return getattr(plant, variant) if all(found) else None
    return None


_FAST_ITEMS = ("present_current", "realtime_tick", "present_input_voltage", "moving_threshold",
               "torque_enable", "operating_mode", "goal_current", "goal_position", "current_limit",
               "hardware_error_status", "bus_watchdog", "id", "baud_rate", "max_position_limit",
               "min_position_limit", "drive_mode", "homing_offset", "status_return_level")


def fast_layout(servos) -> bool:
    """The fast path's compiled functions take every servo's items at the X series' addresses."""
    if not servos:
        return False
    for s in servos:
        regs = s.registers
        if any(regs[n].address != X_SERIES[n].address or regs[n].size != X_SERIES[n].size
               or regs[n].signed != X_SERIES[n].signed for n in _FAST_ITEMS):
            return False
        if any(regs[n].access != "RW" or regs[n].eeprom for n in ("goal_current", "goal_position")):
            return False
    return True
