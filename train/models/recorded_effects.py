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
