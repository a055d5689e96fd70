"""The paper's preprocessing: raw session signals -> the (down-sampled) Dataset every model sees.

For each session (and each continuous piece of it), at the recording rate:

* dq  = L(D(q))          pseudo-derivative of the angle, low-passed once
* ddq = D(D(q))          pseudo-derivative of the (unfiltered) pseudo-derivative
* q   = L(L(q)),  tau = L(L(tau))   low-passed twice

With the pseudo-differentiation cutoff equal to the low-pass cutoff (25 rad/s, the default) every signal
has gone through exactly two first-order lags, so all four carry the same delay (the paper's reason
for filtering the angle and torque twice). The acceleration is not spelled out in the paper; taking the
second pseudo-derivative of the raw pseudo-derivative is the choice that gives it the same two lags.
Then the first `settle_s` of each piece are dropped (filter start-up), every piece is down-sampled to
`downsample_hz` (the low-pass is the anti-alias filter) and the pieces are concatenated with `segment`
ids (no filter ever runs across a boundary). The dead-zone mask uses sigma_j over all the data.

Offline signals: with the paper's causal filters the Dataset also carries the same rows filtered
zero-phase (`Dataset.offline`, the same settings with `zero_phase`): the model that runs in the loop
keeps the causal chain for its predictions, and a parameter value reported from the recording (which
needs no causal filter) is estimated from the zero-phase signals, whose acceleration is far less noisy
(train.models.rigid_body). Their mask is the causal one and the same threshold on the zero-phase
velocity: the causal velocity lags, so for a few samples after a stop it still says "moving" while the
joint already sticks. The offline Dataset also carries the unfiltered angles of the same rows
(`Dataset.angle`): a regressor column's angle-only part (a cogging ripple's sin(n q)) is filtered from
them as the torque is (train.data.angle_columns), which a fast function of the filtered angle is not.
A joint counts as moving in the offline mask only away from its stops and from the ends of its piece,
whose zero-phase signals mix in the stop; and a torque recorded as the command sent after each read is
centred on the read's instant first (train.data.offline_signals: why, and how).

`PreprocessConfig.arm` names the arm whose group is read ("follower" by default, "leader" for
`crane-train fit --arm leader`); it travels with the other settings into Dataset.meta["preprocessing"]
and so into every saved model (model.json "preprocessing" -> "arm"), which is how the evaluation
commands know which arm to read (`read_preprocessed`).
"""

from __future__ import annotations

from dataclasses import asdict, dataclass, field, fields
from typing import TYPE_CHECKING

import numpy as np

from crane_io.errors import ConfigError

from .angle_columns import AngleRows, AngleSeries
from .data_checks import warn
from .dataset import Dataset
from .filters import lowpass, pseudo_diff
from .masks import DeadZoneError, dead_zone_mask, moving_fractions
from .offline_signals import OFFLINE_REACH_TAUS, command_centred, commanded_columns, near_rest
from .session import ARMS, RawSession, read_sessions

if TYPE_CHECKING:
    from collections.abc import Container, Iterable, Sequence
    from os import PathLike
    from pathlib import Path

# A joint whose (filtered) angle spans less than this never moved: a joint held in position mode only
# jitters by an encoder count or two (0.0015 rad each), and its velocity's spread is that jitter.
MIN_TRAVEL_RAD = 0.01
# the arm joints (joint1..joint7): what `--joints all` means and what may be a context joint; the
# gripper is neither
# (crane_io.physics.arm_model.JOINT_NAMES without the gripper; not imported from there: that imports
# pinocchio)
ARM_JOINTS = ("joint1", "joint2", "joint3", "joint4", "joint5", "joint6", "joint7")


def resolve_joints(joints: str | Iterable[str], available: Container[str] | None = None) -> tuple[str, ...]:
    """Learning joints from a list or comma string; "all" means every arm joint (of `available`, the
    joints a session records, when given)."""
    if isinstance(joints, str):
        joints = [j.strip() for j in joints.split(",") if j.strip()]
    joints = tuple(joints)
    if joints == ("all",):
        return tuple(n for n in ARM_JOINTS if available is None or n in available)
    return joints


@dataclass
class PreprocessConfig:
    cutoff_rad_s: float = 25.0  # low-pass cutoff (paper: 25 rad/s)
    pseudo_diff_rad_s: float = 25.0  # pseudo-differentiation cutoff; equal to cutoff_rad_s for equal delay
    downsample_hz: float = 50.0  # rate of the Dataset (paper: 50 Hz)
    joints: tuple[str, ...] = ("joint1", "joint2", "joint4")  # learning joints (paper: joints 0, 1, 2)
    zero_phase: bool = False  # True: forward-backward filtering, no delay at all (not the paper's)
    alpha: float = 0.1  # dead-zone threshold factor (paper: 0.1)
    settle_s: float = 0.2  # dropped at the start of each piece (5 time constants of 25 rad/s)
    split_gap_s: float = 0.05  # a time step longer than this splits a session into separate pieces
    arm: str = "follower"  # the session group the data come from ("leader" or "follower")
    extra: dict = field(default_factory=dict)  # free-form notes carried into Dataset.meta

    def __post_init__(self):
        self.joints = tuple(self.joints)
        for name in ("cutoff_rad_s", "pseudo_diff_rad_s", "downsample_hz"):
            v = getattr(self, name)
            if not (isinstance(v, (int, float)) and np.isfinite(v) and v > 0):
                raise ConfigError(f"preprocessing {name} must be a positive number, got {v!r}")
        if not self.joints:
            raise ConfigError("at least one learning joint must be selected")
        if self.arm not in ARMS:
            raise ConfigError(f"preprocessing arm must be 'leader' or 'follower', got {self.arm!r}")
        if len(set(self.joints)) != len(self.joints):
            raise ConfigError(f"learning joints are repeated: {', '.join(self.joints)}")

    def to_dict(self) -> dict:
        d = asdict(self)
        d["joints"] = list(self.joints)
        return d

    @classmethod
    def from_dict(cls, data: dict) -> PreprocessConfig:
        known = {f.name for f in fields(cls)}
        unknown = set(data) - known
        if unknown:
            raise ConfigError(f"unknown preprocessing setting(s): {', '.join(sorted(unknown))}")
        return cls(**data)


def _pieces(t: np.ndarray, split_gap_s: float, breaks=()) -> list[slice]:
    """The continuous pieces of a session: cut at time steps longer than split_gap_s and at `breaks` (rows
    where the data checks dropped data or found a jump, RawSession.breaks)."""
    cuts = np.union1d(np.flatnonzero(np.diff(t) > split_gap_s) + 1, np.asarray(breaks, dtype=int))
    bounds = [0, *cuts.tolist(), len(t)]
    return [slice(a, b) for a, b in zip(bounds[:-1], bounds[1:])]


def _downsample(t, arrays, rate_hz, target_hz):
    ratio = rate_hz / target_hz
    if ratio < 1 + 1e-9:
        return t, arrays
    step = int(round(ratio))
    if abs(ratio - step) < 1e-6:
        return t[::step], [a[::step] for a in arrays]
    grid = np.arange(t[0], t[-1], 1.0 / target_hz)
    return grid, [np.stack([np.interp(grid, t, a[:, j]) for j in range(a.shape[1])], axis=1) for a in arrays]


def filter_signals(q: np.ndarray, tau: np.ndarray, rate_hz: float, config: PreprocessConfig
                   ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """(q rad, dq rad/s, ddq rad/s^2, tau N m), each (N, J), filtered at the recording rate `rate_hz` (Hz),
    all with the same delay; from positions `q` (N, J) rad and torques `tau` (N, J) N m."""
    c, g, zp = config.cutoff_rad_s, config.pseudo_diff_rad_s, config.zero_phase
    dq_raw = pseudo_diff(q, g, rate_hz, zp)
    dq = lowpass(dq_raw, c, rate_hz, zp)
    ddq = pseudo_diff(dq_raw, g, rate_hz, zp)
    qf = lowpass(lowpass(q, c, rate_hz, zp), c, rate_hz, zp)
    tauf = lowpass(lowpass(tau, c, rate_hz, zp), c, rate_hz, zp)
    return qf, dq, ddq, tauf


def _with_all_joints(config: PreprocessConfig, sessions: list[RawSession]) -> PreprocessConfig:
    """`joints` all made the arm joints every session records."""
    values = config.to_dict()
    values["joints"] = tuple(n for n in ARM_JOINTS if all(n in s.joint_names for s in sessions))
    if not values["joints"]:
        raise ConfigError("`joints` all: the sessions have no arm joint (joint1..joint7) in common")
    return PreprocessConfig.from_dict(values)


def _check_session(s: RawSession, config: PreprocessConfig) -> None:
    """The session is of the configured arm and records the configured joints."""
    if s.arm != config.arm:
        raise ConfigError(f"{s.path or 'the session'} was read from the {s.arm}'s data but the "
                          f"preprocessing settings are for the {config.arm}'s")
    missing = [n for n in config.joints if n not in s.joint_names]
    if missing:
        raise ConfigError(f"{s.path or 'the session'} has no joint(s) {', '.join(missing)} "
                          f"(it has {', '.join(s.joint_names)})")


def _filtered_piece(s: RawSession, piece, cols: list[int], ccols: list[int], settle: int,
                    config: PreprocessConfig) -> tuple:
    """(t, q, dq, ddq, tau, cq, cdq, cddq) of one continuous piece: filtered, settled, down-sampled, the
    learning joints' columns apart from the context joints'; with `config.zero_phase` False these are
    followed by the same seven signals filtered zero-phase (`offline_config`) and the unfiltered angles
    (learning, context joints) at the same rows (train.data.angle_columns)."""
    J = len(cols)
    t, q, tau = s.t[piece], s.q[piece][:, cols + ccols], s.tau[piece][:, cols]
    configs = [config] if config.zero_phase else [config, offline_config(config)]
    torques = [tau] if config.zero_phase else [tau, command_centred(tau, commanded_columns(s, cols))]
    signals = [a for c, torque in zip(configs, torques) for a in filter_signals(q, torque, s.rate_hz, c)]
    if not config.zero_phase:
        signals.append(q)
    keep = slice(settle, None)
    t, signals = _downsample(t[keep], [a[keep] for a in signals], s.rate_hz, config.downsample_hz)
    out = [t]
    for q, dq, ddq, tau in zip(*[iter(signals[:len(configs) * 4])] * 4):
        out += [q[:, :J], dq[:, :J], ddq[:, :J], tau, q[:, J:], dq[:, J:], ddq[:, J:]]
    if not config.zero_phase:
        out += [signals[-1][:, :J], signals[-1][:, J:]]
    return tuple(out)


def offline_config(config: PreprocessConfig) -> PreprocessConfig:
    """The same settings with zero-phase filtering: the offline signals of a Dataset (Dataset.offline),
    for estimates that need no causal filter."""
    values = config.to_dict()
    values["zero_phase"] = True
    return PreprocessConfig.from_dict(values)


def _too_short(sessions: list[RawSession], config: PreprocessConfig, longest: float) -> ConfigError:
    need = config.settle_s + 2.0 / config.downsample_hz
    names = ", ".join(str(x.path or "the session") for x in sessions)
    verb, its = ("is", "its") if len(sessions) == 1 else ("are", "their")
    return ConfigError(f"{names} {verb} too short to preprocess: {its} longest continuous piece lasts "
                       f"{longest:.2g} s, and more than {need:.2g} s are needed (the "
                       f"{config.settle_s:g} s the filters settle in, plus two output samples)")


def _check_travel(q: np.ndarray, joints: Sequence[str]) -> None:
    """Every learning joint moves beyond MIN_TRAVEL_RAD in the data."""
    for name, span in zip(joints, np.ptp(q, axis=0)):
        if span < MIN_TRAVEL_RAD:  # its velocity is jitter, which the mask would call motion
            raise DeadZoneError(f"{name} never moves in the data (its angle stays within "
                                f"{np.degrees(span):.2g} deg), so it cannot be learned; record motion of it "
                                f"or leave it out with `joints`")


def preprocess(sessions: list[RawSession] | RawSession, config: PreprocessConfig | None = None) -> Dataset:
    """Filter, down-sample, concatenate (with segment ids) and mask one or more sessions."""
    config = config or PreprocessConfig()
    if isinstance(sessions, RawSession):
        sessions = [sessions]
    if config.joints == ("all",):  # every arm joint all the sessions record
        config = _with_all_joints(config, sessions)
    keys = ("t", "q", "dq", "ddq", "tau", "cq", "cdq", "cddq", "oq", "odq", "oddq", "otau", "ocq", "ocdq",
            "ocddq", "rq", "rcq")
    parts = {k: [] for k in (*keys, "segment")}
    # context joints: the other arm joints every session records (their recorded angles enter the
    # rigid-body model's kinematics); filtered together with the learning joints, column by column
    context = [n for n in ARM_JOINTS if n not in config.joints
               and all(n in s.joint_names for s in sessions)]
    seg = 0
    dropped = 0
    longest = 0.0  # s, of the pieces too short to use
    for s in sessions:
        _check_session(s, config)
        cols = [s.joint_names.index(n) for n in config.joints]
        ccols = [s.joint_names.index(n) for n in context]
        settle = int(round(config.settle_s * s.rate_hz))
        for piece in _pieces(s.t, config.split_gap_s, s.breaks):
            n = len(s.t[piece])
            if n <= settle + 2 * s.rate_hz / config.downsample_hz:
                dropped += 1
                longest = max(longest, n / s.rate_hz)
                continue
            values = _filtered_piece(s, piece, cols, ccols, settle, config)
            for k, v in zip(keys, values):
                parts[k].append(v)
            parts["segment"].append(np.full(len(values[0]), seg, dtype=int))
            seg += 1
    if not parts["t"]:
        raise _too_short(sessions, config, longest)
    cat = {k: np.concatenate(v) for k, v in parts.items() if v}
    _check_travel(cat["q"], config.joints)
    moving, sigma = dead_zone_mask(cat["dq"], config.alpha, joint_names=config.joints)
    rate = min(config.downsample_hz, min(s.rate_hz for s in sessions))
    meta = {"preprocessing": config.to_dict(), "sigma": sigma.tolist(), "alpha": config.alpha,
            "sources": [s.path for s in sessions], "source_kinds": [s.source for s in sessions],
            "raw_rate_hz": [s.rate_hz for s in sessions], "arm": config.arm, "pieces_dropped": dropped,
            "usable_fraction": moving_fractions(moving, config.joints), "context_joints": list(context),
            "data_checks": [f.to_dict() for s in sessions for f in s.findings]}
    offline, zp = None, offline_config(config).to_dict()
    if "oq" in cat:  # the same rows filtered zero-phase; a joint moves where both velocities say so
        omoving = moving & (np.abs(cat["odq"]) > config.alpha * sigma[None, :])
        reach = OFFLINE_REACH_TAUS / config.cutoff_rad_s * rate
        omoving &= ~near_rest(~omoving, cat["segment"], reach)
        offline = Dataset(joint_names=tuple(config.joints), t=cat["t"], q=cat["oq"], dq=cat["odq"],
                          ddq=cat["oddq"], tau=cat["otau"], moving=omoving, rate_hz=float(rate),
                          segment=cat["segment"], meta={**meta, "preprocessing": zp},
                          context_names=tuple(context), context_q=cat["ocq"], context_dq=cat["ocdq"],
                          context_ddq=cat["ocddq"], angle=_angle_rows(cat, float(rate), config))
    return Dataset(joint_names=tuple(config.joints), t=cat["t"], q=cat["q"], dq=cat["dq"], ddq=cat["ddq"],
                   tau=cat["tau"], moving=moving, rate_hz=float(rate), segment=cat["segment"], meta=meta,
                   context_names=tuple(context), context_q=cat["cq"], context_dq=cat["cdq"],
                   context_ddq=cat["cddq"], offline=offline)


def _angle_rows(cat: dict, rate_hz: float, config: PreprocessConfig) -> AngleRows:
    """Every row of the unfiltered angle series, with the torque's filter (train.data.angle_columns)."""
    series = AngleSeries(t=cat["t"], q=cat["rq"], context_q=cat["rcq"] if cat["rcq"].shape[1] else None,
                         segment=cat["segment"], rate_hz=rate_hz, cutoff_rad_s=config.cutoff_rad_s)
    return AngleRows(series, np.arange(len(cat["t"])))


def read_preprocessed(paths: Path | str | Sequence[str | PathLike[str]], config: PreprocessConfig,
                      hand_free: bool = True) -> Dataset:
    """Read the sessions' `config.arm` group and preprocess it. With `hand_free` (the default: fitting
    and evaluating an inverse-dynamics model), a session whose arm the operator's hand moved is refused
    (train.data.session.HandOnArmError). What the data checks found is issued as DataCheckWarning
    (train.data.data_checks) and kept in meta["data_checks"]."""
    ds = preprocess(read_sessions(paths, config.arm, hand_free=hand_free), config)
    warn(ds.meta["data_checks"])
    return ds
