"""`crane-train compare MODEL_DIR...`: the held-out error per joint of successive models side by side,
as a table and a plot, so the fall is visible (train.evaluation.compare)."""

from __future__ import annotations

import json

import click

from crane_io.cli_support import cli_errors

from .options import force_option


def _default_sessions(model_dir) -> list[str]:
    """The sessions the first model was trained on (what compare evaluates on without --session)."""
    from ..evaluation.heldout import fit_record

    record = fit_record(model_dir)
    sources = record.get("sources") if isinstance(record, dict) else None
    return [s for s in sources if isinstance(s, str)] if isinstance(sources, list) else []


@click.command()
@click.argument("model_dirs", nargs=-1, required=True, type=click.Path(file_okay=False))
@click.option("--session", "sessions", multiple=True, type=click.Path(dir_okay=False),
              help="Session file(s) to evaluate on (repeatable; default: the first model's training "
                   "sessions).")
@click.option("--json", "as_json", is_flag=True, help="Print the comparison as JSON.")
@click.option("-o", "--output", type=click.Path(dir_okay=False), default=None,
              help="Write the bar chart of the error per joint (one bar per model, log axis) to this PNG "
                   "(.pdf, .svg: that format).")
@click.option("--effect-file", "effect_files", multiple=True, type=click.Path(dir_okay=False),
              help="A Python file defining a user effect a model needs (repeatable); it runs only if its "
                   "SHA-256 is the one the model records. Loading a model never runs code by itself.")
@click.option("--metric", type=click.Choice(["mse", "rmse", "nmse"]), default="mse", show_default=True,
              help="The metric of the printed table and of the plot.")
@force_option("the plot")
@cli_errors
def compare(model_dirs, sessions, as_json, output, metric, effect_files, force):
    """Compare MODEL_DIR(s), in the given order, on the same held-out samples."""
    from crane_io.output_files import check_output

    from ..evaluation.compare import compare_models, notes_text, plot, table_text
    from ..evaluation.plots import plot_format
    from ..progress import show_progress

    if output:
        plot_format(output)
        check_output(output, inputs=[*model_dirs, *(sessions or _default_sessions(model_dirs[0]))],
                     force=force, what="plot", make_folders=True)
    from crane_io.physics.effects.spec import offer_effect_files

    offer_effect_files(effect_files)
    result = compare_models(list(model_dirs), list(sessions), progress=show_progress(not as_json))
    if output:
        plot(result, output, metric)
    if as_json:
        doc = result.to_json()
        if output:
            doc["plot"] = str(output)
        click.echo(json.dumps(doc, indent=2))
        return
    click.echo(table_text(result, metric))
    if notes_text(result):
        click.echo(notes_text(result))
    click.echo(f"Evaluated on: {result.evaluated_on}")
    if output:
        click.echo(f"Wrote the plot to {output}")
