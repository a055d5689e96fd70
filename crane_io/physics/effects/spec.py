"""Effects as data: what a saved model, its loop export or a plant stores about each effect it uses, so that
loading rebuilds the effect without running any code.

A spec is a small JSON-able dict of one of three kinds:

    {"kind": "library", "name": "coulomb", "version": 1}
        a built-in effect of crane_io/physics/effects/library.py (rebuilt from the package, never from the
        registry, so a user's effect that took a built-in name is never mistaken for it);
    {"kind": "terms", "name": "discovered-joint2", "version": 1, "joint": "joint2",
     "joints": ["joint1", "joint2", "joint4"], "friction": false, "title": ..., "description": ...,
     "terms": [{"parameter": "sign_dq2", "term": "sign(dq2)", "factors": [["sign", 1]], "unit": "N m",
                "value": 0.21}, ...]}
        a sum of basis terms (crane_io/physics/effects/terms.py), each a named linear parameter whose
        default is `value`: what `crane-train diagnose --discover` finds, or an effect a user writes as data;
    {"kind": "user", "name": "cable-drag", "file": "/abs/cable_drag.py", "sha256": "..."}
        an effect defined in a user's Python file. Rebuilding it runs that file only when the user named
        it on the command line (`--effect-file`, `offer_effect_files`) and its SHA-256 is the recorded
        one, checked on the very bytes that are then run.

`identity(spec)` is the SHA-256 of the spec's canonical JSON: two different effects that share a name never
share an identity. An effect-spec file (`--write-effect-file`, `--effect-file X.json`) is a JSON document
{"format": "crane-effects", "format_version": 1, "effects": [terms spec, ...]}.
"""

from __future__ import annotations

import hashlib
import inspect
import json
import math
import re
import sys
import types
from pathlib import Path

import numpy as np

from crane_io.errors import ConfigError
from crane_io.physics.effects.base import Effect, Param, joint_columns
from crane_io.physics.effects.library import BUILTIN_EFFECTS
from crane_io.physics.effects.terms import check_term, column, term_name, value

KINDS = ("library", "terms", "user")
SPEC_VERSION = 1
FILE_FORMAT = "crane-effects"
FILE_FORMAT_VERSION = 1
MAX_TERMS = 64
_NAME = re.compile(r"^[A-Za-z][A-Za-z0-9_.+-]{0,63}$")
_PARAM = re.compile(r"^[A-Za-z_][A-Za-z0-9_]{0,63}$")
_SHA = re.compile(r"^[0-9a-f]{64}$")
_TEXT_MAX = 2000

# Python effect files run in this process: SHA-256 -> {effect name: class}; and class -> (file, SHA-256)
_RUN: dict[str, dict[str, type[Effect]]] = {}
_SOURCE: dict[type, tuple[str, str]] = {}
# files the user named for loading models (read, hashed, not run): SHA-256 -> (path, bytes)
_OFFERED: dict[str, tuple[str, bytes]] = {}


# ---- identity -----------------------------------------------------------------------------------------
def canonical_json(spec: dict) -> str:
    return json.dumps(spec, sort_keys=True, separators=(",", ":"), ensure_ascii=True, allow_nan=False)


def identity(spec: dict) -> str:
    """SHA-256 (hex) of the spec's canonical JSON (without any "identity" key)."""
    body = {k: v for k, v in spec.items() if k != "identity"}
    return hashlib.sha256(canonical_json(body).encode()).hexdigest()


def short(sha: str) -> str:
    return sha[:12]


# ---- checking specs (plain data in, canonical plain data out) -----------------------------------------
def _text(value, what: str, default: str = "") -> str:
    if value is None:
        return default
    if not isinstance(value, str) or len(value) > _TEXT_MAX:
        raise ConfigError(f"{what} must be a text of at most {_TEXT_MAX} characters")
    return value


def _name(value, where: str) -> str:
    if not isinstance(value, str) or not _NAME.match(value):
        raise ConfigError(f"{where} has an effect name {value!r}; a name is a letter followed by up to 63 "
                          f"letters, digits or . _ + -")
    return value


def check_spec(spec, where: str = "an effect spec") -> dict:
    """The spec as canonical plain data; ConfigError (one sentence) for anything malformed."""
    if not isinstance(spec, dict):
        raise ConfigError(f"{where} must be a table (a JSON object), got {type(spec).__name__}")
    kind = spec.get("kind")
    if kind not in KINDS:
        raise ConfigError(f"{where} has kind {kind!r}; it must be one of {', '.join(KINDS)}")
    name = spec.get("name")
    if kind == "library":
        cls = _builtin(name)
        if cls is None:
            raise ConfigError(f"{where} names the built-in effect {name!r}, which this installation does not "
                              f"have")
        if spec.get("version") != cls.version:
            raise ConfigError(f"{where} records version {spec.get('version')!r} of the built-in effect "
                              f"{name!r}; this installation has version {cls.version}")
        return {"kind": kind, "name": name, "version": cls.version}
    if kind == "user":
        if not isinstance(name, str) or not name or len(name) > 200:
            raise ConfigError(f"{where} has no usable effect name")
        file, sha = spec.get("file"), spec.get("sha256")
        if not isinstance(file, str) or not file or len(file) > 4096:
            raise ConfigError(f"{where} (effect {name!r}) does not name the Python file that defines it")
        if not isinstance(sha, str) or not _SHA.match(sha):
            raise ConfigError(f"{where} (effect {name!r}) has no SHA-256 of the file that defines it")
        return {"kind": kind, "name": name, "file": file, "sha256": sha}
    return _check_terms_spec(spec, _name(name, where), where)


def _check_terms_spec(spec: dict, name: str, where: str) -> dict:
    at = f"{where} (effect {name!r})"
    if spec.get("version", SPEC_VERSION) != SPEC_VERSION:
        raise ConfigError(f"{at} has version {spec.get('version')!r}; this installation reads version "
                          f"{SPEC_VERSION}")
    joints = spec.get("joints")
    names_ok = isinstance(joints, list) and all(isinstance(j, str) and _NAME.match(j) for j in joints)
    if not names_ok or not 0 < len(joints) <= 16 or len(set(joints)) < len(joints):
        raise ConfigError(f"{at} must list its joint order in 'joints' (distinct joint names)")
    joint = spec.get("joint")
    if joint is not None and joint not in joints:
        raise ConfigError(f"{at} is for joint {joint!r}, which is not in its joints {', '.join(joints)}")
    friction = spec.get("friction", False)
    if not isinstance(friction, bool):
        raise ConfigError(f"{at}: 'friction' must be true or false")
    terms = spec.get("terms")
    if not isinstance(terms, list) or not terms or len(terms) > MAX_TERMS:
        raise ConfigError(f"{at} must have between 1 and {MAX_TERMS} terms")
    out_terms, seen = [], set()
    for i, t in enumerate(terms, start=1):
        if not isinstance(t, dict):
            raise ConfigError(f"{at}: term {i} must be a table")
        param = t.get("parameter")
        if not isinstance(param, str) or not _PARAM.match(param) or param in seen:
            raise ConfigError(f"{at}: term {i} needs a distinct parameter name (letters, digits, _), got "
                              f"{param!r}")
        seen.add(param)
        factors = check_term(t.get("factors"), len(joints))
        value = t.get("value", 0.0)
        if isinstance(value, bool) or not isinstance(value, (int, float)) or not math.isfinite(value):
            raise ConfigError(f"{at}: term {i} has value {value!r}, not a finite number")
        out_terms.append({"parameter": param, "term": term_name(factors, joints), "factors": factors,
                          "unit": _text(t.get("unit"), f"{at}: term {i} unit", "N m"), "value": float(value)})
    return {"kind": "terms", "name": name, "version": SPEC_VERSION, "joint": joint, "joints": list(joints),
            "friction": friction, "title": _text(spec.get("title"), f"{at} title"),
            "description": _text(spec.get("description"), f"{at} description"), "terms": out_terms}


def _builtin(name):
    return next((c for c in BUILTIN_EFFECTS if c.name == name), None)


# ---- effects built from terms -----------------------------------------------------------------------------
class TermsEffect(Effect):
    """An effect that is a sum of basis terms (its spec's "terms"), one linear parameter each."""

    spec: dict = {}
    _factors: tuple = ()
    _n_joints: int = 0

    def _term_matrix(self, q, dq, ddq) -> np.ndarray:
        if q.shape[1] != self._n_joints:
            raise ConfigError(f"the effect {self.name!r} reads {self._n_joints} joints "
                              f"({', '.join(self.spec['joints'])}) but the data has {q.shape[1]}")
        return np.stack([column(f, q, dq, ddq) for f in self._factors], axis=1)

    def _columns(self, q, dq, ddq, joint, shape):
        cols = self._term_matrix(q, dq, ddq)
        return joint_columns(len(q), q.shape[1], joint, *cols.T)

    def torque(self, q, dq, ddq, joint, values=None):
        """As Effect.torque, with complete `values` taken as they are (the simulated plant calls it every
        substep)."""
        if values is None or len(values) != len(self.params) or np.ndim(q) != 2:
            return super().torque(q, dq, ddq, joint, values)
        q, dq, ddq = (np.asarray(a, dtype=float) for a in (q, dq, ddq))
        out = np.zeros(q.shape)
        coefs = [values[p.name] for p in self.params]
        if q.shape[0] == 1 and q.shape[1] == self._n_joints:  # one sample: plain floats are faster
            ql, dql, ddql = q[0].tolist(), dq[0].tolist(), ddq[0].tolist()
            out[0, joint] = sum(c * value(f, ql, dql, ddql) for c, f in zip(coefs, self._factors))
            return out
        out[:, joint] = self._term_matrix(q, dq, ddq) @ np.array(coefs)
        return out


def terms_effect_class(spec: dict) -> type[TermsEffect]:
    """An Effect subclass made from a checked terms spec (plain data: nothing is run)."""
    doc = check_spec(spec)
    params = tuple(Param(t["parameter"], t["unit"], t["value"], f"coefficient of {t['term']}")
                   for t in doc["terms"])
    expr = " + ".join(f"{t['parameter']}·{t['term']}" for t in doc["terms"])
    attrs = {"name": doc["name"], "title": doc["title"] or f"terms of {doc['joint'] or 'a joint'}",
             "description": doc["description"] or f"{expr} (N m).",
             "signature": f"the residual of {{joint}} follows {expr}", "params": params, "shape_grid": {},
             "friction": doc["friction"], "spec": doc, "_factors": tuple(t["factors"] for t in doc["terms"]),
             "_n_joints": len(doc["joints"]), "__module__": __name__}
    return type(f"Terms_{short(identity(doc))}", (TermsEffect,), attrs)


# ---- the spec of an effect ---------------------------------------------------------------------------------
def file_sha256(raw: bytes) -> str:
    return hashlib.sha256(raw).hexdigest()


def spec_of(effect: Effect) -> dict:
    """The spec of an effect instance (library, terms, or a user's Python class with its file's SHA-256)."""
    cls = type(effect)
    if cls is _builtin(cls.name):
        return {"kind": "library", "name": cls.name, "version": cls.version}
    if isinstance(effect, TermsEffect):
        return dict(cls.spec)
    if cls not in _SOURCE:
        try:
            path = Path(inspect.getfile(cls)).resolve()
            raw = path.read_bytes()
        except (TypeError, OSError):
            raise ConfigError(f"the effect {cls.name!r} has no source file to record; define it in a Python "
                              f"file and name it with --effect-file") from None
        sha = file_sha256(raw)
        _SOURCE[cls] = (str(path), sha)
        _RUN.setdefault(sha, {})[cls.name] = cls
    file, sha = _SOURCE[cls]
    return {"kind": "user", "name": cls.name, "file": file, "sha256": sha}


# ---- Python effect files: the one place a user's code runs ------------------------------------------------
def read_effect_file(path) -> tuple[Path, bytes, str]:
    """(path, bytes, SHA-256) of an effect file; ConfigError when it cannot be read."""
    path = Path(path)
    if not path.is_file():
        raise ConfigError(f"effect file {path} does not exist")
    try:
        raw = path.read_bytes()
    except OSError as exc:
        raise ConfigError(f"cannot read the effect file {path}: {exc.strerror or exc}") from None
    return path, raw, file_sha256(raw)


def run_python_effects(path: Path, raw: bytes, sha: str) -> list[type[Effect]]:
    """Run the Python source `raw` (read from `path`, hashed to `sha`) and return the Effect subclasses it
    defines. Called only for a file the user named explicitly."""
    if sha in _RUN and _RUN[sha]:
        return list(_RUN[sha].values())
    mod_name = f"crane_user_effects_{sha[:16]}"
    module = types.ModuleType(mod_name)
    module.__file__ = str(path)
    sys.modules[mod_name] = module
    try:
        code = compile(raw, str(path), "exec")
        exec(code, module.__dict__)  # noqa: S102 - the user named this file to define effects
    except BaseException as exc:  # a user's file can fail in any way (even sys.exit): one sentence
        sys.modules.pop(mod_name, None)
        if isinstance(exc, KeyboardInterrupt):
            raise
        raise ConfigError(f"effect file {path} failed to load: {type(exc).__name__}: {exc}") from None
    found = [obj for obj in vars(module).values()
             if inspect.isclass(obj) and issubclass(obj, Effect) and obj.__module__ == mod_name and obj.name]
    if not found:
        raise ConfigError(f"effect file {path} defines no Effect subclass with a name")
    for cls in found:
        _SOURCE[cls] = (str(path.resolve()), sha)
    _RUN[sha] = {cls.name: cls for cls in found}
    return found


def offer_effect_files(paths) -> None:
    """Files the user named so that loading a model may use the effects they define: read and hashed
    now, run only when a model's spec records the same SHA-256 (the bytes hashed are the bytes run)."""
    for p in paths:
        path, raw, sha = read_effect_file(p)
        if path.suffix == ".py":
            _OFFERED[sha] = (str(path), raw)


def forget_offered() -> None:
    _OFFERED.clear()


# ---- rebuilding -------------------------------------------------------------------------------------------
def rebuild(spec: dict, where: str = "the model", hint: str | None = None) -> Effect:
    """A fresh Effect from a checked spec, without running any code a user did not name on the command
    line. ConfigError, one sentence starting with `where`, when it cannot be rebuilt (`hint`: how to
    proceed when a user's Python file is needed and was not named)."""
    kind, name = spec["kind"], spec["name"]
    if kind == "library":
        return _builtin(name)()
    if kind == "terms":
        return terms_effect_class(spec)()
    sha, file = spec["sha256"], spec["file"]
    cls = _RUN.get(sha, {}).get(name)
    if cls is None and sha in _OFFERED:
        path, raw = _OFFERED[sha]
        cls = {c.name: c for c in run_python_effects(Path(path), raw, sha)}.get(name)
        if cls is None:
            raise ConfigError(f"{where} uses the effect {name!r} from {file}, but the file named with "
                              f"--effect-file ({path}) does not define it")
    if cls is None:
        changed = [p for p, _ in _OFFERED.values() if Path(p).name == Path(file).name]
        if changed:
            raise ConfigError(f"{where} uses the effect {name!r} from the Python file {file} with SHA-256 "
                              f"{short(sha)}..., but {changed[0]} has another SHA-256, so it was not run: "
                              f"it changed since the model was fitted; fit the model again with it")
        hint = hint or f"name that file with --effect-file {file} to use it"
        raise ConfigError(f"{where} uses the effect {name!r} defined in the Python file {file} (SHA-256 "
                          f"{short(sha)}...), which loading a model never runs by itself; {hint}")
    return cls()


def effect_table(specs, where: str = "the model", hint: str | None = None) -> dict[str, Effect]:
    """name -> rebuilt Effect for a model's list of specs (each checked; one effect per name)."""
    if not isinstance(specs, list):
        raise ConfigError(f"{where} has an effect list that is not a list")
    out: dict[str, Effect] = {}
    for s in specs:
        doc = check_spec(s, f"an effect spec of {where}")
        if doc["name"] in out:
            raise ConfigError(f"{where} lists two effects named {doc['name']!r}")
        if "identity" in s and s["identity"] != identity(doc):
            raise ConfigError(f"{where} records the effect {doc['name']!r} with an identity that does not "
                              f"match its content; it was altered, fit the model again")
        out[doc["name"]] = rebuild(doc, where, hint)
    return out


def with_identity(spec: dict) -> dict:
    doc = check_spec(spec)
    return {**doc, "identity": identity(doc)}


# ---- effect-spec files -------------------------------------------------------------------------------------
def spec_file_document(specs, **about) -> dict:
    """The JSON document of an effect-spec file holding `specs` (terms specs), plus informational keys."""
    return {"format": FILE_FORMAT, "format_version": FILE_FORMAT_VERSION, **about,
            "effects": [check_spec(s) for s in specs]}


def read_spec_file(path, raw: bytes | None = None) -> list[dict]:
    """The checked terms specs of an effect-spec file (JSON; nothing in it is run)."""
    path = Path(path)
    if raw is None:
        path, raw, _ = read_effect_file(path)
    try:
        doc = json.loads(raw.decode("utf-8"))
    except (UnicodeDecodeError, json.JSONDecodeError, RecursionError):
        raise ConfigError(f"effect-spec file {path} is not readable JSON") from None
    if not isinstance(doc, dict) or doc.get("format") != FILE_FORMAT:
        raise ConfigError(f"{path} is not an effect-spec file (its format is not {FILE_FORMAT!r})")
    if doc.get("format_version") != FILE_FORMAT_VERSION:
        raise ConfigError(f"effect-spec file {path} has format version {doc.get('format_version')!r}; this "
                          f"installation reads version {FILE_FORMAT_VERSION}")
    effects = doc.get("effects")
    if not isinstance(effects, list) or not effects:
        raise ConfigError(f"effect-spec file {path} lists no effects")
    out = [check_spec(s, f"effect {i} of {path}") for i, s in enumerate(effects, start=1)]
    for s in out:
        if s["kind"] != "terms":
            raise ConfigError(f"effect-spec file {path} may define effects of kind 'terms' only, not "
                              f"{s['kind']!r}")
    names = [s["name"] for s in out]
    if len(set(names)) != len(names):
        raise ConfigError(f"effect-spec file {path} defines two effects of one name")
    return out
