"""The identification's verdict: each check with its measured value, its threshold and one sentence;
the thresholds are the user's (`crane-train identify --max-condition ...`)."""

from __future__ import annotations

from dataclasses import asdict, dataclass

import numpy as np


@dataclass(frozen=True)
class Thresholds:
    max_condition: float = 200.0  # of the weighted, column-scaled regressor
    max_rel_stderr: float = 0.10  # relative standard error of every parameter that matters
    negligible: float = 0.01  # a parameter whose torque is below this share of the torque RMS does not matter
    max_heldout_ratio: float = 1.25  # held-out MSE over the fit's own MSE, every joint


@dataclass
class Check:
    name: str
    passed: bool
    value: float
    threshold: float
    sentence: str


def parameter_contribution(phi: np.ndarray, theta: np.ndarray, tau: np.ndarray) -> np.ndarray:
    """(p,) each parameter's torque RMS over the fit's rows as a share of the torque RMS."""
    n, j, p = phi.shape
    part = np.sqrt(np.mean((phi * theta[None, None, :]) ** 2, axis=(0, 1)))
    return part / max(float(np.sqrt(np.mean(tau ** 2))), 1e-12)


def checks(condition: float, names: list[str], theta: np.ndarray, stderr: np.ndarray, share: np.ndarray,
           projection, fit_mse: np.ndarray, heldout_mse: np.ndarray, joint_names,
           t: Thresholds) -> list[Check]:
    out = [Check("condition number", condition <= t.max_condition, condition, t.max_condition,
                 f"the regressor's condition number is {condition:.3g} "
                 f"({'within' if condition <= t.max_condition else 'above'} {t.max_condition:g}): "
                 + ("the data separate the parameters" if condition <= t.max_condition
                    else "the data barely separate some parameters; excite the arm more"))]
    rel = np.where(np.abs(theta) > 0, stderr / np.maximum(np.abs(theta), 1e-300), np.inf)
    judged = share >= t.negligible
    bad = [names[k] for k in np.flatnonzero(judged & (rel > t.max_rel_stderr))]
    worst = float(rel[judged].max(initial=0.0))
    out.append(Check("parameter uncertainty", not bad, worst, t.max_rel_stderr,
                     f"every parameter that carries at least {100 * t.negligible:g} % of the torque is known "
                     f"within {100 * t.max_rel_stderr:g} % (worst {100 * worst:.3g} %)" if not bad else
                     f"{len(bad)} parameter(s) that matter are known only to more than "
                     f"{100 * t.max_rel_stderr:g} %: {', '.join(bad[:5])}{' ...' if len(bad) > 5 else ''}"))
    out.append(Check("physical consistency", bool(projection.within_uncertainty), projection.chi2,
                     float(projection.dof),
                     "the estimate is physically consistent as estimated" if projection.as_estimated else
                     f"the estimate was projected onto the physically consistent set, moving it by chi^2 = "
                     f"{projection.chi2:.3g} over {projection.dof} parameters: "
                     + ("within its uncertainty" if projection.within_uncertainty
                        else "more than its uncertainty explains (a model structure that is wrong?)")))
    ratio = heldout_mse / np.maximum(fit_mse, 1e-300)
    worst_j = int(np.argmax(ratio))
    ok = bool(np.all(ratio <= t.max_heldout_ratio))
    out.append(Check("held-out error", ok, float(ratio[worst_j]), t.max_heldout_ratio,
                     f"the held-out error is at most {ratio[worst_j]:.3g}x the fit's own "
                     f"({joint_names[worst_j]})"
                     + ("" if ok else f", above {t.max_heldout_ratio:g}x: the model does not carry over to "
                                      "other data")))
    return out


def to_json(t: Thresholds, found: list[Check]) -> dict:
    return {"passed": all(c.passed for c in found), "thresholds": asdict(t),
            "checks": [asdict(c) for c in found]}
