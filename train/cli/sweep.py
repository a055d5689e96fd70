"""`crane-train sweep SESSION... -o DIR`: the paper's sample-size experiment, all methods, batched."""

from __future__ import annotations

from dataclasses import replace

import click

from crane_io.cli_support import SEED, Number, cli_errors
from crane_io.errors import ConfigError

from ..models.method_names import SWEEP_METHODS
from ..progress import progress_lines, show_progress
from ..settings import load_config, load_dataset
from .options import data_options, force_option, parse_sizes


@click.command()
@click.argument("sessions", nargs=-1, required=True, type=click.Path(dir_okay=False))
@click.option("-o", "--output", "out_dir", required=True, type=click.Path(),
              help="Directory for results.json, results.csv and the figures (made if missing). It may "
                   "exist and hold other files; each of these four is refused if it exists (unless "
                   "--force) and written whole or not at all.")
@click.option("--sizes", default="300:3000:300", show_default=True,
              help="Training-set sizes: START:STOP:STEP (STOP included) or a comma list.")
@click.option("--trials", default=10, show_default=True, type=Number(int, 1), help="Random draws per size.")
@click.option("--methods", default=",".join(SWEEP_METHODS), show_default=True,
              help="Comma-separated methods to compare.")
@click.option("--seed", default=0, show_default=True, type=SEED, help="Seed of splits, draws and weights.")
@click.option("--epochs", default=None, type=Number(int, 1), help="MLP training epochs [100].")
@click.option("--batch-size", default=None, type=Number(int, 1), help="MLP minibatch size [32].")
@data_options
@click.option("--no-progress", is_flag=True,
              help="No progress bars on a terminal, no progress lines (at most one every 10 s) in a log.")
@force_option("results.json, results.csv and the figures in the directory")
@cli_errors
def sweep(sessions, out_dir, sizes, trials, methods, seed, epochs, batch_size, config_path, joints, alpha,
          zero_phase, scale_to_data, eval_set, no_progress, force):
    """Test MSE against the number of training samples for each method (mean and 95 % CI)."""
    from crane_io.output_files import check_output

    from ..evaluation.sweep import (  # torch, scipy: for the work, not --help
        format_table,
        result_paths,
        run_sweep,
        write_results,
    )

    size_list = parse_sizes(sizes)
    method_list = [m.strip() for m in methods.split(",") if m.strip()]
    cfg = load_config(config_path)
    for path in result_paths(out_dir).values():  # before any work
        check_output(path, inputs=[*sessions, config_path], force=force, what="sweep result",
                     make_folders=True)
    settings = cfg["mlp"]
    if epochs is not None:
        settings = replace(settings, epochs=epochs)
    if batch_size is not None:
        settings = replace(settings, batch_size=batch_size)
    if settings.epochs < 1 or settings.batch_size < 1:
        raise ConfigError("the number of epochs and the batch size must be at least 1")
    if eval_set is not None:
        cfg["splits"] = replace(cfg["splits"], eval_set=eval_set)
    ds = load_dataset(sessions, joints, alpha, zero_phase, cfg["preprocess"])
    # a terminal gets bars; a log (stderr redirected) plain lines at a bounded rate
    progress = show_progress(not no_progress) or progress_lines(not no_progress, prefix="sweep: ") or False
    result = run_sweep(ds, size_list, trials, method_list, seed, progress=progress,
                       split_config=cfg["splits"], scale_to_data=scale_to_data, mlp_settings=settings,
                       notify=lambda sentence: click.echo(f"sweep: {sentence}", err=True))
    paths = write_results(result, out_dir)
    click.echo(format_table(result))
    click.echo(f"\nsweep took {result.meta['timing']['total_s']:.1f} s; wrote "
               + ", ".join(str(p) for p in paths.values()))
