"""The physical effects a fitted model contains, as its options record them (rigid-body, hybrid).

`crane-train fit --effect` stores each as [name, joint, shape] (joint None: on every joint or an
arm-wide effect); older records may hold a plain name or a {"name", "joint"} table.
"""

from __future__ import annotations

from typing import TYPE_CHECKING

if TYPE_CHECKING:
    from .base import Model


def effect_entries(model: Model) -> list[tuple[object, object]]:
    """(effect name, joint or None) for every effect in the model's options, as recorded."""
    out = []
    for entry in (getattr(model, "options", {}) or {}).get("effects") or []:
        if isinstance(entry, dict):
            out.append((entry.get("name"), entry.get("joint")))
        elif isinstance(entry, str):
            out.append((entry, None))
        else:
            out.append((entry[0], entry[1] if len(entry) > 1 else None))
    return out


def effect_labels(model: Model) -> list[str]:
    """'coulomb:joint=joint2' (or just 'payload' without a joint) for every effect in the model."""
    return [f"{name}:joint={joint}" if joint else str(name) for name, joint in effect_entries(model)]


def effect_identities(model: Model) -> dict[str, str]:
    """Effect name -> the identity (SHA-256 of its spec, crane_io.physics.effects.spec) of the effect the
    model records under that name: two effects that share a name but not their definition differ here."""
    from crane_io.physics.effects.spec import identity

    out = {}
    for spec in (getattr(model, "options", {}) or {}).get("effect_specs") or []:
        if isinstance(spec, dict) and isinstance(spec.get("name"), str):
            out[spec["name"]] = identity(spec)
    return out


def effect_keys(model: Model) -> list[str]:
    """Each effect of the model as its label plus its identity ('coulomb:joint=joint2@<sha>'): what makes
    two models' effects the same or not."""
    ids = effect_identities(model)
    return [f"{label}@{ids.get(str(name), '')}" for label, (name, _) in zip(effect_labels(model),
                                                                            effect_entries(model))]


def specs_for(names) -> list[dict]:
    """The spec (crane_io.physics.effects.spec, with its identity) of each distinct effect name, as the
    library holds it now (built-in, an effect-spec file's or a Python file's the user named)."""
    from crane_io.physics.effects import get_effect
    from crane_io.physics.effects.spec import spec_of, with_identity

    out, seen = [], set()
    for name in names:
        if name in seen:
            continue
        seen.add(name)
        out.append(with_identity(spec_of(get_effect(name))))
    return out


def refuse_effect_files(files) -> None:
    """A model that lists Python `effect_files` (saved by an older crane-train) is refused: loading a model
    never runs the code it names."""
    from .base import ModelFileError

    files = [str(f) for f in (files if isinstance(files, (list, tuple)) else [files])] if files else []
    if files:
        raise ModelFileError(f"the model names the Python effect files {', '.join(files)}, which loading a "
                             f"model never runs; fit it again (with --effect-file) so that it records its "
                             f"effects as data")
