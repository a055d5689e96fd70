"""`crane-train fit SESSION... --model METHOD -o MODEL_DIR [--arm leader|follower]`: train one model the
paper's way, print its test metrics and save it (with its preprocessing and normalisation; the arm it was
fitted on is the preprocessing setting `arm`, model.json "preprocessing" -> "arm")."""

from __future__ import annotations

import json
from pathlib import Path

import click

from crane_io.errors import ConfigError, cli_errors

from .cli_options import (
    arm_option,
    data_options,
    hand_on_hint,
    load_config,
    load_dataset,
    parse_effect,
    writable_output,
)
from .method_names import METHOD_NAMES
from .progress import show_progress


def fit_model(sessions, method: str, out_dir, train_size: int | None = None, seed: int = 0,
              effects=(), effect_files=(), joints=None, alpha=None, zero_phase=False,
              scale_to_data=False, epochs: int | None = None, progress: bool = True,
              config_path=None, arm: str | None = None) -> dict:
    """Preprocess `arm`'s data (default: the configuration's, "follower"), split, fit on `train_size`
    samples of the pool (all of it by default), score on the test set, save to out_dir. Returns the
    metrics document (also written as fit_metrics.json). A session whose arm the operator's hand moved
    is refused (train.session.HandOnArmError) before anything is written."""
    import numpy as np  # the work's imports live here, so that `crane-train fit --help` stays light
    import torch
    from tqdm import tqdm

    from .metrics import metrics_table
    from .models.registry import make_model
    from .splits import make_splits

    writable_output(out_dir, "dir")
    cfg = load_config(config_path)
    ds = load_dataset(sessions, joints, alpha, zero_phase, cfg["preprocess"], arm)
    splits = make_splits(ds, cfg["splits"], seed=seed, scale_to_data=scale_to_data)
    pool = splits.pool
    if train_size is not None:
        if not 0 < train_size <= len(pool):
            raise ConfigError(f"--train-size must be between 1 and the pool size {len(pool)}, "
                              f"got {train_size}")
        rows = np.sort(np.random.default_rng([seed, train_size]).choice(len(pool), train_size, replace=False))
        pool = pool.subset(rows)
    options = {}
    if effects or effect_files:
        if method not in ("rigid-body", "hybrid"):
            raise ConfigError(f"--effect and --effect-file apply to rigid-body and hybrid, not {method}")
        options["effects"] = [list(e) for e in effects]
        # absolute, so that the saved model loads from any working directory
        options["effect_files"] = [str(Path(f).resolve()) for f in effect_files]
    has_net = method.startswith("mlp-") or method == "hybrid"  # hybrid: a masked net on the residual
    if has_net:
        m = cfg["mlp"]
        options.update(seed=seed, hidden=m.hidden, lr=m.lr, batch_size=m.batch_size,
                       epochs=epochs if epochs is not None else m.epochs)
    torch.set_num_threads(1)
    # the dead-zone velocity alpha sigma_j of the training data: where the loop's model treats a joint as
    # standing still (collect/model_reaction.py)
    dead_zone = [float(ds.meta["alpha"]) * float(s) for s in ds.meta["sigma"]]
    # the poses the model saw: the loop trusts it only there (collect/model_reaction.py)
    q_range = {"q_min": ds.q.min(axis=0).tolist(), "q_max": ds.q.max(axis=0).tolist()}
    model = make_model(method, ds.joint_names, preprocessing={**ds.meta["preprocessing"],
                                                              "dead_zone_rad_s": dead_zone,
                                                              "input_range": q_range}, **options)
    if has_net:
        bar = tqdm(total=options["epochs"], desc=method, unit="epoch", disable=not progress, leave=False)
        model.fit(pool, splits.val, progress=lambda done, total: bar.update(1))
        bar.close()
    else:
        model.fit(pool, splits.val)
    test = splits.test
    doc = {"method": method, "arm": ds.meta["arm"], "joints": list(ds.joint_names),
           "train_samples": len(pool),
           "train_samples_all_moving": int(pool.all_moving.sum()), "test_samples": len(test), "seed": seed,
           "test": metrics_table(test.tau, model.predict_dataset(test), ds.joint_names),
           "usable_fraction": ds.meta["usable_fraction"],
           "sources": [str(Path(f).resolve()) for f in ds.meta["sources"]]}  # found from any directory
    path = model.save(out_dir)
    (path / "fit_metrics.json").write_text(json.dumps(doc, indent=2))
    return doc


@click.command()
@click.argument("sessions", nargs=-1, required=True, type=click.Path(dir_okay=False))
@click.option("--model", "method", required=True, type=click.Choice(list(METHOD_NAMES)),
              help="Method to train.")
@click.option("-o", "--output", "out_dir", required=True, type=click.Path(file_okay=False),
              help="Model directory to write.")
@click.option("--train-size", type=int, default=None, help="Training samples drawn from the pool [all 6000].")
@click.option("--seed", default=0, show_default=True, type=int, help="Seed of splits, draws and weights.")
@click.option("--effect", "effects", multiple=True, metavar="NAME[:joint=JOINT,shape=VALUE]",
              help="Add a physical effect's columns (rigid-body, hybrid); repeatable. Without joint= a "
                   "joint effect goes on every learning joint.")
@click.option("--effect-file", "effect_files", multiple=True, type=click.Path(dir_okay=False, exists=True),
              help="Python file defining extra effects (see crane_io.effects).")
@click.option("--epochs", type=click.IntRange(min=1), default=None,
              help="Epochs of the network (mlp-mse, mlp-masked, hybrid) [100].")
@arm_option
@data_options
@click.option("--no-progress", is_flag=True,
              help="No progress bar (there is none anyway when stderr is not a terminal).")
@cli_errors
def fit(sessions, method, out_dir, train_size, seed, effects, effect_files, epochs, arm, config_path, joints,
        alpha, zero_phase, scale_to_data, no_progress):
    """Train one model on session files (the follower's data, or the leader's with --arm leader) and
    save it."""
    from .session import HandOnArmError

    try:
        doc = fit_model(sessions, method, out_dir, train_size, seed, [parse_effect(e) for e in effects],
                        effect_files, joints, alpha, zero_phase, scale_to_data, epochs,
                        show_progress(not no_progress), config_path, arm)
    except HandOnArmError as exc:
        raise HandOnArmError(hand_on_hint(exc), exc.path, exc.arm) from None
    click.echo(f"{method} on the {doc['arm']}: trained on {doc['train_samples']} samples "
               f"({doc['train_samples_all_moving']} with every joint moving); "
               f"test on {doc['test_samples']} samples")
    click.echo(f"{'joint':<10}{'MSE (N m)^2':>14}{'RMSE N m':>12}{'NMSE':>10}")
    for j in doc["joints"]:
        t = doc["test"]
        click.echo(f"{j:<10}{t['mse'][j]:>14.4g}{t['rmse'][j]:>12.4g}{t['nmse'][j]:>10.3g}")
    click.echo(f"model written to {out_dir}")
