"""`crane-train export MODEL_DIR...`: write the control loop's numeric export `loop_model.npz` into model
directories saved before crane-train wrote it with every model (`crane-train fit` does it now). Only
that file is written; the model itself (model.json, weights) is read, never changed. The written export
is loaded back as the loop would (crane_io.physics.loop_model.LoopModel) and any reason the loop would still
refuse the model (e.g. zero-phase preprocessing) is reported."""

from __future__ import annotations

from pathlib import Path

import click

from crane_io.cli_support import cli_errors, command_flags, with_flags
from crane_io.errors import CraneError


def export_model(directory, force: bool = False, effect_files=()) -> dict:
    """Write `directory`/loop_model.npz for the saved model there (an existing one replaced only with
    `force`); {path, sha256, method, joints, usable}. `effect_files`: Python files defining user effects
    the model needs (run only with the recorded SHA-256); loading the model runs no code by itself."""
    from crane_io.output_files import check_output
    from crane_io.physics.effects.spec import offer_effect_files
    from crane_io.physics.loop_model import EXPORT_FILE, LoopModel, LoopModelError

    from ..models.base import ModelFileError
    from ..models.loop_export import write_loop_export
    from ..models.registry import load_model

    directory = Path(directory)
    if not directory.is_dir():
        raise ModelFileError(f"model directory {directory} does not exist")
    offer_effect_files(effect_files)
    model = load_model(directory)
    # the model's own files are its inputs; only loop_model.npz is written
    inputs = [p for p in directory.rglob("*") if p.name != EXPORT_FILE]
    check_output(directory / EXPORT_FILE, inputs=inputs, force=force, what="loop export")
    path, sha = write_loop_export(model, directory)
    try:
        LoopModel.load(directory)
        refusal = None
    except LoopModelError as exc:
        refusal = str(exc)
    return {"path": str(path), "sha256": sha, "method": model.method, "joints": list(model.joint_names),
            "refusal": refusal}


@click.command()
@click.argument("model_dirs", nargs=-1, required=True, type=click.Path(file_okay=False))
@click.option("--force", is_flag=True,
              help="Replace a directory's existing loop_model.npz (without it such a directory is refused).")
@click.option("--effect-file", "effect_files", multiple=True, type=click.Path(dir_okay=False),
              help="A Python file defining a user effect a model needs (repeatable); it runs only if its "
                   "SHA-256 is the one the model records.")
@cli_errors
def export(model_dirs, force, effect_files):
    """Write loop_model.npz (the control loop's copy of the weights) into each saved model directory."""
    failed = 0
    for d in model_dirs:
        try:
            doc = export_model(d, force, effect_files)
        except CraneError as exc:
            click.echo(f"Error: {with_flags(str(exc), command_flags(click.get_current_context()))}",
                       err=True)
            failed = max(failed, exc.exit_code)  # a full disk (3) outranks a refused directory (2)
            continue
        click.echo(f"{doc['path']}: {doc['method']} on {', '.join(doc['joints'])}, "
                   f"sha256 {doc['sha256'][:16]}")
        if doc["refusal"]:
            click.echo(f"  note: the control loop will still refuse it: {doc['refusal']}", err=True)
    if failed:
        raise SystemExit(failed)
