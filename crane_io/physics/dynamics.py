"""Rigid-body dynamics of the CRANE-X7 for a chosen set of joints (default joint1, joint2, joint4),
the others locked, computed with pinocchio on the model of crane_io.physics.arm_model.

Sign convention: every torque here is the torque the MOTOR MUST SUPPLY (inverse-dynamics sense):
`inverse_dynamics(q, dq, ddq) = M(q) ddq + C(q, dq) dq + g(q)`. The gravity load that gravity itself
applies to a joint is the negative of `gravity_torque(q)`; e.g. joint 2 holding the arm straight out
forward-tilted (q2 = +90 deg) needs about -3.64 N m.

All methods take (J,) arrays for one sample or (N, J) arrays for N samples (joint order =
`joint_names`, the order given to the constructor) and return arrays of matching leading shape.

Base parameters (numerical): the joint-torque regressor Y(q, dq, ddq) (N J x 10 nb, the standard
parameters of each body: m, m c_x, m c_y, m c_z, I_xx, I_xy, I_yy, I_xz, I_yz, I_zz about the
joint origin, pinocchio's order) is stacked over 400 random samples drawn with a fixed seed from
the joint limits, |dq| <= 3 rad/s and |ddq| <= 20 rad/s^2. A QR decomposition with column pivoting
W P = Q R gives the rank r (|R_ii| > 1e-8 |R_00|); the first r pivoted columns are the independent
ones, and each dependent column is written as a combination of them (beta = R11^-1 R12). Base
parameters are phi_b = phi_1 + beta phi_2 and the base regressor is Y[:, independent]; then
Y phi = Y_b phi_b exactly for every sample. Computed once per ArmDynamics and cached.
"""

from __future__ import annotations

import math

import numpy as np
import pinocchio as pin

from crane_io.errors import ConfigError
from crane_io.physics.arm_model import GRAVITY, TOOL_FRAME, reduced_model

PARAMETER_NAMES = ("m", "mx", "my", "mz", "Ixx", "Ixy", "Iyy", "Ixz", "Iyz", "Izz")
PARAMETER_UNITS = ("kg", "kg m", "kg m", "kg m", "kg m^2", "kg m^2", "kg m^2", "kg m^2", "kg m^2", "kg m^2")

_BASE_SAMPLES = 400
_BASE_SEED = 20240607
_RANK_TOL = 1e-8


def _as_batch(x, j: int, what: str) -> tuple[np.ndarray, bool]:
    a = np.asarray(x, dtype=float)
    single = a.ndim == 1
    if single:
        a = a[None, :]
    if a.ndim != 2 or a.shape[1] != j:
        raise ConfigError(f"{what} must have shape (N, {j}) or ({j},), got {np.shape(x)}")
    return a, single


class ArmDynamics:
    """Rigid-body dynamics of the free `joints`; the rest locked at `locked` angles (rad, default 0).

    payload_mass (kg) is a point mass at the tool frame (0.08 m beyond the gripper base). `identified`: an
    IdentifiedArm (crane_io.physics.identified_model) whose bodies replace the description's; it must
    have been identified for these free joints locked at these angles.
    """

    def __init__(self, joints=("joint1", "joint2", "joint4"), locked: dict[str, float] | None = None,
                 payload_mass: float = 0.0, gravity: float = GRAVITY, identified=None):
        joints = tuple(joints)
        self.locked = {k: float(v) for k, v in (locked or {}).items()}
        clash = [n for n in self.locked if n in joints]
        if clash:
            raise ConfigError(f"joint(s) {', '.join(clash)} cannot be both free and locked in the dynamics")
        self.payload_mass = float(payload_mass)
        self.gravity = float(gravity)
        self.model = reduced_model(joints, self.locked, self.payload_mass, self.gravity)
        if identified is not None:  # crane_io.physics.identified_model.IdentifiedArm: its bodies
            identified.check_configuration(joints, self.locked)
            for name, v in identified.bodies.items():
                self.model.inertias[self.model.getJointId(name)] = pin.Inertia.FromDynamicParameters(v)
        self.data = self.model.createData()
        model_order = [self.model.names[i] for i in range(1, self.model.njoints)]
        self.joint_names: tuple[str, ...] = joints
        # perm[k] = model index of user joint k
        self._perm = np.array([model_order.index(n) for n in joints])
        self._identity = bool(np.all(self._perm == np.arange(len(joints))))
        self.nbodies = self.model.njoints - 1
        self._base = None
        self._base_rows: dict[tuple, tuple] = {}  # _base_decomposition_rows, per set of model-order rows
        tool = self.model.getFrameId(TOOL_FRAME)
        self._tool_joint = self.model.frames[tool].parentJoint
        self._tool_placement = self.model.frames[tool].placement.copy()

    # ---- helpers -----------------------------------------------------------------------------------
    @property
    def n_joints(self) -> int:
        return len(self.joint_names)

    def _to_model(self, a: np.ndarray) -> np.ndarray:
        if self._identity:
            return a
        out = np.empty_like(a)
        out[..., self._perm] = a
        return out

    def _from_model(self, a: np.ndarray) -> np.ndarray:
        return a if self._identity else a[..., self._perm]

    def _batches(self, *arrays_and_names):
        j = self.n_joints
        out, single = [], None
        for arr, what in arrays_and_names:
            a, s = _as_batch(arr, j, what)
            out.append(self._to_model(a))
            single = s if single is None else single
        n = {len(a) for a in out}
        if len(n) != 1:
            raise ConfigError(f"inputs have different numbers of samples: {sorted(n)}")
        if not all(np.isfinite(a).all() for a in out):
            raise ConfigError("the dynamics inputs contain NaN or infinite values")
        return out, single

    # ---- dynamics -----------------------------------------------------------------------------------
    def inverse_dynamics(self, q, dq, ddq) -> np.ndarray:
        """Torque the motors must supply (N, J): M ddq + C dq + g."""
        (q, dq, ddq), single = self._batches((q, "q"), (dq, "dq"), (ddq, "ddq"))
        m, d = self.model, self.data
        out = np.empty_like(q)
        for i in range(len(q)):
            out[i] = pin.rnea(m, d, q[i], dq[i], ddq[i])
        out = self._from_model(out)
        return out[0] if single else out

    def forward_dynamics(self, q, dq, tau) -> np.ndarray:
        """Joint accelerations (N, J) under motor torque tau (no friction): M^-1 (tau - C dq - g)."""
        (q, dq, tau), single = self._batches((q, "q"), (dq, "dq"), (tau, "tau"))
        m, d = self.model, self.data
        out = np.empty_like(q)
        for i in range(len(q)):
            out[i] = pin.aba(m, d, q[i], dq[i], tau[i])
        out = self._from_model(out)
        return out[0] if single else out

    def gravity_torque(self, q) -> np.ndarray:
        """Torque the motors must supply to hold the arm still at q (N, J): g(q)."""
        if self._identity and type(q) is np.ndarray and q.shape == (self.n_joints,) and q.dtype == float:
            # one pose, already in the model's order (the control loop's call, every cycle): the same
            # pinocchio call without the batch bookkeeping
            if not all(map(math.isfinite, q.tolist())):  # np.isfinite(q).all(), in a third of the time
                raise ConfigError("the dynamics inputs contain NaN or infinite values")
            return np.array(pin.computeGeneralizedGravity(self.model, self.data, q))
        (q,), single = self._batches((q, "q"))
        m, d = self.model, self.data
        out = np.empty_like(q)
        for i in range(len(q)):
            out[i] = pin.computeGeneralizedGravity(m, d, q[i])
        out = self._from_model(out)
        return out[0] if single else out

    def nonlinear_effects(self, q, dq) -> np.ndarray:
        """C(q, dq) dq + g(q), (N, J)."""
        (q, dq), single = self._batches((q, "q"), (dq, "dq"))
        m, d = self.model, self.data
        out = np.empty_like(q)
        for i in range(len(q)):
            out[i] = pin.nonLinearEffects(m, d, q[i], dq[i])
        out = self._from_model(out)
        return out[0] if single else out

    def mass_matrix(self, q) -> np.ndarray:
        """Joint-space inertia matrix (N, J, J) or (J, J), in joint_names order."""
        (q,), single = self._batches((q, "q"))
        m, d = self.model, self.data
        j = self.n_joints
        out = np.empty((len(q), j, j))
        for i in range(len(q)):
            mm = pin.crba(m, d, q[i])
            out[i] = np.triu(mm) + np.triu(mm, 1).T
        if not self._identity:
            out = out[:, self._perm][:, :, self._perm]
        return out[0] if single else out

    def mass_matrix_diagonal(self, q) -> np.ndarray:
        """The diagonal of mass_matrix(q), (N, J) or (J,): the joints' own link inertias M_ii(q)."""
        if self._identity and type(q) is np.ndarray and q.shape == (self.n_joints,) and q.dtype == float:
            # one pose in the model's order (the controller's pose-dependent inertia): the same values
            # (mass_matrix's diagonal is crba's plus the 0 of the mirrored strict upper triangle)
            if not all(map(math.isfinite, q.tolist())):
                raise ConfigError("the dynamics inputs contain NaN or infinite values")
            return pin.crba(self.model, self.data, q).diagonal() + 0.0
        return np.diagonal(self.mass_matrix(q), axis1=-2, axis2=-1).copy()

    # ---- regressors ------------------------------------------------------------------------------------
    def _regressor_model_order(self, q, dq, ddq) -> np.ndarray:
        m, d = self.model, self.data
        out = np.empty((len(q), self.n_joints, 10 * self.nbodies))
        for i in range(len(q)):
            out[i] = pin.computeJointTorqueRegressor(m, d, q[i], dq[i], ddq[i])
        return out

    def regressor(self, q, dq, ddq) -> np.ndarray:
        """Joint-torque regressor (N, J, 10 nbodies): inverse_dynamics = regressor @ standard_parameters()."""
        (q, dq, ddq), single = self._batches((q, "q"), (dq, "dq"), (ddq, "ddq"))
        out = self._regressor_model_order(q, dq, ddq)
        if not self._identity:
            out = out[:, self._perm]
        return out[0] if single else out

    def standard_parameters(self) -> np.ndarray:
        """(10 nbodies,) standard inertial parameters of the bodies (locked links merged in)."""
        return np.concatenate([self.model.inertias[i].toDynamicParameters()
                               for i in range(1, self.model.njoints)])

    def standard_parameter_names(self) -> list[str]:
        """'<joint>.<param>' for each standard parameter, e.g. 'joint2.Izz' (body moved by joint2)."""
        bodies = [self.model.names[i] for i in range(1, self.model.njoints)]
        return [f"{b}.{p}" for b in bodies for p in PARAMETER_NAMES]

    def standard_parameter_units(self) -> list[str]:
        return list(PARAMETER_UNITS) * self.nbodies

    def _base_decomposition(self):
        if self._base is None:
            self._base = self._decompose()
        return self._base

    def _decompose(self, model_rows=None) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """(independent columns, dependent columns, beta) of the regressor stacked over the fixed random
        samples (module docstring), over the rows `model_rows` (model order; None: every row)."""
        import scipy.linalg  # here: a simulated run never needs it, and importing it costs ~0.3 s of start-up

        rng = np.random.default_rng(_BASE_SEED)
        lo = np.array([self.model.lowerPositionLimit[k] for k in range(self.model.nq)])
        hi = np.array([self.model.upperPositionLimit[k] for k in range(self.model.nq)])
        n = _BASE_SAMPLES
        q = rng.uniform(lo, hi, size=(n, self.n_joints))
        dq = rng.uniform(-3, 3, size=(n, self.n_joints))
        ddq = rng.uniform(-20, 20, size=(n, self.n_joints))
        w = self._regressor_model_order(q, dq, ddq)
        if model_rows is not None:
            w = w[:, list(model_rows)]
        w = w.reshape(-1, 10 * self.nbodies)
        _, r, piv = scipy.linalg.qr(w, mode="economic", pivoting=True)
        diag = np.abs(np.diag(r))
        rank = int(np.sum(diag > _RANK_TOL * diag[0]))
        indep, dep = piv[:rank], piv[rank:]
        beta = scipy.linalg.solve_triangular(r[:rank, :rank], r[:rank, rank:])
        # tidy numerical dust so combinations read cleanly
        beta[np.abs(beta) < 1e-10] = 0.0
        return indep, dep, beta

    def base_regressor(self, q, dq, ddq) -> np.ndarray:
        """(N, J, B): inverse_dynamics = base_regressor @ base_parameters()."""
        (q, dq, ddq), single = self._batches((q, "q"), (dq, "dq"), (ddq, "ddq"))
        indep, _, _ = self._base_decomposition()
        out = self._regressor_model_order(q, dq, ddq)[:, :, indep]
        if not self._identity:
            out = out[:, self._perm]
        return out[0] if single else out

    def base_parameters(self) -> np.ndarray:
        """(B,) base parameters phi_1 + beta phi_2 of this model's standard parameters."""
        indep, dep, beta = self._base_decomposition()
        phi = self.standard_parameters()
        return phi[indep] + beta @ phi[dep]

    @property
    def n_base(self) -> int:
        return len(self._base_decomposition()[0])

    def base_parameter_names(self) -> list[str]:
        """Short name of each base parameter: its leading standard parameter, with '+' when others
        were merged into it (see base_parameter_expressions for the full combination)."""
        indep, dep, beta = self._base_decomposition()
        names = self.standard_parameter_names()
        return [names[c] + ("+" if np.any(beta[k] != 0) else "") for k, c in enumerate(indep)]

    def base_parameter_expressions(self) -> list[str]:
        """Each base parameter as a linear combination of standard parameters."""
        indep, dep, beta = self._base_decomposition()
        names = self.standard_parameter_names()
        out = []
        for k, c in enumerate(indep):
            terms = [names[c]] + [f"{beta[k, i]:+.6g}*{names[d]}"
                                  for i, d in enumerate(dep) if beta[k, i] != 0]
            out.append(" ".join(terms))
        return out

    # ---- base parameters seen from some joints' rows only ---------------------------------------------
    # A learning model may free more joints than it learns (train: the other joints' recorded motion
    # enters the kinematics) and then has torque data for the rows of its learning joints only. The
    # parameters identifiable from those rows are the base parameters of the regressor restricted to
    # them: the same construction as above (same random samples, QR with column pivoting) on the chosen
    # rows. With every joint's row chosen these are exactly base_regressor / base_parameters.
    def _row_index(self, rows) -> np.ndarray:
        rows = tuple(rows)
        bad = [r for r in rows if r not in self.joint_names]
        if bad or not rows:
            raise ConfigError(f"rows {', '.join(bad) or '(none)'} are not free joints of this model "
                              f"({', '.join(self.joint_names)})")
        return np.array([self.joint_names.index(r) for r in rows])

    def _base_decomposition_rows(self, rows):
        rows = tuple(rows)
        if sorted(rows) == sorted(self.joint_names):
            return self._base_decomposition()
        key = tuple(sorted(self._perm[self._row_index(rows)].tolist()))  # model-order rows
        if key not in self._base_rows:
            self._base_rows[key] = self._decompose(key)
        return self._base_rows[key]

    def base_regressor_rows(self, q, dq, ddq, rows) -> np.ndarray:
        """(N, len(rows), B_rows): the torques of the joints `rows` (names, in that order) =
        base_regressor_rows @ base_parameters_rows(rows). q, dq, ddq cover every free joint."""
        (q, dq, ddq), single = self._batches((q, "q"), (dq, "dq"), (ddq, "ddq"))
        indep, _, _ = self._base_decomposition_rows(rows)
        out = self._regressor_model_order(q, dq, ddq)[:, self._perm[self._row_index(rows)]][:, :, indep]
        return out[0] if single else out

    def base_parameters_rows(self, rows) -> np.ndarray:
        indep, dep, beta = self._base_decomposition_rows(rows)
        phi = self.standard_parameters()
        return phi[indep] + beta @ phi[dep]

    def base_parameter_names_rows(self, rows) -> list[str]:
        indep, dep, beta = self._base_decomposition_rows(rows)
        names = self.standard_parameter_names()
        return [names[c] + ("+" if np.any(beta[k] != 0) else "") for k, c in enumerate(indep)]

    def base_independent_columns_rows(self, rows) -> np.ndarray:
        """Indices of the standard parameters that are the base parameters of `rows` (their leading ones)."""
        return self._base_decomposition_rows(rows)[0]

    def base_map_rows(self, rows) -> np.ndarray:
        """(B_rows, 10 nbodies) matrix K of the base parameters of `rows` as combinations of the standard
        parameters: base_parameters_rows(rows) = K @ standard_parameters() (model order)."""
        indep, dep, beta = self._base_decomposition_rows(rows)
        k = np.zeros((len(indep), 10 * self.nbodies))
        k[np.arange(len(indep)), indep] = 1.0
        k[:, dep] = beta
        return k

    def body_names(self) -> list[str]:
        """The name of each body's joint, in the order of standard_parameters()."""
        return [self.model.names[i] for i in range(1, self.model.njoints)]

    # ---- payload -------------------------------------------------------------------------------------
    def payload_torque(self, q, dq, ddq, mass: float = 1.0) -> np.ndarray:
        """(N, J) extra motor torque caused by a point mass (kg) at the tool frame; linear in mass."""
        (q, dq, ddq), single = self._batches((q, "q"), (dq, "dq"), (ddq, "ddq"))
        point = pin.Inertia(1.0, self._tool_placement.translation.copy(), np.zeros((3, 3)))
        params = point.toDynamicParameters()
        block = slice(10 * (self._tool_joint - 1), 10 * self._tool_joint)
        reg = self._regressor_model_order(q, dq, ddq)[:, :, block]
        out = self._from_model(reg @ params) * float(mass)
        return out[0] if single else out
