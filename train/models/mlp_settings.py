"""The networks' training settings ([mlp] in train.toml), apart from the trainer so that reading a
configuration does not import torch."""

from __future__ import annotations

from dataclasses import dataclass

DEFAULT_BATCH_SIZE = 32


@dataclass
class MLPSettings:
    hidden: int = 64  # hidden units (paper: 64)
    lr: float = 0.01  # Adam learning rate (paper: 0.01)
    epochs: int = 100  # paper: 100
    batch_size: int = DEFAULT_BATCH_SIZE  # minibatch size (the paper does not say)
    betas: tuple[float, float] = (0.9, 0.999)  # Adam defaults
    eps: float = 1e-8
