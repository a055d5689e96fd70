"""`crane-train diagnose --discover --write-effect-file PATH.json`: the discovered terms as an effect-spec
file (crane_io/physics/effects/spec.py), effects as data that `--effect-file` reads without running
anything: one effect per joint with a significant discovery, named by what was found (`effect_name`:
"joint2-sign-dq+sign-dq-cos4q", the joint and its terms), one named linear parameter per term (the
estimate as its default), each term in the basis grammar of crane_io/physics/effects/terms.py, the very
columns the discovery fitted. Every text in the file (session and model paths included) is a JSON
string, so nothing it embeds can become code."""

from __future__ import annotations

import hashlib
from pathlib import Path
from typing import TYPE_CHECKING

from crane_io.errors import ConfigError
from crane_io.physics.effects.spec import spec_file_document
from crane_io.physics.effects.terms import joint_label

from .discovery import Discovery, JointDiscovery

if TYPE_CHECKING:
    from collections.abc import Sequence

SUFFIX = ".json"


MAX_NAME = 64  # an effect name's length (crane_io.physics.effects.spec)
MAX_DESCRIPTION = 2000  # characters of an effect's description (crane_io.physics.effects.spec)


def _factor_slug(f: list, j: int, labels: Sequence[str]) -> str:
    """A factor of the basis grammar in a name: the joint's own signals unlabelled ("q", "sign-dq",
    "cos4q"), another joint's with its label ("dq_j4"); numbers written exactly (repr), so that two
    different factors never share a slug."""
    def at(k):
        return "" if k == j else f"_j{labels[k]}"

    op = f[0]
    if op == "1":
        return "const"
    if op in ("q", "dq", "ddq"):
        return f"{op}{at(f[1])}"
    if op == "sign":
        return f"sign-dq{at(f[1])}"
    if op == "tanh":
        return f"tanh-dq{at(f[1])}-{float(f[2])!r}"
    if op == "abs":
        return f"abs-{f[1]}{at(f[2])}"
    if op == "pow":
        return f"{f[1]}{at(f[2])}-p{f[3]}"
    if op in ("sin", "cos"):
        angle = "q" if list(f[2]) == [j] else "q" + "".join(f"_j{labels[k]}" for k in f[2])
        return f"{op}{f[1] if f[1] != 1 else ''}{angle}"
    shape = "".join(f"-{k}.{float(v)!r}" for k, v in sorted(f[4].items()))
    return f"lib.{f[1]}.{f[3]}{at(f[2])}{shape}"


def term_slug(expr: list, j: int, joint_names: Sequence[str]) -> str:
    """A term in a name: its factors' slugs joined by "-" ("sign-dq-cos4q")."""
    labels = [joint_label(n, i) for i, n in enumerate(joint_names)]
    return "-".join(_factor_slug(f, j, labels) for f in expr)


def effect_name(d: JointDiscovery, joints: Sequence[str]) -> str:
    """The name of a discovery's effect, derived from its definition: the joint, then its terms' slugs in
    sorted order joined by "+" ("joint2-sign-dq+sign-dq-cos4q"). The same terms on the same joint always
    give the same name and different terms a different one; a name longer than MAX_NAME characters keeps
    its start and ends in the first 10 hex digits of the SHA-256 of the full one."""
    j = list(joints).index(d.joint)
    full = f"{d.joint}-" + "+".join(sorted(term_slug(t.expr, j, joints) for t in d.terms))
    if len(full) <= MAX_NAME:
        return full
    digest = hashlib.sha256(full.encode()).hexdigest()[:10]
    return f"{full[:MAX_NAME - 11]}-{digest}"


def _parameters(d: JointDiscovery) -> list[str]:
    names, out = set(), []
    for t in d.terms:
        name = t.parameter or "c"
        base, i = name, 2
        while name in names:
            name, i = f"{base}_{i}", i + 1
        names.add(name)
        out.append(name)
    return out


def effect_spec(d: JointDiscovery, joints: Sequence[str]) -> dict:
    """The terms spec of one joint's discovery."""
    terms = ", ".join(f"{t.term} = {t.coefficient:.4g} ± {t.stderr:.2g} {t.unit}" for t in d.terms)
    blocks = ", ".join(f"{100 * r:.0f}%" for r in d.fold_reductions)
    on_top = (f" Discovered on top of the library's {d.on_top_of} on {d.joint}: fit with both "
              f"(--effect {d.on_top_of}:joint={d.joint})." if d.on_top_of else "")
    description = (f"{d.joint}: tau += {d.expression} (N m), found by crane-train diagnose --discover. "
                   f"Terms (estimate ± delete-a-block jackknife standard error): {terms}. Held-out error "
                   f"removed: {100 * d.error_reduction:.0f}% (per block: {blocks}).{on_top}")
    if len(description) > MAX_DESCRIPTION:  # the terms and their estimates are in "terms" as well
        description = (f"{d.joint}: a sum of {len(d.terms)} terms found by crane-train diagnose --discover "
                       f"(their estimates are the defaults below). Held-out error removed: "
                       f"{100 * d.error_reduction:.0f}%.{on_top}")
    return {"kind": "terms", "name": effect_name(d, joints), "version": 1, "joint": d.joint,
            "joints": list(joints), "friction": False, "title": f"discovered term of {d.joint}",
            "description": description,
            "terms": [{"parameter": p, "factors": t.expr, "unit": t.unit, "value": t.coefficient}
                      for p, t in zip(_parameters(d), d.terms)]}


def _found(discovery: Discovery) -> list[JointDiscovery]:
    return [d for d in discovery.discovered if d.significant and d.terms]


def effect_document(discovery: Discovery, model_dir: Path | str = "MODEL_DIR",
                    sessions: Sequence[Path | str] = ()) -> dict:
    """The effect-spec document for every significant discovery (ConfigError if none)."""
    found = _found(discovery)
    if not found:
        raise ConfigError("no significant discovery: there is no term to write as an effect")
    adds = " ".join(f"--effect {effect_name(d, discovery.joints)}:joint={d.joint}"
                    + (f" --effect {d.on_top_of}:joint={d.joint}" if d.on_top_of else "") for d in found)
    flag = "--discover-all" if discovery.settings.get("every_joint") else "--discover"
    return spec_file_document(
        [effect_spec(d, discovery.joints) for d in found],
        found_by={"command": "crane-train diagnose", "model": str(model_dir),
                  "sessions": [str(s) for s in sessions], "flag": flag},
        use=f"crane-train fit SESSION... --model rigid-body --effect-file THIS_FILE {adds} -o NEW_DIR "
            "(with the effects the model already has); then crane-train compare OLD_DIR NEW_DIR")


def write_effect_file(path: Path | str, discovery: Discovery, model_dir: Path | str = "MODEL_DIR",
                      sessions: Sequence[Path | str] = ()) -> tuple[Path, list]:
    """Write the effect-spec file atomically (the path checked by the caller with
    crane_io.output_files.check_output); returns (path, [(effect name, joint, library effect it sits on or
    None)])."""
    import json

    from crane_io.output_files import write_text_atomic

    path = Path(path)
    check_suffix(path)
    text = json.dumps(effect_document(discovery, model_dir, sessions), indent=2, ensure_ascii=True,
                      allow_nan=False)
    write_text_atomic(path, text + "\n", what="effect-spec file")
    return path, [(effect_name(d, discovery.joints), d.joint, d.on_top_of) for d in _found(discovery)]


def check_suffix(path: Path | str) -> None:
    if Path(path).suffix != SUFFIX:
        raise ConfigError(f"--write-effect-file writes effects as data: give a path ending in {SUFFIX}, "
                          f"got {path}")
