"""The paper's dead-zone mask (its equation 2): joint j moves in sample i when |dq_ij| > alpha sigma_j.

sigma_j is the standard deviation of joint j's (preprocessed) velocity over all the data given; the
mask is what the masked loss multiplies each joint's squared error by, and "all joints move" selects
the samples plain MSE and the rigid-body fit may use.
"""

from __future__ import annotations

from typing import TYPE_CHECKING

import numpy as np

from crane_io.errors import CraneError

if TYPE_CHECKING:
    from collections.abc import Sequence


class DeadZoneError(CraneError):
    """Data whose dead-zone mask cannot be used (a joint that never moves)."""


def velocity_sigma(dq: np.ndarray, joint_names: Sequence[str] | None = None) -> np.ndarray:
    """(J,) standard deviation of each joint's velocity `dq` ((N, J) rad/s), in rad/s; a joint that never
    moves is an error."""
    dq = np.atleast_2d(np.asarray(dq, dtype=float))
    sigma = dq.std(axis=0)
    names = list(joint_names) if joint_names is not None else [f"column {j}" for j in range(dq.shape[1])]
    for j, s in enumerate(sigma):
        if not np.isfinite(s) or s < 1e-9:
            raise DeadZoneError(f"joint {names[j]} never moves in the data (velocity spread {s:.2g} rad/s), "
                                f"so it cannot be learned; record motion of it or leave it out with `joints`")
    return sigma


def dead_zone_mask(dq: np.ndarray, alpha: float = 0.1, sigma: np.ndarray | None = None,
                   joint_names: Sequence[str] | None = None) -> tuple[np.ndarray, np.ndarray]:
    """(moving (N, J) bool, sigma (J,) rad/s): r_ij = |dq_ij| > alpha * sigma_j, for velocities `dq`
    (N, J) rad/s; `alpha` is dimensionless."""
    if not (np.isfinite(alpha) and alpha >= 0):
        raise DeadZoneError(f"alpha must be a non-negative number, got {alpha!r}")
    dq = np.atleast_2d(np.asarray(dq, dtype=float))
    if sigma is None:
        sigma = velocity_sigma(dq, joint_names)
    moving = np.abs(dq) > alpha * np.asarray(sigma)[None, :]
    if joint_names is not None:
        for j, name in enumerate(joint_names):
            if not moving[:, j].any():
                raise DeadZoneError(f"joint {name} is never above the dead-zone threshold "
                                    f"{alpha * sigma[j]:.3g} rad/s, so it cannot be learned")
    return moving, np.asarray(sigma, dtype=float)


def moving_fractions(moving: np.ndarray, joint_names: Sequence[str] | None = None) -> dict:
    """{'per_joint': {name: fraction}, 'all_joints': fraction} of samples in which joints move."""
    moving = np.atleast_2d(np.asarray(moving, dtype=bool))
    names = list(joint_names) if joint_names is not None else [str(j) for j in range(moving.shape[1])]
    n = max(len(moving), 1)
    return {"per_joint": {name: float(moving[:, j].sum() / n) for j, name in enumerate(names)},
            "all_joints": float(moving.all(axis=1).sum() / n)}
