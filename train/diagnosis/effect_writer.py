"""`crane-train diagnose --discover --write-effect-file PATH.json`: the discovered terms as an effect-spec
file (crane_io/physics/effects/spec.py), effects as data that `--effect-file` reads without running
anything: one effect per joint with a significant discovery, `discovered-JOINT`, one named linear
parameter per term (the estimate as its default), each term in the basis grammar of
crane_io/physics/effects/terms.py, the very columns the discovery fitted. Every text in the file (session
and model paths included) is a JSON string, so nothing it embeds can become code."""

from __future__ import annotations

from pathlib import Path
from typing import TYPE_CHECKING

from crane_io.errors import ConfigError
from crane_io.physics.effects.spec import spec_file_document

from .discovery import Discovery, JointDiscovery

if TYPE_CHECKING:
    from collections.abc import Sequence

SUFFIX = ".json"


def effect_name(joint: str) -> str:
    return f"discovered-{joint}"


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
    return {"kind": "terms", "name": effect_name(d.joint), "version": 1, "joint": d.joint,
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
    adds = " ".join(f"--effect {effect_name(d.joint)}:joint={d.joint}"
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
    return path, [(effect_name(d.joint), d.joint, d.on_top_of) for d in _found(discovery)]


def check_suffix(path: Path | str) -> None:
    if Path(path).suffix != SUFFIX:
        raise ConfigError(f"--write-effect-file writes effects as data: give a path ending in {SUFFIX}, "
                          f"got {path}")
