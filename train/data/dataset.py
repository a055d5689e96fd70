"""The preprocessed data every model sees: one row per (down-sampled) sample, SI units.

Produced by the preprocessing pipeline (train.data.preprocess) from one or more session files;
consumed by every model, the sweep, the report and the diagnosis.

Context joints: the session's other arm joints (joint1..joint7 that are not learning joints; the gripper
is never one) travel along as `context_names` with their filtered angle, velocity and acceleration
(`context_q`, `context_dq`, `context_ddq`, (N, K), the same preprocessing as the learning joints). The
rigid-body model puts them into its kinematics (train.models.rigid_body); the networks keep the
paper's inputs (the learning joints' q, dq, ddq) and ignore them.

Offline signals: `offline`, when given, is a Dataset of the same rows filtered zero-phase (no delay,
forward-backward; train.data.preprocess) — what a parameter estimate may use that needs no causal
filter (train.models.rigid_body reports its parameter values from it). None when the data themselves
are zero-phase or were made without it.

Angle series: `angle`, on the offline Dataset, says which rows of the preprocessed data's unfiltered
angle series (train.data.angle_columns) its rows are; a regressor column's angle-only part is then
filtered from it as the torque is (angle_columns.columns_on). None elsewhere.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import TYPE_CHECKING

import numpy as np

if TYPE_CHECKING:
    from collections.abc import Sequence

    from .angle_columns import AngleRows


@dataclass
class Dataset:
    joint_names: tuple[str, ...]  # the J learning joints, as named in the session
    t: np.ndarray  # (N,) s
    q: np.ndarray  # (N, J) rad
    dq: np.ndarray  # (N, J) rad/s
    ddq: np.ndarray  # (N, J) rad/s^2
    tau: np.ndarray  # (N, J) N m
    moving: np.ndarray  # (N, J) bool: the dead-zone mask r_ij (True = joint j moves in sample i)
    rate_hz: float  # sample rate after down-sampling
    segment: np.ndarray = field(default=None)  # (N,) int: which session/continuous piece a row is from
    meta: dict = field(default_factory=dict)  # preprocessing settings, thresholds sigma_j, sources
    context_names: tuple[str, ...] = ()  # the other recorded arm joints (not learned; kinematic context)
    context_q: np.ndarray = field(default=None)  # (N, K) rad
    context_dq: np.ndarray = field(default=None)  # (N, K) rad/s
    context_ddq: np.ndarray = field(default=None)  # (N, K) rad/s^2
    offline: Dataset | None = field(default=None, repr=False)  # the same rows filtered zero-phase
    angle: AngleRows | None = field(default=None, repr=False)  # the rows of the unfiltered angle series

    def __post_init__(self):
        if self.segment is None:
            self.segment = np.zeros(len(self.t), dtype=int)
        self.context_names = tuple(self.context_names or ())
        if self.context_names:
            k = len(self.context_names)
            for name in ("context_q", "context_dq", "context_ddq"):
                a = getattr(self, name)
                if a is None or np.shape(a) != (len(self.t), k):
                    raise ValueError(f"{name} must have shape ({len(self.t)}, {k}), got {np.shape(a)}")
        if self.offline is not None and len(self.offline) != len(self.t):
            raise ValueError(f"offline must have {len(self.t)} rows, got {len(self.offline)}")
        if self.angle is not None and len(self.angle.rows) != len(self.t):
            raise ValueError(f"angle must index {len(self.t)} rows, got {len(self.angle.rows)}")

    @property
    def context(self) -> dict | None:
        """{'names', 'q', 'dq', 'ddq'} of the context joints, or None when the data has none."""
        if not self.context_names:
            return None
        return {"names": self.context_names, "q": self.context_q, "dq": self.context_dq,
                "ddq": self.context_ddq}

    def __len__(self) -> int:
        return len(self.t)

    @property
    def all_moving(self) -> np.ndarray:
        """(N,) bool: every joint moves (the samples plain MSE and the rigid-body fit may use)."""
        return self.moving.all(axis=1)

    def subset(self, index: np.ndarray | slice | Sequence[int]) -> Dataset:
        index = np.asarray(index)
        return Dataset(self.joint_names, self.t[index], self.q[index], self.dq[index],
                       self.ddq[index], self.tau[index], self.moving[index], self.rate_hz,
                       self.segment[index], dict(self.meta), self.context_names,
                       *((None, None, None) if not self.context_names else
                         (self.context_q[index], self.context_dq[index], self.context_ddq[index])),
                       None if self.offline is None else self.offline.subset(index),
                       None if self.angle is None else self.angle.subset(index))
