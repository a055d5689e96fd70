"""The physics model: torque = base regressor (crane_io.physics.dynamics) @ base parameters, plus the
columns of any chosen physical effects (crane_io.physics.effects), fitted by recursive least squares.

Which torque equations the fit uses (option `rows`): "all-moving", the paper's, every joint's equation
of the training samples in which every joint moves (as the paper does for its Newton-Euler baseline);
"per-joint", each joint's equation of the samples in which that joint moves (the masked loss's and the
diagnosis's choice: a standing joint's row holds an unknown static friction, a moving joint's row is
valid whatever the others do); "auto" (default): per-joint where the splits' validation set is
per-joint (from 4 learning joints on: at seven joints only ~8 % of samples have every joint moving, and
a 300-sample training set would leave some 25 equations per joint for ~60 parameters), all-moving
otherwise. Shape grids are then scored the same way on the validation set. The estimator is a real
recursive least-squares filter with forgetting factor 1: starting from theta = 0, P = p0 I, it takes the
data in time order, `block` samples (J rows each; one row each per-joint) per update

    K = P Phi^T (I + Phi P Phi^T)^-1,   theta += K (y - Phi theta),   P -= K Phi P.

With forgetting factor 1 taking one sample or a block of samples per update gives the same estimate
(block=1 is the textbook row-by-row form; the default block of 64 samples is just faster); the result
equals least squares regularised by 1/p0, i.e. plain least squares for large p0. Columns are scaled to
unit RMS on the training data before the filter runs, so p0 means the same for every column.
Standard errors: the delete-a-block jackknife over contiguous time blocks of the fit's samples
(train.evaluation.block_uncertainty; blocks of >= 3 s, 5 to 20 of them, a repeated sample in its first
occurrence's block), which holds for serially correlated residuals where sqrt(diag(s^2 P)) (s^2 =
RSS / (rows - parameters)) counts every row as independent and is too small. fit_info
records the method, the block count and the 95 % interval's factor (value +- ci95_factor x stderr,
Student's t with blocks - 1 degrees of freedom).

Reported values: the model predicts with `theta`, fitted on the data as given (the paper's causal
signals for a loop model). When the data carry the same samples filtered zero-phase (Dataset.offline,
train.data.preprocess) the same regressor, shapes and rows are fitted once more on those, and that is
what the model reports (`reported_parameters`, `parameters_table`, `effect_values`; fit_info
"reported_from" says which; the causal value stays in the table as `loop_value`): the causal
acceleration's noise (errors in a regressor) shrinks the fitted inertias and biases every coefficient
correlated with them (a spring in back-and-forth moves, a rotor inertia), which a zero-phase estimate
of the same samples, with its far less noisy acceleration, does not. Rows where the zero-phase velocity
already says a joint stands still are left out of it. There each column's angle-only part (a cogging
ripple, a spring, gravity) is filtered from the unfiltered angle as the torque is
(train.data.angle_columns), which a fast function of the filtered angle is not.

Effects: `effects=[(name, joint_name or None, shape dict or None), ...]`. A joint-scope effect with
joint None is added once per learning joint. An effect with shape parameters (e.g. a Stribeck
velocity) and no shape given tries every value of its grid and keeps the one with the lowest validation
MSE (effects are tuned one after another, in the order given). The model records every effect it uses
as data (option `effect_specs`, crane_io/physics/effects/spec.py: a library effect by name and version, a
discovered one as its terms, a user's Python effect by file and SHA-256) and rebuilds its effects from
those specs only, never by name from the library, so loading it runs no code and an effect of the same
name elsewhere is never mistaken for its own.

Context joints (the other arm joints' recorded angles enter the kinematics, option `context`, default
True): a Dataset carries the filtered q, dq, ddq of the session's other arm joints (joint1..joint7, not
the gripper; train.data.dataset). At fit, each such joint is either
* still in the training data (its filtered angle spans less than MIN_TRAVEL_RAD, 0.01 rad): locked in
  the pinocchio model at its median recorded angle (rounded to 1e-3 rad), not at 0 - a held joint sits
  wherever the session held it; or
* moving: a free joint of the pinocchio model, its recorded q, dq and ddq entering the kinematics
  (gravity direction, Coriolis and inertial coupling) - a "context joint".
The dynamics are then ArmDynamics(learning joints + context joints, locked = the still joints'
medians and any `locked` given), and the regressor is its base regressor restricted to the rows of the
learning joints (ArmDynamics.base_regressor_rows): the base parameters identifiable from the learning
joints' torques only, since the context joints' torques are not modelled. Arm joints the data does not
record stay at `locked` (default 0). With no moving context joint the regressor is exactly the plain
base regressor of the learning joints (with the still joints at their medians). A model with context
joints records them in model.json (state "context_joints"), and predicting on data without them is
refused in one sentence. `context=False` is the old model: every other joint at `locked` (default 0).

Starting from an identified arm model (option `start_from`, the [identified] table of an arm_model.toml
as train.models.rigid_body_prior.arm_model_table reads it; `start_weight` torque equations' worth): the
filter starts at the identified parameters with a finite covariance, so the fit is least squares
regularised towards them (train.models.rigid_body_prior). The model records the table it started from.
"""

from __future__ import annotations

from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

from crane_io.errors import ConfigError, CraneError

from ..data.angle_columns import columns_on
from ..data.dataset import Dataset
from ..data.splits import AUTO_ALL_MOVING_MAX_JOINTS
from ..data.splits import per_joint as per_joint_set
from ..evaluation.block_uncertainty import BlockPlan, least_squares_jackknife, sample_blocks, t_factor
from .base import Model, ModelFileError
from .model_files import read_arrays
from .recorded_effects import refuse_effect_files, specs_for

if TYPE_CHECKING:
    from crane_io.physics.dynamics import ArmDynamics

ARRAYS = "rigid_body.npz"
_DYNAMICS_CACHE: dict = {}  # building the pinocchio model and its base decomposition is the slow part


def _arm_dynamics(joints, locked, payload_mass):
    key = (tuple(joints), tuple(sorted((locked or {}).items())), float(payload_mass))
    if key not in _DYNAMICS_CACHE:
        from crane_io.physics.dynamics import ArmDynamics
        _DYNAMICS_CACHE[key] = ArmDynamics(joints=tuple(joints), locked=locked or None,
                                           payload_mass=payload_mass)
    return _DYNAMICS_CACHE[key]


def rls(Phi: np.ndarray, y: np.ndarray, block: int = 64, p0=1e8) -> tuple[np.ndarray, np.ndarray]:
    """Recursive least squares, forgetting factor 1, from theta = 0. Phi (N, k, p) stacked rows per
    sample, y (N, k); p0: the initial covariance's diagonal (a number, or one per parameter).
    Returns (theta (p,), P (p, p))."""
    Phi = np.asarray(Phi, dtype=float)
    y = np.asarray(y, dtype=float)
    n, k, p = Phi.shape
    theta = np.zeros(p)
    P = np.diag(np.broadcast_to(np.asarray(p0, dtype=float), (p,))).copy()
    for start in range(0, n, block):
        A = Phi[start:start + block].reshape(-1, p)
        b = y[start:start + block].reshape(-1)
        PA = P @ A.T  # (p, m)
        S = np.eye(len(b)) + A @ PA
        K = np.linalg.solve(S, PA.T).T  # (p, m) = P A^T S^-1 (S symmetric)
        theta = theta + K @ (b - A @ theta)
        P = P - K @ PA.T
        P = 0.5 * (P + P.T)
    return theta, P


FIT_ROWS = ("auto", "all-moving", "per-joint")
REPORTED_ZERO_PHASE = ("zero-phase derivatives of the same samples (the model predicts with its causal fit, "
                       "`loop_value`)")
REPORTED_OWN = "the model's own fit"


class RigidBodyModel(Model):
    method = "rigid-body"

    def __init__(self, joint_names, preprocessing: dict | None = None, effects=(), effect_specs=None,
                 block: int = 64, p0: float = 1e8, payload_mass: float = 0.0, locked: dict | None = None,
                 context: bool = True, rows: str = "auto", effect_files=(), start_from: dict | None = None,
                 start_weight: float = 100.0):
        refuse_effect_files(effect_files)
        if not (np.isfinite(start_weight) and start_weight > 0):
            raise ConfigError(f"start_weight must be a positive number of torque equations, got "
                              f"{start_weight}")
        if rows not in FIT_ROWS:
            raise ConfigError(f"rows must be one of {', '.join(FIT_ROWS)}, got {rows!r}")
        specs = []
        for spec in effects or ():
            if isinstance(spec, str):
                spec = (spec, None, None)
            spec = tuple(spec) + (None,) * (3 - len(spec))
            specs.append([spec[0], spec[1], dict(spec[2]) if spec[2] else None])
        if effect_specs is None:  # a new model: the effects as the library holds them now, as data
            effect_specs = specs_for(s[0] for s in specs)
        if not isinstance(effect_specs, list) or not all(isinstance(s, dict) for s in effect_specs):
            raise ModelFileError("the model's effect_specs is not a list of effect specs")
        recorded = {s.get("name") for s in effect_specs}
        lacking = [s[0] for s in specs if s[0] not in recorded]
        if lacking:
            raise ModelFileError(f"the model uses the effect {lacking[0]!r} but records no spec of it")
        super().__init__(joint_names, preprocessing, effects=specs, effect_specs=effect_specs,
                         block=int(block), p0=float(p0), payload_mass=float(payload_mass),
                         locked=dict(locked or {}), context=bool(context), rows=rows,
                         start_from=start_from, start_weight=float(start_weight))
        self._table: dict | None = None  # effect name -> Effect, rebuilt from effect_specs
        self.block, self.p0 = int(block), float(p0)
        self._dyn: ArmDynamics | None = None
        self.context_joints: tuple[str, ...] = ()  # other arm joints that move: free in the kinematics
        self.locked_resolved: dict | None = None  # locked angles the dynamics use (None: options' locked)
        self.theta: np.ndarray | None = None
        self.stderr: np.ndarray | None = None
        self.reported: dict | None = None  # {"theta", "stderr"} from Dataset.offline, or None (theta's)
        self.names: list[str] = []
        self.terms: list[dict] = []  # resolved effect terms: name, joint (index or None), shape
        self.fit_info: dict = {}

    # ---- effects (rebuilt from the specs this model records, never looked up by name elsewhere) ----------
    def effect_table(self, where: str = "the model") -> dict:
        """name -> Effect of every effect the model uses, rebuilt from its recorded specs (a user's Python
        effect only from a file named with --effect-file whose SHA-256 is the recorded one)."""
        if self._table is None:
            from crane_io.physics.effects.spec import effect_table

            self._table = effect_table(self.options["effect_specs"], where)
        return self._table

    def effect_by_name(self, name: str):
        table = self.effect_table()
        if not isinstance(name, str) or name not in table:
            raise ModelFileError(f"the model uses the effect {name!r} but records no spec of it; fit it "
                                 f"again")
        return table[name]

    # ---- regressor -------------------------------------------------------------------------------
    @property
    def dynamics(self) -> ArmDynamics:
        """ArmDynamics of the learning joints followed by the context joints (the others locked)."""
        if self._dyn is None:
            locked = self.options["locked"] if self.locked_resolved is None else self.locked_resolved
            self._dyn = _arm_dynamics(self.joint_names + tuple(self.context_joints), locked,
                                      self.options["payload_mass"])
        return self._dyn

    @property
    def n_base(self) -> int:
        return len(self.dynamics.base_independent_columns_rows(self.joint_names))

    def base_independent_columns(self) -> np.ndarray:
        """Standard-parameter indices (of self.dynamics) of the base parameters."""
        return self.dynamics.base_independent_columns_rows(self.joint_names)

    def _resolve_context(self, ds: Dataset) -> None:
        """Which of the data's other arm joints move (free, context) and where the still ones sit."""
        given = {k: float(v) for k, v in (self.options["locked"] or {}).items()}
        ctx = ds.context if self.options.get("context", True) else None
        self._dyn = None
        if ctx is None:
            self.context_joints, self.locked_resolved = (), None
            return
        from ..data.preprocess import MIN_TRAVEL_RAD

        locked, moving = dict(given), []
        for k, name in enumerate(ctx["names"]):
            if name in given:
                continue
            col = np.asarray(ctx["q"][:, k], dtype=float)
            if len(col) and np.ptp(col) >= MIN_TRAVEL_RAD:
                moving.append(name)
            else:
                locked[name] = round(float(np.median(col)), 3) + 0.0 if len(col) else 0.0  # no -0.0
        self.context_joints, self.locked_resolved = tuple(moving), locked

    def _full_inputs(self, q, dq, ddq, context):
        """q, dq, ddq of the learning joints followed by the context joints' (from `context`)."""
        if not self.context_joints:
            return q, dq, ddq
        names = tuple((context or {}).get("names") or ())
        missing = [n for n in self.context_joints if n not in names]
        if missing:
            raise ConfigError(f"this rigid-body model's kinematics use the recorded angles of "
                              f"{', '.join(missing)} (context joints, moving in its training data), which "
                              f"the data given to it lacks; give data that records them (a Dataset from "
                              f"the sessions) or fit a model with context=False")
        idx = [names.index(n) for n in self.context_joints]
        out = []
        for a, key in ((q, "q"), (dq, "dq"), (ddq, "ddq")):
            c = np.atleast_2d(np.asarray(context[key], dtype=float))[:, idx]
            if len(c) != len(a):
                raise ConfigError(f"the context joints have {len(c)} samples but the learning joints "
                                  f"{len(a)}")
            out.append(np.hstack([a, c]))
        return tuple(out)

    def _resolve_terms(self) -> list[dict]:
        terms = []
        for name, joint, shape in self.options["effects"]:
            effect = self.effect_by_name(name)
            if effect.scope == "arm":
                if joint is not None:
                    raise ConfigError(f"effect {name} acts on the whole arm (one parameter for all joints); "
                                      f"give it without joint=")
                terms.append({"name": name, "joint": None, "shape": shape})
                continue
            if joint is None:
                joints = list(range(len(self.joint_names)))
            elif joint in self.joint_names:
                joints = [self.joint_names.index(joint)]
            else:
                raise ConfigError(f"effect {name} names joint {joint!r}, which is not one of the learning "
                                  f"joints {', '.join(self.joint_names)}")
            terms += [{"name": name, "joint": j, "shape": shape} for j in joints]
        return terms

    def _term_columns(self, term, q, dq, ddq, shape=None):
        effect = self.effect_by_name(term["name"])
        return effect.columns(q, dq, ddq, term["joint"], shape if shape is not None else term["shape"])

    def regressor(self, q: np.ndarray, dq: np.ndarray, ddq: np.ndarray, terms: list[dict] | None = None,
                  context: dict | None = None) -> np.ndarray:
        """(N, J, p) base regressor followed by every effect term's columns (predict = regressor @ theta,
        N m), from q (N, J) rad, dq (N, J) rad/s, ddq (N, J) rad/s^2. `context`: the context joints'
        {'names', 'q', 'dq', 'ddq'} (Dataset.context), needed when the model has any."""
        q, dq, ddq = (np.atleast_2d(np.asarray(a, dtype=float)) for a in (q, dq, ddq))
        fq, fdq, fddq = self._full_inputs(q, dq, ddq, context)
        if self.context_joints:
            cols = [self.dynamics.base_regressor_rows(fq, fdq, fddq, self.joint_names)]
        else:
            cols = [self.dynamics.base_regressor(q, dq, ddq)]
        for term in (self.terms if terms is None else terms):
            cols.append(self._term_columns(term, q, dq, ddq))
        return np.concatenate(cols, axis=2)

    def _parameter_names(self, terms) -> list[str]:
        names = list(self.dynamics.base_parameter_names_rows(self.joint_names))
        for term in terms:
            joint = None if term["joint"] is None else self.joint_names[term["joint"]]
            names += self.effect_by_name(term["name"]).column_names(joint, term["shape"])
        return names

    # ---- fitting ---------------------------------------------------------------------------------
    def _solve(self, ds: Dataset, terms, per_joint: bool = False, uncertainty: bool = False):
        """Least squares of the torque equations: every joint's of every sample, or (per_joint) each
        joint's only where that joint moves. Returns (theta, standard errors, residual variance, the
        block plan of the standard errors); with `uncertainty` False (the shape search) the standard
        errors are those of the least-squares covariance and the plan None."""
        Phi = columns_on(ds, lambda d: self.regressor(d.q, d.dq, d.ddq, terms, d.context))
        y = ds.tau
        sample = np.arange(len(ds))
        if per_joint:
            sample = np.nonzero(ds.moving)[0]
            Phi, y = Phi[ds.moving][:, None, :], y[ds.moving][:, None]
        scale = np.sqrt((Phi ** 2).mean(axis=(0, 1)))
        scale = np.where(scale > 1e-12, scale, 1.0)
        theta0, p0 = self._start(terms, Phi.shape[2])
        y_fit = y - Phi @ theta0  # the filter estimates the step from the start
        theta_s, P_s = rls(Phi / scale, y_fit, self.block, p0)
        theta = theta_s / scale + theta0
        resid = y - Phi @ theta
        dof = max(resid.size - len(theta), 1)
        s2 = float((resid ** 2).sum() / dof)
        if not uncertainty:
            return theta, np.sqrt(np.clip(np.diag(P_s), 0, None) * s2) / scale, s2, None
        plan = fit_blocks(ds)
        p = len(theta)
        rows = np.repeat(plan.ids[sample], y.shape[1])  # each equation's block (its sample's)
        se_s = least_squares_jackknife((Phi / scale).reshape(-1, p), y_fit.reshape(-1), rows, plan.count,
                                       ridge=1.0 / p0)
        return theta, se_s / scale, s2, plan

    def _start(self, terms, p: int) -> tuple[np.ndarray, np.ndarray]:
        """The filter's start (p,) and initial covariance diagonal (p,), in the columns' unit-RMS scale:
        zero and `p0` (plain least squares), or the identified arm model's parameters held with the
        weight of `start_weight` torque equations (train.models.rigid_body_prior)."""
        table = self.options.get("start_from")
        if not table:
            return np.zeros(p), np.full(p, self.p0)
        from .rigid_body_prior import start_point

        locked = self.options["locked"] if self.locked_resolved is None else self.locked_resolved
        theta0, given = start_point(table, self.dynamics, self.joint_names, self.context_joints, locked,
                                    self._parameter_names(terms))
        return theta0, np.where(given, 1.0 / self.options["start_weight"], self.p0)

    def _check_given_shape(self, term, ds: Dataset) -> None:
        """A shape given on the command line (`--effect stribeck:stribeck_velocity=...`) must make the
        effect's columns finite and not all zero on the data, or the fit would silently ignore it."""
        cols = self._term_columns(term, ds.q, ds.dq, ds.ddq)
        if np.all(np.isfinite(cols)) and np.abs(cols).max(initial=0.0) > 0:
            return
        where = "" if term["joint"] is None else f" on {self.joint_names[term['joint']]}"
        given = ", ".join(f"{k}={v:g}" for k, v in term["shape"].items())
        grid = self.effect_by_name(term["name"]).shape_grid
        hint = "; ".join(f"{k} is tried among {', '.join(f'{x:g}' for x in v)}" for k, v in grid.items())
        raise ConfigError(f"effect {term['name']}{where} with {given} adds "
                          f"{'nothing' if np.all(np.isfinite(cols)) else 'non-finite torque'} on this data; "
                          f"give another value or none{f' ({hint} when none is given)' if hint else ''}")

    def fit(self, train: Dataset, val: Dataset | None = None) -> RigidBodyModel:
        if tuple(train.joint_names) != self.joint_names:
            raise CraneError(f"the data has joints {', '.join(train.joint_names)} but the model was made "
                             f"for {', '.join(self.joint_names)}")
        per_joint = self._rows_mode(val) == "per-joint"
        rows = np.flatnonzero(train.moving.any(axis=1) if per_joint else train.all_moving)
        self._resolve_context(train)
        terms = self._resolve_terms()
        n_par = self.n_base + sum(self.effect_by_name(t["name"]).n_columns() for t in terms)
        self._check_enough_rows(train, rows, per_joint, n_par // len(self.joint_names) + 1)
        fit_ds = train.subset(rows)
        val_ds = _validation_rows(val, per_joint, fit_ds)
        for term in terms:
            if term["shape"] is not None:
                self._check_given_shape(term, fit_ds)
        tuned = self._tune_shapes(terms, fit_ds, val_ds, per_joint)
        self.terms = terms
        self.theta, self.stderr, s2, plan = self._solve(fit_ds, terms, per_joint, uncertainty=True)
        self.names = self._parameter_names(terms)
        self.reported = self._reported(fit_ds, terms, per_joint, n_par)
        self.fit_info = {"rows": int(len(rows)), "residual_variance": s2, "shape_search": tuned,
                         "rows_used": "per-joint" if per_joint else "all-moving",
                         "stderr_method": plan.describe(), "stderr_blocks": int(plan.count),
                         "ci95_factor": t_factor(plan.count),
                         "reported_from": REPORTED_ZERO_PHASE if self.reported else REPORTED_OWN}
        if self.options.get("start_from"):
            self.fit_info["start"] = {"arm_model": self.options["start_from"].get("source", ""),
                                      "weight": self.options["start_weight"]}
        if not self.preprocessing:
            self.preprocessing = dict(train.meta.get("preprocessing", {}))
        return self

    def _reported(self, fit_ds: Dataset, terms, per_joint: bool, n_par: int) -> dict | None:
        """{"theta", "stderr"} of the same fit on the zero-phase signals of the fit's samples (where
        those, too, say the joints move), or None when the data carry none or too few such rows."""
        off = fit_ds.offline
        if off is None:
            return None
        if not per_joint:
            off = off.subset(np.flatnonzero(off.all_moving))
        need = n_par // len(self.joint_names) + 1 if per_joint else n_par + 1
        if (off.moving.sum(axis=0).min() if per_joint else len(off)) < need:
            return None
        theta, stderr = self._solve(off, terms, per_joint, uncertainty=True)[:2]
        return {"theta": theta, "stderr": stderr}

    def _check_enough_rows(self, train: Dataset, rows: np.ndarray, per_joint: bool, need: int) -> None:
        """The fit's rows hold at least `need` samples (per joint, where each joint moves, when per-joint)."""
        if per_joint:
            counts = train.moving.sum(axis=0)
            if counts.min() < need:
                j = int(np.argmin(counts))
                raise CraneError(f"the rigid-body fit needs at least {need} samples in which each joint "
                                 f"moves; {self.joint_names[j]} moves in {int(counts[j])} of the training "
                                 "data")
        elif len(rows) < need:
            raise CraneError(f"the rigid-body fit needs at least {need} samples with every joint moving; "
                             f"the training data has {len(rows)}")

    def _tune_shapes(self, terms: list[dict], fit_ds: Dataset, val_ds: Dataset,
                     per_joint: bool) -> list[dict]:
        """Give each term without a shape the best of its effect's shape options on the validation rows
        (in place); the record of each search."""
        tuned = []
        for i, term in enumerate(terms):
            effect = self.effect_by_name(term["name"])
            options = effect.shape_options()
            if term["shape"] is not None or len(options) <= 1:
                continue
            scores = [self._shape_score(terms, i, shape, fit_ds, val_ds, per_joint) for shape in options]
            best = int(np.argmin(scores))
            terms[i]["shape"] = options[best]
            tuned.append({"effect": term["name"], "joint": term["joint"], "shape": options[best],
                          "val_mse": scores[best], "grid": options, "grid_val_mse": scores})
        return tuned

    def _shape_score(self, terms: list[dict], i: int, shape, fit_ds: Dataset, val_ds: Dataset,
                     per_joint: bool) -> float:
        """Validation mean squared error of the fit with term i given `shape`."""
        trial = [dict(t) for t in terms]
        trial[i]["shape"] = shape
        theta = self._solve(fit_ds, trial, per_joint)[0]
        pred = self.regressor(val_ds.q, val_ds.dq, val_ds.ddq, trial, val_ds.context) @ theta
        err = (val_ds.tau - pred) ** 2
        return float(err[val_ds.moving].mean() if per_joint else err.mean())

    def _rows_mode(self, val: Dataset | None) -> str:
        """Which torque equations the fit uses: "all-moving" (the paper's: every joint's, of the samples
        in which every joint moves) or "per-joint" (each joint's where that joint moves, as the
        diagnosis and the masked loss do). "auto": per-joint where the validation set is per-joint
        (train.data.splits: from 4 learning joints on, where samples with every joint moving grow scarce;
        without a validation set, by the same joint count)."""
        mode = self.options.get("rows", "auto")
        if mode != "auto":
            return mode
        if val is not None:
            return "per-joint" if per_joint_set(val) else "all-moving"
        return "per-joint" if len(self.joint_names) > AUTO_ALL_MOVING_MAX_JOINTS else "all-moving"

    @property
    def is_fitted(self) -> bool:
        return self.theta is not None

    def linear_basis(self, q: np.ndarray, dq: np.ndarray, ddq: np.ndarray,
                     context: dict | None = None) -> np.ndarray | None:
        """The regressor (base parameters and effect columns): predict = regressor @ theta."""
        return self.regressor(q, dq, ddq, context=context) if self.is_fitted else None

    def predict(self, q: np.ndarray, dq: np.ndarray, ddq: np.ndarray,
                context: dict | None = None) -> np.ndarray:
        """(N, J) joint torques, N m, from positions q (N, J) rad, velocities dq (N, J) rad/s and
        accelerations ddq (N, J) rad/s^2;
        `context`: the context joints' {'names', 'q', 'dq', 'ddq'} (Dataset.context)."""
        self._check_fitted()
        return self.regressor(q, dq, ddq, context=context) @ self.theta

    def predict_dataset(self, ds: Dataset) -> np.ndarray:
        return self.predict(ds.q, ds.dq, ds.ddq, context=ds.context)

    def reported_parameters(self) -> tuple[np.ndarray, np.ndarray]:
        """(values (p,), standard errors (p,)) the model reports: from the zero-phase signals of the
        fit's samples when the data carried them (fit_info["reported_from"] says), else its own theta."""
        if self.reported is not None:
            return self.reported["theta"], self.reported["stderr"]
        return self.theta, self.stderr

    def parameters_table(self) -> list[dict]:
        """One row per fitted parameter: name, value, standard error, relative standard error (the
        reported estimate, `reported_parameters`) and `loop_value`, the value the model predicts with."""
        out = []
        theta, stderr = self.reported_parameters()
        for name, v, se, own in zip(self.names, theta, stderr, self.theta):
            out.append({"name": name, "value": float(v), "stderr": float(se),
                        "rel_stderr": float(se / abs(v)) if v != 0 else float("inf"),
                        "loop_value": float(own)})
        return out

    def effect_values(self) -> list[dict]:
        """Named physical values of every effect term (from its reported coefficients and shape)."""
        out, k = [], self.n_base
        theta = self.reported_parameters()[0]
        for term in self.terms:
            effect = self.effect_by_name(term["name"])
            n = effect.n_columns()
            joint = None if term["joint"] is None else self.joint_names[term["joint"]]
            out.append({"effect": term["name"], "joint": joint,
                        "values": effect.values_from_coefficients(theta[k:k + n], term["shape"])})
            k += n
        return out

    # ---- persistence -----------------------------------------------------------------------------
    def _state(self) -> dict:
        return {"terms": self.terms, "names": self.names, "fit_info": self.fit_info,
                "context_joints": list(self.context_joints), "locked_resolved": self.locked_resolved}

    def _save_extra(self, directory: Path) -> None:
        extra = {} if self.reported is None else {"reported_theta": self.reported["theta"],
                                                  "reported_stderr": self.reported["stderr"]}
        np.savez(directory / ARRAYS, theta=self.theta, stderr=self.stderr, **extra)

    def _load_extra(self, directory: Path, state: dict) -> None:
        path = Path(directory) / ARRAYS
        try:
            self.theta, self.stderr = read_arrays(directory, ARRAYS, {"theta": 1, "stderr": 1}).values()
            self.terms = state["terms"]
            self.names = state["names"]
        except FileNotFoundError:
            raise ModelFileError(f"{directory} lacks its parameters {ARRAYS}; fit the model again") from None
        except KeyError as exc:
            raise ModelFileError(f"{directory} is incomplete: {exc.args[0]!r} is missing from its "
                                 f"{ARRAYS} or model.json; fit the model again") from None
        except (OSError, ValueError, EOFError):
            raise ModelFileError(f"{path} is corrupt, not a readable numpy .npz file; fit the model "
                                 f"again") from None
        self.fit_info = state.get("fit_info", {})
        self.reported = None
        if self.fit_info.get("reported_from") == REPORTED_ZERO_PHASE:
            r = read_arrays(directory, ARRAYS, {"reported_theta": 1, "reported_stderr": 1})
            if not r["reported_theta"].shape == r["reported_stderr"].shape == self.theta.shape:
                raise ModelFileError(f"{path} holds {r['reported_theta'].size} reported values for "
                                     f"{self.theta.size} parameters; fit the model again")
            self.reported = {"theta": r["reported_theta"], "stderr": r["reported_stderr"]}
        self.context_joints = tuple(state.get("context_joints") or ())  # older models: none
        lr = state.get("locked_resolved")
        self.locked_resolved = None if lr is None else {str(k): float(v) for k, v in lr.items()}
        self._dyn = None
        self._table = None
        self.effect_table(f"the model in {directory}")  # an effect it cannot rebuild: refused now
        for term in self.terms if isinstance(self.terms, list) else ():
            if isinstance(term, dict):
                self.effect_by_name(term.get("name"))


def fit_blocks(ds: Dataset) -> BlockPlan:
    """The contiguous time blocks of the fit's samples (train.evaluation.block_uncertainty): in time
    order within each segment (the training pool's rows may come in shuffled blocks), a repeated sample
    in its first occurrence's block."""
    order = np.lexsort((ds.t, ds.segment))
    rank = np.empty(len(ds), dtype=float)
    rank[order] = np.arange(len(ds))
    values = np.hstack([ds.q, ds.dq, ds.ddq, ds.tau])
    return sample_blocks(rank, ds.rate_hz, values)


def _validation_rows(val: Dataset | None, per_joint: bool, fit_ds: Dataset) -> Dataset:
    """The validation rows the shape search scores on: the fit's own rows without a validation set or
    where the validation set has none."""
    if per_joint:
        val_ds = val.subset(np.flatnonzero(val.moving.any(axis=1))) if val is not None else fit_ds
    else:
        val_ds = val.subset(np.flatnonzero(val.all_moving)) if val is not None else fit_ds
    if len(val_ds) == 0:  # a per-joint validation set (train.data.splits) may hold no all-moving row
        val_ds = fit_ds
    return val_ds
