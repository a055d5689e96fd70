"""Physically consistent inertial parameters: the identified base parameters projected onto the set a
real arm can have.

A body's ten standard parameters (pinocchio's order: m, m c_x, m c_y, m c_z, I_xx, I_xy, I_yy, I_xz, I_yz,
I_zz about the joint origin) are physically consistent - positive mass, positive definite inertia about
the centre of mass, the triangle inequalities of its principal moments - exactly when its pseudo-inertia

    J = [[ tr(I)/2 * 1 - I,  m c ],
         [ (m c)^T,          m   ]]

is positive semidefinite (Wensing, Kim and Slotine, "Linear matrix inequalities for physically consistent
inertial parameter identification", IEEE RA-L 2018). The base parameters are linear in the standard ones,
beta = K phi (crane_io.physics.dynamics.ArmDynamics.base_map_rows), so the closest consistent estimate is
a semidefinite program (cvxpy):

    minimise  || L ([K phi; f] - theta_hat) ||^2 + eps || (phi - phi_0) / s ||^2
    subject to  J_b(phi) >= 0 and m_b >= m_min for every body b,  f_k >= 0 for friction coefficients

with L^T L the inverse of the estimate's covariance plus its diagonal (`metric`: a jackknife covariance from
few blocks is singular) for theta_hat (base parameters then the other columns, f),
phi_0 the description's nominal standard parameters (s their scale) and a small eps: the data decide every
direction they can see, the nominal model the directions they cannot (which no torque prediction depends
on). The estimate is "consistent as estimated" when the projection does not move it (chi^2 below 1e-4 per
parameter),
"consistent within its uncertainty" when chi^2 lies within the 99 % quantile of its distribution.
"""

from __future__ import annotations

import warnings
from dataclasses import dataclass

import numpy as np

from crane_io.errors import ConfigError
from crane_io.physics.identified_model import pseudo_inertia

from .estimate import IdentificationError

MIN_MASS = 1e-3  # kg: a body lighter than this is not a body
LENGTH = 0.1  # m: the arm's link scale, for the solver's units
MARGIN = 1e-6  # kg (solver units): the projection lands this far inside the set, not on its edge
AS_ESTIMATED = 1e-4  # chi^2 per parameter below which the projection did not move the estimate
REGULARISATION = 1e-6


@dataclass
class Projection:
    theta: np.ndarray  # (p,) consistent base parameters and the other columns
    phi: np.ndarray  # (10 B,) consistent standard parameters (model order)
    chi2: float  # || L (theta - theta_hat) ||^2
    dof: int
    as_estimated: bool  # the estimate itself is consistent
    within_uncertainty: bool  # the projection moved it less than its uncertainty explains
    bodies: list[dict]  # per body: name, mass, com, principal moments, smallest pseudo-inertia eigenvalue


def _cvx_pseudo_inertia(cp, v):
    m, hx, hy, hz, ixx, ixy, iyy, ixz, iyz, izz = (v[k] for k in range(10))
    half = 0.5 * (ixx + iyy + izz)
    return cp.bmat([[half - ixx, -ixy, -ixz, hx],
                    [-ixy, half - iyy, -iyz, hy],
                    [-ixz, -iyz, half - izz, hz],
                    [hx, hy, hz, m]])


def body_summary(name: str, phi10: np.ndarray) -> dict:
    """Mass, centre of mass, principal moments about it, and the smallest pseudo-inertia eigenvalue."""
    m = float(phi10[0])
    com = phi10[1:4] / m if m > 0 else np.full(3, np.nan)
    ixx, ixy, iyy, ixz, iyz, izz = phi10[4:]
    inertia = np.array([[ixx, ixy, ixz], [ixy, iyy, iyz], [ixz, iyz, izz]])
    if m > 0:
        c = com
        inertia = inertia - m * (np.dot(c, c) * np.eye(3) - np.outer(c, c))
    moments = np.sort(np.linalg.eigvalsh(0.5 * (inertia + inertia.T)))
    return {"body": name, "mass": m, "com": [float(x) for x in com],
            "principal_moments": [float(x) for x in moments],
            "min_pseudo_inertia_eigenvalue": float(np.linalg.eigvalsh(pseudo_inertia(phi10)).min())}


def metric(cov: np.ndarray) -> np.ndarray:
    """The covariance the projection measures distances with: `cov` plus its own diagonal. A jackknife
    covariance from B blocks has rank at most B - 1 (e.g. 4 of 21 parameters from five blocks); its
    unseen directions would count as known exactly, and the solver would be asked to keep them to
    within rounding. With the diagonal added, every parameter is held to within its own variance."""
    cov = 0.5 * (np.asarray(cov, float) + np.asarray(cov, float).T)
    return cov + np.diag(np.clip(np.diag(cov), 0.0, None))


def _whitening(cov: np.ndarray) -> np.ndarray:
    """L with L^T L = metric(cov)^-1 (eigenvalues floored so a near-singular covariance stays usable)."""
    vals, vecs = np.linalg.eigh(metric(cov))
    floor = max(vals.max(initial=0.0), 1e-300) * 1e-14
    return (vecs / np.sqrt(np.maximum(vals, floor))).T


def project(theta_hat: np.ndarray, cov: np.ndarray, base_map: np.ndarray, phi_nominal: np.ndarray,
            body_names: list[str], nonnegative: np.ndarray) -> Projection:
    """The consistent estimate closest to theta_hat (module docstring). theta_hat (p,) = the B base
    parameters (base_map (B, 10 nb) @ phi) then p - B other columns; nonnegative (p - B,) bool: which of
    those must not be negative (friction coefficients)."""
    try:
        import cvxpy as cp
    except ImportError:
        raise ConfigError("physically consistent identification needs cvxpy: pip install "
                          "'crane-x7[identify]'") from None
    from scipy.stats import chi2 as chi2_dist

    theta_hat = np.asarray(theta_hat, float)
    nb_std = base_map.shape[1]
    n_base = base_map.shape[0]
    n_other = len(theta_hat) - n_base
    w = _whitening(cov)
    # the solver works in units where every quantity is of order one: the standard parameters as
    # phi = phi_0 + s x, the other columns as theta_hat + t y, each pseudo-inertia scaled by the congruence
    # diag(1/L, 1/L, 1/L, 1) with L = LENGTH (which keeps it semidefinite exactly when it was)
    scale = np.maximum(np.abs(phi_nominal), 1e-4)
    x = cp.Variable(nb_std)
    phi = phi_nominal + cp.multiply(scale, x)
    t_other = np.sqrt(np.clip(np.diag(cov)[n_base:], 1e-24, None))
    y = cp.Variable(n_other) if n_other else None
    other = theta_hat[n_base:] + cp.multiply(t_other, y) if n_other else None
    theta = cp.hstack([base_map @ phi, other]) if n_other else base_map @ phi
    objective = cp.sum_squares(w @ theta - w @ theta_hat) + REGULARISATION * cp.sum_squares(x)
    congruence = np.diag([1 / LENGTH, 1 / LENGTH, 1 / LENGTH, 1.0])
    constraints = []
    for b in range(nb_std // 10):
        v = phi[10 * b:10 * b + 10]
        constraints += [congruence @ _cvx_pseudo_inertia(cp, v) @ congruence >> MARGIN * np.eye(4),
                         v[0] >= MIN_MASS]
    if n_other and np.any(nonnegative):
        constraints.append(other[np.flatnonzero(nonnegative)] >= 0)
    problem = cp.Problem(cp.Minimize(objective), constraints)
    for solver in [s for s in ("CLARABEL", "SCS") if s in cp.installed_solvers()]:
        try:
            with warnings.catch_warnings():  # "optimal_inaccurate" is judged below, by chi^2 and the cone
                warnings.simplefilter("ignore", UserWarning)
                problem.solve(solver=solver)
        except cp.error.SolverError:
            continue
        if problem.status in ("optimal", "optimal_inaccurate") and x.value is not None:
            break
    if problem.status not in ("optimal", "optimal_inaccurate") or x.value is None:
        raise IdentificationError(f"the consistency projection found no solution ({problem.status})")
    phi = phi_nominal + scale * np.asarray(x.value, float)
    other = theta_hat[n_base:] + t_other * np.asarray(y.value, float) if n_other else np.zeros(0)
    phi_c = phi
    theta_c = np.concatenate([base_map @ phi_c, other])
    r = w @ (theta_c - theta_hat)
    chi2 = float(r @ r)
    dof = len(theta_hat)
    bodies = [body_summary(name, phi_c[10 * b:10 * b + 10]) for b, name in enumerate(body_names)]
    return Projection(theta=theta_c, phi=phi_c, chi2=chi2, dof=dof, as_estimated=chi2 <= AS_ESTIMATED * dof,
                      within_uncertainty=chi2 <= float(chi2_dist.ppf(0.99, dof)), bodies=bodies)
