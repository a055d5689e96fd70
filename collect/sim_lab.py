"""A simulated lab on the wire: two simulated CRANE-X7 arms on pseudo-terminals, a simulated person's
hand on one of them, for `crane-collect sim-serve --pair`.

`crane-collect run --leader-port L --follower-port F` then drives them through exactly the code that
drives real arms (ports, one bus thread per arm, real-time pacing), and the session it records has a
hand in it, so `crane-train` can train on it.

The hand (`HandOnPlant`) wraps the plant of the arm it holds. It cannot see the controller, only what a
person holding a real arm would notice: whether the arm is alive. It takes hold once every bilateral
joint of its arm has been torque-on in current mode (operating mode 0) for `hand_delay_s` of the arm's
time (by then the alignment, which starts from two arms at rest in the same pose, is over), then moves
the arm as the in-process `run --sim` operator does (collect/operator.py, the same seeded process,
task "free" or "contact"). When the torque goes off, or any of its joints leaves current mode, the hand
lets go at once; the next engagement starts a new sequence of moves from wherever the arm is.

    lab = SimulatedLab.build(plant="crane-x7", seed=0, hand_on="leader", clock="lockstep")
    lab.serve({"leader": "/tmp/leader", "follower": "/tmp/follower"})   # PtyServers, links announced
    ...
    lab.stop()
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field, replace

import numpy as np

from crane_io.description import ArmDescription, default_arm
from crane_io.errors import ConfigError

from .arm_pair import ARMS
from .config import Config, load_config
from .operator import SimulatedOperator

DEFAULT_HAND_DELAY_S = 1.0  # s of the arm's time between its torque coming on and the hand taking hold
_CURRENT_MODE = 0


class PlantWrapper:
    """A plant around another (the Plant protocol of crane_io.sim.plant_api): every call and attribute
    passes through to the wrapped plant (truth, environment, errors) unless a subclass changes it."""

    def __init__(self, plant):
        self.plant = plant
        self.servo_ids = plant.servo_ids

    def __getattr__(self, name):  # everything not defined here is the wrapped plant's
        return getattr(self.__dict__["plant"], name)

    def step(self, command, dt: float) -> None:
        self.plant.step(command, dt)

    def read(self):
        return self.plant.read()

    def hardware_errors(self) -> dict[int, int]:
        return self.plant.hardware_errors()

    def set_external_torque(self, torque) -> None:
        self.plant.set_external_torque(torque)


class HandOnPlant(PlantWrapper):
    """A plant with a simulated person's hand on it."""

    def __init__(self, plant, operator: SimulatedOperator, arm: ArmDescription,
                 hand_delay_s: float = DEFAULT_HAND_DELAY_S):
        if not hand_delay_s >= 0:
            raise ConfigError(f"the hand's delay must be 0 s or more, got {hand_delay_s}")
        super().__init__(plant)
        self.operator = operator
        self.hand_delay_s = float(hand_delay_s)
        self._bil = np.array([n in arm.bilateral_joints for n in arm.joint_names])
        self._zero = np.zeros(len(plant.servo_ids))
        self.time = 0.0  # s of the arm's time (the sum of every step's dt)
        self.engaged_since: float | None = None  # when the arm came alive under current control
        self.holding = False  # the hand is on the arm and moving it
        self.engagements = 0  # how many times the hand took hold

    def _alive(self, command) -> bool:
        b = self._bil
        return bool(np.all(command.torque_enabled[b]) and np.all(command.operating_mode[b] == _CURRENT_MODE))

    def step(self, command, dt: float) -> None:
        if self._alive(command):
            if self.engaged_since is None:
                self.engaged_since = self.time
            starting = not self.holding and self.time - self.engaged_since >= self.hand_delay_s
            if self.holding or starting:
                s = self.plant.read()
                if starting:
                    self.operator.start(s.position, self.time)
                    self.holding = True
                    self.engagements += 1
                self.plant.set_external_torque(self.operator.torque(self.time, s.position, s.velocity))
        elif self.engaged_since is not None:
            self.engaged_since = None
            self.holding = False
            self.plant.set_external_torque(self._zero)
        self.plant.step(command, dt)
        self.time += dt


class OffsetPlant(PlantWrapper):
    """A plant whose servos' encoders are off: each reads its joint's angle plus `offsets` (rad, servo
    order) and holds a goal position that much short, as a real arm does before calibration."""

    def __init__(self, plant, offsets):
        super().__init__(plant)
        self.offsets = np.asarray(offsets, dtype=float)
        if self.offsets.shape != (len(self.servo_ids),):
            raise ConfigError(f"encoder offsets need {len(self.servo_ids)} values, got {self.offsets.shape}")

    def step(self, command, dt: float) -> None:
        self.plant.step(replace(command, goal_position=command.goal_position - self.offsets), dt)

    def read(self):
        s = self.plant.read()
        return replace(s, position=s.position + self.offsets)


def parse_offsets(specs, arm: ArmDescription, arms=ARMS) -> dict:
    """`--encoder-offset` values "ARM:JOINT=RAD" (or "JOINT=RAD" for one arm, arms=("arm",)) ->
    {arm: (n,) offsets}; ConfigError (one sentence) for anything else."""
    out = {}
    for spec in specs:
        head, _, value = spec.partition("=")
        who, _, joint = head.rpartition(":")
        who = who or (arms[0] if len(arms) == 1 else "")
        if who not in arms or joint not in arm.joint_names or not value:
            want = "ARM:JOINT=RAD with ARM leader or follower" if len(arms) > 1 else "JOINT=RAD"
            raise ConfigError(f"`encoder_offsets` {spec!r}: expected {want} and JOINT one of "
                              f"{', '.join(arm.joint_names)}")
        try:
            rad = float(value)
        except ValueError:
            rad = math.nan
        if not (math.isfinite(rad) and abs(rad) <= math.pi):
            raise ConfigError(f"`encoder_offsets` {spec!r}: {value!r} is not a number of radians "
                              "between -pi and pi")
        out.setdefault(who, np.zeros(len(arm.joint_names)))[arm.joint_names.index(joint)] = rad
    return out


@dataclass
class SimulatedLab:
    """Two simulated arms (leader, follower) and the hand; `serve(links)` puts them on pseudo-terminals."""

    plants: dict  # arm name -> plant behind the servos (a HandOnPlant and/or an OffsetPlant around it)
    chains: dict  # arm name -> crane_io.sim.chain.SimulatedChain
    hand: HandOnPlant
    hand_on: str
    clock: str
    plant_name: str
    servers: dict = field(default_factory=dict)  # arm name -> PtyServer, once served

    @classmethod
    def build(cls, *, plant: str | None = None, seed: int = 0, hand_on: str = "leader",
              clock: str = "wall", period_s: float = 0.002, config: Config | None = None,
              task: str | None = None, hand_delay_s: float = DEFAULT_HAND_DELAY_S,
              arm: ArmDescription | None = None, fast_sync_read: bool = True,
              return_delay_time: int | None = None, encoder_offsets: dict | None = None,
              supply_voltage: float | None = None) -> SimulatedLab:
        """The leader's and the follower's plants (seeds 2 seed and 2 seed + 1, as `run --sim`; the
        preset's objects only in the follower's world) behind servo chains, the hand on `hand_on`;
        `encoder_offsets` {arm: (n,) rad}: that arm's encoders read that much more than the truth (the
        hand feels the true angles); `supply_voltage` (V): both arms' servo supply (make_plant)."""
        from crane_io.sim.chain import SimulatedChain

        from .sim_arms import default_plant, make_plant

        if hand_on not in ARMS:
            raise ConfigError(f"the hand goes on the leader or the follower, not {hand_on!r}")
        arm = arm or default_arm()
        config = config or load_config()
        if task is not None:
            config = config.with_operator_task(task)
        plants, chains = {}, {}
        for k, name in enumerate(ARMS):
            plants[name] = make_plant(plant, seed * 2 + k, arm, objects=name == "follower",
                                      supply_voltage=supply_voltage)
        environment = getattr(plants["follower"], "environment", None) or []
        operator = SimulatedOperator(seed, arm, config.loop.rate_hz, config, environment=environment)
        hand = HandOnPlant(plants[hand_on], operator, arm, hand_delay_s)
        plants[hand_on] = hand
        for name, offsets in (encoder_offsets or {}).items():
            plants[name] = OffsetPlant(plants[name], offsets)
        for name in ARMS:
            chains[name] = SimulatedChain.for_arm(arm, plants[name], clock=clock, period_s=period_s,
                                                  fast_sync_read=fast_sync_read,
                                                  return_delay_time=return_delay_time)
        return cls(plants, chains, hand, hand_on, clock, plant or default_plant(arm))

    def serve(self, links: dict, adapter=None) -> dict:
        """Serve each arm on a pseudo-terminal linked at links[name]; returns {name: PtyServer}. If the
        second cannot start, the first is stopped again (ConfigError, one sentence). `adapter`: each
        link's crane_io.sim.adapter_timing.AdapterTiming (a U2D2 per arm), or None."""
        from crane_io.sim.transport import PtyServer

        if len({str(p) for p in links.values()}) != len(links):
            raise ConfigError("the leader's and the follower's links must be two different paths")
        try:
            for name in ARMS:
                self.servers[name] = PtyServer(self.chains[name], links[name], adapter=adapter).start()
        except BaseException:
            self.stop()
            raise
        return self.servers

    def error(self) -> BaseException | None:
        """The first error a server thread stopped on, or None."""
        for server in self.servers.values():
            if server.error is not None:
                return server.error
        return None

    def stop(self) -> None:
        for server in self.servers.values():
            server.stop()
        self.servers = {}
