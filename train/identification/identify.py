"""Identify the arm's rigid-body and friction parameters from sessions (excitation or bilateral data):
weighted least squares with honest uncertainties (estimate.py), the physically consistent projection
(consistency.py) and a verdict against the user's thresholds (verdict.py). The result is a rigid-body model
like `crane-train fit --model rigid-body` makes (compare, report, diagnose and the control loop read it),
with identification.json beside it.

The data are split as `fit` splits them (training pool, validation, test blocks); the parameters are
estimated on the pool and judged on the test blocks. Sessions are filtered forward and backward
(`zero_phase`, the default: the data are offline, so nothing needs a causal filter) or with the paper's
causal chain (as `fit` filters them, so the model folder runs in the control loop): the causal chain
delays q, dq, ddq and tau alike, but the regressor is nonlinear in them, so the filtered torque is not
quite the regressor of the filtered motion (docs/identification.md, "Results"). The jackknife's blocks
are the speeds of an excitation's speed cycle, or contiguous time blocks (blocks.py).

Each joint's torque equation is used where that joint moves faster than `min_speed` (MIN_SPEED by
default; a joint that moves that fast in less than FASTEST_SHARE of the samples where it moves: in its
fastest FASTEST_SHARE of them). Below it lies what friction does within milliseconds at a reversal or a
stop (the Coulomb step, stiction, sticking); the filters spread that torque over the slow samples around
it (the zero-phase filter on both sides), where no friction model of the velocity follows it, and the
least squares tilts the inertias to absorb it (docs/identification.md, "Results"). An effect that acts
only below `min_speed` (Stribeck friction of 0.05 rad/s) is refused then; `min_speed=0` uses every moving
sample. The fit's and the held-out errors are measured on every moving sample either way: the model is
used on all of them.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from .blocks import excitation_schedule, speed_blocks
from .consistency import Projection, project
from .estimate import Estimate, IdentificationError, weighted_least_squares
from .verdict import Check, Thresholds, checks, parameter_contribution, to_json

DEFAULT_EFFECTS = ("viscous", "coulomb")
# friction coefficients a real joint cannot have negative
NONNEGATIVE = ("viscous.viscous", "coulomb.coulomb")
IDENTIFICATION_JSON = "identification.json"
ARM_MODEL_TOML = "arm_model.toml"  # the identified bodies for the dynamics, the controller and the plant
MIN_SPEED = 0.3  # rad/s: a joint's slower samples are left out of the fit (module docstring)
# rad/s: the low-pass (and pseudo-derivative) cutoff of zero-phase identification (module docstring)
ZERO_PHASE_CUTOFF = 60.0
FASTEST_SHARE = 0.2  # a joint that rarely reaches MIN_SPEED is fitted on this share of its fastest samples


@dataclass
class Identification:
    fit: object  # train.api.FitResult: the model (consistent parameters) and its test metrics
    names: list[str]
    estimate: Estimate
    projection: Projection
    checks: list[Check]
    thresholds: Thresholds
    n_base: int
    fit_mse: np.ndarray
    heldout_mse: np.ndarray
    share: np.ndarray = field(repr=False)
    uncertainty: str = ""  # how the covariance was found (the jackknife's blocks)
    min_speed: float = 0.0  # rad/s: the minimum speed asked for
    # (J,) rad/s: each joint's slowest sample used (the minimum speed, or its fastest FASTEST_SHARE's)
    fit_speeds: np.ndarray = field(default_factory=lambda: np.zeros(0), repr=False)
    filter: dict = field(default_factory=dict)  # zero_phase, cutoff_rad_s of the data identified from

    @property
    def passed(self) -> bool:
        return all(c.passed for c in self.checks)

    def to_json(self) -> dict:
        est, se = self.estimate.theta, self.estimate.stderr
        half, known = self.estimate.interval95, self.estimate.identifiable
        params = [{"name": n, "kind": "base" if k < self.n_base else "other", "estimate": float(est[k]),
                   "stderr": float(se[k]), "interval95": float(half[k]), "identifiable": bool(known[k]),
                   "rel_stderr": float(se[k] / abs(est[k])) if est[k] != 0 else None,
                   "consistent": float(self.projection.theta[k]), "torque_share": float(self.share[k])}
                  for k, n in enumerate(self.names)]
        joints = list(self.fit.model.joint_names)
        return {"format": "crane-identification", "format_version": 1,
                "joints": joints, "rows": self.estimate.rows, "min_speed": self.min_speed,
                "filter": self.filter,
                "fit_speed": dict(zip(joints, np.asarray(self.fit_speeds, float).tolist())),
                "condition_number": self.estimate.condition,
                "uncertainty": self.uncertainty,
                "residual_std": dict(zip(joints, self.estimate.sigma.tolist())),
                "parameters": params,
                "correlated_pairs": [{"a": self.names[i], "b": self.names[k], "r": r}
                                     for i, k, r in self.estimate.correlated],
                "consistency": {"as_estimated": self.projection.as_estimated,
                                "within_uncertainty": self.projection.within_uncertainty,
                                "chi2": self.projection.chi2, "dof": self.projection.dof,
                                "bodies": self.projection.bodies},
                "fit_mse": dict(zip(joints, self.fit_mse.tolist())),
                "heldout_mse": dict(zip(joints, self.heldout_mse.tolist())),
                "verdict": to_json(self.thresholds, self.checks)}

    def arm_model(self):
        """The consistent bodies and friction as an IdentifiedArm (crane_io.physics.identified_model)."""
        from crane_io.physics.arm_model import JOINT_NAMES
        from crane_io.physics.identified_model import IdentifiedArm, into_consistent

        dyn = self.fit.model.dynamics
        phi = self.projection.phi
        bodies = {name: into_consistent(phi[10 * b:10 * b + 10]) for b, name in enumerate(dyn.body_names())}
        locked = {n: float(dyn.locked.get(n, 0.0)) for n in JOINT_NAMES if n not in dyn.joint_names}
        friction: dict[str, dict[str, float]] = {}
        for k, name in enumerate(self.names[self.n_base:], start=self.n_base):
            column, _, joint = name.partition("@")
            if column in NONNEGATIVE and joint:
                value = max(float(self.projection.theta[k]), 0.0)
                friction.setdefault(joint, {})[column.split(".")[0]] = value
        return IdentifiedArm(tuple(dyn.joint_names), locked, bodies, float(dyn.payload_mass), friction)

    def save(self, out_dir, *, force: bool = False) -> Path:
        """The model folder with identification.json and arm_model.toml in it, whole or not at all."""
        self.fit.documents[IDENTIFICATION_JSON] = self.to_json()
        self.fit.documents[ARM_MODEL_TOML] = _loadable(self.arm_model().to_toml())
        return self.fit.save(out_dir, force=force)


def _loadable(text: str) -> str:
    """`text` (an arm_model.toml) when the toolkit's own loader accepts it; IdentificationError otherwise:
    a folder whose arm model the simulator and the controller would refuse is never written."""
    import tomllib

    from crane_io.errors import ConfigError
    from crane_io.physics.identified_model import IdentifiedArm

    try:
        IdentifiedArm.from_dict(tomllib.loads(text)["identified"], "the identified arm model")
    except ConfigError as e:
        raise IdentificationError(f"{e}; the data do not pin the bodies down: record a longer or richer "
                                  "excitation (docs/excitation.md)") from None
    return text


def _filter(ds) -> dict:
    """How the data were filtered (their preprocessing settings): zero-phase or causal, the cutoff."""
    pre = ds.meta.get("preprocessing", {})
    return {"zero_phase": bool(pre.get("zero_phase", False)), "cutoff_rad_s": pre.get("cutoff_rad_s")}


def _mse_where_moving(tau: np.ndarray, pred: np.ndarray, moving: np.ndarray) -> np.ndarray:
    err = (tau - pred) ** 2
    return np.array([err[moving[:, j], j].mean() if moving[:, j].any() else np.nan
                     for j in range(tau.shape[1])])


def _fit_rows(pool, phi: np.ndarray, names: list[str], min_speed: float) -> tuple[np.ndarray, np.ndarray]:
    """((N, J) bool, (J,) rad/s): where each joint moves fast enough, and how fast that is (the module
    docstring); IdentificationError when a parameter's column vanishes on those rows."""
    if not (np.isfinite(min_speed) and min_speed >= 0):
        raise IdentificationError(f"the minimum speed must be 0 or more rad/s, got {min_speed!r}")
    speed = np.abs(pool.dq)
    limits = np.zeros(speed.shape[1])
    for j in range(speed.shape[1]):
        moving = speed[pool.moving[:, j], j]
        if min_speed > 0 and moving.size:
            limits[j] = min(min_speed, float(np.quantile(moving, 1.0 - FASTEST_SHARE)))
    used = pool.moving & (speed >= limits)
    if min_speed > 0:
        norm = np.linalg.norm(phi[used], axis=0)
        for k in np.flatnonzero(norm <= 1e-9 * norm.max(initial=0.0)):
            raise IdentificationError(f"{names[k]} does not act in the samples faster than the minimum speed "
                                      f"of {min_speed:g} rad/s: identify with a lower minimum speed (0 uses "
                                      f"every moving sample) or without that effect")
    return used, limits


def _blocks(ds, pool, sources):
    """(BlockPlan, its description) of the pool's rows: speed blocks for excitation sessions of several
    speeds, else contiguous time blocks (blocks.py)."""
    from ..models.rigid_body import fit_blocks

    plan = None
    if sources:
        schedules = [excitation_schedule(p) for p in sources]
        plan = speed_blocks(ds.t, ds.segment, pool.t, pool.segment, schedules, ds.rate_hz)
    if plan is not None:
        return plan, (f"delete-a-block jackknife over the {plan.count} speeds of the excitation's speed "
                      f"cycle (each speed's periods one block)")
    plan = fit_blocks(pool)
    return plan, plan.describe()


def _load(paths, arm, joints, config, zero_phase: bool, cutoff: float | None):
    """The sessions at `paths` read and preprocessed as train.api.load_sessions does, with the filters'
    cutoff `cutoff` (identify's argument)."""
    import dataclasses

    from ..api import load_settings
    from ..settings import load_dataset

    if cutoff is None and zero_phase:
        cutoff = ZERO_PHASE_CUTOFF
    pre = load_settings(config)["preprocess"]
    if cutoff is not None:
        if not (np.isfinite(cutoff) and cutoff > 0):
            raise IdentificationError(f"the filters' cutoff must be a positive number of rad/s, got "
                                      f"{cutoff!r}")
        pre = dataclasses.replace(pre, cutoff_rad_s=float(cutoff), pseudo_diff_rad_s=float(cutoff))
    return load_dataset([str(p) for p in paths], joints, None, zero_phase, pre, arm)


def identify(data, *, effects: Sequence[str] = DEFAULT_EFFECTS, seed: int = 0, scale_to_data: bool = False,
             config=None, arm: str | None = None, joints=None, thresholds: Thresholds | None = None,
             zero_phase: bool = True, min_speed: float = MIN_SPEED,
             cutoff: float | None = None) -> Identification:
    """Identify from `data` (a Dataset, or session file(s) read as train.api.load_sessions reads them;
    `zero_phase`: filtered forward and backward; `cutoff` rad/s: the filters' cutoff, None: identify's
    (ZERO_PHASE_CUTOFF) for zero-phase filtering, the settings' for the causal chain; `min_speed` rad/s:
    the slowest samples used, the module docstring)."""
    from ..api import FitResult, load_settings, model_preprocessing, test_metrics
    from ..data.splits import make_splits
    from ..models.registry import make_model
    from ..settings import parse_effect

    thresholds = thresholds or Thresholds()
    sources = None
    if not hasattr(data, "tau"):
        sources = [data] if isinstance(data, (str, Path)) else list(data)
        data = _load(sources, arm, joints, config, zero_phase, cutoff)
    ds = data
    splits = make_splits(ds, load_settings(config)["splits"], seed=seed, scale_to_data=scale_to_data)
    pool = splits.pool
    effect_list = [list(parse_effect(str(e))) for e in effects]
    model = make_model("rigid-body", ds.joint_names, preprocessing=model_preprocessing(ds, splits),
                       effects=effect_list, rows="per-joint")
    model.fit(pool, splits.val)  # resolves the context joints and the effect terms
    phi = model.regressor(pool.q, pool.dq, pool.ddq, context=pool.context)
    plan, uncertainty = _blocks(ds, pool, sources)
    names = list(model.names)
    used, fit_speeds = _fit_rows(pool, phi, names, min_speed)
    est = weighted_least_squares(phi, pool.tau, used, plan)
    dyn = model.dynamics
    n_base = model.n_base
    nonneg = np.array([n.split("@")[0] in NONNEGATIVE for n in names[n_base:]], dtype=bool)
    proj = project(est.theta, est.cov, dyn.base_map_rows(model.joint_names), dyn.standard_parameters(),
                   dyn.body_names(), nonneg)
    model.theta, model.stderr = proj.theta.copy(), est.stderr.copy()
    model.fit_info = {**model.fit_info, "estimator": "weighted least squares, consistent projection",
                      "condition_number": est.condition}
    fit_mse = _mse_where_moving(pool.tau, phi @ proj.theta, pool.moving)
    test = splits.test
    heldout_mse = _mse_where_moving(test.tau, model.predict_dataset(test), test.moving)
    share = parameter_contribution(phi, est.theta, pool.tau)
    found = checks(est.condition, names, est.theta, est.stderr, share, proj, fit_mse, heldout_mse,
                   model.joint_names, thresholds)
    fit = FitResult(model, test_metrics(model, ds, splits, pool, "rigid-body", seed), ds, splits)
    return Identification(fit=fit, names=names, estimate=est, projection=proj, checks=found,
                          thresholds=thresholds, n_base=n_base, fit_mse=fit_mse, heldout_mse=heldout_mse,
                          share=share, uncertainty=uncertainty, min_speed=float(min_speed),
                          fit_speeds=fit_speeds, filter=_filter(ds))


def text(result: Identification) -> str:
    """The identification as a person reads it: parameters with sigma %, bodies, checks, verdict."""
    doc = result.to_json()
    cutoff = doc["filter"]["cutoff_rad_s"]
    lines = [f"identified {len(doc['parameters'])} parameters of {', '.join(doc['joints'])} from "
             f"{doc['rows']} torque equations (each joint's where it moves at least "
             + ", ".join(f"{v:.2g}" for v in doc["fit_speed"].values())
             + f" rad/s fast); condition number {doc['condition_number']:.3g}",
             f"filtered {'forward and backward' if doc['filter']['zero_phase'] else 'causally'}"
             + ("" if cutoff is None else f" at {cutoff:g} rad/s"),
             f"uncertainty: {doc['uncertainty']}",
             "", f"{'parameter':32s} {'estimate':>12s} {'sigma %':>8s} {'consistent':>12s} {'torque %':>8s}"]
    for p in doc["parameters"]:
        rel = "-" if p["rel_stderr"] is None else f"{100 * p['rel_stderr']:.3g}"
        lines.append(f"{p['name']:32s} {p['estimate']:12.5g} {rel:>8s} {p['consistent']:12.5g} "
                     f"{100 * p['torque_share']:8.3g}" + ("" if p["identifiable"] else "  not identifiable"))
    unknown = [p["name"] for p in doc["parameters"] if not p["identifiable"]]
    if unknown:
        lines += ["", f"not identifiable (estimate within two standard errors of zero): {len(unknown)} of "
                      f"{len(doc['parameters'])}"]
    if doc["correlated_pairs"]:
        lines += ["", "strongly correlated: " + "; ".join(f"{c['a']} ~ {c['b']} (r = {c['r']:+.3f})"
                                                         for c in doc["correlated_pairs"][:8])]
    lines += ["", "bodies (consistent):"]
    for b in doc["consistency"]["bodies"]:
        moments = ", ".join(f"{x:.3g}" for x in b["principal_moments"])
        lines.append(f"  {b['body']}: mass {b['mass']:.4g} kg, principal moments about the centre of mass "
                     f"{moments} kg m^2")
    lines.append("")
    for c in result.checks:
        lines.append(f"{'PASS' if c.passed else 'FAIL'}  {c.name}: {c.sentence}")
    lines.append(f"verdict: {'PASS' if result.passed else 'FAIL'}")
    return "\n".join(lines)
