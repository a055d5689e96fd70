"""The crane-session file format (HDF5), declared once: names, dtypes, shapes, units, attributes.

The writer (collect/recorder.py), the readers (train/data/session.py, train/evaluation/fidelity.py), the tools
that copy or recover a session (collect/recovery.py, collect/session_copy.py), the importer
(train/data/importer.py) and the docs test (tests/test_session_format.py, which checks README.md's section
"The session file" against this module, both ways) all take the format's names from here. collect and
train both depend on crane_io and never on each other, so the format lives here.

A session file holds:

* root attributes: the required ones (`REQUIRED_ROOT`), which every reader insists on, and the
  optional ones crane-collect writes (`OPTIONAL_ROOT`); `crane-train import` adds `IMPORT_ROOT`
  (documented in docs/train.md);
* one group per arm (`ARMS`) with the per-cycle members `ARM_MEMBERS`; `/follower/t`, `/follower/q`
  and `/follower/tau` (`REQUIRED_MEMBERS`) are the contract's minimum;
* `/timing/` with the per-cycle loop timing `TIMING_MEMBERS` and the loop's summary as attributes
  (`TIMING_SUMMARY_ATTRS`, `TIMING_REALTIME_ATTRS`, `lockstep`);
* `/events`, a resizable 1-D dataset of `EVENT_DTYPE` (fixed-length UTF-8 byte strings: SWMR cannot
  append variable-length data).

The writing constants (`FILTERS`, the chunk length in seconds, the events' chunk, the fill values) are
part of the format too: a reader may rely on the fletcher32 checksums and the NaN fill.

The simulated plants' true external torques go to a file of their own, format "crane-truth-trace"
(`TRUTH_TRACE_*`), never into the session.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

FORMAT = "crane-session"
FORMAT_VERSION = 1  # the version written, and the newest one the readers understand

ARMS = ("leader", "follower")
REQUIRED_ARM = "follower"  # the arm whose t, q and tau every session must hold
TIMING = "timing"  # the group of per-cycle loop timing
EVENTS = "events"  # the root dataset of events


@dataclass(frozen=True)
class Attribute:
    """A root (or group) attribute: `kind` as the README's tables write it ("str", "int", "float",
    "bool", "str array (J,)", ...), `unit` where it has one, `json_keys` for a str attribute that holds
    a JSON object (its documented keys)."""

    name: str
    kind: str
    meaning: str
    unit: str = ""
    json_keys: tuple[str, ...] = ()


@dataclass(frozen=True)
class Member:
    """A per-cycle dataset: (N,) or, `per_joint`, (N, J) with one column per `joint_names` entry."""

    name: str
    dtype: type
    per_joint: bool
    unit: str
    meaning: str

    @property
    def shape(self) -> str:
        """The shape as the README's tables write it."""
        return "(N, J)" if self.per_joint else "(N,)"

    def row_shape(self, joints: int) -> tuple:
        """The shape of one row for `joints` columns: (J,) or ()."""
        return (joints,) if self.per_joint else ()


# -- root attributes -------------------------------------------------------------------------------------
FORMAT_ATTR, VERSION_ATTR, RATE_ATTR, JOINT_NAMES_ATTR, SOURCE_ATTR = (
    "format", "format_version", "rate_hz", "joint_names", "source")
COMPLETE_ATTR, END_REASON_ATTR, RATE_ACHIEVED_ATTR = "complete", "end_reason", "rate_hz_achieved"
REQUIRED_ROOT = (
    Attribute(FORMAT_ATTR, "str", f'"{FORMAT}"'),
    Attribute(VERSION_ATTR, "int", str(FORMAT_VERSION)),
    Attribute(RATE_ATTR, "float", "nominal sample rate of the recording (the control rate)", "Hz"),
    Attribute(JOINT_NAMES_ATTR, "str array (J,)", "name of each column of the (N, J) datasets"),
    Attribute(SOURCE_ATTR, "str", '"hardware", "sim", or another word naming the rig'),
)
REQUIRED_ATTRS = tuple(a.name for a in REQUIRED_ROOT)

MODEL_JSON_KEYS = ("path", "method", "effects", "joints", "fitted_on", "sha256", "filters", "cutoff_rad_s",
                   "pseudo_diff_rad_s")
CALIBRATION_JSON_KEYS = ("name", "key", "created", "path", "offsets_rad")
TAU_FROM_GOAL, TAU_FROM_PRESENT = "goal_current", "present_current"  # bilateral joints; held joints
TAU_SOURCES = (TAU_FROM_GOAL, TAU_FROM_PRESENT)  # crane-collect's values of `tau_source`
NOMINAL_MODEL = "nominal"  # `leader_model` / `follower_model` of an observer on the nominal model
HAND_ON = "hand_on"
DEFAULT_HAND_ON = "leader"  # a session without `hand_on`: the operator moved the leader (normal use)
END_REASONS = ("duration", "interrupted", "terminated", "safety_stop", "error", "crashed")

TAU_SOURCE_ATTR, TORQUE_CONSTANTS_ATTR = "tau_source", "torque_constants"
SERVO_IDS_ATTR, SERVO_MODELS_ATTR, FIRMWARE_ATTR = "servo_ids", "servo_models", "firmware_versions"
BILATERAL_JOINTS_ATTR, SOFTWARE_VERSION_ATTR, START_TIME_ATTR = (
    "bilateral_joints", "software_version", "start_time")
CONFIG_TOML_ATTR, SEED_ATTR, GRAVITY_MODEL_ATTR, LOCKSTEP_ATTR = (
    "config_toml", "seed", "gravity_model", "lockstep")
ARM_MODEL_TOML_ATTR = "arm_model_toml"


def model_attr(arm: str) -> str:
    """The root attribute naming the model in `arm`'s reaction-force observer ("leader_model", ...)."""
    return f"{arm}_model"


def calibration_attr(arm: str) -> str:
    """The root attribute holding `arm`'s calibration ("leader_calibration", ...)."""
    return f"{arm}_calibration"


def firmware_attr(arm: str) -> str:
    """The root attribute holding `arm`'s firmware versions ("leader_firmware_versions", ...)."""
    return f"{arm}_firmware_versions"


OPTIONAL_ROOT = (
    Attribute(TAU_SOURCE_ATTR, "str array (J,)", "per column: what tau was made of (TAU_SOURCES)"),
    Attribute(TORQUE_CONSTANTS_ATTR, "float (J,)", "the torque constants used for tau", "N m/A"),
    Attribute(SERVO_IDS_ATTR, "int (J,)", "servo ID of each column"),
    Attribute(SERVO_MODELS_ATTR, "str (J,)", "servo model of each column as the follower reported it"),
    Attribute(FIRMWARE_ATTR, "int (J,)", "the follower's firmware versions"),
    Attribute(firmware_attr("leader"), "int (J,)", "the leader's firmware versions"),
    Attribute(firmware_attr("follower"), "int (J,)", "the follower's firmware versions"),
    Attribute(BILATERAL_JOINTS_ATTR, "str array", "the joints under bilateral control"),
    Attribute(SOFTWARE_VERSION_ATTR, "str", "the crane-x7 version that wrote the file"),
    Attribute(START_TIME_ATTR, "str", "ISO 8601, UTC"),
    Attribute(CONFIG_TOML_ATTR, "str", "the complete configuration used, as TOML"),
    Attribute(ARM_MODEL_TOML_ATTR, "str", '"" or the identified arm model of the nominal observers, as TOML'),
    Attribute(RATE_ACHIEVED_ATTR, "float", "NaN until the recording ends", "Hz"),
    Attribute(COMPLETE_ATTR, "bool", "False while recording, True after a clean end"),
    Attribute(SEED_ATTR, "int", "the simulation's seed (sim only)"),
    Attribute(HAND_ON, "str", '"leader" or "follower": the arm the operator\'s hand moved'),
    Attribute(model_attr("leader"), "str", '"nominal" or the JSON of the model in the leader\'s observer',
              json_keys=MODEL_JSON_KEYS),
    Attribute(model_attr("follower"), "str", '"nominal" or the JSON of the model in the follower\'s observer',
              json_keys=MODEL_JSON_KEYS),
    Attribute(calibration_attr("leader"), "str", '"" or the JSON of the leader\'s calibration',
              json_keys=CALIBRATION_JSON_KEYS),
    Attribute(calibration_attr("follower"), "str", '"" or the JSON of the follower\'s calibration',
              json_keys=CALIBRATION_JSON_KEYS),
    Attribute(END_REASON_ATTR, "str", "why the recording ended; \"\" while recording"),
    Attribute(GRAVITY_MODEL_ATTR, "str", "the reaction-force observer's gravity model"),
    Attribute(LOCKSTEP_ATTR, "bool", "simulated faster than real time"),
)
OPTIONAL_ATTRS = tuple(a.name for a in OPTIONAL_ROOT)

IMPORT_ROOT = (  # written by `crane-train import` (docs/train.md)
    Attribute("imported_from", "str", "the input file's name"),
    Attribute("import_map", "str", "the column map used (KEY=COLUMN pairs), as JSON"),
    Attribute("import_units", "str", "the input's units, as JSON"),
    Attribute("import_time_offset_s", "float", "the input's first time (subtracted)", "s"),
)

EXCITATION_ATTR, EXCITATION_ARM_ATTR, EXCITATION_TRAJECTORY_ATTR, EXCITATION_START_ATTR = (
    "excitation", "excitation_arm", "excitation_trajectory", "excitation_start_s")
EXCITATION_ROOT = (  # written by `crane-collect excite` (docs/excitation.md)
    Attribute(EXCITATION_ATTR, "bool", "True: excitation data (one arm ran an exciting trajectory alone)"),
    Attribute(EXCITATION_ARM_ATTR, "str", '"leader" or "follower": the arm that ran the trajectory'),
    Attribute(EXCITATION_TRAJECTORY_ATTR, "str", "the trajectory's JSON (physics/excitation_trajectory)"),
    Attribute(EXCITATION_START_ATTR, "float", "session time the trajectory starts (after the approach)", "s"),
)

# -- per-arm members (creation order is the order here) --------------------------------------------------
T, Q, TAU, CURRENT, DQ, TAU_RES = "t", "q", "tau", "current", "dq", "tau_res"
DQ_SERVO, GOAL_CURRENT, TAU_DIS, Q_GOAL = "dq_servo", "goal_current", "tau_dis", "q_goal"
ARM_MEMBERS = (
    Member(T, np.float64, False, "s", "time of each sample since the start of the recording"),
    Member(Q, np.float64, True, "rad", "joint angle (servo position)"),
    Member(TAU, np.float64, True, "N m", "joint torque commanded"),
    Member(DQ_SERVO, np.float32, True, "rad/s", "servo-reported Present Velocity"),
    Member(CURRENT, np.float32, True, "A", "servo-reported Present Current"),
    Member(GOAL_CURRENT, np.float32, True, "A", "Goal Current written"),
    Member(DQ, np.float32, True, "rad/s", "the controller's pseudo-derivative velocity"),
    Member(TAU_DIS, np.float32, True, "N m", "disturbance-observer estimate"),
    Member(TAU_RES, np.float32, True, "N m", "reaction-force-observer estimate"),
    Member(Q_GOAL, np.float32, True, "rad", "goal position of held joints"),
)
ARM_MEMBER = {m.name: m for m in ARM_MEMBERS}
REQUIRED_MEMBERS = (T, Q, TAU)

# -- /timing ---------------------------------------------------------------------------------------------
CYCLE_START = "cycle_start"  # the time of the timing rows, as t is the arms'
PERIOD, COMPUTE_TIME, OVERRUN = "period", "compute_time", "overrun"


def bus_time(arm: str) -> str:
    """The /timing member of `arm`'s bus time ("bus_time_leader", ...)."""
    return f"bus_time_{arm}"


TIMING_MEMBERS = (
    Member(CYCLE_START, np.float64, False, "s", "monotonic since start"),
    Member(PERIOD, np.float32, False, "s", "since the previous cycle"),
    Member(bus_time("leader"), np.float32, False, "s", "spent in read+write on the leader's bus"),
    Member(bus_time("follower"), np.float32, False, "s", "spent in read+write on the follower's bus"),
    Member(COMPUTE_TIME, np.float32, False, "s", "spent computing the cycle"),
    Member(OVERRUN, np.bool_, False, "", "the cycle missed its deadline"),
)
TIMING_MEMBER = {m.name: m for m in TIMING_MEMBERS}
# the loop's sections (collect/pacing.py's CycleTimer times these) and its summary, /timing attributes
TIMING_SECTIONS = ("bus_leader", "bus_follower", "compute", "record")
TIMING_SUMMARY_ATTRS = ("cycles", "overruns", "skipped_deadlines", "nominal_period_s", "period_mean_s",
                        "period_std_s", "period_p99_s", "period_max_s", "rate_hz",
                        *(f"{s}_{w}_s" for s in TIMING_SECTIONS for w in ("mean", "max")))
# what a paced loop asked the operating system for and was granted (collect/realtime.py)
(REALTIME_SCHEDULING_ATTR, REALTIME_PRIORITY_ATTR, REALTIME_FIFO_ATTR, REALTIME_MEMORY_LOCKED_ATTR,
 REALTIME_CPU_ATTR, REALTIME_GC_FROZEN_ATTR, REALTIME_REFUSED_ATTR) = TIMING_REALTIME_ATTRS = (
    "realtime_scheduling", "realtime_priority", "realtime_fifo", "realtime_memory_locked", "realtime_cpu",
    "realtime_gc_frozen", "realtime_refused")
TIMING_LOCKSTEP = LOCKSTEP_ATTR

# -- /events ---------------------------------------------------------------------------------------------
EVENT_WIDTHS = {"kind": 24, "joint": 16, "message": 240}  # bytes of UTF-8
EVENT_DTYPE = np.dtype([("t", "<f8"), ("kind", f"S{EVENT_WIDTHS['kind']}"),
                        ("joint", f"S{EVENT_WIDTHS['joint']}"), ("message", f"S{EVENT_WIDTHS['message']}")])
EVENT_CHUNK_ROWS = 64
EVENT_KINDS = ("start", "warning", "comm_error", "safety_stop", "interrupted", "error", "end", "torque_state",
               "model_fallback", "model_resumed", "recovered")

# -- writing rules ---------------------------------------------------------------------------------------
FILTERS = {"compression": "gzip", "compression_opts": 1, "shuffle": True, "fletcher32": True}
CHUNK_S = 0.5  # a chunk of the per-cycle datasets holds this much recorded time
MAX_UNSAVED_S = 0.9  # in real time, a partly filled chunk is written when its oldest row is this old
COMPACT_ABOVE = 0.15  # rewrite the closed file when superseded chunks exceed this fraction of it


def fill_value(dtype):
    """The fill value of a per-cycle dataset: NaN for floats, 0 otherwise."""
    return np.nan if np.issubdtype(dtype, np.floating) else 0


def arm_path(arm: str, member: str) -> str:
    """"follower/q" and the like."""
    return f"{arm}/{member}"


def timing_path(member: str) -> str:
    """"timing/period" and the like."""
    return f"{TIMING}/{member}"


# -- the truth trace: a file of its own (collect/truth_trace.py) -----------------------------------------
TRUTH_TRACE_FORMAT = "crane-truth-trace"
TRUTH_TRACE_VERSION = 1
TRUTH_TRACE_T = "t"
TRUTH_TRACE_TAU_EXT = "tau_ext"
TRUTH_TRACE_LEADER_TAU_EXT = "leader/tau_ext"
TRUTH_TRACE_IN_CONTACT = "in_contact"
