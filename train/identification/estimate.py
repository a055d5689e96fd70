"""Weighted least squares of a linear torque model, as identification toolboxes do it.

Each joint's torque equation is used where that joint moves (a standing joint's torque holds an unknown
static friction). Two steps: ordinary least squares gives each joint's residual standard deviation
sigma_j; the weighted fit divides joint j's equations by sigma_j, so every equation counts by its noise.

The uncertainty accounts for serial correlation: the residuals of a recording at 50 Hz are correlated
over tens of samples, so the textbook covariance s^2 (A^T A)^-1 is too small. The covariance is the
delete-a-block jackknife's over contiguous time blocks (train.evaluation.block_uncertainty: the same
blocks and estimator as `crane-train fit`'s standard errors; a repeated sample stays in its first
occurrence's block). A recording never gets a smaller error than its independent-sample value: where the
jackknife comes out below the textbook value on average (few blocks, by chance), the textbook covariance
is used; otherwise each parameter whose jackknife variance lies below its textbook variance is raised to
it (its correlations kept). A jackknife over five blocks estimates each variance from four degrees of
freedom, so some come out several times too small by chance; the t factor of the interval covers that
spread only for an estimate that is unbiased, and the textbook value is a floor the data justify anyway.

A parameter is identifiable when the data tell its value from zero: its relative standard error is at
most IDENTIFIABLE_REL_STDERR (the estimate lies at least two standard errors from zero, a t test at
about 95 %). Any direction the data cannot see (a near-null direction of the regressor) gives the
parameters along it a large standard error, so they fail the same test. A parameter that fails it is
reported as not identifiable: its value is whatever the noise made it, and its interval says only that.
The 95 % interval is +- t x stderr with Student's t at the jackknife's blocks - 1 degrees of freedom
(train.evaluation.block_uncertainty.t_factor).

The condition number is that of the weighted regressor with every column scaled to unit norm (the
figure identification papers quote: how well the data separate the parameters, independent of units).
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from crane_io.errors import CraneError

from ..evaluation.block_uncertainty import BlockPlan, least_squares_covariance, t_factor

IDENTIFIABLE_REL_STDERR = 0.5  # a parameter is identifiable when its estimate lies >= 2 stderr from zero
CORRELATED = 0.95  # |correlation| above which two estimates are reported as a strongly correlated pair


class IdentificationError(CraneError):
    """The data cannot identify the parameters (too few rows, a joint that never moves, a rank-deficient
    regressor)."""


@dataclass
class Estimate:
    theta: np.ndarray  # (p,) weighted least-squares estimate
    cov: np.ndarray  # (p, p) its covariance (serial correlation accounted for)
    sigma: np.ndarray  # (J,) each joint's residual standard deviation, N m
    condition: float  # condition number of the weighted, column-scaled regressor
    rows: int  # torque equations used
    correlated: list[tuple[int, int, float]] = field(default_factory=list)  # (i, j, r) with |r| > CORRELATED
    blocks: int = 0  # the jackknife's blocks (0: the textbook covariance was used)

    @property
    def stderr(self) -> np.ndarray:
        return np.sqrt(np.clip(np.diag(self.cov), 0.0, None))

    @property
    def interval95(self) -> np.ndarray:
        """(p,) half-width of each parameter's 95 % interval (the module docstring)."""
        return (t_factor(self.blocks) if self.blocks >= 2 else 1.959964) * self.stderr

    @property
    def identifiable(self) -> np.ndarray:
        """(p,) bool: the parameter's estimate lies at least 1 / IDENTIFIABLE_REL_STDERR stderr from zero."""
        return self.stderr <= IDENTIFIABLE_REL_STDERR * np.abs(self.theta)


def _stack(phi: np.ndarray, tau: np.ndarray, moving: np.ndarray):
    """Per-joint rows: (A (m, p), y (m,), joint index (m,), sample index (m,)) of every joint's equation
    where it moves."""
    n, j, p = phi.shape
    sample, joint = np.nonzero(moving)
    return phi[sample, joint], tau[sample, joint], joint, sample


def _solve(a: np.ndarray, y: np.ndarray) -> np.ndarray:
    return np.linalg.lstsq(a, y, rcond=None)[0]


def _never_below_iid(cov: np.ndarray, cov_iid: np.ndarray, blocks: int) -> tuple[np.ndarray, int]:
    """(covariance, the jackknife's blocks or 0 for the textbook one): the jackknife's `cov`, each
    parameter's variance raised to at least its textbook value `cov_iid` (the module docstring: a few
    blocks' spread can be small by chance), its correlations kept; the textbook covariance itself when
    the jackknife lies below it on average."""
    ratio = np.diag(cov) / np.maximum(np.diag(cov_iid), 1e-300)
    if ratio.mean() < 1.0:
        return cov_iid, 0
    lift = np.sqrt(np.maximum(1.0 / np.maximum(ratio, 1e-300), 1.0))
    return cov * np.outer(lift, lift), blocks


def weighted_least_squares(phi: np.ndarray, tau: np.ndarray, moving: np.ndarray, plan: BlockPlan) -> Estimate:
    """The estimate of theta in tau = phi @ theta from phi (N, J, p), tau (N, J) N m, the dead-zone mask
    moving (N, J) and the samples' time blocks `plan` (train.evaluation.block_uncertainty)."""
    phi, tau, moving = np.asarray(phi, float), np.asarray(tau, float), np.asarray(moving, bool)
    n, nj, p = phi.shape
    counts = moving.sum(axis=0)
    if counts.size == 0 or counts.min() < max(p // nj + 1, 2 * plan.count):
        j = int(np.argmin(counts))
        raise IdentificationError(f"joint #{j + 1} moves in only {int(counts[j])} samples; identifying "
                                  f"{p} parameters needs more motion (an exciting trajectory, or a longer "
                                  f"recording)")
    a, y, joint, sample = _stack(phi, tau, moving)
    scale = np.linalg.norm(a, axis=0)
    if np.any(scale < 1e-12 * max(scale.max(initial=0.0), 1e-300)):
        raise IdentificationError("a parameter's regressor column is zero on this data: the data cannot "
                                  "identify it")
    theta0 = _solve(a / scale, y) / scale
    resid0 = y - a @ theta0
    sigma = np.array([np.sqrt(np.mean(resid0[joint == k] ** 2)) for k in range(nj)])
    sigma = np.maximum(sigma, 1e-9)
    w = 1.0 / sigma[joint]
    aw, yw = a * w[:, None], y * w
    col = np.linalg.norm(aw, axis=0)
    sv = np.linalg.svd(aw / col, compute_uv=False)
    condition = float(sv[0] / sv[-1]) if sv[-1] > 0 else float("inf")
    if not np.isfinite(condition) or condition > 1e10:
        raise IdentificationError("the regressor is rank-deficient on this data: some parameters cannot "
                                  "be told apart (an exciting trajectory moves every joint over its range)")
    theta = _solve(aw / col, yw) / col
    resid = yw - aw @ theta
    dof = max(len(yw) - p, 1)
    s2 = float(resid @ resid / dof)
    ata_inv = np.linalg.inv((aw / col).T @ (aw / col)) / np.outer(col, col)
    cov_iid = s2 * ata_inv
    cov = least_squares_covariance(aw / col, yw, plan.ids[sample], plan.count) / np.outer(col, col)
    cov, blocks = _never_below_iid(cov, cov_iid, plan.count)
    cov = 0.5 * (cov + cov.T)
    se = np.sqrt(np.clip(np.diag(cov), 1e-300, None))
    corr = cov / np.outer(se, se)
    pairs = [(i, k, float(corr[i, k])) for i in range(p) for k in range(i + 1, p)
             if abs(corr[i, k]) > CORRELATED]
    return Estimate(theta=theta, cov=cov, sigma=sigma, condition=condition, rows=int(len(y)),
                    correlated=pairs, blocks=blocks)
