"""Per-joint error metrics on SI torques (numpy). All return (J,) arrays unless said otherwise.

`mask` (N, J) bool restricts each joint's average to the rows where the mask is True (masked
variants: the error of a joint while it moves); rows=None uses every row.
"""

from __future__ import annotations

import numpy as np


def _check(tau, tau_hat):
    tau = np.atleast_2d(np.asarray(tau, dtype=float))
    tau_hat = np.atleast_2d(np.asarray(tau_hat, dtype=float))
    if tau.shape != tau_hat.shape:
        raise ValueError(f"measured {tau.shape} and predicted {tau_hat.shape} torques differ in shape")
    return tau, tau_hat


def mse(tau, tau_hat, mask=None) -> np.ndarray:
    """Mean squared error per joint, N^2 m^2 (NaN for a joint whose mask is empty)."""
    tau, tau_hat = _check(tau, tau_hat)
    err2 = (tau - tau_hat) ** 2
    if mask is None:
        return err2.mean(axis=0)
    mask = np.asarray(mask, dtype=bool)
    count = mask.sum(axis=0)
    with np.errstate(invalid="ignore", divide="ignore"):
        return np.where(count > 0, (err2 * mask).sum(axis=0) / np.maximum(count, 1), np.nan)


def rmse(tau, tau_hat, mask=None) -> np.ndarray:
    """Root mean squared error per joint, N m."""
    return np.sqrt(mse(tau, tau_hat, mask))


def torque_variance(tau, mask=None) -> np.ndarray:
    tau = np.atleast_2d(np.asarray(tau, dtype=float))
    if mask is None:
        return tau.var(axis=0)
    mask = np.asarray(mask, dtype=bool)
    out = np.full(tau.shape[1], np.nan)
    for j in range(tau.shape[1]):
        if mask[:, j].any():
            out[j] = tau[mask[:, j], j].var()
    return out


def nmse(tau, tau_hat, mask=None) -> np.ndarray:
    """MSE divided by the variance of the measured torque (same rows): 0 perfect, 1 = predicting the mean."""
    var = torque_variance(tau, mask)
    with np.errstate(invalid="ignore", divide="ignore"):
        return mse(tau, tau_hat, mask) / np.where(var > 0, var, np.nan)


def masked_loss_value(tau, tau_hat, moving) -> float:
    """The paper's eq. (3) evaluated on numpy arrays (the masked loss over all rows)."""
    tau, tau_hat = _check(tau, tau_hat)
    return float((np.asarray(moving, dtype=float) * (tau - tau_hat) ** 2).mean())


def metrics_table(tau, tau_hat, joint_names, mask=None) -> dict:
    """{'mse': {joint: v}, 'rmse': ..., 'nmse': ...} as plain floats (JSON-ready)."""
    out = {}
    for name, fn in (("mse", mse), ("rmse", rmse), ("nmse", nmse)):
        vals = fn(tau, tau_hat, mask)
        out[name] = {j: float(v) for j, v in zip(joint_names, vals)}
    return out
