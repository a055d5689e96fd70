"""The two simulated arms of `crane-collect run --sim`: their plants, their in-process servo chains
(dxlsim://), and the follower plant's truth on request.

    sims = make_sim_arms(plant, seed, config, arm)  # {"leader": SimulatedArm, "follower": SimulatedArm}
    ports = {name: sims[name].url for name in ARMS}

The in-process arms always run on the lockstep clock (one control period per Goal Current or Goal
Position sync write), also with `--realtime`, where the loop is paced by the wall clock. They run in
the loop's own thread: on the wall clock their physics would be stepped inside every bus transfer of
every cycle (three transfers per arm in the alignment, each forcing at least one plant step), about
half of each 2 ms cycle on an idle machine. A machine a little slower, or busy, then stretches the
cycles and the delay between reading an arm and its goal current taking effect until the 500 Hz
controller oscillates into the velocity guard, or makes every slow cycle's catch-up slower still
until the Bus Watchdog expires. In lockstep the physics costs the same, but it never runs between a
read and the write that answers it, and a cycle that comes late delays the simulated time instead
of breaking the control: the loop's overruns say how well the machine kept up. Arms that follow the
wall clock beside the loop, as real arms do, are `crane-collect sim-serve` processes on ptys.
"""

from __future__ import annotations

import itertools
import os
from dataclasses import replace
from pathlib import Path

from crane_io.description import ArmDescription
from crane_io.errors import ConfigError

from .arm_pair import ARMS
from .config import PAPER_JOINTS, Config

_RUNS = itertools.count()  # tells apart the simulated arms of this process's runs

# The arm-plant preset of a run without --plant: "crane-x7" (the paper's three joints: every published
# figure and pinned session) while the bilateral joints are among joint1, joint2, joint4; the seven-joint
# CRANE-X7 once any other joint is bilateral (its joints' effects, rotor inertia and friction).
DEFAULT_PLANT = "crane-x7"
DEFAULT_PLANT_7DOF = "crane-x7-7dof"


def default_plant(arm: ArmDescription) -> str:
    """The preset used without --plant for the arm's bilateral joints (see DEFAULT_PLANT_7DOF)."""
    return DEFAULT_PLANT if all(n in PAPER_JOINTS for n in arm.bilateral_joints) else DEFAULT_PLANT_7DOF


def make_plant(spec: str | None, seed: int, arm: ArmDescription, objects: bool = True,
               supply_voltage: float | None = None):
    """The plant behind a simulated arm: ArmPlant from a preset/TOML (default: default_plant(arm)) that
    integrates the arm's bilateral joints, or "simple" for the light SimplePlant. `objects=False`:
    without the preset's [[environment]] (the leader's world: only the follower touches objects). A
    preset whose effects or objects sit on joints the run holds is the plant's ConfigError (one
    sentence). `supply_voltage` (V): the servos' supply (the arm plant's [supply] enabled at that voltage;
    ConfigError for the simple plant, which has no supply model)."""
    from crane_io.sim.simple_plant import SimplePlant

    if spec == "simple":
        if supply_voltage is not None:
            raise ConfigError("the simple plant has no supply model; use an arm-plant preset with a supply "
                              "voltage")
        return SimplePlant.from_arm(arm)
    try:
        from crane_io.sim.arm_plant import ArmPlant
        from crane_io.sim.plant_config import load_plant_config
    except ImportError:
        if spec is None:
            return SimplePlant.from_arm(arm)
        raise ConfigError(f"`plant` {spec} needs crane_io.sim.arm_plant, which is not installed; "
                          "use `plant` simple") from None
    name = spec or default_plant(arm)
    config = load_plant_config(name)
    config = config if objects else config.without_environment()
    if supply_voltage is not None:
        config = replace(config, supply=replace(config.supply, enabled=True, voltage=float(supply_voltage)))
    # The arm plant integrates arm joints only: a bilateral gripper is its simple current-driven servo
    # (inertia and viscous friction), as every held servo is when its mode is current.
    joints = tuple(n for n in arm.bilateral_joints if n != "gripper")
    if spec is None and joints:
        # the default arm with some of its joints held (e.g. joint 3): their friction is no part of the
        # physics; a plant the user names is taken as it is (and refused below if it does not fit)
        config = config.restricted_to(joints)
    try:
        return ArmPlant(config, seed=seed, joints=joints or None)
    except ConfigError as exc:  # e.g. an effect on a joint the run holds: say which plant, which joints
        bil = ", ".join(arm.bilateral_joints)
        raise ConfigError(f"plant {name} with the bilateral joints {bil}: {str(exc).rstrip('.')}; pass "
                          "`plant` with one whose effects and objects sit on those joints") from None


def make_sim_arms(plant: str | None, seed: int, config: Config, arm: ArmDescription) -> dict:
    """Leader and follower simulated arms on the plant `plant` (make_plant; seeds 2 seed and 2 seed + 1),
    in lockstep; the plant's objects ([[environment]]) are in the follower's world only."""
    from crane_io.sim import simulated_arm

    # Lockstep, also for --realtime (see the module docstring); start-up (ping, configure, torque on)
    # then never lets the simulated arms fall under gravity while their torque is off.
    clock = "lockstep"
    sims = {}
    tag = f"{os.getpid()}-{next(_RUNS):x}"
    for k, name in enumerate(ARMS):
        arm_plant = make_plant(plant, seed * 2 + k, arm, objects=name == "follower")
        sims[name] = simulated_arm(name=f"{name}-{tag}", plant=arm_plant, clock=clock,
                                   period_s=config.loop.period_s, arm=arm, return_delay_time=0)
    return sims


def write_truth(sims: dict, path: str | Path) -> Path:
    """Write the follower plant's truth (effects, parameters, seed) to `path`, a file of its own: the
    session never holds it. One sentence (ConfigError) for a plant without truth or an unwritable path."""
    return write_plant_truth(sims["follower"].plant, path)


def write_plant_truth(plant, path: str | Path) -> Path:
    """Write `plant`'s truth to `path` (see write_truth), whole or not at all (crane_io.output_files: a
    full disk is one sentence); the path is checked by the command (never an input, `force`)."""
    from crane_io.output_files import atomic_path

    if not hasattr(plant, "write_truth"):
        raise ConfigError("`truth` needs an arm plant (a preset or TOML file), not `plant` simple")
    with atomic_path(path, "truth file") as tmp:
        plant.write_truth(tmp)
    return Path(path)


def make_operator(seed: int, config: Config, arm: ArmDescription, sims: dict):
    """The simulated operator (seeded by `seed`); in the "contact" task it is told the objects of the
    follower's world (the follower's plant environment)."""
    from .operator import SimulatedOperator

    environment = getattr(sims["follower"].plant, "environment", None) or []
    return SimulatedOperator(seed, arm, config.loop.rate_hz, config, environment=environment)

