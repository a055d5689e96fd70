"""A simple capsule model of the CRANE-X7 for keeping planned motion clear of the table and of itself.

Four capsules of radius RADIUS along the kinematic chain of crane_io.physics.arm_model (its joint
origins, the world frame's origin on the table top, z up):

    base:  the world origin -> joint2      upper: joint2 -> joint4
    fore:  joint4 -> joint6                hand:  joint6 -> the tool frame

The clearance of a pose is the smallest of
- the height above the table (z = 0) of the fore and hand capsules (their lowest point: an end of the
  segment) less RADIUS;
- the distance between the non-adjacent capsules (base-fore, base-hand, upper-hand) less 2 RADIUS,
  measured between SEGMENT_POINTS points along each segment.

It is negative where two capsules overlap or one dips into the table. The joints not given are at
their `locked` angles (default 0 rad).
"""

from __future__ import annotations

import numpy as np
import pinocchio as pin

from crane_io.errors import ConfigError
from crane_io.physics.arm_model import JOINT_NAMES, TOOL_FRAME, full_model

RADIUS = 0.04  # m: every capsule's radius (the links are about 0.05 m wide; the wrist's servos stick out)
SEGMENT_POINTS = 9
_POINTS = ("origin", "joint2", "joint4", "joint6", TOOL_FRAME)
_CAPSULES = {"base": (0, 1), "upper": (1, 2), "fore": (2, 3), "hand": (3, 4)}
_PAIRS = (("base", "fore"), ("base", "hand"), ("upper", "hand"))
_ABOVE_TABLE = ("fore", "hand")


class ArmClearance:
    """`clearance(q)` (m) of poses q (N, J) or (J,) of the free `joints`."""

    def __init__(self, joints, locked: dict[str, float] | None = None):
        self.model = full_model()
        self.data = self.model.createData()
        unknown = [n for n in list(joints) + list(locked or {}) if n not in JOINT_NAMES]
        if unknown:
            raise ConfigError(f"unknown joint {unknown[0]!r} for the clearance model")
        self.q_ref = pin.neutral(self.model)
        for name, value in (locked or {}).items():
            self.q_ref[self._idx(name)] = float(value)
        self.idx = np.array([self._idx(n) for n in joints], dtype=int)
        self._joint_ids = [self.model.getJointId(n) for n in ("joint2", "joint4", "joint6")]
        self._tool = self.model.getFrameId(TOOL_FRAME)
        self._s = np.linspace(0.0, 1.0, SEGMENT_POINTS)

    def _idx(self, name: str) -> int:
        return self.model.joints[self.model.getJointId(name)].idx_q

    def points(self, q) -> np.ndarray:
        """(N, 5, 3) m: the world origin, joint2, joint4, joint6 and the tool frame of each pose."""
        q = np.atleast_2d(np.asarray(q, dtype=float))
        out = np.zeros((len(q), len(_POINTS), 3))
        full = self.q_ref.copy()
        model, data = self.model, self.data
        for i, qi in enumerate(q):
            full[self.idx] = qi
            pin.forwardKinematics(model, data, full)
            for k, jid in enumerate(self._joint_ids, start=1):
                out[i, k] = data.oMi[jid].translation
            out[i, 4] = pin.updateFramePlacement(model, data, self._tool).translation
        return out

    def clearance(self, q) -> np.ndarray:
        """(N,) m, or a float for one pose (the module docstring)."""
        single = np.asarray(q).ndim == 1
        p = self.points(q)
        s = self._s[None, :, None]
        seg = {name: p[:, i0, None, :] + s * (p[:, i1, None, :] - p[:, i0, None, :])
               for name, (i0, i1) in _CAPSULES.items()}  # (N, S, 3) each
        low = np.min([seg[n][:, :, 2].min(axis=1) for n in _ABOVE_TABLE], axis=0) - RADIUS
        gaps = [np.linalg.norm(seg[a][:, :, None, :] - seg[b][:, None, :, :], axis=3).min(axis=(1, 2))
                for a, b in _PAIRS]
        out = np.minimum(low, np.min(gaps, axis=0) - 2 * RADIUS)
        return float(out[0]) if single else out
