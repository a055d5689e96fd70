"""`crane-train report MODEL_DIR SESSION... -o REPORT.html`: one self-contained page showing where the
model fails, evaluated on the held-out part of the sessions (train.evaluation.report,
train.evaluation.heldout)."""

from __future__ import annotations

import click

from crane_io.cli_support import SEED, cli_errors

from .options import force_option


@click.command()
@click.argument("model_dir", type=click.Path(file_okay=False))
@click.argument("sessions", nargs=-1, required=True, type=click.Path(dir_okay=False))
@click.option("-o", "--output", required=True, type=click.Path(dir_okay=False),
              help="The HTML file to write (never one of the inputs; made whole or not at all).")
@click.option("--diagnosis/--no-diagnosis", default=True, show_default=True,
              help="Add the diagnosis sentences (which effect is missing) to the page.")
@click.option("--discover", is_flag=True,
              help="Add the terms discovery finds in the residual (crane-train diagnose --discover), each "
                   "plotted against it.")
@click.option("--seed", type=SEED, default=None,
              help="Split seed (default: the one the model was trained with).")
@click.option("--effect-file", "effect_files", multiple=True, type=click.Path(dir_okay=False),
              help="A Python file defining a user effect the model needs (repeatable); it runs only if its "
                   "SHA-256 is the one the model records.")
@force_option("the HTML file")
@cli_errors
def report(model_dir, sessions, output, diagnosis, discover, seed, effect_files, force):
    """Write an HTML report of MODEL_DIR's error on the held-out part of SESSION(s)."""
    from crane_io.output_files import check_output

    from ..api import make_report

    # checked before the line below (make_report checks it again before its work)
    check_output(output, inputs=[model_dir, *sessions], force=force, what="report", make_folders=True)
    click.echo(f"Evaluating {model_dir} on the held-out part of {', '.join(sessions)} ...", err=True)
    path = make_report(model_dir, list(sessions), output, seed=seed, diagnosis=diagnosis, discover=discover,
                       force=force, effect_files=effect_files)
    click.echo(f"Wrote {path} ({path.stat().st_size / 1e3:.0f} kB); open it in a browser (works offline).")
