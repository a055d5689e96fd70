"""The preprocessed data every model sees: one row per (down-sampled) sample, SI units.

Produced by the preprocessing pipeline (train.preprocess) from one or more session files;
consumed by every model, the sweep, the report and the diagnosis.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np


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

    def __post_init__(self):
        if self.segment is None:
            self.segment = np.zeros(len(self.t), dtype=int)

    def __len__(self) -> int:
        return len(self.t)

    @property
    def all_moving(self) -> np.ndarray:
        """(N,) bool: every joint moves (the samples plain MSE and the rigid-body fit may use)."""
        return self.moving.all(axis=1)

    def subset(self, index) -> Dataset:
        index = np.asarray(index)
        return Dataset(self.joint_names, self.t[index], self.q[index], self.dq[index],
                       self.ddq[index], self.tau[index], self.moving[index], self.rate_hz,
                       self.segment[index], dict(self.meta))
