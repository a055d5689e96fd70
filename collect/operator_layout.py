"""The simulated operator's hand: the interface of its two backends (`PythonHand` in collect/operator.py,
the reference; `CompiledHand` in collect/operator_kernel.py), which both compute
collect/operator_kernel.hand_torque on every move's joint.

A move is a row (index, t0, T, a, d): the joint's index in the arm, the move's start and duration T (s,
T > 0), its start angle a and its length d = b - a (rad), in this order wherever a row is read.
"""

from __future__ import annotations

from abc import ABC, abstractmethod

import numpy as np

MOVE_FIELDS = ("index", "t0", "T", "a", "d")  # a move's row


class Hand(ABC):
    """The interface of the hand's backends: `moves(rows)` the moves (a list of rows, one per bilateral
    joint) in the form `torque(t, moves, q, dq)` reads them, which gives the hand's torque (n,): on the
    moves' joints hand_torque of the arm's angles q (n,) and velocities dq (n,), 0 elsewhere."""

    compiled: bool

    def __init__(self, n: int, stiffness: float, damping: float, max_torque: float):
        self.n = n
        self._gains = (float(stiffness), float(damping), float(max_torque))

    @abstractmethod
    def moves(self, rows: list):
        """The rows in the form `torque` reads."""

    @abstractmethod
    def torque(self, t: float, moves, q: np.ndarray, dq: np.ndarray) -> np.ndarray:
        """The hand's torque (n,) at time t."""
