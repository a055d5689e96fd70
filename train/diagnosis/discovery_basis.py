"""The basis of `crane-train diagnose --discover` (train/diagnosis/discovery.py): physically meaningful terms
a joint's missing torque may be made of, each a named column computed from (q, dq, ddq).

For the joint j under study (variables q_j, dq_j, ddq_j; "2" for joint2) and every other joint k:

- own joint: a constant, sign(dq_j) and smooth signs tanh(dq_j/v), dq_j, |dq_j|·dq_j, dq_j³, ddq_j,
  powers of q_j (q_j, q_j², q_j³, q_j·|q_j|), sin/cos(n·q_j) for n = 1..6 (a stiffness that changes
  with the angle);
- friction whose level changes with position: sign(dq_j)·q_j, sign(dq_j)·q_j², sign(dq_j)·sin/cos(n·q_j),
  n = 1..6;
- damping that changes with position: dq_j·q_j, dq_j·q_j², dq_j·sin/cos(n·q_j), n = 1..6;
- coupling from the other joints: sign(dq_k), tanh(dq_k/v), dq_k, |dq_k|·dq_k, ddq_k, sin/cos(n·q_k)
  (n = 1, 2), sign(dq_j)·sin/cos(q_k) (friction loaded by another joint's pose), dq_j·dq_k;
- sums of angles as gravity produces them: sin/cos(q_a + q_b) for every pair, and of all joints;
- the effects library's own columns on joint j, for every point of their shape grid (Stribeck bumps,
  cogging harmonics, backlash reversal, ...).

The polynomials in q_j describe a smooth shape over the observed range of the angle; a harmonic
sin/cos(n·q) describes one that repeats, and it is a candidate only when the angle it reads was observed
over at least one of its periods, 2π/n (`periodic_refusals`; the library's cogging alike with its
cycles per revolution): a few percent of a period cannot tell a ripple from a slope.

Columns that duplicate an earlier one (correlation beyond 0.9999 on the joint's moving samples, e.g.
the library's Coulomb column and sign(dq_j)) or that are zero there are dropped. Every term carries the
expression in the basis grammar of crane_io/physics/effects/terms.py (plain data, computed over a whitelist
of numpy functions), so the effect-spec file written from a discovery (train/diagnosis/effect_writer.py)
computes exactly the column that was fitted.
"""

from __future__ import annotations

import math
import re
from dataclasses import dataclass
from typing import TYPE_CHECKING

import numpy as np

from crane_io.errors import CraneError
from crane_io.physics.effects.terms import column, joint_label, term_name

if TYPE_CHECKING:
    from collections.abc import Sequence

SMOOTH_SIGN_VELOCITIES = (0.05, 0.25)  # rad/s: v of tanh(dq/v)
HARMONICS = tuple(range(1, 7))  # n of sin/cos(n·q_j) of the joint's own angle
_SKIP_LIBRARY = {"payload", "torque-constant-error"}  # need the arm's dynamics; not a column of one joint


@dataclass(frozen=True)
class Term:
    name: str  # readable: "sign(dq2)·cos(2·q2)"
    expr: list  # in the basis grammar (crane_io.physics.effects.terms): [["sign", 1], ["cos", 2, [1]]]
    unit: str  # unit of the coefficient that multiplies it: "N m", "N m s/rad", ...
    family: str  # "velocity sign", "velocity sign x angle", "coupling", ...
    variables: frozenset  # the signals it reads: {"dq2", "q2"}
    factors: tuple = ()  # readable factors whose product it is (for factoring an expression)

    @property
    def parameter(self) -> str:
        """A Python identifier for the term's coefficient: 'sign_dq2_cos_2q2'."""
        s = self.name.replace("·", "_").replace("|", "abs_").replace("²", "2").replace("³", "3")
        s = re.sub(r"[^0-9a-zA-Z]+", "_", s).strip("_").lower()
        return s if s and not s[0].isdigit() else f"c_{s}"


def evaluate(term: Term, q: np.ndarray, dq: np.ndarray, ddq: np.ndarray) -> np.ndarray:
    """(N,) column of `term`, computed over the basis grammar's whitelist (nothing is run as code)."""
    return column(term.expr, np.asarray(q, dtype=float), np.asarray(dq, dtype=float),
                  np.asarray(ddq, dtype=float))


def _piece(expr: list, joint_names, variables) -> tuple:
    """(name, expr, variables, readable factors) of a one-factor piece."""
    name = term_name(expr, joint_names)
    return (name, expr, frozenset(variables), (name,))


def _mul(a: tuple, b: tuple, family: str, unit: str) -> tuple:
    """Product of two pieces as a term tuple."""
    return (f"{a[0]}·{b[0]}", a[1] + b[1], unit, family, a[2] | b[2], a[3] + b[3])


class _Pieces:
    """One-factor pieces of the joints' signals, named after the joints."""

    def __init__(self, joint_names: Sequence[str]):
        self.joint_names = joint_names
        self.labels = [joint_label(n, i) for i, n in enumerate(joint_names)]

    def piece(self, expr, *variables):
        return _piece(expr, self.joint_names, variables)

    def q(self, k):
        return self.piece([["q", k]], f"q{self.labels[k]}")

    def dq(self, k):
        return self.piece([["dq", k]], f"dq{self.labels[k]}")

    def sgn(self, k):
        return self.piece([["sign", k]], f"dq{self.labels[k]}")

    def trig(self, fn, n, k):
        return self.piece([[fn, n, [k]]], f"q{self.labels[k]}")


def _single(p: tuple, unit: str, family: str) -> tuple:
    """A one-factor piece as a term tuple."""
    return p[:2] + (unit, family) + p[2:]


def _own_terms(P: _Pieces, j: int) -> list[tuple]:
    """The joint's own signals: constant, velocity signs, velocity, acceleration, powers and harmonics of
    its angle."""
    L = P.labels[j]
    out = [_single(P.piece([["1"]]), "N m", "constant"), _single(P.sgn(j), "N m", "velocity sign")]
    for v in SMOOTH_SIGN_VELOCITIES:
        out.append(_single(P.piece([["tanh", j, v]], f"dq{L}"), "N m", "velocity sign"))
    out += [
        _single(P.dq(j), "N m s/rad", "velocity"),
        _single(P.piece([["abs", "dq", j], ["dq", j]], f"dq{L}"), "N m s^2/rad^2", "velocity"),
        _single(P.piece([["pow", "dq", j, 3]], f"dq{L}"), "N m s^3/rad^3", "velocity"),
        _single(P.piece([["ddq", j]], f"ddq{L}"), "N m s^2/rad", "acceleration"),
        _single(P.q(j), "N m/rad", "angle"),
        _single(P.piece([["pow", "q", j, 2]], f"q{L}"), "N m/rad^2", "angle"),
        _single(P.piece([["pow", "q", j, 3]], f"q{L}"), "N m/rad^3", "angle"),
        _single(P.piece([["q", j], ["abs", "q", j]], f"q{L}"), "N m/rad^2", "angle"),
    ]
    out += [_single(P.trig(fn, n, j), "N m", "angle") for n in HARMONICS for fn in ("sin", "cos")]
    return out


def _position_dependent_terms(P: _Pieces, j: int) -> list[tuple]:
    """Friction and damping of joint j whose level changes with its angle."""
    L = P.labels[j]
    square = P.piece([["pow", "q", j, 2]], f"q{L}")
    out = [_mul(P.sgn(j), P.q(j), "velocity sign x angle", "N m/rad"),
           _mul(P.sgn(j), square, "velocity sign x angle", "N m/rad^2"),
           _mul(P.dq(j), P.q(j), "velocity x angle", "N m s/rad^2"),
           _mul(P.dq(j), square, "velocity x angle", "N m s/rad^3")]
    for n in HARMONICS:
        for fn in ("sin", "cos"):
            out.append(_mul(P.sgn(j), P.trig(fn, n, j), "velocity sign x angle", "N m"))
            out.append(_mul(P.dq(j), P.trig(fn, n, j), "velocity x angle", "N m s/rad"))
    return out


def _coupling_terms(P: _Pieces, j: int, k: int) -> list[tuple]:
    """Torque on joint j from another joint k's motion and pose."""
    K = P.labels[k]
    out = [
        _single(P.sgn(k), "N m", "coupling"),
        _single(P.piece([["tanh", k, 0.25]], f"dq{K}"), "N m", "coupling"),
        _single(P.dq(k), "N m s/rad", "coupling"),
        _single(P.piece([["abs", "dq", k], ["dq", k]], f"dq{K}"), "N m s^2/rad^2", "coupling"),
        _single(P.piece([["ddq", k]], f"ddq{K}"), "N m s^2/rad", "coupling"),
    ]
    out += [_single(P.trig(fn, n, k), "N m", "coupling") for n in (1, 2) for fn in ("sin", "cos")]
    out += [_mul(P.sgn(j), P.trig(fn, 1, k), "coupling", "N m") for fn in ("sin", "cos")]
    out.append(_mul(P.dq(j), P.dq(k), "coupling", "N m s^2/rad^2"))
    return out


def _angle_sum_terms(P: _Pieces) -> list[tuple]:
    """sin/cos of the sum of every pair of angles, and of all of them (more than two joints)."""
    n_j = len(P.joint_names)
    groups = [(a, b) for a in range(n_j) for b in range(a + 1, n_j)]
    if n_j > 2:
        groups.append(tuple(range(n_j)))
    return [_single(P.piece([[fn, 1, list(g)]], *(f"q{P.labels[k]}" for k in g)), "N m", "sum of angles")
            for g in groups for fn in ("sin", "cos")]


def generate(joint_names: Sequence[str], j: int, library: bool = True) -> list[Term]:
    """Every candidate term for joint index `j` of `joint_names` (before dropping duplicates)."""
    P = _Pieces(joint_names)
    out = _own_terms(P, j) + _position_dependent_terms(P, j)
    for k in range(len(joint_names)):
        if k != j:
            out += _coupling_terms(P, j, k)
    out += _angle_sum_terms(P)
    terms = [Term(*t) for t in out]
    if library:
        terms += library_terms(joint_names, j)
    return terms


def library_terms(joint_names: Sequence[str], j: int) -> list[Term]:
    """The library's joint-scope effects as terms on joint j: one per column and point of the shape grid."""
    from crane_io.physics.effects.library import BUILTIN_EFFECTS

    from .effects import shape_options

    L = joint_label(joint_names[j], j)
    out = []
    for cls in BUILTIN_EFFECTS:
        effect = cls()
        if effect.scope != "joint" or effect.name in _SKIP_LIBRARY:
            continue
        for shape in shape_options(effect):
            shape = {k: float(v) for k, v in (shape or {}).items()}
            try:
                k_cols = effect.n_columns()
            except CraneError:
                continue
            for c, p in enumerate(effect.linear_params[:k_cols]):
                expr = [["library", effect.name, j, c, dict(shape)]]
                name = term_name(expr, joint_names)
                out.append(Term(name, expr, p.unit, "library", frozenset({f"q{L}", f"dq{L}", f"ddq{L}"}),
                                (name,)))
    return out


def columns(terms: list[Term], q: np.ndarray, dq: np.ndarray, ddq: np.ndarray) -> np.ndarray:
    """(N, m) matrix of the terms' columns (each in its term's unit), from q (N, J) rad, dq (N, J) rad/s
    and ddq (N, J) rad/s^2."""
    if not terms:
        return np.zeros((len(q), 0))
    return np.stack([evaluate(t, q, dq, ddq) for t in terms], axis=1)


def distinct(terms: list[Term], T: np.ndarray, rows: np.ndarray, tol: float = 1e-2) -> list[int]:
    """Indices of the terms whose column on `rows` is finite, not zero and not (nearly) a linear
    combination of the earlier kept ones (what is left after projecting it on them is below `tol` of its
    norm: the library's Coulomb column is sign(dq), its spring columns are q and a constant)."""
    keep: list[int] = []
    basis: list[np.ndarray] = []  # orthonormal
    for i in range(T.shape[1]):
        c = T[rows, i]
        if not np.isfinite(c).all():
            continue
        nrm = float(np.linalg.norm(c))
        if nrm < 1e-9 * np.sqrt(max(len(c), 1)):
            continue
        r = c.copy()
        for _ in range(2):  # twice: Gram-Schmidt loses orthogonality once
            for v in basis:
                r -= (v @ r) * v
        rn = float(np.linalg.norm(r))
        if rn < tol * nrm:
            continue
        keep.append(i)
        basis.append(r / rn)
    return keep


def periods(term: Term) -> list[tuple[tuple[int, ...], float]]:
    """(joint columns whose summed angle it reads, period in rad) of each periodic factor of `term`:
    sin/cos(n·q) repeats every 2π/n, the library's cogging every 2π/cycles_per_rev."""
    out = []
    for f in term.expr:
        if f[0] in ("sin", "cos"):
            out.append((tuple(f[2]), 2 * math.pi / f[1]))
        elif f[0] == "library" and "cycles_per_rev" in f[4]:
            out.append(((f[2],), 2 * math.pi / float(f[4]["cycles_per_rev"])))
    return out


@dataclass(frozen=True)
class Refusal:
    """Periodic terms of one angle left out of the basis: the angle was observed over less than their
    period."""
    angle: str  # "q2", "q2 + q4"
    observed: float  # rad, the range of the angle over the rows
    shortest: float  # rad, the shortest refused period
    longest: float  # rad, the longest one
    count: int  # refused terms

    def sentence(self) -> str:
        span = (f"{self.shortest:.2f} rad" if math.isclose(self.shortest, self.longest)
                else f"{self.shortest:.2f}-{self.longest:.2f} rad")
        return (f"{self.count} periodic term(s) of {self.angle} (periods {span}) were not considered: "
                f"{self.angle} was observed over {self.observed:.2f} rad, less than one period.")


def periodic_refusals(terms: list[Term], q: np.ndarray, rows: np.ndarray, joint_names: Sequence[str]
                      ) -> tuple[list[int], list[Refusal]]:
    """(indices of the terms kept, the refusals): a term with a periodic factor is kept only when the
    angle that factor reads spans at least one period over `rows` (module docstring)."""
    labels = [joint_label(n, i) for i, n in enumerate(joint_names)]
    spans: dict[tuple[int, ...], float] = {}
    refused: dict[tuple[int, ...], list[float]] = {}
    keep = []
    for i, t in enumerate(terms):
        ok = True
        for cols, period in periods(t):
            if cols not in spans:
                angle = q[np.ix_(rows, list(cols))].sum(axis=1) if len(rows) else np.zeros(0)
                spans[cols] = float(np.ptp(angle)) if len(angle) else 0.0
            if spans[cols] < period:
                refused.setdefault(cols, []).append(period)
                ok = False
        if ok:
            keep.append(i)
    out = [Refusal(" + ".join(f"q{labels[k]}" for k in cols), spans[cols], min(p), max(p), len(p))
           for cols, p in refused.items()]
    return keep, out
