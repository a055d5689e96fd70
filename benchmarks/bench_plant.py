"""Simulated seconds per wall-clock second of the CRANE-X7 arm plant (crane_io.sim.arm_plant.ArmPlant).

1. The plant alone, stepped at 500 Hz (2 ms steps, 0.25 ms substeps) under a slowly varying current
   that makes the joints move, stop and stick (preset crane-x7).
2. The plant behind the simulated servo chain in lockstep mode, driven through the real client
   (crane_io.dynamixel.bus.DynamixelBus: one fast sync read + one Goal Current sync write per 2 ms cycle, real
   Protocol 2.0 bytes through dxlsim://). Goal: at least 5x real time, i.e. < 0.4 ms a cycle.
3. Two such arms (leader and follower, as in a bilateral session) stepped alternately in one thread.
4. The same with all seven joints integrated (preset crane-x7-7dof): the plant alone and two
   arms in lockstep.
5. The compiled substep kernel (crane_io.sim.plant_kernel, the default) against the reference path
   (`ArmPlant(kernel=False)`: Python floats per substep, the same bits), 3 and 7 joints, the plant alone:
   blocks of the two alternated in one process, CPU time, and their ratio.
6. The simulated chain side alone (SimulatedChain.feed: Goal Current Sync Write + Fast Sync Read bytes
   in, the reply out, the plant step included) on its fast path (crane_io.sim.chain_kernel, the default)
   against its general path (`SimulatedChain(fast=False)`), 3 and 7 joints: blocks alternated, CPU time.

Every timed loop runs one cycle first (the kernel's first call in a process loads it from numba's cache,
or compiles it once on a new machine: see `first_call`).

The machine these run on is shared, so every figure is measured in `REPEATS` blocks: the wall-clock
figure is the best block (least disturbed by other jobs) and the CPU figure counts only this process's
CPU time (time.process_time) over all blocks, which other jobs do not inflate.
"""

from __future__ import annotations

import time

import numpy as np

from crane_io.sim.arm_plant import ArmPlant
from crane_io.sim.plant_api import ActuatorCommand

PERIOD = 0.002
# amplitude (N m) of the varying torque on each integrated joint: above breakaway, so joints move, stop
# and stick (joints 1, 2, 4 as before the plant took any joint set)
AMPLITUDE = {"joint1": 0.35, "joint2": 0.5, "joint3": 0.3, "joint4": 0.3, "joint5": 0.25, "joint6": 0.25,
             "joint7": 0.2}
GOAL = 5.0  # x real time, one arm through the chain in lockstep
REPEATS = 5


_PER_JOINT: dict[tuple[str, ...], tuple[list[int], np.ndarray]] = {}


def _per_joint(joints: tuple[str, ...]) -> tuple[list[int], np.ndarray]:
    """(servo indices, amplitudes) of the integrated joints (kept: the drive is in the timed loop)."""
    if joints not in _PER_JOINT:
        names = ("joint1", "joint2", "joint3", "joint4", "joint5", "joint6", "joint7", "gripper")
        _PER_JOINT[joints] = ([names.index(n) for n in joints], np.array([AMPLITUDE[n] for n in joints]))
    return _PER_JOINT[joints]


def _drive(plant: ArmPlant, i: int) -> np.ndarray:
    cur = np.zeros(8)
    wave = np.sin(2 * np.pi * 0.4 * i * PERIOD)
    idx, amplitude = _per_joint(plant.joints)
    tau = plant.dyn.gravity_torque(plant.q) + amplitude * wave
    cur[idx] = tau / plant.kt[idx]
    return cur


def _timed(cycle, steps: int) -> tuple[float, float]:
    """(best wall s per cycle over REPEATS blocks, CPU s per cycle over all) of cycle(i), i = 0..steps-1."""
    block = max(1, steps // REPEATS)
    best, cpu0, done = float("inf"), time.process_time(), 0
    for b in range(REPEATS):
        t0 = time.perf_counter()
        for i in range(b * block, (b + 1) * block):
            cycle(i)
        best = min(best, (time.perf_counter() - t0) / block)
        done += block
    return best, (time.process_time() - cpu0) / done


def _alone_cycle(preset: str, kernel: bool | None = None):
    plant = ArmPlant(preset, seed=0, kernel=kernel)
    n = 8
    enabled, mode = np.ones(n, bool), np.zeros(n, int)
    gains, limit, goal = np.tile([800, 0, 0], (n, 1)), np.full(n, 3.2), np.zeros(n)

    def cycle(i):
        plant.step(ActuatorCommand(enabled, mode, _drive(plant, i), goal, gains, limit), PERIOD)
        plant.read()

    cycle(0)  # warm-up (the kernel's first call)
    return cycle


def plant_alone(steps: int, preset: str = "crane-x7", kernel: bool | None = None) -> tuple[float, float]:
    return _timed(_alone_cycle(preset, kernel), steps)


def kernel_vs_reference(steps: int, preset: str = "crane-x7") -> tuple[float, float]:
    """(reference CPU s per step, kernel CPU s per step) of the plant alone, blocks alternated."""
    per_step = _alternated({True: _alone_cycle(preset, True), False: _alone_cycle(preset, False)}, steps)
    return per_step[False], per_step[True]


def _alternated(cycles: dict, steps: int) -> dict:
    """CPU s per call of each cycle(i) in `cycles`, run in alternated blocks (2 x REPEATS of them) so that
    a change in the machine's load falls on all of them alike."""
    cpu = dict.fromkeys(cycles, 0.0)
    block = max(1, steps // (2 * REPEATS))
    for b in range(2 * REPEATS):
        for key, cycle in cycles.items():
            t = time.process_time()
            for i in range(b * block, (b + 1) * block):
                cycle(i)
            cpu[key] += time.process_time() - t
    done = block * 2 * REPEATS
    return {key: c / done for key, c in cpu.items()}


def first_call(preset: str = "crane-x7") -> float:
    """CPU s of a fresh process's first kernel plant beyond a second one: importing numba and loading the
    machine code from the cache (compiling when there is none)."""
    import subprocess
    import sys

    code = ("import time; from crane_io.sim.arm_plant import ArmPlant; "
            f"t = time.process_time(); ArmPlant({preset!r}, seed=0); a = time.process_time() - t; "
            f"t = time.process_time(); ArmPlant({preset!r}, seed=0); b = time.process_time() - t; "
            "print(a - b)")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True)
    return float(out.stdout.strip().splitlines()[-1])


def through_chain(steps: int, arms: int = 1, preset: str = "crane-x7") -> tuple[float, float]:
    """Seconds per lockstep cycle of `arms` simulated arms, each behind its own chain and bus."""
    from contextlib import ExitStack

    from crane_io.dynamixel.bus import DynamixelBus
    from crane_io.sim import simulated_arm

    with ExitStack() as stack:
        pairs = []
        for _ in range(arms):
            plant = ArmPlant(preset, seed=0)
            sim = simulated_arm(plant=plant, clock="lockstep", period_s=PERIOD)
            stack.callback(sim.close)
            bus = stack.enter_context(DynamixelBus(sim.url))
            bus.ping_all()
            bus.configure(watchdog_s=0.5)
            bus.torque_on()
            pairs.append((plant, bus))

        def cycle(i):
            for plant, bus in pairs:
                bus.read_state()
                bus.write_goal_current(_drive(plant, i))

        cycle(0)  # warm-up (the kernel's first call)
        return _timed(cycle, steps)


def _chain_cycle(preset: str, fast: bool):
    """One arm-cycle of the simulated chain side alone (crane_io.sim.chain.SimulatedChain.feed, plant step
    included): prebuilt Goal Current Sync Write (the integrated joints' servos in current mode) + Fast
    Sync Read of the present block of all 8 servos, on the fast or the general path."""
    from crane_io.sim import protocol as p
    from crane_io.sim.chain import SimulatedChain

    plant = ArmPlant(preset, seed=0)
    chain = SimulatedChain(plant, fast=fast)
    cur_ids = [plant.servo_ids[i] for i in plant._bi_l]
    for sid in cur_ids:
        chain.feed(p.instruction_packet(sid, p.INST_WRITE, bytes((11, 0, 0))))  # current mode
    for sid in plant.servo_ids:
        chain.feed(p.instruction_packet(sid, p.INST_WRITE, bytes((64, 0, 1))))  # torque on
    idx, amplitude = _per_joint(plant.joints)
    waves = [(amplitude * np.sin(2 * np.pi * 0.4 * i * PERIOD) / plant.kt[idx] / 2.69e-3).astype(int)
             for i in range(250)]  # a slowly varying current (one period of it, repeated)
    writes = [p.instruction_packet(p.BROADCAST_ID, p.INST_SYNC_WRITE, bytes((102, 0, 2, 0)) + b"".join(
        bytes((sid,)) + int(v).to_bytes(2, "little", signed=True) for sid, v in zip(cur_ids, w)))
        for w in waves]
    read = p.instruction_packet(p.BROADCAST_ID, p.INST_FAST_SYNC_READ,
                                bytes((126, 0, 10, 0)) + bytes(plant.servo_ids))
    feed = chain.feed

    def cycle(i):
        feed(writes[i % 250])
        feed(read)

    cycle(0)
    return cycle


def chain_fast_vs_general(cycles: int, preset: str = "crane-x7") -> tuple[float, float]:
    """(general path, fast path) CPU s per arm-cycle of the chain side (_chain_cycle), blocks alternated."""
    per_cycle = _alternated({False: _chain_cycle(preset, False), True: _chain_cycle(preset, True)}, cycles)
    return per_cycle[False], per_cycle[True]


def _rows(label: str, wall: float, cpu: float, note: str, goal: float | None = None) -> list[dict]:
    rows = [{"benchmark": "plant", "metric": f"{label}: simulated s per wall s", "value": PERIOD / wall,
             "unit": "x real time", "note": note},
            {"benchmark": "plant", "metric": f"{label}: simulated s per CPU s", "value": PERIOD / cpu,
             "unit": "x real time", "note": "this process's CPU time only"},
            {"benchmark": "plant", "metric": f"{label}: cycle", "value": wall * 1e3, "unit": "ms",
             "note": f"best of {REPEATS} blocks; CPU {cpu * 1e3:.3f} ms"}]
    if goal is not None:
        met = PERIOD / cpu >= goal and PERIOD / wall >= goal
        rows.append({"benchmark": "plant", "metric": f"{label}: goal >= {goal:g}x real time",
                     "value": "met" if met else "NOT met", "unit": "",
                     "note": f"needs < {PERIOD / goal * 1e3:.2f} ms per cycle (wall and CPU)"})
    return rows


def run(quick: bool = False) -> list[dict]:
    steps = 500 if quick else 5000
    rows = _rows("ArmPlant alone", *plant_alone(steps),
                 f"{steps} steps of 2 ms, 0.25 ms substeps, preset crane-x7")
    try:
        rows += _rows("1 arm, bus + chain, lockstep", *through_chain(steps),
                      f"{steps} cycles: fast sync read + Goal Current sync write, dxlsim://", goal=GOAL)
        rows += _rows("2 arms, bus + chain, lockstep", *through_chain(steps // 2, arms=2),
                      f"{steps // 2} cycles of leader + follower in one thread")
        rows += _rows("7 joints: ArmPlant alone", *plant_alone(steps // 2, "crane-x7-7dof"),
                      f"{steps // 2} steps of 2 ms, preset crane-x7-7dof (all seven integrated)")
        rows += _rows("7 joints: 2 arms, bus + chain, lockstep",
                      *through_chain(steps // 4, arms=2, preset="crane-x7-7dof"),
                      f"{steps // 4} cycles of leader + follower, preset crane-x7-7dof")
        for preset, label in (("crane-x7", "3 joints"), ("crane-x7-7dof", "7 joints")):
            ref, fast = kernel_vs_reference(steps // 2, preset)
            note = f"CPU {ref * 1e6:.1f} / {fast * 1e6:.1f} us a step (with read), blocks alternated"
            rows.append({"benchmark": "plant", "metric": f"{label}: ArmPlant alone, reference path / kernel",
                         "value": ref / fast, "unit": "x", "note": note})
        for preset, label in (("crane-x7", "3 joints"), ("crane-x7-7dof", "7 joints")):
            general, fast = chain_fast_vs_general(steps, preset)
            note = (f"CPU {general * 1e6:.1f} / {fast * 1e6:.1f} us an arm-cycle (Goal Current sync write + "
                    "fast sync read bytes in, reply out, plant step included), blocks alternated")
            rows.append({"benchmark": "plant", "metric": f"{label}: chain side, general / fast path",
                         "value": general / fast, "unit": "x", "note": note})
        rows.append({"benchmark": "plant", "metric": "kernel: first plant in a process",
                     "value": first_call(),
                     "unit": "CPU s", "note": "numba import + cached machine code (no cache: compile)"})
    except ImportError as exc:  # the chain or bus layer is not there
        rows.append({"benchmark": "plant", "metric": "ArmPlant + servo chain, lockstep",
                     "value": float("nan"), "unit": "x real time", "note": f"skipped: {exc}"})
    return rows


if __name__ == "__main__":
    import sys
    from pathlib import Path

    sys.path.insert(0, str(Path(__file__).resolve().parent))
    from run_all import table

    print(table(run(quick="--quick" in sys.argv)))
