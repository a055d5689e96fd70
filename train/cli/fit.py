"""`crane-train fit SESSION... --model METHOD -o MODEL_DIR [--arm leader|follower]`: train one model the
paper's way, print its test metrics and save it (with its preprocessing and normalisation; the arm it was
fitted on is the preprocessing setting `arm`, model.json "preprocessing" -> "arm")."""

from __future__ import annotations

import click

from crane_io.cli_support import SEED, Number, cli_errors, interval_format

from ..models.method_names import METHOD_NAMES
from ..progress import show_progress
from ..settings import parse_effect
from .options import arm_option, data_options, force_option, hand_on_hint


def _fit_and_save(sessions, method: str, out_dir, train_size: int | None = None, seed: int = 0,
              effects=(), effect_files=(), joints=None, alpha=None, zero_phase=False,
              scale_to_data=False, epochs: int | None = None, progress: bool = True,
              config_path=None, arm: str | None = None, eval_set: str | None = None,
              force: bool = False, start_from=None, start_weight: float = 100.0):
    """train.api.fit on `arm`'s data of the sessions, saved to out_dir (with fit_metrics.json); returns the
    FitResult (its metrics document and model). The output is checked before any work; a session whose
    arm the operator's hand moved is refused (train.data.session.HandOnArmError) before anything is
    written."""
    from tqdm import tqdm

    from ..api import check_model_output, fit

    check_model_output(out_dir, [*sessions, *effect_files, config_path, start_from], force)
    bar = None
    if progress and (method.startswith("mlp-") or method == "hybrid"):
        bar = tqdm(desc=method, unit="epoch", leave=False)

    def step(done, total):
        bar.total = total
        bar.update(1)

    result = fit(list(sessions), method, effects=effects, effect_files=effect_files, train_size=train_size,
                 seed=seed, epochs=epochs, scale_to_data=scale_to_data, config=config_path, arm=arm,
                 joints=joints, alpha=alpha, zero_phase=zero_phase, progress=step if bar else None,
                 eval_set=eval_set, start_from=start_from, start_weight=start_weight)
    if bar is not None:
        bar.close()
    result.save(out_dir, force=force)
    return result


def effect_lines(model) -> list[str]:
    """The fitted effect parameters of a rigid-body model (or a hybrid's physics part) with their standard
    errors and 95 % intervals, and how those were computed; none for other models."""
    from ..models.rigid_body import REPORTED_OWN

    rigid = getattr(model, "rigid", model)
    if getattr(rigid, "method", None) != "rigid-body" or not rigid.is_fitted:
        return []
    rows = rigid.parameters_table()[rigid.n_base:]
    if not rows:
        return []
    info = rigid.fit_info
    factor = float(info.get("ci95_factor", 1.96))
    lines = [f"effect parameters (± standard error: {info.get('stderr_method', 'least-squares covariance')}; "
             f"95 % interval = value ± {factor:.3g} x standard error)"]
    source = info.get("reported_from")
    if source and source != REPORTED_OWN:
        lines.append(f"  values from {source}")
    for r in rows:
        half = factor * r["stderr"]
        f = interval_format(r["value"], half, least=4)
        loop = f"  loop {r['loop_value']:{f}}" if source and source != REPORTED_OWN else ""
        lines.append(f"  {r['name']:<34}{format(r['value'], f):>11} ± {r['stderr']:<9.2g}"
                     f"[{r['value'] - half:{f}}, {r['value'] + half:{f}}]{loop}")
    return lines


@click.command()
@click.argument("sessions", nargs=-1, required=True, type=click.Path(dir_okay=False))
@click.option("--model", "method", required=True, type=click.Choice(list(METHOD_NAMES)),
              help="Method to train.")
@click.option("-o", "--output", "out_dir", required=True, type=click.Path(),
              help="Model directory to write (made if missing). It is written whole or not at all; an "
                   "existing one is replaced whole, only with --force and only if it holds a model "
                   "(or nothing).")
@click.option("--train-size", type=Number(int, 1), default=None,
              help="Training samples drawn from the pool [all 6000].")
@click.option("--seed", default=0, show_default=True, type=SEED, help="Seed of splits, draws and weights.")
@click.option("--effect", "effects", multiple=True, metavar="NAME[:joint=JOINT,shape=VALUE]",
              help="Add a physical effect's columns (rigid-body, hybrid); repeatable. Without joint= a "
                   "joint effect goes on every learning joint.")
@click.option("--effect-file", "effect_files", multiple=True, type=click.Path(dir_okay=False, exists=True),
              help="A file defining extra effects: an effect-spec file (.json, data, e.g. from diagnose "
                   "--write-effect-file) or a Python file (.py, run; the model records its SHA-256).")
@click.option("--epochs", type=Number(int, 1), default=None,
              help="Epochs of the network (mlp-mse, mlp-masked, hybrid) [100].")
@click.option("--start-from", "start_from", type=click.Path(dir_okay=False, exists=True), default=None,
              metavar="ARM_MODEL_TOML",
              help="rigid-body: start the fit from an identified arm model (arm_model.toml of `crane-train "
                   "identify`) and regularise it towards the model's parameters; the model records it.")
@click.option("--start-weight", type=Number(float, 0.0, low_open=True), default=100.0, show_default=True,
              help="How many torque equations the --start-from parameters count as.")
@arm_option
@data_options
@click.option("--no-progress", is_flag=True,
              help="No progress bar (there is none anyway when stderr is not a terminal).")
@force_option("the model directory")
@cli_errors
def fit(sessions, method, out_dir, train_size, seed, effects, effect_files, epochs, arm, config_path, joints,
        alpha, zero_phase, scale_to_data, eval_set, no_progress, force, start_from, start_weight):
    """Train one model on session files (the follower's data, or the leader's with --arm leader) and
    save it."""
    from ..data.session import HandOnArmError

    try:
        result = _fit_and_save(sessions, method, out_dir, train_size, seed,
                               [parse_effect(e) for e in effects], effect_files, joints, alpha, zero_phase,
                               scale_to_data, epochs, show_progress(not no_progress), config_path, arm,
                               eval_set, force, start_from, start_weight)
    except HandOnArmError as exc:
        raise HandOnArmError(hand_on_hint(exc), exc.path, exc.arm) from None
    doc = result.metrics
    click.echo(f"{method} on the {doc['arm']}: trained on {doc['train_samples']} samples "
               f"({doc['train_samples_all_moving']} with every joint moving); "
               f"test on {doc['test_samples']} samples"
               + (" (each joint scored where it moves)" if doc.get("eval_set") == "per-joint" else ""))
    click.echo(f"{'joint':<10}{'MSE (N m)^2':>14}{'RMSE N m':>12}{'NMSE':>10}")
    for j in doc["joints"]:
        t = doc["test"]
        click.echo(f"{j:<10}{t['mse'][j]:>14.4g}{t['rmse'][j]:>12.4g}{t['nmse'][j]:>10.3g}")
    for line in effect_lines(result.model):
        click.echo(line)
    start = getattr(result.model, "fit_info", {}).get("start")
    if start:
        click.echo(f"started from the identified arm model {start['arm_model']} (weighing as much as "
                   f"{start['weight']:g} torque equations)")
    click.echo(f"model written to {out_dir}")
