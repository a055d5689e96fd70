"""Training losses (torch). The paper's masked loss, its equation (3):

    L = 1/n sum_i ( 1/J sum_j r_ij (tau_ij - tau_hat_ij)^2 )

n is the number of samples in the batch and J the number of joints. Note the 1/J: a sample in which
only one joint moves contributes a third of what it would if all three moved; the paper normalises by
J, not by the number of moving joints, and so do we. With every r_ij = 1 it is exactly the MSE.
"""

from __future__ import annotations

import torch


def mse_loss(pred: torch.Tensor, target: torch.Tensor) -> torch.Tensor:
    """Mean over samples and joints of the squared error."""
    return ((pred - target) ** 2).mean()


def masked_loss(pred: torch.Tensor, target: torch.Tensor, moving: torch.Tensor) -> torch.Tensor:
    """The paper's eq. (3); `moving` (n, J) is the dead-zone mask r (bool or 0/1)."""
    r = moving.to(pred.dtype)
    return (r * (pred - target) ** 2).mean()


def weighted_loss(pred: torch.Tensor, target: torch.Tensor, weight: torch.Tensor,
                  count: torch.Tensor) -> torch.Tensor:
    """Batched form used by train.models.batched: per model m,
    sum_{i,j} weight_mij (pred - target)^2 / (J * count_m), summed over models.

    pred, target, weight: (M, B, J); count: (M,) samples of model m in this batch (0 -> no loss).
    With weight = r and count = n this is eq. (3) for each model; with weight = 1 it is the MSE.
    """
    J = pred.shape[-1]
    per_model = (weight * (pred - target) ** 2).sum(dim=(1, 2)) / (J * count.clamp(min=1))
    return per_model.sum()
