"""A closed grammar of basis terms: the columns a discovered effect is made of, as plain data.

A term is a product of factors; a factor is a short JSON list naming one function of the joints' signals
(k: a column of the joint order the term was found in, q (N, J) rad, dq rad/s, ddq rad/s^2):

    ["1"]                         1
    ["q", k], ["dq", k], ["ddq", k]   the signal of column k
    ["sign", k]                   sign(dq_k)
    ["tanh", k, v]                tanh(dq_k / v), v > 0 rad/s
    ["abs", "q" | "dq", k]        |q_k|, |dq_k|
    ["pow", "q" | "dq", k, p]     q_k^p, dq_k^p (p = 2 or 3)
    ["sin" | "cos", n, [k, ...]]  sin(n (q_a + q_b + ...)), n = 1..64
    ["library", NAME, k, c, {SHAPE}]  column c of the built-in effect NAME on column k at that shape

`columns` computes a term with numpy over this whitelist (nothing is evaluated as code); `term_name`
renders it readably ("sign(dq2)·cos(2·q2)", the joints labelled by their names' trailing digits).
`check_term` refuses anything outside the grammar in one sentence. The discovery basis
(train/diagnosis/discovery_basis.py) builds its candidates in this grammar, so a discovered effect saved as
data computes exactly the columns the discovery fitted.
"""

from __future__ import annotations

import math
import re
from typing import TYPE_CHECKING

import numpy as np

from crane_io.errors import ConfigError

if TYPE_CHECKING:
    from collections.abc import Sequence

SIGNALS = ("q", "dq", "ddq")
POWERS = (2, 3)
MAX_HARMONIC = 64
MAX_FACTORS = 8
_SUPER = {2: "²", 3: "³"}
# built-in effects a term may use as a column of one joint (payload and torque-constant-error read the
# arm's dynamics; backlash's plant-only parameters do not enter its columns)
_NOT_A_TERM = ("payload", "torque-constant-error")


def joint_label(name: str, index: int) -> str:
    """The label of a joint in term names: the trailing digits of its name ("joint2" -> "2"), else its
    position from 1."""
    m = re.search(r"(\d+)$", str(name))
    return m.group(1) if m else str(index + 1)


def library_effect(name: str):
    """A fresh instance of the built-in effect `name` (never a user's effect of that name), for terms."""
    from crane_io.physics.effects.library import BUILTIN_EFFECTS

    cls = next((c for c in BUILTIN_EFFECTS if c.name == name), None)
    if cls is None or name in _NOT_A_TERM or cls.scope != "joint":
        raise ConfigError(f"a term can use a built-in effect of one joint, not {name!r}")
    return cls()


def _is_int(x) -> bool:
    return isinstance(x, int) and not isinstance(x, bool)


def _is_number(x) -> bool:
    return isinstance(x, (int, float)) and not isinstance(x, bool) and math.isfinite(x)


def _column(k, n_joints: int, what: str) -> int:
    if not _is_int(k) or not 0 <= k < n_joints:
        raise ConfigError(f"{what} names joint column {k!r}, not one of 0..{n_joints - 1}")
    return k


def _distinct_columns(ks, n_joints: int, what: str) -> list[int]:
    """The joint columns of a sum of angles, each named once."""
    cols = [_column(k, n_joints, what) for k in ks]
    if len(set(cols)) != len(cols):
        raise ConfigError(f"{what} names a joint column twice: {list(ks)!r}")
    return cols


def _library_args(args: list, n_joints: int, what: str) -> list:
    """[effect name, joint column, effect column, shape] of a library factor, checked against the effect."""
    effect = library_effect(args[0])
    k = _column(args[1], n_joints, what)
    if not _is_int(args[2]) or not 0 <= args[2] < effect.n_columns():
        raise ConfigError(f"the built-in effect {args[0]!r} has {effect.n_columns()} column(s), a term "
                          f"names column {args[2]!r}")
    known = {p.name for p in effect.shape_params}
    shape = {}
    for key, v in args[3].items():
        if key not in known or not _is_number(v):
            raise ConfigError(f"the built-in effect {args[0]!r} in a term has no shape {key!r} = {v!r} "
                              f"(its shape parameters: {', '.join(sorted(known)) or 'none'})")
        shape[key] = float(v)
    return [args[0], k, args[2], shape]


def check_factor(f, n_joints: int) -> list:
    """The factor as canonical plain data (lists, floats); ConfigError for anything outside the grammar."""
    if not isinstance(f, (list, tuple)) or not f or not isinstance(f[0], str):
        raise ConfigError(f"a term factor must be a list starting with its function's name, got "
                          f"{str(f)[:80]}")
    op, args = f[0], list(f[1:])
    what = f"the factor {op!r}"
    if op == "1" and not args:
        return ["1"]
    if op in (*SIGNALS, "sign") and len(args) == 1:
        return [op, _column(args[0], n_joints, what)]
    if op == "tanh" and len(args) == 2 and _is_number(args[1]) and args[1] > 0:
        return [op, _column(args[0], n_joints, what), float(args[1])]
    if op == "abs" and len(args) == 2 and args[0] in ("q", "dq"):
        return [op, args[0], _column(args[1], n_joints, what)]
    if op == "pow" and len(args) == 3 and args[0] in ("q", "dq") and args[2] in POWERS and _is_int(args[2]):
        return [op, args[0], _column(args[1], n_joints, what), args[2]]
    if (op in ("sin", "cos") and len(args) == 2 and _is_int(args[0]) and 1 <= args[0] <= MAX_HARMONIC
            and isinstance(args[1], (list, tuple)) and args[1]):
        return [op, args[0], _distinct_columns(args[1], n_joints, what)]
    if op == "library" and len(args) == 4 and isinstance(args[0], str) and isinstance(args[3], dict):
        return [op, *_library_args(args, n_joints, what)]
    raise ConfigError(f"{str(f)[:80]} is not a factor of the basis grammar (1, q, dq, ddq, sign, tanh, abs, "
                      f"pow, sin, cos, library, each with its arguments)")


def check_term(factors, n_joints: int) -> list:
    """A term (a non-empty list of factors) as canonical plain data; ConfigError when outside the grammar."""
    if not isinstance(factors, (list, tuple)) or not 0 < len(factors) <= MAX_FACTORS:
        raise ConfigError(f"a term must be a list of 1 to {MAX_FACTORS} factors, got {str(factors)[:80]}")
    return [check_factor(f, n_joints) for f in factors]


def factor_name(f: Sequence, labels: Sequence[str]) -> str:
    op = f[0]
    if op == "1":
        return "1"
    if op in SIGNALS:
        return f"{op}{labels[f[1]]}"
    if op == "sign":
        return f"sign(dq{labels[f[1]]})"
    if op == "tanh":
        return f"tanh(dq{labels[f[1]]}/{f[2]:g})"
    if op == "abs":
        return f"|{f[1]}{labels[f[2]]}|"
    if op == "pow":
        return f"{f[1]}{labels[f[2]]}{_SUPER[f[3]]}"
    if op in ("sin", "cos"):
        arg = " + ".join(f"q{labels[k]}" for k in f[2])
        return f"{op}({arg})" if f[1] == 1 else f"{op}({f[1]}·{arg})"
    effect = library_effect(f[1])
    p = effect.linear_params[f[3]]
    base = effect.name if effect.n_columns() == 1 else f"{effect.name}.{p.name}"
    where = ", ".join(f"{k}={v:g}" for k, v in f[4].items())
    return f"{base}(joint{labels[f[2]]}; {where})" if where else f"{base}(joint{labels[f[2]]})"


def term_name(factors: Sequence, joint_names: Sequence[str]) -> str:
    """Readable name of a term, e.g. "sign(dq2)·cos(2·q2)"."""
    labels = [joint_label(n, i) for i, n in enumerate(joint_names)]
    return "·".join(factor_name(f, labels) for f in factors)


def _factor_column(f: Sequence, q, dq, ddq) -> np.ndarray:
    op = f[0]
    if op == "1":
        return np.ones(q.shape[0])
    if op in SIGNALS:
        return {"q": q, "dq": dq, "ddq": ddq}[op][:, f[1]]
    if op == "sign":
        return np.sign(dq[:, f[1]])
    if op == "tanh":
        return np.tanh(dq[:, f[1]] / f[2])
    if op == "abs":
        return np.abs((q if f[1] == "q" else dq)[:, f[2]])
    if op == "pow":
        return (q if f[1] == "q" else dq)[:, f[2]] ** f[3]
    if op in ("sin", "cos"):
        arg = q[:, f[2][0]]
        for k in f[2][1:]:
            arg = arg + q[:, k]
        arg = arg if f[1] == 1 else f[1] * arg
        return np.sin(arg) if op == "sin" else np.cos(arg)
    return library_effect(f[1]).columns(q, dq, ddq, f[2], f[4])[:, f[2], f[3]]


def _sign(x: float) -> float:
    return 1.0 if x > 0 else (-1.0 if x < 0 else 0.0)  # as np.sign: 0 at 0


def _factor_value(f: Sequence, q: list, dq: list, ddq: list) -> float:
    op = f[0]
    if op == "1":
        return 1.0
    if op in SIGNALS:
        return {"q": q, "dq": dq, "ddq": ddq}[op][f[1]]
    if op == "sign":
        return _sign(dq[f[1]])
    if op == "tanh":
        return math.tanh(dq[f[1]] / f[2])
    if op == "abs":
        return abs((q if f[1] == "q" else dq)[f[2]])
    if op == "pow":
        return (q if f[1] == "q" else dq)[f[2]] ** f[3]
    if op in ("sin", "cos"):
        arg = q[f[2][0]]
        for k in f[2][1:]:
            arg = arg + q[k]
        arg = arg if f[1] == 1 else f[1] * arg
        return math.sin(arg) if op == "sin" else math.cos(arg)
    a = np.array([q]), np.array([dq]), np.array([ddq])
    return float(library_effect(f[1]).columns(*a, f[2], f[4])[0, f[2], f[3]])


def value(factors: Sequence, q: list, dq: list, ddq: list) -> float:
    """A checked term for one sample given as lists of floats (the simulated plant's substep)."""
    out = 1.0
    for f in factors:
        out *= _factor_value(f, q, dq, ddq)
    return out


def column(factors: Sequence, q: np.ndarray, dq: np.ndarray, ddq: np.ndarray) -> np.ndarray:
    """(N,) column of a checked term from (N, J) arrays."""
    out = None
    for f in factors:
        c = _factor_column(f, q, dq, ddq)
        out = c if out is None else out * c
    return np.broadcast_to(np.asarray(out, dtype=float), (q.shape[0],)).copy()
