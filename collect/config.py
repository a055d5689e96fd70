"""The collect configuration: controller, loop, safety and simulated-operator parameters.

The packaged `collect/config/bilateral.toml` holds every key with its documented default. A user
file (`load_config(path)`, `crane-collect run --config FILE`) overrides any subset of it
(crane_io.toml_config.merge_defaults); an unknown key, a wrong type or an impossible value raises
`ConfigError` with one sentence naming the key.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from importlib import resources
from pathlib import Path

from crane_io.description import default_arm
from crane_io.errors import ConfigError
from crane_io.toml_config import dump_toml, expect, merge_defaults, read_toml

DEG = math.pi / 180.0
# The controller's default gains and observer cutoffs need at least this rate: at 50 Hz the simulated
# arms already oscillate into the velocity guard during the alignment. The servos' bus cannot go faster
# than the top.
MIN_RATE_HZ = 100.0
MAX_RATE_HZ = 2000.0
GRAVITY_MODELS = ("dynamics", "coefficients", "none")
# The joints a [bilateral] joints list (or --joints) may name, in the arm's order; "all" is the seven arm
# joints (the gripper only when named: it closes on what it holds, see docs/collect.md).
JOINT_NAMES = ("joint1", "joint2", "joint3", "joint4", "joint5", "joint6", "joint7", "gripper")
ARM_JOINTS = JOINT_NAMES[:7]
# The paper's three joints: the default bilateral set (every published figure and pinned session).
PAPER_JOINTS = ("joint1", "joint2", "joint4")
INERTIA_MODELS = ("dynamics", "constant")
DITHER_WAVES = ("sine", "square")
MODEL_FILTERS = ("training", "observer")  # controller.model_filters (docs/collect.md, "A learned model")
# the friction dither needs at least this many control cycles per period (4: a square wave's two levels
# are each held for two cycles; a sine is sampled at its peaks and zero crossings)
DITHER_MIN_CYCLES = 4
# joint -> (lower, upper) rad: [held] and [operator.start_deg] angles must lie within them
_JOINT_LIMITS = {j.name: (j.lower, j.upper) for j in default_arm().joints}


@dataclass(frozen=True)
class JointGains:
    inertia: float  # kg m^2, nominal J
    kp: float  # 1/s^2
    kd: float  # 1/s
    kf: float  # dimensionless
    cutoff: float  # rad/s, pseudo-derivative and observer cutoff g
    viscous: float  # N m s/rad, RFOB viscous friction D
    dither: float = 1.0  # follower's dither on this joint, x controller.dither_amplitude (< 0: antiphase)
    dither_min_velocity: float = 0.0  # rad/s: this joint's dither amplitude >= it x 2 pi f x J(q) (0: off)
    model_cutoff: float = 0.0  # rad/s: this joint's loop filters with a model (0: controller.model_cutoff)


@dataclass(frozen=True)
class LoopConfig:
    rate_hz: float
    spin_s: float
    status_hz: float
    status_log_s: float  # s of wall time between status lines when stderr is not a terminal

    @property
    def period_s(self) -> float:
        return 1.0 / self.rate_hz


@dataclass(frozen=True)
class ControllerConfig:
    gravity_model: str
    gravity_m0: float
    gravity_m1: float
    gravity_m2: float
    position_deadband: float  # rad
    inertia_model: str
    inertia_update_cycles: int
    joints: dict[str, JointGains]
    dither_amplitude: float = 0.0  # N m, follower friction dither on every bilateral joint (0: off)
    dither_frequency: float = 50.0  # Hz
    dither_wave: str = "sine"  # "sine" or "square"
    dither_filter: bool = True  # the follower's tau_res averaged over one dither period
    model_coulomb_velocity: float = 0.0  # rad/s, v0: a model's Coulomb sign(dq) -> tanh(dq/v0); 0: off
    model_filters: str = "training"  # a model's observer: "training" (two lags) or "observer" (one lag of g)
    model_cutoff: float = 0.0  # rad/s: "training" filters at this cutoff instead of the model's (0: its own)


@dataclass(frozen=True)
class SafetyConfig:
    watchdog_s: float
    current_fraction: float
    limit_margin: float  # rad
    limit_stiffness: float  # N m/rad
    limit_damping: float  # N m s/rad
    limit_overshoot: float  # rad
    error_budget_consecutive: int
    error_budget_per_second: int
    hardware_poll_cycles: int
    agree_tolerance: float  # rad
    max_start_difference: float  # rad
    homing_speed: float  # rad/s
    velocity_limit: dict[str, float]  # rad/s per joint


@dataclass(frozen=True)
class OperatorConfig:
    duty: float
    mean_on_s: float
    min_move_s: float
    max_move_s: float
    peak_speed: float
    workspace_margin: float  # rad
    stiffness: float
    damping: float
    max_torque: float
    start: dict[str, float]  # rad, sim start pose per joint
    task: str = "free"  # "free": free motion only; "contact": also presses against the follower's objects
    press_fraction: float = 0.3  # contact task: fraction of the time spent pressing, in (0, 1)
    press_torque_min: float = 0.3  # N m: the smallest target press torque (norm over the joints)
    press_torque_max: float = 1.5  # N m: the largest
    press_min_s: float = 1.0  # s: the shortest press (force ramp and hold)
    press_max_s: float = 4.0  # s: the longest press


OPERATOR_TASKS = ("free", "contact")


SCHEDULING = ("fifo", "off")


@dataclass(frozen=True)
class RealtimeConfig:
    """[realtime]: what a paced loop (hardware, --sim --realtime) asks the OS for (collect/realtime.py)."""

    scheduling: str = "fifo"  # "fifo": SCHED_FIFO at `priority`; "off": normal scheduling
    priority: int = 40  # 1..99
    pin: bool = True  # pin the loop to `cpu` (only when SCHED_FIFO was granted)
    cpu: int = -1  # -1: the last core the process may use
    lock_memory: bool = True  # mlockall(MCL_CURRENT | MCL_FUTURE)
    freeze_gc: bool = True  # no automatic garbage collection in the cycle


@dataclass(frozen=True)
class Config:
    loop: LoopConfig
    controller: ControllerConfig
    held: dict[str, float]  # rad, goal position of each joint when held in position mode
    safety: SafetyConfig
    operator: OperatorConfig
    values: dict  # the complete merged configuration as plain TOML data (degrees as written)
    realtime: RealtimeConfig = RealtimeConfig()
    # [bilateral] joints: the joints under bilateral control, in the arm's order (the rest held)
    bilateral: tuple[str, ...] = PAPER_JOINTS

    def to_toml(self) -> str:
        """The complete configuration used, as TOML text (stored in every session)."""
        return dump_toml(self.values)

    def with_rate(self, rate_hz: float) -> Config:
        if not (math.isfinite(rate_hz) and MIN_RATE_HZ <= rate_hz <= MAX_RATE_HZ):
            raise ConfigError(f"`rate` must be between {MIN_RATE_HZ:g} and {MAX_RATE_HZ:g} Hz, "
                              f"got {rate_hz:g}")
        values = _deep_copy(self.values)
        values["loop"]["rate_hz"] = float(rate_hz)
        return _build(values, "`rate`")

    def with_bilateral_joints(self, spec: str | list | tuple, where: str = "joints") -> Config:
        """The same configuration with another bilateral joint set: a list of joint names, or the text of
        the `joints` option (comma-separated names, or "all" for joint1..joint7). `where` is the name of
        the setting the set came from, as the sentences show it (backquoted). One sentence for a bad set."""
        values = _deep_copy(self.values)
        values["bilateral"]["joints"] = list(parse_joints(spec, f"`{where}`"))
        return _build(values, f"`{where}`")

    def with_operator_task(self, task: str) -> Config:
        """The same configuration with the simulated operator's task set ("free" or "contact")."""
        if task not in OPERATOR_TASKS:
            raise ConfigError(f"the operator task must be one of {', '.join(OPERATOR_TASKS)}, got {task!r}")
        values = _deep_copy(self.values)
        values["operator"]["task"] = task
        return _build(values, "`task`")


def parse_joints(spec: str | list | tuple, where: str = "`joints`") -> tuple[str, ...]:
    """A bilateral joint set from "all", "all,gripper", "joint1,joint2,joint4" or a list of names: the
    names in the arm's order (joint1 .. joint7, gripper; "all" stands for joint1 .. joint7). ConfigError
    (one sentence) for an unknown name, a name given twice, an empty set or anything that is not text."""
    if isinstance(spec, str):
        text = spec.strip()
        names = [n.strip() for n in text.split(",")] if text else []
        if "" in names:
            raise ConfigError(f"{where} {spec!r} has an empty item; separate joint names by single commas")
        names = [m for n in names for m in (ARM_JOINTS if n.lower() == "all" else (n,))]
    elif isinstance(spec, (list, tuple)):
        names = [m for n in spec for m in (ARM_JOINTS if isinstance(n, str) and n.lower() == "all" else (n,))]
    else:
        raise ConfigError(f"{where} must be a list of joint names or \"all\", got {spec!r}")
    for n in names:
        if not isinstance(n, str):
            raise ConfigError(f"{where} must name joints as text, got {n!r}")
        if n not in JOINT_NAMES:
            raise ConfigError(f"{where} names unknown joint {n!r} (joints: {', '.join(JOINT_NAMES)}, or all)")
    if not names:
        raise ConfigError(f"{where} names no joint; give at least one of {', '.join(JOINT_NAMES)}, or all")
    twice = sorted({n for n in names if names.count(n) > 1}, key=JOINT_NAMES.index)
    if twice:
        raise ConfigError(f"{where} names {twice[0]} twice")
    return tuple(n for n in JOINT_NAMES if n in names)


# ---- loading ---------------------------------------------------------------------------------------

def default_config_text() -> str:
    return resources.files("collect").joinpath("config/bilateral.toml").read_text()


def load_config(path: str | Path | None = None) -> Config:
    """The defaults, overridden by the TOML file at `path` (if given)."""
    values = read_toml(text=default_config_text(), where="the default configuration")
    where = "the default configuration"
    if path is not None:
        where = str(path)
        merge_defaults(values, read_toml(path), where)
    return _build(values, where)


def _need(cond: bool, where: str, key: str, what: str, value) -> None:
    expect(cond, f"{key!r} in {where}", what, value)


def _pos(where, key, value):
    _need(math.isfinite(value) and value > 0, where, key, "a positive number", value)
    return value


def _nonneg(where, key, value):
    _need(math.isfinite(value) and value >= 0, where, key, "zero or positive", value)
    return value


def _finite(where, key, value):
    _need(math.isfinite(value), where, key, "a finite number", value)
    return value


def _angle(where, key, joint, value_deg) -> float:
    """A joint angle given in degrees, within the joint's limits (crane_io.description): rad."""
    lower, upper = _JOINT_LIMITS[joint]
    _need(math.isfinite(value_deg) and lower <= value_deg * DEG <= upper, where, key,
          f"an angle within {joint}'s limits, {lower / DEG:g} to {upper / DEG:g} deg", value_deg)
    return value_deg * DEG


def _build(values: dict, where: str) -> Config:
    lp = values["loop"]
    loop = LoopConfig(
        rate_hz=_pos(where, "loop.rate_hz", lp["rate_hz"]),
        spin_s=_nonneg(where, "loop.spin_s", lp["spin_s"]),
        status_hz=_nonneg(where, "loop.status_hz", lp["status_hz"]),
        status_log_s=_nonneg(where, "loop.status_log_s", lp["status_log_s"]),
    )
    _need(MIN_RATE_HZ <= loop.rate_hz <= MAX_RATE_HZ, where, "loop.rate_hz",
          f"between {MIN_RATE_HZ:g} and {MAX_RATE_HZ:g} Hz", loop.rate_hz)
    _need(loop.spin_s <= loop.period_s, where, "loop.spin_s", f"at most one control period "
          f"({loop.period_s:g} s)", loop.spin_s)
    _need(loop.status_hz <= loop.rate_hz, where, "loop.status_hz", f"at most the loop's rate "
          f"({loop.rate_hz:g} Hz: one status line a cycle)", loop.status_hz)

    c = values["controller"]
    _need(c["gravity_model"] in GRAVITY_MODELS, where, "controller.gravity_model",
          "one of " + ", ".join(GRAVITY_MODELS), c["gravity_model"])
    joints = {}
    for name, table in c.items():
        if not isinstance(table, dict):
            continue
        gains = {}
        for key in ("inertia", "kp", "cutoff"):
            gains[key] = _pos(where, f"controller.{name}.{key}", table[key])
        for key in ("kd", "kf", "viscous", "dither", "dither_min_velocity", "model_cutoff"):
            check = _finite if key == "dither" else _nonneg  # dither < 0: antiphase
            gains[key] = check(where, f"controller.{name}.{key}", table[key])
        joints[name] = JointGains(**gains)
    for key in ("gravity_m0", "gravity_m1", "gravity_m2"):
        _need(math.isfinite(c[key]), where, f"controller.{key}", "a finite number", c[key])
    controller = ControllerConfig(
        gravity_model=c["gravity_model"],
        gravity_m0=c["gravity_m0"], gravity_m1=c["gravity_m1"], gravity_m2=c["gravity_m2"],
        position_deadband=_nonneg(where, "controller.position_deadband_deg",
                                  c["position_deadband_deg"]) * DEG,
        inertia_model=c["inertia_model"],
        inertia_update_cycles=c["inertia_update_cycles"],
        joints=joints,
        dither_amplitude=_nonneg(where, "controller.dither_amplitude", c["dither_amplitude"]),
        dither_frequency=_pos(where, "controller.dither_frequency", c["dither_frequency"]),
        dither_wave=c["dither_wave"],
        dither_filter=c["dither_filter"],
        model_coulomb_velocity=_nonneg(where, "controller.model_coulomb_velocity",
                                       c["model_coulomb_velocity"]),
        model_filters=c["model_filters"],
        model_cutoff=_nonneg(where, "controller.model_cutoff", c["model_cutoff"]),
    )
    _need(c["model_filters"] in MODEL_FILTERS, where, "controller.model_filters",
          "one of " + ", ".join(MODEL_FILTERS), c["model_filters"])
    _need(c["dither_wave"] in DITHER_WAVES, where, "controller.dither_wave",
          "one of " + ", ".join(DITHER_WAVES), c["dither_wave"])
    # the frequency matters only with the dither on: with it off (the default) every rate 100..2000 Hz runs
    _need(controller.dither_amplitude == 0 or controller.dither_frequency * DITHER_MIN_CYCLES <= loop.rate_hz,
          where, "controller.dither_frequency", f"at most loop.rate_hz / {DITHER_MIN_CYCLES} "
          f"({loop.rate_hz / DITHER_MIN_CYCLES:g} Hz) with the dither on (dither_amplitude > 0)",
          controller.dither_frequency)
    _need(c["inertia_model"] in INERTIA_MODELS, where, "controller.inertia_model",
          "one of " + ", ".join(INERTIA_MODELS), c["inertia_model"])
    _need(c["inertia_update_cycles"] >= 1, where, "controller.inertia_update_cycles", "at least 1",
          c["inertia_update_cycles"])

    held = {k[: -len("_deg")]: _angle(where, f"held.{k}", k[: -len("_deg")], v)
            for k, v in values["held"].items()}

    s = values["safety"]
    vel = {}
    for name, value in s["velocity_limit"].items():
        vel[name] = _pos(where, f"safety.velocity_limit.{name}", value)
    frac = s["current_fraction"]
    _need(0 < frac <= 1, where, "safety.current_fraction", "in (0, 1]", frac)
    wd = s["watchdog_s"]
    _need(0.02 <= wd <= 2.54, where, "safety.watchdog_s", "between 0.02 and 2.54 s", wd)
    for key in ("error_budget_consecutive", "error_budget_per_second", "hardware_poll_cycles"):
        _need(s[key] >= 1, where, f"safety.{key}", "at least 1", s[key])
    safety = SafetyConfig(
        watchdog_s=wd,
        current_fraction=frac,
        limit_margin=_nonneg(where, "safety.limit_margin_deg", s["limit_margin_deg"]) * DEG,
        limit_stiffness=_nonneg(where, "safety.limit_stiffness", s["limit_stiffness"]),
        limit_damping=_nonneg(where, "safety.limit_damping", s["limit_damping"]),
        limit_overshoot=_nonneg(where, "safety.limit_overshoot_deg", s["limit_overshoot_deg"]) * DEG,
        error_budget_consecutive=s["error_budget_consecutive"],
        error_budget_per_second=s["error_budget_per_second"],
        hardware_poll_cycles=s["hardware_poll_cycles"],
        agree_tolerance=_nonneg(where, "safety.agree_tolerance_deg", s["agree_tolerance_deg"]) * DEG,
        max_start_difference=_pos(where, "safety.max_start_difference_deg",
                                  s["max_start_difference_deg"]) * DEG,
        homing_speed=_pos(where, "safety.homing_speed", s["homing_speed"]),
        velocity_limit=vel,
    )

    o = values["operator"]
    _need(0 < o["duty"] <= 1, where, "operator.duty", "in (0, 1]", o["duty"])
    operator = OperatorConfig(
        duty=o["duty"],
        mean_on_s=_pos(where, "operator.mean_on_s", o["mean_on_s"]),
        min_move_s=_pos(where, "operator.min_move_s", o["min_move_s"]),
        max_move_s=_pos(where, "operator.max_move_s", o["max_move_s"]),
        peak_speed=_pos(where, "operator.peak_speed", o["peak_speed"]),
        workspace_margin=_nonneg(where, "operator.workspace_margin_deg", o["workspace_margin_deg"]) * DEG,
        stiffness=_pos(where, "operator.stiffness", o["stiffness"]),
        damping=_nonneg(where, "operator.damping", o["damping"]),
        max_torque=_pos(where, "operator.max_torque", o["max_torque"]),
        start={k: _angle(where, f"operator.start_deg.{k}", k, v) for k, v in o["start_deg"].items()},
        **_operator_task(o, where),
    )
    slowest = min(vel.values(), default=math.inf)
    _need(safety.homing_speed <= slowest, where, "safety.homing_speed",
          f"at most the smallest safety.velocity_limit ({slowest:g} rad/s)", safety.homing_speed)
    _need(operator.min_move_s <= operator.max_move_s, where, "operator.min_move_s",
          "at most operator.max_move_s", operator.min_move_s)

    bilateral = parse_joints(values["bilateral"]["joints"], f"bilateral.joints in {where}")
    _check_gravity_model(controller.gravity_model, bilateral, where)

    r = values["realtime"]
    _need(r["scheduling"] in SCHEDULING, where, "realtime.scheduling", "one of " + ", ".join(SCHEDULING),
          r["scheduling"])
    _need(1 <= r["priority"] <= 99, where, "realtime.priority", "between 1 and 99", r["priority"])
    _need(r["cpu"] >= -1, where, "realtime.cpu", "a core number, or -1 for the last core", r["cpu"])
    realtime = RealtimeConfig(scheduling=r["scheduling"], priority=r["priority"], pin=r["pin"],
                              cpu=r["cpu"], lock_memory=r["lock_memory"], freeze_gc=r["freeze_gc"])
    return Config(loop=loop, controller=controller, held=held, safety=safety, operator=operator,
                  values=values, realtime=realtime, bilateral=bilateral)


def _check_gravity_model(model: str, bilateral: tuple[str, ...], where: str) -> None:
    """The "coefficients" gravity model (SKL's sines) has terms for joint2 and joint4 only (joint1's
    axis is vertical): with any other bilateral joint that joint's gravity would be missing from its
    reaction force, so the combination is refused."""
    other = [n for n in bilateral if n not in PAPER_JOINTS]
    if model == "coefficients" and other:
        raise ConfigError(f"controller.gravity_model = \"coefficients\" in {where} has no gravity term for "
                          f"{other[0]}; use gravity_model = \"dynamics\" with the bilateral joints "
                          f"{', '.join(bilateral)}")


def _operator_task(o: dict, where: str) -> dict:
    """The [operator] task keys (task, press_*), checked."""
    _need(o["task"] in OPERATOR_TASKS, where, "operator.task", "one of " + ", ".join(OPERATOR_TASKS),
          o["task"])
    _need(0 < o["press_fraction"] < 1, where, "operator.press_fraction", "in (0, 1)", o["press_fraction"])
    keys = ("press_torque_min", "press_torque_max", "press_min_s", "press_max_s")
    out = {k: _pos(where, f"operator.{k}", o[k]) for k in keys}
    _need(out["press_torque_min"] <= out["press_torque_max"], where, "operator.press_torque_min",
          "at most operator.press_torque_max", out["press_torque_min"])
    _need(out["press_min_s"] <= out["press_max_s"], where, "operator.press_min_s",
          "at most operator.press_max_s", out["press_min_s"])
    return {"task": o["task"], "press_fraction": o["press_fraction"], **out}


def _deep_copy(d):
    return {k: _deep_copy(v) if isinstance(v, dict) else v for k, v in d.items()}
