"""`crane-train identify SESSION... -o MODEL_DIR`: the arm's rigid-body and friction parameters by
weighted least squares, with relative standard errors, the condition number, strongly correlated pairs,
the physically consistent projection and a verdict against thresholds (train.identification). Writes a
rigid-body model folder with identification.json; the exit status is 1 when the verdict fails (after
writing it), so scripts can tell."""

from __future__ import annotations

import json
import sys

import click

from crane_io.cli_support import SEED, Number, cli_errors

from ..identification.identify import DEFAULT_EFFECTS, MIN_SPEED, ZERO_PHASE_CUTOFF
from ..identification.verdict import Thresholds
from .options import arm_option, force_option

DEFAULTS = Thresholds()


@click.command()
@click.argument("sessions", nargs=-1, required=True, type=click.Path(dir_okay=False))
@click.option("-o", "--output", "out_dir", required=True, type=click.Path(),
              help="Model directory to write (a rigid-body model with identification.json), whole or not at "
                   "all; an existing one only with --force.")
@click.option("--effect", "effects", multiple=True, metavar="NAME[:joint=JOINT,shape=VALUE]",
              help=f"A friction (or other) effect identified beside the rigid body, on every joint or "
                   f"(joint=) one; repeatable [{', '.join(DEFAULT_EFFECTS)}].")
@click.option("--joints", default=None,
              help="Comma-separated joints to identify, or 'all' [joint1,joint2,joint4].")
@arm_option
@click.option("--seed", default=0, show_default=True, type=SEED, help="Seed of the splits.")
@click.option("--scale-to-data", is_flag=True,
              help="Shrink the split sizes to fit short data instead of stopping with an error.")
@click.option("--config", "config_path", default=None, type=click.Path(dir_okay=False),
              help="TOML overriding train/config/train.toml.")
@click.option("--max-condition", type=Number(float, 1), default=DEFAULTS.max_condition, show_default=True,
              help="Verdict: the largest condition number of the weighted, column-scaled regressor.")
@click.option("--max-rel-stderr", type=Number(float, 0), default=DEFAULTS.max_rel_stderr, show_default=True,
              help="Verdict: the largest relative standard error of a parameter that matters.")
@click.option("--negligible", type=Number(float, 0, 1), default=DEFAULTS.negligible, show_default=True,
              help="A parameter whose torque is below this share of the torque RMS does not matter.")
@click.option("--max-heldout-ratio", type=Number(float, 1), default=DEFAULTS.max_heldout_ratio,
              show_default=True, help="Verdict: the largest held-out MSE over the fit's own, per joint.")
@click.option("--zero-phase/--causal", default=True, show_default=True,
              help="Filter the sessions forward and backward (no lag), or with the paper's causal chain "
                   "(then the model folder runs in the control loop too; arm_model.toml runs either way).")
@click.option("--min-speed", type=Number(float, 0), default=MIN_SPEED, show_default=True,
              help="rad/s: each joint's torque is fitted where it moves at least this fast (slower samples "
                   "hold the friction of reversals and stops, which the filters spread); 0 uses every "
                   "moving sample.")
@click.option("--cutoff", type=Number(float, 0, low_open=True, unit="rad/s"), default=None,
              help=f"rad/s: the filters' cutoff [{ZERO_PHASE_CUTOFF:g} with --zero-phase (a low cutoff "
                   f"biases the inertias: the rigid body is nonlinear in the motion it attenuates), the "
                   f"settings' with --causal].")
@click.option("--json", "as_json", is_flag=True, help="Print identification.json instead of the table.")
@force_option("the model directory")
@cli_errors
def identify(sessions, out_dir, effects, joints, arm, seed, scale_to_data, config_path, max_condition,
             max_rel_stderr, negligible, max_heldout_ratio, zero_phase, min_speed, cutoff, as_json, force):
    """Identify the arm's inertial and friction parameters from SESSION(s): excitation or bilateral data."""
    from ..api import check_model_output
    from ..identification.identify import identify as run_identification
    from ..identification.identify import text

    check_model_output(out_dir, [*sessions, config_path], force)
    thresholds = Thresholds(max_condition, max_rel_stderr, negligible, max_heldout_ratio)
    result = run_identification(list(sessions), effects=effects or DEFAULT_EFFECTS, seed=seed,
                                scale_to_data=scale_to_data, config=config_path, arm=arm, joints=joints,
                                thresholds=thresholds, zero_phase=zero_phase,
                                min_speed=min_speed, cutoff=cutoff)
    result.save(out_dir, force=force)
    if as_json:
        click.echo(json.dumps(result.to_json(), indent=2))
    else:
        click.echo(text(result))
        click.echo(f"model written to {out_dir}")
    if not result.passed:
        sys.exit(1)
