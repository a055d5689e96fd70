"""`crane-train diagnose --discover --write-effect-file PATH.py`: the discovered terms as an effect file
in the format `--effect-file` loads (crane_io.physics.effects.load_effect_file): one Effect subclass per joint
with a significant discovery, one named linear parameter per term (its estimate as the default, the
jackknife uncertainty in its description), the expression and how it was found in the docstring. The
terms' code is the very code the discovery evaluated (train/diagnosis/discovery_basis.py), so a refit with the
file fits the same columns."""

from __future__ import annotations

import re
import textwrap
from pathlib import Path
from typing import TYPE_CHECKING

from crane_io.errors import ConfigError

from .discovery import Discovery, JointDiscovery

if TYPE_CHECKING:
    from collections.abc import Sequence


def effect_name(joint: str) -> str:
    return f"discovered-{joint}"


def _class_name(joint: str) -> str:
    return "Discovered" + "".join(p.capitalize() for p in re.split(r"[^0-9a-zA-Z]+", joint) if p)


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


def _effect_class(d: JointDiscovery) -> str:
    params = _parameters(d)
    terms = "\n".join(f"    {p}: {t.term} = {t.coefficient:.4g} ± {t.stderr:.2g} {t.unit}"
                      for p, t in zip(params, d.terms))
    extra = (f"\nDiscovered on top of the library's {d.on_top_of} on {d.joint}: fit with both "
             f"(--effect {d.on_top_of}:joint={d.joint}).\n" if d.on_top_of else "")
    blocks = ", ".join(f"{100 * r:.0f}%" for r in d.fold_reductions)
    doc = (f"{d.joint}: tau += {d.expression} (N m).\n\n"
           f"Terms (parameter: term = estimate ± delete-a-block jackknife standard error):\n{terms}\n"
           f"{extra}\nHeld-out error removed: {100 * d.error_reduction:.0f}% (per block: {blocks}); "
           "selected and fitted without the block it is scored on.\n")
    plist = "\n".join(
        f"        Param({p!r}, {t.unit!r}, {t.coefficient:.6g}, "
        f"{f'coefficient of {t.term} (discovered: {t.coefficient:.3g} ± {t.stderr:.2g})'!r}),"
        for p, t in zip(params, d.terms))
    cols = "\n".join(f"            {t.code},  # {t.term}" for t in d.terms)
    return (f"class {_class_name(d.joint)}(Effect):\n"
            f'    """{textwrap.indent(doc, "    ").strip()}\n    """\n\n'
            f"    name = {effect_name(d.joint)!r}\n"
            f"    title = {f'discovered term of {d.joint}'!r}\n"
            f"    description = {d.expression + ' (N m), found by crane-train diagnose --discover.'!r}\n"
            f"    signature = {f'the residual of {{joint}} follows {d.expression}'!r}\n"
            f"    params = (\n{plist}\n    )\n\n"
            f"    def _columns(self, q, dq, ddq, joint, shape):\n"
            f"        _check(q)\n"
            f"        return joint_columns(\n            len(q), q.shape[1], joint,\n{cols}\n        )\n")


def effect_source(discovery: Discovery, model_dir: Path | str = "MODEL_DIR",
                  sessions: Sequence[Path | str] = ()) -> str:
    """The Python source of the effect file for every significant discovery (ConfigError if none)."""
    found = [d for d in discovery.discovered if d.significant and d.terms]
    if not found:
        raise ConfigError("no significant discovery: there is no term to write as an effect")
    joints = tuple(discovery.joints)
    adds = " ".join(f"--effect {effect_name(d.joint)}:joint={d.joint}"
                    + (f" --effect {d.on_top_of}:joint={d.joint}" if d.on_top_of else "") for d in found)
    flag = "--discover-all" if discovery.settings.get("every_joint") else "--discover"
    head = (f'"""Terms discovered by `crane-train diagnose {model_dir} {" ".join(map(str, sessions))} '
            f'{flag}`.\n\n'
            f"Add them to a model (with the effects it already has):\n\n"
            f"    crane-train fit SESSION... --model rigid-body --effect-file THIS_FILE.py {adds} \\\n"
            "        -o NEW_DIR\n\n"
            "then `crane-train compare OLD_DIR NEW_DIR` shows the error fall. One effect per joint; each\n"
            "term is a named parameter (the discovery's estimate is its default). The terms read the joints\n"
            f"by their column in {joints}; edit freely (drop a term, rename a parameter).\n"
            '"""\n\n')
    body = ("import numpy as np  # noqa: F401  (used by the terms)\n\n"
            "from crane_io.physics.effects import Effect, Param, get_effect  # noqa: F401\n"
            "from crane_io.physics.effects.base import joint_columns\n"
            "from crane_io.errors import ConfigError\n\n"
            f"JOINTS = {joints!r}  # the column order the terms' indices refer to\n\n\n"
            "def _check(q):\n"
            "    if q.shape[1] != len(JOINTS):\n"
            "        raise ConfigError(f\"these discovered terms read {len(JOINTS)} joints {JOINTS}, \"\n"
            "                          f\"the model has {q.shape[1]}\")\n")
    classes = "\n\n".join(_effect_class(d) for d in found)
    return head + body + "\n\n" + classes


def write_effect_file(path: Path | str, discovery: Discovery, model_dir: Path | str = "MODEL_DIR",
                      sessions: Sequence[Path | str] = ()) -> tuple[Path, list]:
    """Write the effect file; returns (path, [(effect name, joint, library effect it sits on or None)])."""
    path = Path(path)
    if path.suffix != ".py":
        raise ConfigError(f"the effect file must end in .py, got {path}")
    from crane_io.output_files import write_text_atomic  # whole or not at all; a full disk: one sentence

    write_text_atomic(path, effect_source(discovery, model_dir, sessions), "effect file")
    return path, [(effect_name(d.joint), d.joint, d.on_top_of) for d in discovery.discovered
                  if d.significant and d.terms]
