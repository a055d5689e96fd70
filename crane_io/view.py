"""A bilateral session seen in rerun (the optional extra `crane-x7[view]`): live from `crane-collect run
--view` (collect/live_view.py) and replayed from a file by `crane-train view` (train/replay.py).

Both write the same entities, on the timeline `session_time` (the session's `t`, s):

| entity | what | unit |
|---|---|---|
| `leader/q`, `follower/q` | joint angles, one series per joint | rad |
| `leader/tau`, `follower/tau` | joint torque (as recorded: commanded, or present current x Kt) | N m |
| `leader/tau_dis`, `follower/tau_dis` | disturbance-observer estimate, bilateral joints | N m |
| `leader/tau_res`, `follower/tau_res` | reaction-force-observer estimate, bilateral joints | N m |
| `loop/tracking_error` | leader q - follower q, bilateral joints | rad |
| `loop/period` | the loop's period at the sample and the longest one since the previous sample | s |
| `arms/leader`, `arms/follower` | the arm in 3D (line strip and points) | m |

The 3D arm: the base, the joint origins 1..7 and the tool point, from the project's own kinematic model
(crane_io/physics/arm_model.py, pinocchio forward kinematics); the two arms side by side, `ARM_OFFSET_M` apart
along y.

rerun is imported only when a view is made (`import_rerun`), never at import time of this module, so the
command lines' help stays light; without rerun installed the error is one sentence naming the extra.
"""

from __future__ import annotations

import uuid
from pathlib import Path

import numpy as np

from crane_io.errors import ConfigError

INSTALL_HINT = "pip install 'crane-x7[view]'"
TIMELINE = "session_time"
ARMS = ("leader", "follower")
# signal name -> (unit, only the bilateral joints)
SIGNALS = {"q": ("rad", False), "tau": ("N m", False), "tau_dis": ("N m", True), "tau_res": ("N m", True)}
ARM_OFFSET_M = 0.3  # the leader drawn at y = +0.3 m, the follower at y = -0.3 m
ARM_COLORS = {"leader": (80, 160, 255), "follower": (255, 140, 60)}


class ViewUnavailableError(ConfigError):
    """The view was asked for but rerun-sdk is not installed."""


class ViewError(ConfigError):
    """The view could not be opened (a file that cannot be written, a viewer that cannot start)."""


def _viewer_executable() -> str | None:
    """The rerun viewer on PATH, else the one installed beside this interpreter (a virtual environment
    that was not activated), else None (rerun then says it found none)."""
    import shutil
    import sys

    found = shutil.which("rerun")
    if found:
        return found
    beside = Path(sys.executable).parent / "rerun"
    return str(beside) if beside.exists() else None


def import_rerun():
    """The rerun module, or ViewUnavailableError (one sentence naming the extra to install)."""
    try:
        import rerun
    except ImportError:
        raise ViewUnavailableError(f"the view needs rerun-sdk, which is not installed; install it with "
                                   f"{INSTALL_HINT}") from None
    return rerun


class ArmKinematics:
    """Positions (K, 3) m of the base, the joint origins 1..7 and the tool point of the CRANE-X7 for one
    row of joint angles given in `joint_names` order (joints not given stay at 0 rad)."""

    def __init__(self, joint_names):
        import pinocchio as pin

        from crane_io.physics.arm_model import JOINT_NAMES, TOOL_FRAME, full_model

        self._pin = pin
        self.model = full_model()
        self.data = self.model.createData()
        names = list(joint_names)
        self._q = pin.neutral(self.model)
        # (index in the model's configuration, column of the given rows)
        pairs = [(self.model.joints[self.model.getJointId(n)].idx_q, names.index(n))
                 for n in JOINT_NAMES if n in names]
        self._q_idx = np.array([p[0] for p in pairs], dtype=int)
        self._cols = np.array([p[1] for p in pairs], dtype=int)
        self._joints = [self.model.getJointId(n) for n in JOINT_NAMES if n != "gripper"]
        self._tool = self.model.getFrameId(TOOL_FRAME)
        self.n_points = len(self._joints) + 2

    def points(self, q_row, out: np.ndarray | None = None) -> np.ndarray:
        pin, m, d = self._pin, self.model, self.data
        q = self._q
        vals = np.asarray(q_row, dtype=float)[self._cols]
        q[self._q_idx] = np.where(np.isfinite(vals), vals, 0.0)
        pin.forwardKinematics(m, d, q)
        out = np.empty((self.n_points, 3)) if out is None else out
        out[0] = 0.0
        for i, jid in enumerate(self._joints, start=1):
            out[i] = d.oMi[jid].translation
        out[-1] = pin.updateFramePlacement(m, d, self._tool).translation
        return out


class SessionView:
    """One rerun recording of a bilateral session; see the module docstring for its entities.

    `save` (a path, `.rrd`) streams the recording to that file; otherwise `spawn=True` starts a viewer
    (and streams to it). Nothing is written until `open()`; the static parts (series names, the arms'
    placement) are logged at construction and reach the sink when it opens. `keys` lists the time-series
    entities and `arm_keys` the 3D ones; `log_part` logs one of them for one sample (the live view spreads
    a sample's parts over several control cycles), `log_columns` many samples at once (replay).
    """

    def __init__(self, joint_names, bilateral_joints, *, save: str | Path | None = None, spawn: bool = False,
                 application_id: str = "crane-x7", recording_name: str | None = None, arms=ARMS):
        rr = import_rerun()
        self.rr = rr
        self.joint_names = tuple(joint_names)
        self.bilateral = tuple(n for n in self.joint_names if n in set(bilateral_joints))
        self.bil_cols = np.array([self.joint_names.index(n) for n in self.bilateral], dtype=int)
        self.arms = tuple(arms)
        self.save_path = Path(save) if save is not None else None
        self.spawn = spawn and save is None
        self.kin = ArmKinematics(self.joint_names)
        self._pts = np.empty((self.kin.n_points, 3))
        self.rec = rr.RecordingStream(application_id, recording_id=uuid.uuid4())
        # a sample's components built from these descriptors directly: about 20 % cheaper per call than
        # the archetypes' constructors
        self._d_scalars = rr.Scalars.descriptor_scalars()
        self._d_strips = rr.LineStrips3D.descriptor_strips()
        self._d_positions = rr.Points3D.descriptor_positions()
        if recording_name:
            self.rec.send_recording_name(recording_name)
        self.keys: list[str] = []  # time-series entities
        self._cols: dict[str, np.ndarray | None] = {}  # columns of the full row logged by each entity
        for arm in self.arms:
            for sig, (unit, bil_only) in SIGNALS.items():
                self._series(f"{arm}/{sig}", self.bilateral if bil_only else self.joint_names, unit,
                             self.bil_cols if bil_only else None)
        if "leader" in self.arms and "follower" in self.arms and self.bilateral:
            self._series("loop/tracking_error", self.bilateral, "rad", None)
        self._series("loop/period", ("period", "longest since the previous sample"), "s", None)
        self.arm_keys = [f"arms/{arm}" for arm in self.arms]
        log = self.rec.log
        log("arms", rr.ViewCoordinates.RIGHT_HAND_Z_UP, static=True)
        for i, arm in enumerate(self.arms):
            y = ARM_OFFSET_M * (1 if i == 0 else -1) if len(self.arms) > 1 else 0.0
            color = ARM_COLORS.get(arm, (200, 200, 200))
            # what never changes is logged once: a sample carries only the strip and the points
            log(f"arms/{arm}", rr.Transform3D(translation=[0.0, y, 0.0]),
                rr.LineStrips3D.from_fields(colors=[color], radii=[0.006]),
                rr.Points3D.from_fields(colors=[color], radii=[0.012]), static=True)
        self.opened = False

    def _series(self, key: str, names, unit: str, cols) -> None:
        self.keys.append(key)
        self._cols[key] = cols
        self.rec.log(key, self.rr.SeriesLines(names=[f"{n} ({unit})" for n in names]), static=True)

    def open(self) -> None:
        """Start writing: the .rrd file (`save`) or a spawned viewer. Raises ViewError (one sentence)."""
        if self.opened:
            return
        try:
            if self.save_path is not None:
                self.save_path.parent.mkdir(parents=True, exist_ok=True)
                self.rec.save(str(self.save_path))
            elif self.spawn:
                from rerun.sinks import spawn

                spawn(recording=self.rec, executable_path=_viewer_executable())
        except Exception as exc:  # noqa: BLE001 - rerun raises several kinds; one sentence for the user
            where = f"write {self.save_path}" if self.save_path is not None else "start the rerun viewer"
            first = (str(exc).strip().splitlines() or [exc.__class__.__name__])[0].rstrip(".")
            raise ViewError(f"the view could not {where}: {first} (`view_save` FILE.rrd writes a file "
                            f"instead)") from None
        self.opened = True

    # -- one sample -------------------------------------------------------------------------------------
    def set_time(self, t: float) -> None:
        self.rec.set_time(TIMELINE, duration=float(t))

    def log_part(self, key: str, t: float, sample: dict) -> None:
        """Log entity `key` (one of keys + arm_keys) of one sample at session time t. `sample` maps
        "<arm>/<signal>" to a full (J,) row in joint_names order, "loop/tracking_error" to the bilateral
        joints' errors and "loop/period" to (period, longest)."""
        rr = self.rr
        self.set_time(t)
        if key.startswith("arms/"):
            arm = key[5:]
            pts = self.kin.points(sample[f"{arm}/q"], self._pts)
            comps = rr.components
            self.rec.log(key, [comps.LineStrip3DBatch([pts]).described(self._d_strips),
                               comps.Position3DBatch(pts).described(self._d_positions)])
            return
        row = np.asarray(sample[key], dtype=float)
        cols = self._cols[key]
        values = row if cols is None else row[cols]
        self.rec.log(key, [rr.components.ScalarBatch(values).described(self._d_scalars)])

    def log_sample(self, t: float, sample: dict) -> None:
        """Every entity of one sample (the keys missing from `sample` are left out)."""
        for key in self.keys + self.arm_keys:
            if key in sample or (key.startswith("arms/") and f"{key[5:]}/q" in sample):
                self.log_part(key, t, sample)

    # -- many samples (replay) ----------------------------------------------------------------------------
    def log_columns(self, t, data: dict) -> None:
        """Many samples at once: `t` (N,) s and `data` mapping the same keys as `log_part`'s sample to
        (N, J) (or (N, K)) arrays; entities whose data are missing are left out."""
        rr = self.rr
        t = np.asarray(t, dtype=float)
        index = [rr.TimeColumn(TIMELINE, duration=t)]
        for key in self.keys:
            if key not in data:
                continue
            arr = np.asarray(data[key], dtype=float)
            cols = self._cols[key]
            arr = arr if cols is None else arr[:, cols]
            self.rec.send_columns(key, indexes=index, columns=rr.Scalars.columns(scalars=arr))
        n = len(t)
        k = self.kin.n_points
        for arm in self.arms:
            q = data.get(f"{arm}/q")
            if q is None:
                continue
            pts = np.empty((n, k, 3))
            for i in range(n):
                self.kin.points(q[i], pts[i])
            strips = rr.LineStrips3D.columns(strips=list(pts))
            points = rr.Points3D.columns(positions=pts.reshape(-1, 3)).partition([k] * n)
            self.rec.send_columns(f"arms/{arm}", indexes=index, columns=[*strips, *points])

    def close(self) -> None:
        """Flush what was logged and close the sink (the .rrd file is complete afterwards)."""
        if self.opened:
            self.rec.flush(timeout_sec=10.0)
        self.rec.disconnect()
        self.opened = False
