"""`crane-train effects`: the physical-effects library — name, parameters with units, what each effect
models and the residual signature it leaves when a model lacks it. Effects from a user's Python file
or an effect-spec file (`--effect-file`) are listed too."""

from __future__ import annotations

import json

import click

from crane_io.cli_support import cli_errors


def effect_rows(effect_files=()) -> list[dict]:
    """One dict per library effect (after loading the given effect files)."""
    from crane_io.physics.effects import list_effects, load_effect_file

    for path in effect_files:
        load_effect_file(path)
    rows = []
    for e in list_effects():
        e = e() if isinstance(e, type) else e
        params = [{"name": p.name, "unit": getattr(p, "unit", ""), "default": getattr(p, "default", None),
                   "linear": bool(getattr(p, "linear", True)), "description": getattr(p, "description", ""),
                   "model": bool(getattr(p, "model", True))}
                  for p in getattr(e, "params", ())]
        signature = str(getattr(e, "signature", "") or "")
        try:
            signature = signature.format(joint="the joint")
        except (KeyError, IndexError, ValueError):
            pass
        rows.append({"name": e.name, "title": getattr(e, "title", e.name),
                     "scope": getattr(e, "scope", "joint"),
                     "description": getattr(e, "description", ""), "signature": signature,
                     "parameters": params,
                     "shape_grid": {k: list(v) for k, v in (getattr(e, "shape_grid", None) or {}).items()}})
    return rows


@click.command()
@click.option("--effect-file", "effect_files", multiple=True, type=click.Path(dir_okay=False),
              help="An effect-spec file (.json, read as data) or a Python file defining Effect subclasses "
                   "(.py, run); its effects are listed too (repeatable).")
@click.option("--json", "as_json", is_flag=True, help="Print the list as JSON.")
@cli_errors
def effects(effect_files, as_json):
    """List the physical effects a model can add (--effect NAME[:joint=JOINT]) and the diagnosis tries."""
    rows = effect_rows(effect_files)
    if as_json:
        click.echo(json.dumps({"effects": rows}, indent=2, default=str))
        return
    for r in rows:
        scope = "whole arm" if r["scope"] == "arm" else "one joint"
        click.echo(f"{r['name']}  —  {r['title']} ({scope})")
        if r["description"]:
            click.echo(f"    what it models: {r['description']}")
        if r["signature"]:
            click.echo(f"    residual signature when missing: {r['signature']}")
        for p in r["parameters"]:
            kind = ("simulated plant only" if not p["model"] else
                    "fitted linearly" if p["linear"] else "chosen from a grid")
            unit = f" [{p['unit']}]" if p["unit"] else ""
            desc = f": {p['description']}" if p["description"] else ""
            click.echo(f"    - {p['name']}{unit} ({kind}){desc}")
        click.echo("")
    click.echo("Add one to a physics model with: crane-train fit SESSION --model rigid-body "
               "--effect NAME[:joint=JOINT] -o MODEL_DIR")
