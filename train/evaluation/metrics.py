"""Per-joint error metrics on SI torques (numpy). All return (J,) arrays unless said otherwise.

`mask` (N, J) bool restricts each joint's average to the rows where the mask is True (masked
variants: the error of a joint while it moves); rows=None uses every row.
"""

from __future__ import annotations

from typing import TYPE_CHECKING

import numpy as np

if TYPE_CHECKING:
    from collections.abc import Sequence


def _check(tau, tau_hat):
    tau = np.atleast_2d(np.asarray(tau, dtype=float))
    tau_hat = np.atleast_2d(np.asarray(tau_hat, dtype=float))
    if tau.shape != tau_hat.shape:
        raise ValueError(f"measured {tau.shape} and predicted {tau_hat.shape} torques differ in shape")
    return tau, tau_hat


def mse(tau: np.ndarray, tau_hat: np.ndarray, mask: np.ndarray | None = None) -> np.ndarray:
    """(J,) mean squared error per joint of torques (N, J) N m over the rows of `mask` (N, J) bool
    (None: all), in N^2 m^2 (NaN for a joint whose mask is empty)."""
    tau, tau_hat = _check(tau, tau_hat)
    err2 = (tau - tau_hat) ** 2
    if mask is None:
        return err2.mean(axis=0)
    mask = np.asarray(mask, dtype=bool)
    count = mask.sum(axis=0)
    with np.errstate(invalid="ignore", divide="ignore"):
        return np.where(count > 0, (err2 * mask).sum(axis=0) / np.maximum(count, 1), np.nan)


def rmse(tau: np.ndarray, tau_hat: np.ndarray, mask: np.ndarray | None = None) -> np.ndarray:
    """(J,) root mean squared error per joint, N m (torques (N, J) N m, as for `mse`)."""
    return np.sqrt(mse(tau, tau_hat, mask))


def torque_variance(tau: np.ndarray, mask: np.ndarray | None = None) -> np.ndarray:
    """(J,) variance of each joint's torque `tau` (N, J) N m over the rows of `mask` (None: all), N^2 m^2."""
    tau = np.atleast_2d(np.asarray(tau, dtype=float))
    if mask is None:
        return tau.var(axis=0)
    mask = np.asarray(mask, dtype=bool)
    out = np.full(tau.shape[1], np.nan)
    for j in range(tau.shape[1]):
        if mask[:, j].any():
            out[j] = tau[mask[:, j], j].var()
    return out


def nmse(tau: np.ndarray, tau_hat: np.ndarray, mask: np.ndarray | None = None) -> np.ndarray:
    """MSE divided by the variance of the measured torque (same rows): 0 perfect, 1 = predicting the mean."""
    var = torque_variance(tau, mask)
    with np.errstate(invalid="ignore", divide="ignore"):
        return mse(tau, tau_hat, mask) / np.where(var > 0, var, np.nan)


def masked_loss_value(tau: np.ndarray, tau_hat: np.ndarray, moving: np.ndarray) -> float:
    """The paper's eq. (3) evaluated on numpy arrays (the masked loss over all rows), N^2 m^2; tau, tau_hat
    (N, J) N m, moving (N, J) bool."""
    tau, tau_hat = _check(tau, tau_hat)
    return float((np.asarray(moving, dtype=float) * (tau - tau_hat) ** 2).mean())


def metrics_table(tau: np.ndarray, tau_hat: np.ndarray, joint_names: Sequence[str],
                  mask: np.ndarray | None = None) -> dict:
    """{'mse': {joint: v}, 'rmse': ..., 'nmse': ...} as plain floats (JSON-ready): mse in N^2 m^2, rmse
    in N m, nmse dimensionless."""
    out = {}
    for name, fn in (("mse", mse), ("rmse", rmse), ("nmse", nmse)):
        vals = fn(tau, tau_hat, mask)
        out[name] = {j: float(v) for j, v in zip(joint_names, vals)}
    return out
