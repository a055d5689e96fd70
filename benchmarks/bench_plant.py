"""Simulated seconds per wall-clock second of the CRANE-X7 arm plant (crane_io.arm_plant.ArmPlant).

1. The plant alone, stepped at 500 Hz (2 ms steps, 0.25 ms substeps) under a slowly varying current
   that makes the joints move, stop and stick (preset crane-x7).
2. The plant behind the simulated servo chain in lockstep mode, driven through the real client
   (crane_io.bus.DynamixelBus: one fast sync read + one Goal Current sync write per 2 ms cycle).
Goal: at least 5x real time in lockstep.
"""

from __future__ import annotations

import time

import numpy as np

from crane_io.arm_plant import ArmPlant
from crane_io.sim.plant_api import ActuatorCommand

PERIOD = 0.002
BI = [0, 1, 3]


def _drive(plant: ArmPlant, i: int) -> np.ndarray:
    cur = np.zeros(8)
    wave = np.sin(2 * np.pi * 0.4 * i * PERIOD)
    tau = plant.dyn.gravity_torque(plant.q) + np.array([0.35, 0.5, 0.3]) * wave
    cur[BI] = tau / plant.kt[BI]
    return cur


def plant_alone(steps: int) -> float:
    plant = ArmPlant("crane-x7", seed=0)
    n = 8
    enabled, mode = np.ones(n, bool), np.zeros(n, int)
    gains, limit, goal = np.tile([800, 0, 0], (n, 1)), np.full(n, 3.2), np.zeros(n)
    t0 = time.perf_counter()
    for i in range(steps):
        plant.step(ActuatorCommand(enabled, mode, _drive(plant, i), goal, gains, limit), PERIOD)
        plant.read()
    return steps * PERIOD / (time.perf_counter() - t0)


def through_chain(steps: int) -> float:
    from crane_io.bus import DynamixelBus
    from crane_io.sim import simulated_arm

    plant = ArmPlant("crane-x7", seed=0)
    sim = simulated_arm(plant=plant, clock="lockstep", period_s=PERIOD)
    try:
        with DynamixelBus(sim.url) as bus:
            bus.ping_all()
            bus.configure(watchdog_s=0.5)
            bus.torque_on()
            t0 = time.perf_counter()
            for i in range(steps):
                bus.read_state()
                bus.write_goal_current(_drive(plant, i))
            elapsed = time.perf_counter() - t0
    finally:
        sim.close()
    return steps * PERIOD / elapsed


def run(quick: bool = False) -> list[dict]:
    steps = 500 if quick else 5000
    rows = [{"benchmark": "plant", "metric": "ArmPlant alone: simulated s per wall s",
             "value": plant_alone(steps),
             "unit": "x real time", "note": f"{steps} steps of 2 ms, 0.25 ms substeps, preset crane-x7"}]
    try:
        value = through_chain(steps)
        rows.append({"benchmark": "plant", "metric": "ArmPlant + servo chain + DynamixelBus, lockstep",
                     "value": value, "unit": "x real time",
                     "note": f"{steps} cycles: fast sync read + Goal Current sync write; goal >= 5"})
    except ImportError as exc:  # the chain or bus layer is not there
        rows.append({"benchmark": "plant", "metric": "ArmPlant + servo chain, lockstep",
                     "value": float("nan"),
                     "unit": "x real time", "note": f"skipped: {exc}"})
    return rows


if __name__ == "__main__":
    for row in run(quick=False):
        print(f"{row['metric']:<55} {row['value']:8.2f} {row['unit']}  ({row['note']})")
