"""How faithful was a bilateral session's force channel? (`crane-train fidelity`.)

The reaction-force observer of each arm estimates the torque the world puts on it with the observer's
sign (a hand pushing a joint positive gives tau_res < 0: tau_res estimates -tau_ext). What it gets
wrong is what a better model in the loop buys back:

* in free motion (the follower touches nothing) every N m of the follower's tau_res is false force
  the operator feels (`follower_false_rms`), split into the samples where the joint moves and where it
  stands still by the paper's dead-zone rule on the follower's velocity, |dq| > alpha std(dq) with
  alpha = 0.1 (`..._moving`, `..._still`): standing still, the torque that held the joint lies anywhere
  in its static-friction band, which no model of (q, dq, ddq) can tell from an outside force; the
  leader's tau_res there is the hand's torque plus the leader's own model error (`leader_rms`), and
  with the truth known `leader_hand_error_rms` = RMS(leader tau_res + leader tau_ext) is the error of
  the hand-torque estimate alone and `hand_true_rms` = RMS(leader tau_ext) is the torque the hand
  really pushed with;
* in contact, `contact_error_rms` = RMS(follower tau_res + tau_ext) is the error of the contact
  estimate (zero when tau_res = -tau_ext), against `contact_true_rms` = RMS(tau_ext);
* over all kept samples, `force_sum_rms` = RMS(leader tau_res + follower tau_res) (the 4-channel
  force law drives it to zero) and `tracking_rms` = RMS(leader q - follower q).

Per bilateral joint (those whose observers ran: tau_res finite on both arms), after dropping the first
`settle_s`. "Free" samples are those farther than `contact_guard_s` from any contact sample; the contact
samples and the true torques come from a truth trace (`crane-collect run --sim --truth-trace T.h5`),
without which every sample counts as free. Files are opened read-only and never modified; every
problem is one sentence (a CraneError).
"""

from __future__ import annotations

import json
from dataclasses import dataclass, field
from pathlib import Path

import h5py
import numpy as np

from crane_io import session_format as sf
from crane_io.errors import CraneError, SessionFileError
from crane_io.h5check import member
from crane_io.session_format import TRUTH_TRACE_FORMAT as TRUTH_FORMAT
from crane_io.session_format import TRUTH_TRACE_VERSION as TRUTH_FORMAT_VERSION

from ..data.session import _open, _read, check_version, read_session
from ..data.session_check import check_format_attr, check_joint_names, dataset, open_checked, read_attrs

NOMINAL = "nominal model"
DEAD_ZONE_ALPHA = 0.1  # a joint moves when |dq| > alpha std(dq) (the paper's dead-zone rule)
T_TOLERANCE_S = 1e-6  # the trace's t must equal the session's follower/t within this


class FidelityError(CraneError):
    """A session and truth trace that cannot be measured together (another session, no bilateral joint)."""


@dataclass
class Fidelity:
    session: str
    truth_trace: str | None
    settle_s: float
    contact_guard_s: float
    joints: dict  # joint name -> {metric: value (None when there were no samples for it)}
    samples: int  # kept after the settle time
    free_samples: int
    contact_samples: int
    rate_hz: float
    models: dict  # arm -> the model in its loop (the session's JSON attribute, decoded) or "nominal model"
    notes: list[str] = field(default_factory=list)

    @property
    def contact_s(self) -> float:
        return self.contact_samples / self.rate_hz

    @property
    def free_s(self) -> float:
        return self.free_samples / self.rate_hz

    def to_json(self) -> dict:
        return {"session": self.session, "truth_trace": self.truth_trace, "settle_s": self.settle_s,
                "contact_guard_s": self.contact_guard_s, "samples": self.samples,
                "free_samples": self.free_samples, "free_s": self.free_s,
                "contact_samples": self.contact_samples, "contact_s": self.contact_s,
                "models": self.models, "joints": self.joints, "notes": self.notes}


@dataclass
class _Trace:
    t: np.ndarray
    tau_ext: np.ndarray  # (N, J) follower, world on the arm
    leader_tau_ext: np.ndarray | None  # (N, J) leader (the hand), or None when the trace lacks it
    in_contact: np.ndarray  # (N,) bool


def _rms(x: np.ndarray) -> float | None:
    return float(np.sqrt(np.mean(np.square(x)))) if len(x) else None


def _model_attr(attrs: dict, arm: str):
    value = attrs.get(sf.model_attr(arm))
    if value in (None, ""):
        return NOMINAL
    try:
        return json.loads(value)
    except (TypeError, ValueError):
        return str(value)


def _arm_member(path: Path, f: h5py.File, arm: str, key: str, n: int, joints: int) -> np.ndarray:
    name = sf.arm_path(arm, key)
    ds = dataset(path, f, name, joints, required=False)
    if ds is None:
        raise SessionFileError(f"{path} has no /{name} dataset, so its force channel cannot be measured")
    if ds.shape[0] < n:
        raise SessionFileError(f"{path}: /{name} has shape {ds.shape}, expected ({n}, {joints})")
    return _read(path, ds, n)


def _read_trace(path: Path, joint_names: tuple[str, ...]) -> _Trace:
    f = open_checked(path, "truth trace", "a truth trace")
    with f:
        attrs = read_attrs(path, f)
        check_format_attr(path, attrs, TRUTH_FORMAT, "a truth trace")
        check_version(path, attrs, TRUTH_FORMAT, TRUTH_FORMAT_VERSION)
        if sf.JOINT_NAMES_ATTR not in attrs:
            raise SessionFileError(f"{path} lacks the required attribute {sf.JOINT_NAMES_ATTR}")
        names = check_joint_names(path, attrs)
        if names != tuple(joint_names):
            raise FidelityError(f"{path} names the joints {', '.join(map(str, names))} but the session has "
                                f"{', '.join(joint_names)}; it is the truth trace of another session")
        j = len(joint_names)
        t_key, ext_key, leader_key, contact_key = (sf.TRUTH_TRACE_T, sf.TRUTH_TRACE_TAU_EXT,
                                                   sf.TRUTH_TRACE_LEADER_TAU_EXT, sf.TRUTH_TRACE_IN_CONTACT)
        sets = {t_key: dataset(path, f, t_key), ext_key: dataset(path, f, ext_key, j),
                contact_key: member(path, f, contact_key),
                leader_key: dataset(path, f, leader_key, j, required=False)}
        contact = sets[contact_key]
        if contact is None:
            raise SessionFileError(f"{path} lacks the dataset /{contact_key} of a truth trace")
        if contact.dtype.kind not in "biu" or contact.ndim != 1:
            raise SessionFileError(f"{path}: /{contact_key} has shape {contact.shape} and type "
                                   f"{contact.dtype}, expected flags of shape (N,)")
        n = min(ds.shape[0] for ds in sets.values() if ds is not None)
        t = _read(path, sets[t_key], n)
        tau_ext = _read(path, sets[ext_key], n)
        leader = _read(path, sets[leader_key], n) if sets[leader_key] is not None else None
        in_contact = _read(path, contact, n) != 0
    return _Trace(t, tau_ext, leader, in_contact)


def _near_contact(t: np.ndarray, contact: np.ndarray, guard_s: float) -> np.ndarray:
    """(N,) bool: within guard_s of some contact sample (the contact samples included)."""
    times = t[contact]
    if not len(times):
        return np.zeros(len(t), bool)
    i = np.clip(np.searchsorted(times, t), 1, len(times)) - 1
    j = np.clip(i + 1, 0, len(times) - 1)
    nearest = np.minimum(np.abs(t - times[i]), np.abs(t - times[j]))
    return nearest <= guard_s + 1e-12


def _check_times(settle_s: float, contact_guard_s: float) -> None:
    if not (np.isfinite(settle_s) and settle_s >= 0):
        raise FidelityError(f"the settle time must be a number of seconds >= 0, got {settle_s!r}")
    if not (np.isfinite(contact_guard_s) and contact_guard_s >= 0):
        raise FidelityError(f"the contact guard must be a number of seconds >= 0, got {contact_guard_s!r}")


def _aligned_trace(tpath: Path, path: Path, names, t: np.ndarray, notes: list) -> tuple[_Trace, int]:
    """The truth trace and the number of rows it shares with the session (whose times it must match)."""
    n = len(t)
    trace = _read_trace(tpath, names)
    m = min(n, len(trace.t))
    if len(trace.t) != n:
        notes.append(f"the truth trace has {len(trace.t)} rows and the session {n}: the first {m} "
                     f"(the common part) are used.")
    off = np.abs(trace.t[:m] - t[:m]) > T_TOLERANCE_S
    if off.any():
        row = int(np.argmax(off))
        raise FidelityError(f"{tpath} is not the truth trace of {path}: its t differs from the "
                            f"session's follower/t (first at row {row}: {trace.t[row]:.6g} s against "
                            f"{t[row]:.6g} s)")
    return trace, m


def _sample_classes(trace: _Trace | None, keep: np.ndarray, t: np.ndarray, contact_guard_s: float,
                    notes: list) -> tuple:
    """(contact, free, tau_ext, leader tau_ext): the samples in contact and in free motion, and the true
    external torques (None where unknown)."""
    n = len(t)
    if trace is None:
        notes.append("no truth trace: every sample counts as free motion (contact, if any, is not told "
                     "apart) and the estimates' errors against the true torques are not measured.")
        return np.zeros(n, bool), keep, None, None
    contact = keep & trace.in_contact[:n]
    free = keep & ~_near_contact(t, trace.in_contact[:n], contact_guard_s)
    ext_l = trace.leader_tau_ext[:n] if trace.leader_tau_ext is not None else None
    if ext_l is None:
        notes.append("the truth trace has no /leader/tau_ext: the hand-torque error is not measured.")
    return contact, free, trace.tau_ext[:n], ext_l


def _joint_metrics(j: int, keep, free, contact, r_l, r_f, q_l, q_f, dq_f, ext, ext_l) -> dict:
    """The force-channel metrics of joint column j."""
    v = dq_f[keep, j]
    moving = np.abs(dq_f[:, j]) > DEAD_ZONE_ALPHA * (np.std(v) if len(v) else 0.0)
    m = {"follower_false_rms": _rms(r_f[free, j]),
         "follower_false_rms_moving": _rms(r_f[free & moving, j]),
         "follower_false_rms_still": _rms(r_f[free & ~moving, j]),
         "moving_fraction": float(moving[free].mean()) if free.any() else None,
         "leader_rms": _rms(r_l[free, j])}
    if ext_l is not None:
        m["leader_hand_error_rms"] = _rms(r_l[free, j] + ext_l[free, j])
        m["hand_true_rms"] = _rms(ext_l[free, j])
    if ext is not None:
        err, true = _rms(r_f[contact, j] + ext[contact, j]), _rms(ext[contact, j])
        m.update(contact_error_rms=err, contact_true_rms=true,
                 contact_error_ratio=err / true if err is not None and true else None)
    track = _rms(q_l[keep, j] - q_f[keep, j])
    m.update(force_sum_rms=_rms(r_l[keep, j] + r_f[keep, j]), tracking_rms=track,
             tracking_rms_deg=float(np.degrees(track)))
    return m


def measure_fidelity(session: Path | str, truth_trace: Path | str | None = None, settle_s: float = 1.0,
                     contact_guard_s: float = 0.3) -> Fidelity:
    """The force-channel metrics of one bilateral session (see the module docstring)."""
    _check_times(settle_s, contact_guard_s)
    path = Path(session)
    fol = read_session(path, "follower")
    lead = read_session(path, "leader")
    names = fol.joint_names
    n = min(len(fol), len(lead))
    notes = []
    if len(fol) != len(lead):
        notes.append(f"the leader has {len(lead)} rows and the follower {len(fol)}: the first {n} are used.")
    with _open(path) as f:
        res = {arm: _arm_member(path, f, arm, sf.TAU_RES, n, len(names)) for arm in sf.ARMS}
        dq_f = _arm_member(path, f, "follower", sf.DQ, n, len(names))
    t = fol.t[:n]
    trace = None
    if truth_trace is not None:
        trace, n = _aligned_trace(Path(truth_trace), path, names, t, notes)
        t = t[:n]
    keep = t >= t[0] + settle_s
    if not keep.any():
        raise FidelityError(f"{path} lasts {t[-1] - t[0]:.3g} s, not more than the {settle_s:g} s settle "
                            f"time; give a shorter settle time")
    r_l, r_f = res["leader"][:n], res["follower"][:n]
    q_l, q_f = lead.q[:n], fol.q[:n]
    bilateral = np.isfinite(r_f[keep]).all(axis=0) & np.isfinite(r_l[keep]).all(axis=0)
    if not bilateral.any():
        raise FidelityError(f"{path} has no bilateral joint (no joint's reaction-force observer ran on both "
                            f"arms through the session), so there is no force channel to measure")
    contact, free, ext, ext_l = _sample_classes(trace, keep, t, contact_guard_s, notes)
    dq_f = dq_f[:n]
    joints = {names[j]: _joint_metrics(j, keep, free, contact, r_l, r_f, q_l, q_f, dq_f, ext, ext_l)
              for j in np.flatnonzero(bilateral)}
    models = {arm: _model_attr(fol.attrs, arm) for arm in ("leader", "follower")}
    return Fidelity(session=str(path), truth_trace=None if truth_trace is None else str(truth_trace),
                    settle_s=float(settle_s), contact_guard_s=float(contact_guard_s), joints=joints,
                    samples=int(keep.sum()), free_samples=int(free.sum()), contact_samples=int(contact.sum()),
                    rate_hz=fol.rate_hz, models=models, notes=notes)


def _model_text(model) -> str:
    if model == NOMINAL:
        return NOMINAL
    if isinstance(model, dict):
        parts = [str(model.get("method") or "model")]
        if model.get("effects"):
            effects = model["effects"]
            parts.append("+ " + ", ".join(map(str, effects)) if isinstance(effects, list) else str(effects))
        if model.get("path"):
            parts.append(f"({model['path']})")
        return " ".join(parts)
    return str(model)


def _num(value, fmt: str = ".4f") -> str:
    return "-" if value is None else format(value, fmt)


def fidelity_text(result: Fidelity) -> str:
    """A table per joint (units in the headers) and a short summary."""
    has_trace = result.truth_trace is not None
    cols = [("follower_false_rms", "false N m"), ("follower_false_rms_moving", "moving"),
            ("follower_false_rms_still", "still"), ("leader_rms", "leader N m")]
    if any("leader_hand_error_rms" in m for m in result.joints.values()):
        cols += [("leader_hand_error_rms", "hand err N m"), ("hand_true_rms", "hand N m")]
    if has_trace:
        cols += [("contact_error_rms", "contact err N m"), ("contact_true_rms", "contact true N m"),
                 ("contact_error_ratio", "err/true")]
    cols += [("force_sum_rms", "sum N m"), ("tracking_rms", "track rad"), ("tracking_rms_deg", "track deg")]
    width = [max(len(h), 9) + 2 for _, h in cols]
    lines = [f"Force-channel fidelity of {result.session}"
             + (f" (truth: {result.truth_trace})" if has_trace else " (no truth trace)"),
             f"models in the loop: leader {_model_text(result.models['leader'])}; "
             f"follower {_model_text(result.models['follower'])}",
             f"{result.samples} samples after the first {result.settle_s:g} s: {result.free_samples} in free "
             f"motion ({result.free_s:.1f} s)"
             + (f", {result.contact_samples} in contact ({result.contact_s:.1f} s; guard "
                f"{result.contact_guard_s:g} s around contact)" if has_trace else ""),
             "RMS per joint: false = follower tau_res in free motion (moving / still: where the joint moved "
             "or stood still),\n  leader = leader tau_res in free motion,"
             + (" hand err = leader tau_res + hand torque in free motion, hand = the hand's true torque,\n"
                "  contact err = follower tau_res + tau_ext in contact, " if has_trace else "\n  ")
             + "sum = leader + follower tau_res (all kept samples), track = leader q - follower q.",
             "", f"{'joint':<10}" + "".join(f"{h:>{w}}" for (_, h), w in zip(cols, width))]
    for name, m in result.joints.items():
        cells = []
        for (key, _), w in zip(cols, width):
            fmt = ".3f" if key in ("contact_error_ratio", "tracking_rms_deg") else ".4f"
            cells.append(f"{_num(m.get(key), fmt):>{w}}")
        lines.append(f"{name:<10}" + "".join(cells))
    lines += ["", summary_text(result)]
    lines += [f"Note: {n}" for n in result.notes]
    return "\n".join(lines)


def summary_text(result: Fidelity) -> str:
    """One or two sentences: where the false force is largest, and how well contact is estimated."""
    free = {k: m["follower_false_rms"] for k, m in result.joints.items()
            if m["follower_false_rms"] is not None}
    parts = []
    if free:
        worst = max(free, key=free.get)
        mean = np.mean(list(free.values()))
        if result.truth_trace is not None:
            parts.append(f"The operator feels up to {free[worst]:.3g} N m RMS of false force in free motion "
                         f"({worst}; mean over joints {mean:.3g} N m).")
        else:
            parts.append(f"The follower's tau_res is up to {free[worst]:.3g} N m RMS over the whole session "
                         f"({worst}; mean over joints {mean:.3g} N m): false force wherever the follower "
                         f"touched nothing.")
    ratios = {k: m.get("contact_error_ratio") for k, m in result.joints.items()}
    ratios = {k: v for k, v in ratios.items() if v is not None}
    if ratios:
        worst = max(ratios, key=ratios.get)
        parts.append(f"In contact ({result.contact_s:.1f} s) the follower's estimate is off by "
                     f"{100 * ratios[worst]:.0f}% of the true torque RMS at worst ({worst}).")
    elif result.truth_trace is not None:
        parts.append("The follower touched nothing after the settle time, so contact is not measured.")
    return " ".join(parts)
