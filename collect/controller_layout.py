"""The 4-channel controller's data and arrays, and the interface of its two backends.

`BilateralController` (collect/controller.py) holds the configuration's parameters, the gravity and
inertia models; the arithmetic of a cycle is its backend's, chosen when the controller is built:
- `NumpyLaw` (collect/controller_numpy.py), the reference: numpy arrays, learned reaction models, the
  friction dither; runs on real arms;
- `CompiledLaw` (collect/controller_kernel.py): the same operations per joint compiled with numba, the
  same bits, one call per cycle; a simulated run takes it.

Both implement `ControlLaw`. The compiled one keeps its state and reads its parameters in the arrays laid
out here (rows of (rows, n) float64 arrays, n the arm's joints); the safety monitor writes its limits in
the rows `SAFETY_ROWS` names (SafetyMonitor.kernel_constants).
"""

from __future__ import annotations

import functools
from abc import ABC, abstractmethod
from dataclasses import dataclass

import numpy as np


@dataclass
class ArmSignals:
    """What one arm's bus read gave this cycle, in arm.joints order (SI)."""

    q: np.ndarray  # (n,) rad
    dq_servo: np.ndarray | None = None  # (n,) rad/s, servo-reported (recorded, not used by the law)
    current: np.ndarray | None = None  # (n,) A, servo-reported


@dataclass
class ArmEstimates:
    """The controller's internal signals for one arm, recorded in the session."""

    dq: np.ndarray  # (n,) rad/s, pseudo-derivative
    tau_dis: np.ndarray  # (n,) N m, DOB estimate (NaN for held joints)
    tau_res: np.ndarray  # (n,) N m, RFOB estimate (NaN for held joints)


@dataclass
class Commands:
    """Goal torques and currents for both arms, (n,) in arm.joints order; 0 for held joints."""

    leader_tau: np.ndarray
    follower_tau: np.ndarray
    leader_current: np.ndarray
    follower_current: np.ndarray


# state rows of one arm: pseudo-derivative integrator z, DOB low-pass y, torque applied last cycle, g J,
# the nominal inertia J, the gravity torque; the leader's rows, then the follower's (S_* + S_ARM)
S_Z, S_Y, S_AP, S_GJ, S_J, S_GRAV = range(6)
S_ARM = 6
N_STATE = 2 * S_ARM
# parameter rows: the controller's attributes of these names (`held`: NaN on the held joints, else 0),
# then exp(-g dt) of the cycle's period (BilateralController.decay)
PARAMETERS = ("g", "kp", "kd", "kf", "D", "bil", "kt", "held")
C_G, C_KP, C_KD, C_KF, C_D, C_BIL, C_KT, C_HELD = range(len(PARAMETERS))
C_DECAY = len(PARAMETERS)
N_CONST = C_DECAY + 1
# output rows: each arm's dq, tau_dis, tau_res; the goal torques and currents; `control` adds both arms'
# goal torques after the safety clamps
O_DQ_L, O_DIS_L, O_RES_L, O_DQ_F, O_DIS_F, O_RES_F, O_TAU_L, O_TAU_F, O_CUR_L, O_CUR_F = range(10)
O_LIM_L, O_LIM_F = 10, 11
N_OUT, N_OUT_CONTROL = 10, 12
# the safety monitor's rows: its attributes of these names, in this order
SAFETY_ROWS = ("soft_lower", "soft_upper", "tau_max", "stop_lower", "stop_upper", "vmax", "bil_f")
K_SOFT_LO, K_SOFT_HI, K_TAU_MAX, K_STOP_LO, K_STOP_HI, K_VMAX, K_BIL = range(len(SAFETY_ROWS))
N_SAFETY = len(SAFETY_ROWS)
# status bits of the compiled calls. `control`, per arm (leader << 0, follower << 1): in the soft zone (the
# clamps are left to SafetyMonitor.limit_torque), past a stop or the velocity guard (SafetyMonitor.check
# says which). NONFINITE: a joint the gravity model covers is NaN or infinite; nothing was done.
SOFT_ZONE, CHECK, NONFINITE = 1, 4, 16


class RowCommands(Commands):
    """Commands as rows of an output array (`O_*` below), each made when first read (the caller of the
    compiled `control` mostly reads the clamped torques instead)."""

    def __init__(self, out: np.ndarray | None = None, **fields):  # the fields are the properties below
        self._out = out
        if out is None:  # the fields given (dataclasses.replace, copy)
            Commands.__init__(self, **fields)

    @functools.cached_property
    def leader_tau(self) -> np.ndarray:
        return self._out[O_TAU_L]

    @functools.cached_property
    def follower_tau(self) -> np.ndarray:
        return self._out[O_TAU_F]

    @functools.cached_property
    def leader_current(self) -> np.ndarray:
        return self._out[O_CUR_L]

    @functools.cached_property
    def follower_current(self) -> np.ndarray:
        return self._out[O_CUR_F]


class ControlLaw(ABC):
    """One backend of BilateralController: the observers' state and a cycle's arithmetic. `leader`,
    `follower`: the ArmEstimates of the last cycle (None after `reset`); `dither`: the dither added to the
    follower's last step (n,)."""

    compiled: bool
    leader: ArmEstimates | None
    follower: ArmEstimates | None
    dither: np.ndarray

    @abstractmethod
    def reset(self) -> None:
        """Forget the observers' state: the next cycle starts them again."""

    @abstractmethod
    def step(self, leader: ArmSignals, follower: ArmSignals, dt: float) -> Commands:
        """A bilateral cycle (BilateralController.step)."""

    @abstractmethod
    def hold(self, leader: ArmSignals, follower: ArmSignals, ref_leader: tuple, ref_follower: tuple,
             dt: float) -> Commands:
        """A cycle of per-arm position control to the references (BilateralController.hold)."""

    def control(self, leader: ArmSignals, follower: ArmSignals, dt: float, safety) -> tuple:
        """`step`, the safety clamps of both goal torques (`safety.limit_torque(q, tau, dq_servo)`), `applied`
        of what they give, and the safety checks (`safety.check` of the leader, then of the follower):
        (commands, clamped leader torque, clamped follower torque, the first breach or None)."""
        cmd = self.step(leader, follower, dt)
        return (cmd, *guarded(cmd, leader, follower, safety, self.applied))

    @abstractmethod
    def applied(self, tau_leader: np.ndarray, tau_follower: np.ndarray) -> None:
        """The torques actually commanded this cycle, for the observers."""

    @abstractmethod
    def observer(self, arm: str):
        """`arm`'s observer ("leader" or "follower"): z, y, applied (None before the first cycle), J;
        model (its ModelReaction or None) and fallback (the model's joints on the nominal observer)."""


def guarded(cmd: Commands, leader: ArmSignals, follower: ArmSignals, safety, applied) -> tuple:
    """The safety clamps of both goal torques of `cmd` (`safety.limit_torque(q, tau, dq_servo)`), `applied`
    of what they give (the observers see what went out), then the safety checks (the leader's, then the
    follower's): (clamped leader torque, clamped follower torque, the first breach or None). Every cycle of
    the bilateral law and of a held or excited arm goes through it."""
    tau_l = safety.limit_torque(leader.q, cmd.leader_tau, leader.dq_servo)
    tau_f = safety.limit_torque(follower.q, cmd.follower_tau, follower.dq_servo)
    applied(tau_l, tau_f)
    breach = safety.check("leader", leader.q, leader.dq_servo)
    if breach is None:
        breach = safety.check("follower", follower.q, follower.dq_servo)
    return tau_l, tau_f, breach
