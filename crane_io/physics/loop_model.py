"""A saved crane-train model as the 500 Hz control loop uses it: one sample at a time, float64 numpy, no
torch, no train package.

    model = LoopModel.load("models/masked")    # LoopModelError (one sentence) if the loop cannot use it
    model.check_for_arm(arm.bilateral_joints, "follower")
    tau = model.predict_one(q, dq, ddq)         # (J,) rad, rad/s, rad/s^2 in joint_names order -> N m

What is read: the model directory's `model.json` (format "crane-model": method, joint names, the
preprocessing the training data went through, units, the arm) and its numeric export `loop_model.npz`,
written by crane-train next to model.json (`Model.save`, or `crane-train export DIR` for a model saved
before exports existed). The export holds plain arrays only (loaded without pickle):

    format_version      int, EXPORT_FORMAT_VERSION
    method, joint_names the model's; must agree with model.json
    units               JSON {"q": "rad", "dq": "rad/s", "ddq": "rad/s^2", "tau": "N m"}
    source_files        the model's weight files (relative paths) and source_sha256, one SHA-256 over
    source_sha256       them: an export older than the weights it was made from is refused
    mlp_W1 (3J, H), mlp_b1 (H,), mlp_W2 (H, J), mlp_b2 (J,), mlp_x_mean/x_std (3J,), mlp_y_mean/y_std (J,)
                        the network (mlp-mse, mlp-masked, hybrid), float64 copies of its float32 weights
    rigid_theta_full    (10 nbodies,) standard parameters: the fitted base parameters at the independent
                        columns, zero at the dependent ones (rigid-body, hybrid)
    rigid_locked_joints, rigid_locked_angles, rigid_payload_mass
                        how the model's ArmDynamics was built (joints = joint_names; the locked angles
                        are the other joints' recorded medians for a model fitted with context)
    rigid_context_joints  (only when present) other joints whose recorded motion the model's kinematics
                        read; the loop gets the model's own joints only, so loading such a model is
                        refused in one sentence
    rigid_effects       JSON list of effect terms {"name", "joint" (index or null), "shape", "n_coefs"}
    rigid_effect_coefs  their coefficients, concatenated in that order
    rigid_effect_specs  JSON list of the effects the terms use, as data (crane_io/physics/effects/spec.py):
                        rebuilt without running code; an effect defined in a user's Python file is
                        refused unless that file was named (offer_effect_files) with the recorded SHA-256.
                        An older export without it may use built-in effects only; one that lists
                        `rigid_effect_files` (Python files) is refused

`sha256` is the hex digest of loop_model.npz's bytes (the weights the loop runs with); when model.json
records the export's digest (`"loop_export": {"sha256": ...}`, written by Model.save) the two must agree.

The forward paths (also used by train.models.fast_predict):
- MLPPath: y = relu(x W1' + b1') W2' + b2' with the input and output standardisation folded in;
- RigidPath: pinocchio's joint-torque regressor of the one sample @ theta_full, plus each effect term
  (a one-joint effect defined by its `formula`, crane_io/physics/effects/base.py, evaluates that formula on
  floats; any other effect goes through its `columns`, which allocates);
- hybrid: the sum of the two.
Buffers are allocated once; `predict_one` writes into `out` (default: a buffer of the model that the
next call overwrites). Inputs are not checked in the call. Against the model's own `predict` (torch
float32 for the networks) the result agrees to float32 precision (about 1e-6 relative).
"""

from __future__ import annotations

import hashlib
import json
import math
from pathlib import Path

import numpy as np

from crane_io.errors import ConfigError, CraneError
from crane_io.physics.effects.base import SCALAR_OPS, smooth_sign_ops
from crane_io.physics.loop_model_check import export_problem, npz_arrays, preprocessing_problem, read_bytes

MODEL_JSON = "model.json"
EXPORT_FILE = "loop_model.npz"
EXPORT_FORMAT_VERSION = 1
SI_UNITS = {"q": "rad", "dq": "rad/s", "ddq": "rad/s^2", "tau": "N m"}
METHODS = ("rigid-body", "mlp-mse", "mlp-masked", "hybrid")
NETWORK_METHODS = ("mlp-mse", "mlp-masked", "hybrid")
RIGID_METHODS = ("rigid-body", "hybrid")
ARMS = ("leader", "follower")
MLP_KEYS = ("W1", "b1", "W2", "b2", "x_mean", "x_std", "y_mean", "y_std")


class LoopModelError(CraneError):
    """A model directory the control loop cannot use (one sentence naming the directory)."""


# ---- forward paths --------------------------------------------------------------------------------------
class MLPPath:
    """The paper's network in float64: y = relu(x W1' + b1') W2' + b2', x = [q, dq, ddq], with the
    standardisation ((x - x_mean) / x_std in, y y_std + y_mean out) folded into the weights once."""

    def __init__(self, W1, b1, W2, b2, x_mean, x_std, y_mean, y_std):
        w1, w2 = np.asarray(W1, dtype=np.float64), np.asarray(W2, dtype=np.float64)  # (D, H), (H, J)
        b1, b2 = np.asarray(b1, dtype=np.float64), np.asarray(b2, dtype=np.float64)
        x_mean, x_std = np.asarray(x_mean, dtype=np.float64), np.asarray(x_std, dtype=np.float64)
        y_mean, y_std = np.asarray(y_mean, dtype=np.float64), np.asarray(y_std, dtype=np.float64)
        d, h = w1.shape
        # the biases ride along as the last row of each matrix (input and hidden vectors end in a 1), so
        # a call is two matrix products and a ReLU, all into preallocated buffers
        self.w1b = np.vstack([w1 / x_std[:, None], (b1 - (x_mean / x_std) @ w1)[None, :]])  # (D+1, H)
        self.w2b = np.vstack([w2 * y_std[None, :], (b2 * y_std + y_mean)[None, :]])  # (H+1, J)
        self.w1, self.b1 = self.w1b[:d], self.w1b[d]
        self.w2, self.b2 = self.w2b[:h], self.w2b[h]
        self.n_joints = self.w2.shape[1]
        self._x = np.ones(d + 1)
        self._h = np.ones(h + 1)
        self._hh = self._h[:h]  # the ReLU's part (the trailing 1 stays)

    @staticmethod
    def check_shapes(arrays: dict) -> str | None:
        """What is wrong with the shapes of a network's arrays {W1, b1, ..., y_std}, or None."""
        w1, w2 = np.shape(arrays["W1"]), np.shape(arrays["W2"])
        if len(w1) != 2 or len(w2) != 2:
            return f"its network weights have shapes {w1} and {w2}, not matrices"
        d, h = w1
        j = w2[1]
        want = {"W2": (h, j), "b1": (h,), "b2": (j,), "x_mean": (d,), "x_std": (d,), "y_mean": (j,),
                "y_std": (j,)}
        for k, shape in want.items():
            if np.shape(arrays[k]) != shape:
                return f"its network array {k} has shape {np.shape(arrays[k])}, expected {shape}"
        if d != 3 * j:
            return f"its network takes {d} inputs for {j} joints (expected {3 * j})"
        return None

    def __call__(self, q, dq, ddq, out: np.ndarray) -> np.ndarray:
        j, x, hh = self.n_joints, self._x, self._hh
        x[:j] = q
        x[j:2 * j] = dq
        x[2 * j:3 * j] = ddq
        np.dot(x, self.w1b, out=hh)
        np.maximum(hh, 0.0, out=hh)
        np.dot(self._h, self.w2b, out=out)
        return out


def _smoothed_effects() -> frozenset[str]:
    """The built-in effects whose sign(dq) set_coulomb_velocity smooths (the library's friction effects)."""
    from crane_io.physics.effects import library

    return frozenset(cls.name for cls in library.BUILTIN_EFFECTS if cls.friction)


class RigidPath:
    """Base regressor of one sample (pinocchio) @ standard parameters, plus effect terms.

    `theta_full`: (10 nbodies,) standard parameters of the dynamics of `joint_names` (the others locked
    at `locked`, a point mass `payload_mass` at the tool), or give a built `dynamics`
    (crane_io.physics.dynamics.ArmDynamics) instead; `terms`: [(effect instance, joint index or None,
    shape dict or None, coefficients), ...]."""

    def __init__(self, joint_names, theta_full, terms=(), locked: dict | None = None,
                 payload_mass: float = 0.0, dynamics=None):
        import pinocchio as pin

        if dynamics is None:
            from crane_io.physics.dynamics import ArmDynamics

            dynamics = ArmDynamics(joints=tuple(joint_names), locked=locked or None,
                                   payload_mass=payload_mass)
        self.dynamics = dynamics
        self._pin = pin
        self._model = dynamics.model
        self._data = dynamics.model.createData()  # a data of its own: the dynamics may be used elsewhere
        self._perm = None if dynamics._identity else np.asarray(dynamics._perm)
        self.n_joints = dynamics.n_joints
        self.theta_full = np.asarray(theta_full, dtype=np.float64).copy()
        if self.theta_full.shape != (10 * dynamics.nbodies,):
            raise ConfigError(f"the rigid-body parameters have shape {self.theta_full.shape}, expected "
                              f"({10 * dynamics.nbodies},) for joints {', '.join(dynamics.joint_names)}")
        self._qm, self._dqm, self._ddqm = (np.empty(self.n_joints) for _ in range(3))
        self._tau_model = np.empty(self.n_joints)
        self.scalar_terms: list[tuple] = []  # (joint, effect, coefficients, shape): its formula on floats
        self.generic_terms: list[tuple] = []  # (effect, joint or None, shape, coefficients)
        for effect, joint, shape, coefs in terms:
            coefs = np.asarray(coefs, dtype=np.float64).ravel()
            if coefs.shape != (effect.n_columns(),):
                raise ConfigError(f"effect {effect.name} has {effect.n_columns()} coefficients, "
                                  f"{coefs.size} were given")
            if joint is not None and not 0 <= int(joint) < self.n_joints:
                raise ConfigError(f"effect {effect.name} acts on joint index {joint}, out of range for "
                                  f"{self.n_joints} joints")
            if joint is not None and effect.has_scalar_form:
                self.scalar_terms.append((int(joint), effect, tuple(float(c) for c in coefs),
                                          effect._shape(shape)))
            else:
                self.generic_terms.append((effect, None if joint is None else int(joint), shape, coefs))
        self._formulas = tuple((j, effect.formula, coefs, shape)
                               for j, effect, coefs, shape in self.scalar_terms)
        self._ops = SCALAR_OPS  # as fitted: sign(dq)
        self.coulomb_velocity = 0.0

    def set_coulomb_velocity(self, v0: float) -> None:
        """The friction terms' sign(dq) becomes tanh(dq / v0) (v0 rad/s > 0; 0: the sign as fitted, the
        model's own prediction). Applies to the built-in coulomb, coulomb-asym, stribeck and stiction
        terms; ConfigError for a negative or non-finite v0, or when such a term is not one of the
        scalar built-in terms (a user effect named like one, or one acting on every joint)."""
        v0 = float(v0)
        if not (math.isfinite(v0) and v0 >= 0):
            raise ConfigError(f"the Coulomb smoothing velocity must be zero or a positive number of "
                              f"rad/s, not {v0}")
        smoothed = _smoothed_effects()
        for effect, _, _, _ in self.generic_terms:
            if v0 > 0 and effect.name in smoothed:
                raise ConfigError(f"the effect term {effect.name} of this model cannot be smoothed in the "
                                  f"loop (it is not a built-in term of one joint)")
        self._ops = SCALAR_OPS if v0 == 0 else smooth_sign_ops(v0)
        self.coulomb_velocity = v0

    def __call__(self, q, dq, ddq, out: np.ndarray) -> np.ndarray:
        if self._perm is None:
            qm, dqm, ddqm = q, dq, ddq
        else:
            qm, dqm, ddqm = self._qm, self._dqm, self._ddqm
            qm[self._perm] = q
            dqm[self._perm] = dq
            ddqm[self._perm] = ddq
        y = self._pin.computeJointTorqueRegressor(self._model, self._data, qm, dqm, ddqm)
        if self._perm is None:
            np.dot(y, self.theta_full, out=out)
        else:
            np.dot(y, self.theta_full, out=self._tau_model)
            out[:] = self._tau_model[self._perm]
        if self._formulas:  # on Python floats: faster than numpy scalars
            qs, vs, accs = q.tolist(), dq.tolist(), ddq.tolist()
            ops = self._ops
            for joint, formula, coefs, shape in self._formulas:
                out[joint] += formula(qs[joint], vs[joint], accs[joint], coefs, shape, ops)
        for effect, joint, shape, coefs in self.generic_terms:
            out += effect.columns(q[None], dq[None], ddq[None], joint, shape)[0] @ coefs
        return out


class PathSum:
    """The sum of forward paths for one sample: `predict_one(q, dq, ddq, out=None) -> (J,) N m`."""

    def __init__(self, joint_names, paths):
        self.joint_names = tuple(joint_names)
        self.paths = list(paths)
        self._first, self._rest = self.paths[0], tuple(self.paths[1:])
        self._out = np.zeros(len(self.joint_names))
        self._part = np.zeros(len(self.joint_names))

    def predict_one(self, q: np.ndarray, dq: np.ndarray, ddq: np.ndarray,
                    out: np.ndarray | None = None) -> np.ndarray:
        """(J,) motor torque, N m, for one sample of (J,) q rad, dq rad/s, ddq rad/s^2 (float64)."""
        out = self._out if out is None else out
        self._first(q, dq, ddq, out)
        for path in self._rest:
            out += path(q, dq, ddq, self._part)
        return out


# ---- the loaded model -------------------------------------------------------------------------------------
def file_sha256(path) -> str:
    return hashlib.sha256(Path(path).read_bytes()).hexdigest()


def sources_sha256(directory, relative_paths) -> str:
    """One SHA-256 over the named files of a model directory (their paths and their bytes' digests)."""
    h = hashlib.sha256()
    for rel in relative_paths:
        h.update(str(rel).encode() + b"\0" + file_sha256(Path(directory) / rel).encode() + b"\n")
    return h.hexdigest()


class LoopModel(PathSum):
    """A crane-train model loaded for the control loop (see the module docstring)."""

    def __init__(self, path: str, method: str, joint_names, arm: str, effects: list, preprocessing: dict,
                 units: dict, sha256: str, paths):
        super().__init__(joint_names, paths)
        self.path = str(path)
        self.method = method
        self.arm = arm
        self.effects = list(effects)
        self.preprocessing = dict(preprocessing)
        self.units = dict(units)
        self.sha256 = sha256
        self._coulomb_velocity = 0.0

    def __repr__(self) -> str:
        return f"<LoopModel {self.method} {', '.join(self.joint_names)} from {self.path}>"

    @classmethod
    def load(cls, directory) -> LoopModel:
        return _Loader(directory).load()

    @property
    def coulomb_velocity(self) -> float:
        """v0 of `set_coulomb_velocity` (0: the friction terms' sign as fitted)."""
        return self._coulomb_velocity

    def set_coulomb_velocity(self, v0: float) -> None:
        """In every rigid-body path, the built-in Coulomb-type terms' sign(dq) becomes tanh(dq / v0)
        (RigidPath.set_coulomb_velocity; v0 = 0 restores the model's own prediction). A network has no
        such term: for mlp-* models the call only records v0; a hybrid's network part is unchanged."""
        for path in self.paths:
            if isinstance(path, RigidPath):
                path.set_coulomb_velocity(v0)
        self._coulomb_velocity = float(v0)

    def check_for_arm(self, bilateral_joints, arm: str | None = None) -> None:
        """LoopModelError unless every joint of the model is among `bilateral_joints` (and, when `arm` is
        given, the model was fitted on that arm's data)."""
        bilateral = tuple(bilateral_joints)
        if arm is not None and arm != self.arm:
            raise LoopModelError(f"the model in {self.path} was fitted on the {self.arm}'s data, so it "
                                 f"cannot serve the {arm}'s observer")
        for joint in self.joint_names:
            if joint not in bilateral:
                raise LoopModelError(f"the model in {self.path} covers {joint}, which is not a bilateral "
                                     f"joint of this arm ({', '.join(bilateral) or 'none'})")


def check_for_arm(model: LoopModel, bilateral_joints, arm: str | None = None) -> None:
    """Function form of LoopModel.check_for_arm."""
    model.check_for_arm(bilateral_joints, arm)


class _Loader:
    """The checks of LoopModel.load, each refusal one sentence naming the directory."""

    def __init__(self, directory):
        self.dir = Path(directory)

    def fail(self, what: str) -> LoopModelError:
        return LoopModelError(f"the model in {self.dir} {what}")

    def load(self) -> LoopModel:
        d = self.dir
        if not d.is_dir():
            raise LoopModelError(f"model directory {d} does not exist")
        doc = self._model_json()
        if not isinstance(doc.get("loop_export") or {}, dict):
            raise self.fail(f"has a {MODEL_JSON} whose loop_export is not a record; fit it again")
        method = doc.get("method")
        if method not in METHODS:
            raise self.fail(f"is of method {method!r}, which the control loop cannot run "
                            f"(it runs {', '.join(METHODS)})")
        names = doc.get("joint_names")
        if not isinstance(names, list) or not names or not all(isinstance(n, str) for n in names):
            raise self.fail("has no joint names in its model.json; fit it again")
        units = doc.get("units", SI_UNITS)
        if units != SI_UNITS:
            raise self.fail(f"has units {units}, not the SI units the loop feeds it ({SI_UNITS})")
        pre = self._preprocessing(doc.get("preprocessing"))
        if (problem := preprocessing_problem(pre, len(names))) is not None:
            raise self.fail(f"records an unusable preprocessing setting: {problem}; fit it again")
        arm = doc.get("arm", pre.get("arm", "follower"))
        if arm not in ARMS:
            raise self.fail(f"was fitted on the data of arm {arm!r}, which is neither leader nor follower")
        raw, arrays = self._export()
        sha = hashlib.sha256(raw).hexdigest()
        recorded = (doc.get("loop_export") or {}).get("sha256")
        if recorded is not None and recorded != sha:
            raise self.fail(f"has a {EXPORT_FILE} whose SHA-256 differs from the one its model.json records, "
                            f"so it was not written with these weights; export it again with "
                            f"`crane-train export {d}`")
        if (problem := export_problem(arrays)) is not None:
            raise self.fail(f"has an unusable loop export: {problem}; export it again with "
                            f"`crane-train export {d}`")
        self._check_export_header(arrays, method, tuple(names))
        paths, effects = self._paths(arrays, method, tuple(names))
        return LoopModel(str(d), method, names, arm, effects, pre, SI_UNITS, sha, paths)

    def _model_json(self) -> dict:
        path = self.dir / MODEL_JSON
        if not path.is_file():
            raise LoopModelError(f"{self.dir} is not a crane-x7 model directory (it has no {MODEL_JSON})")
        raw, problem = read_bytes(path)
        if problem is not None:
            raise LoopModelError(f"the {MODEL_JSON} in {self.dir} {problem}")
        try:
            doc = json.loads(raw.decode("utf-8"))
        except (ValueError, RecursionError):
            raise LoopModelError(f"the {MODEL_JSON} in {self.dir} is corrupt, not readable JSON") from None
        if not isinstance(doc, dict) or doc.get("format") != "crane-model":
            raise LoopModelError(f"{self.dir} does not hold a crane-x7 model (its {MODEL_JSON} is not a "
                                 f"crane-model file)")
        return doc

    def _preprocessing(self, pre) -> dict:
        if not isinstance(pre, dict):
            pre = {}
        missing = [k for k in ("cutoff_rad_s", "pseudo_diff_rad_s", "zero_phase") if k not in pre]
        if missing:
            raise self.fail(f"does not record the preprocessing settings {', '.join(missing)}, so the loop "
                            f"cannot filter its inputs as in training; fit it with crane-train fit")
        if pre["zero_phase"]:
            raise self.fail("was trained on zero-phase (forward-backward) filtered data, which a causal "
                            "control loop cannot produce; fit it without zero-phase filtering")
        for k in ("cutoff_rad_s", "pseudo_diff_rad_s"):
            v = pre[k]
            if isinstance(v, bool) or not isinstance(v, (int, float)) or not math.isfinite(v) or v <= 0:
                raise self.fail(f"records the preprocessing setting {k} = {v!r}, not a positive number")
        return dict(pre)

    def _export(self):
        path = self.dir / EXPORT_FILE
        if not path.is_file():
            raise self.fail(f"has no loop export {EXPORT_FILE}; export it with "
                            f"`crane-train export {self.dir}`")
        raw, problem = read_bytes(path)
        arrays = None
        if problem is None:
            arrays, problem = npz_arrays(raw)
        if problem is not None:
            raise self.fail(f"has a {EXPORT_FILE} that {problem}; export it again with "
                            f"`crane-train export {self.dir}`")
        return raw, arrays

    def _check_export_header(self, a: dict, method: str, names: tuple) -> None:
        again = f"export it again with `crane-train export {self.dir}`"
        for k in ("format_version", "method", "joint_names", "units", "source_files", "source_sha256"):
            if k not in a:
                raise self.fail(f"has a {EXPORT_FILE} without {k!r}; {again}")
        self._check_export_model(a, method, names, again)
        try:
            units = json.loads(str(a["units"]))
        except json.JSONDecodeError:
            units = None
        if units != SI_UNITS:
            raise self.fail(f"has a loop export in units {units}, not SI ({SI_UNITS}); {again}")
        files = [str(f) for f in np.atleast_1d(a["source_files"])]
        missing = [f for f in files if not (self.dir / f).is_file()]
        if missing:
            raise self.fail(f"lacks {missing[0]}, the weights its loop export was made from; fit it again")
        if sources_sha256(self.dir, files) != str(a["source_sha256"]):
            raise self.fail(f"has weights ({', '.join(files)}) that changed after its {EXPORT_FILE} was "
                            f"written; {again}")

    def _check_export_model(self, a: dict, method: str, names: tuple, again: str) -> None:
        """The export's format version is known, and its method and joints are the model's."""
        try:
            version = int(a["format_version"])
        except (TypeError, ValueError):
            version = None
        if version != EXPORT_FORMAT_VERSION:
            raise self.fail(f"has a loop export of format version {a['format_version']!s}, which this "
                            f"installation does not know (it reads version {EXPORT_FORMAT_VERSION}); {again}")
        if str(a["method"]) != method:
            raise self.fail(f"has a loop export of method {str(a['method'])!r} but its model.json says "
                            f"{method!r}; {again}")
        exported = tuple(str(n) for n in np.atleast_1d(a["joint_names"]))
        if exported != names:
            raise self.fail(f"has a loop export for joints {', '.join(exported)} but its model.json names "
                            f"{', '.join(names)}; {again}")

    def _paths(self, a: dict, method: str, names: tuple):
        again = f"export it again with `crane-train export {self.dir}`"
        paths, effects = [], []
        if method in RIGID_METHODS:
            path, effects = self._rigid(a, names, again)
            paths.append(path)
        if method in NETWORK_METHODS:
            keys = {k: f"mlp_{k}" for k in MLP_KEYS}
            lacking = [v for v in keys.values() if v not in a]
            if lacking:
                raise self.fail(f"has a loop export without the network array {lacking[0]}; {again}")
            arrays = {k: a[v] for k, v in keys.items()}
            problem = MLPPath.check_shapes(arrays)
            if problem is None and np.shape(arrays["W2"])[1] != len(names):
                problem = f"its network has {np.shape(arrays['W2'])[1]} outputs for {len(names)} joints"
            if problem is None and not all(np.all(np.isfinite(v)) for v in arrays.values()):
                problem = "its network weights are not all finite"
            if problem is None and np.any(arrays["x_std"] == 0):
                problem = "its input standardisation has a zero spread"
            if problem is not None:
                raise self.fail(f"has an inconsistent loop export: {problem}; {again}")
            paths.append(MLPPath(**arrays))
        return paths, effects

    def _effects(self, recorded, again: str) -> dict | None:
        """name -> Effect rebuilt from the export's effect specs (crane_io.physics.effects.spec: data, no
        code runs); None for an export that predates them (then only built-in effects are rebuilt)."""
        if recorded is None:
            return None
        from crane_io.physics.effects.spec import effect_table

        try:
            return effect_table(recorded, f"the model in {self.dir}",
                                hint="the control loop runs no user code: write the effect as data (an "
                                     "effect-spec file) and fit the model again")
        except ConfigError as exc:
            raise LoopModelError(str(exc)) from None

    def _term_effect(self, table, recorded, spec: dict, again: str):
        """The effect of one exported term: from the export's specs (its identity checked), or for an
        export without specs the built-in effect of that name."""
        name = spec.get("name")
        if table is None:
            from crane_io.physics.effects.spec import check_spec, rebuild

            try:
                return rebuild(check_spec({"kind": "library", "name": name, "version": 1}))
            except ConfigError:
                raise self.fail(f"uses the effect {name!r}, which is not built in and is not recorded as "
                                f"data in its loop export; fit it again") from None
        from crane_io.physics.effects.spec import identity

        effect = table.get(name) if isinstance(name, str) else None
        own = next((s for s in recorded if s.get("name") == name), None)
        if effect is None or spec.get("identity") not in (None, identity(own)):
            raise self.fail(f"has an inconsistent loop export: the effect term {name!r} has no matching "
                            f"spec; {again}")
        return effect

    def _check_rigid_loop_ready(self, a: dict, again: str) -> None:
        """The rigid-body part has every array, names no Python effect file and no context joint."""
        keys = ("rigid_theta_full", "rigid_locked_joints", "rigid_locked_angles", "rigid_payload_mass",
                "rigid_effects", "rigid_effect_coefs")
        lacking = [k for k in keys if k not in a]
        if lacking:
            raise self.fail(f"has a loop export without {lacking[0]}; {again}")
        if "rigid_effect_files" in a and np.atleast_1d(a["rigid_effect_files"]).size:
            files = ", ".join(str(f) for f in np.atleast_1d(a["rigid_effect_files"]))
            raise self.fail(f"names the Python effect files {files}, which loading a model never runs; fit "
                            f"it again so that it records its effects as data")
        if "rigid_context_joints" in a and np.atleast_1d(a["rigid_context_joints"]).size:
            ctx = ", ".join(str(n) for n in np.atleast_1d(a["rigid_context_joints"]))
            raise self.fail(f"is a rigid-body model whose kinematics read the recorded motion of {ctx} "
                            f"(context joints that moved in its training data), which the control loop "
                            f"does not pass to a model; fit it with those joints among `joints`, or on "
                            f"data where they are held still")

    def _rigid_effect_lists(self, a: dict, again: str) -> tuple[list, list | None]:
        """(effect terms, recorded effect specs or None) of the rigid-body part."""
        try:
            specs = json.loads(str(a["rigid_effects"]))
            recorded = json.loads(str(a["rigid_effect_specs"])) if "rigid_effect_specs" in a else None
        except (json.JSONDecodeError, RecursionError):
            raise self.fail(f"has a loop export whose effect list is not readable; {again}") from None
        if not isinstance(specs, list) or not all(isinstance(s, dict) for s in specs):
            raise self.fail(f"has a loop export whose effect list is not a list of tables; {again}")
        return specs, recorded

    def _rigid_terms(self, specs: list, table, recorded, coefs: np.ndarray, names: tuple,
                     again: str) -> tuple[list, list]:
        """(terms (effect, joint, shape, coefficients), labels) of the effect specs, which use every
        coefficient."""
        terms, labels, k = [], [], 0
        for spec in specs:
            name, joint, shape = spec.get("name"), spec.get("joint"), spec.get("shape")
            n = spec.get("n_coefs")
            effect = self._term_effect(table, recorded, spec, again)
            if n != effect.n_columns() or k + effect.n_columns() > coefs.size:
                raise self.fail(f"has an inconsistent loop export: effect {name} needs "
                                f"{effect.n_columns()} coefficients; {again}")
            if joint is not None and not (isinstance(joint, int) and 0 <= joint < len(names)):
                raise self.fail(f"has an inconsistent loop export: effect {name} acts on joint index "
                                f"{joint!r} of {len(names)} joints; {again}")
            terms.append((effect, joint, shape, coefs[k:k + n]))
            labels.append(name if joint is None else f"{name}:{names[joint]}")
            k += n
        if k != coefs.size:
            raise self.fail(f"has an inconsistent loop export: {coefs.size} effect coefficients for effect "
                            f"terms with {k}; {again}")
        return terms, labels

    def _rigid(self, a: dict, names: tuple, again: str):
        self._check_rigid_loop_ready(a, again)
        locked_names = [str(n) for n in np.atleast_1d(a["rigid_locked_joints"])]
        locked_angles = np.atleast_1d(np.asarray(a["rigid_locked_angles"], dtype=float))
        if len(locked_names) != len(locked_angles):
            raise self.fail(f"has an inconsistent loop export: {len(locked_names)} locked joints but "
                            f"{len(locked_angles)} locked angles; {again}")
        specs, recorded = self._rigid_effect_lists(a, again)
        table = self._effects(recorded, again)
        coefs = np.atleast_1d(np.asarray(a["rigid_effect_coefs"], dtype=float))
        terms, labels = self._rigid_terms(specs, table, recorded, coefs, names, again)
        theta = np.asarray(a["rigid_theta_full"], dtype=float)
        if not np.all(np.isfinite(theta)) or not np.all(np.isfinite(coefs)):
            raise self.fail(f"has a loop export whose rigid-body parameters are not all finite; {again}")
        try:
            path = RigidPath(names, theta, terms, locked=dict(zip(locked_names, locked_angles.tolist())),
                             payload_mass=float(a["rigid_payload_mass"]))
        except ConfigError as exc:
            raise self.fail(f"has a rigid-body part that cannot be built ({exc})") from None
        return path, labels
