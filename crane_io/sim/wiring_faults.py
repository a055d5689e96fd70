"""Miswired simulated arms: the mistakes a lab makes when it first puts an arm together, planted in a
simulated chain so that `crane-collect selftest` can be shown to catch them.

    faults = WiringFaults(swap_ids=(2, 3), reversed_joints=("joint4",), current_sign=-1.0)
    plant, models = apply_wiring_faults(plant, arm, faults)
    chain = SimulatedChain(plant, models, ...)

- `swap_ids` (a, b): the servos of two joints carry each other's IDs. The servo that sits in joint a's
  place (its motor, its encoder, its model) answers to ID b and the other way round. The chain is built
  in `plant.servo_ids` order, so the faulty plant only renames its servos.
- `reversed_joints`: the joint's motor and encoder turn the other way than the description says (a
  servo mounted the other way round, or a horn on the wrong side): the servo reads minus the joint's
  angle, velocity and motor current, and its goal position and goal current drive the joint the
  other way. The servo itself stays consistent (its position control works), only its sign is wrong.
- `wrong_models` {ID: model name}: the servo with that ID reports another model number (another
  servo was fitted); its physics is the arm's.
- `current_sign`, `current_scale`: every servo's current sensor reads `sign x scale` times the current
  the motor draws; -1 is a sensor of the wrong sign, 2 stands for a torque constant off by a factor 2
  (the current that holds a load is half or twice what the description's torque constant predicts).
"""

from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np

from crane_io.dynamixel.control_table import MODELS
from crane_io.errors import ConfigError

__all__ = ["FaultyWiringPlant", "WiringFaults", "apply_wiring_faults", "parse_id_pair", "parse_model_entry"]


@dataclass(frozen=True)
class WiringFaults:
    """The miswirings of one simulated arm (see the module docstring); the default is a healthy arm."""

    swap_ids: tuple[int, int] | None = None
    reversed_joints: tuple[str, ...] = ()
    wrong_models: tuple[tuple[int, str], ...] = ()  # (ID, model name) pairs
    current_sign: float = 1.0
    current_scale: float = 1.0

    @property
    def any(self) -> bool:
        return (self.swap_ids is not None or bool(self.reversed_joints) or bool(self.wrong_models)
                or self.current_sign != 1.0 or self.current_scale != 1.0)

    def describe(self) -> str:
        """One phrase naming the planted faults ("healthy wiring" for none)."""
        parts = []
        if self.swap_ids is not None:
            parts.append(f"IDs {self.swap_ids[0]} and {self.swap_ids[1]} swapped")
        parts += [f"{n} reversed" for n in self.reversed_joints]
        parts += [f"ID {sid} a {model}" for sid, model in self.wrong_models]
        if self.current_sign != 1.0:
            parts.append("current sensor of the wrong sign")
        if self.current_scale != 1.0:
            parts.append(f"current sensor x{self.current_scale:g}")
        return ", ".join(parts) or "healthy wiring"


def parse_id_pair(text: str) -> tuple[int, int]:
    """"2,3" -> (2, 3); ConfigError (one sentence) for anything else."""
    parts = [p.strip() for p in str(text).split(",")]
    if len(parts) != 2 or not all(p.isdigit() for p in parts) or parts[0] == parts[1]:
        raise ConfigError(f"`swap_ids` takes two different servo IDs as A,B (e.g. 2,3), got {text!r}")
    return int(parts[0]), int(parts[1])


def parse_model_entry(text: str) -> tuple[int, str]:
    """"5=XM540-W270" -> (5, "XM540-W270"); ConfigError (one sentence) for anything else."""
    sid, sep, model = str(text).partition("=")
    if not sep or not sid.strip().isdigit() or model.strip() not in MODELS:
        raise ConfigError(f"`wrong_models` takes ID=MODEL with MODEL one of {', '.join(MODELS)}, "
                          f"got {text!r}")
    return int(sid), model.strip()


def _check(faults: WiringFaults, arm) -> None:
    ids = set(arm.servo_ids)
    if faults.swap_ids is not None and not set(faults.swap_ids) <= ids:
        raise ConfigError(f"`swap_ids` {faults.swap_ids[0]},{faults.swap_ids[1]} names a servo the arm does "
                          f"not have (IDs {', '.join(map(str, sorted(ids)))})")
    for name in faults.reversed_joints:
        arm.joint(name)  # DescriptionError naming the joints for an unknown one
    for sid, model in faults.wrong_models:
        if sid not in ids:
            raise ConfigError(f"`wrong_models` names servo ID {sid}, which the arm does not have")
        if model not in MODELS:
            raise ConfigError(f"`wrong_models` names unknown servo model {model!r} "
                              f"(models: {', '.join(MODELS)})")
    for what, value in (("current_sign", faults.current_sign), ("current_scale", faults.current_scale)):
        if not (np.isfinite(value) and value != 0):
            raise ConfigError(f"`{what}` must be a finite number other than 0, got {value}")
    if faults.current_sign not in (1.0, -1.0):
        raise ConfigError(f"`current_sign` must be 1 or -1, got {faults.current_sign:g}")
    if faults.current_scale < 0:
        raise ConfigError(f"`current_scale` must be positive, got {faults.current_scale:g}")


class FaultyWiringPlant:
    """A plant seen through miswired servos (the Plant protocol of crane_io.sim.plant_api): every call
    and attribute not changed here passes through to the wrapped plant."""

    def __init__(self, plant, servo_ids: tuple[int, ...], signs: np.ndarray, current_gain: float):
        self.plant = plant
        self.servo_ids = tuple(servo_ids)
        self._renamed = dict(zip(plant.servo_ids, self.servo_ids))
        self.signs = np.asarray(signs, dtype=float)
        self.current_gain = float(current_gain)

    def __getattr__(self, name):  # everything not defined here is the wrapped plant's
        return getattr(self.__dict__["plant"], name)

    def step(self, command, dt: float) -> None:
        s = self.signs
        self.plant.step(replace(command, goal_position=np.asarray(command.goal_position) * s,
                                goal_current=np.asarray(command.goal_current) * s), dt)

    def read(self):
        r = self.plant.read()
        s = self.signs
        return replace(r, position=np.asarray(r.position) * s, velocity=np.asarray(r.velocity) * s,
                       current=np.asarray(r.current) * s * self.current_gain)

    def hardware_errors(self) -> dict[int, int]:
        return {self._renamed.get(sid, sid): bits for sid, bits in self.plant.hardware_errors().items()}

    def set_external_torque(self, torque) -> None:
        self.plant.set_external_torque(torque)


def apply_wiring_faults(plant, arm, faults: WiringFaults | None):
    """(plant, {servo ID: model name}) for a SimulatedChain of `arm` built on `plant` with `faults`
    planted; the plant unchanged (and the description's models) when there are none. ConfigError (one
    sentence) for a fault that does not fit the arm."""
    models = {j.servo_id: j.model for j in arm.joints}
    if faults is None or not faults.any:
        return plant, models
    _check(faults, arm)
    ids = list(plant.servo_ids)
    if faults.swap_ids is not None:
        a, b = faults.swap_ids
        ia, ib = ids.index(a), ids.index(b)
        ids[ia], ids[ib] = b, a
        models[a], models[b] = models[b], models[a]  # each servo keeps its model under its new ID
    for sid, model in faults.wrong_models:
        models[sid] = model
    by_id = {j.servo_id: j.name for j in arm.joints}
    signs = np.array([-1.0 if by_id.get(sid) in faults.reversed_joints else 1.0 for sid in plant.servo_ids])
    wrapped = FaultyWiringPlant(plant, tuple(ids), signs, faults.current_sign * faults.current_scale)
    return wrapped, models
