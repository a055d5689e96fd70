"""`crane-train diagnose MODEL_DIR SESSION...`: which physical effect is the model missing?

The sessions are preprocessed as the model's training did; the model's error is explained, effect by
effect, with cross-validation over contiguous time blocks (train.diagnose): a physics model is refitted
per fold on all samples, any other model is judged only on the samples it never trained on
(train.heldout.diagnosis_data).
"""

from __future__ import annotations

import json

import click

from crane_io.errors import cli_errors

from .diagnosis_defaults import DEFAULT_FOLDS, DEFAULT_MIN_REDUCTION


def _params_text(params: dict) -> str:
    return ", ".join(f"{n} = {p['value']:.3g} ± {p['std']:.2g} {p['unit']}".rstrip()
                     for n, p in params.items())


@click.command()
@click.argument("model_dir", type=click.Path(file_okay=False))
@click.argument("sessions", nargs=-1, required=True, type=click.Path(dir_okay=False))
@click.option("--json", "as_json", is_flag=True, help="Print the diagnosis as JSON (candidates, summary).")
@click.option("--folds", default=DEFAULT_FOLDS, show_default=True, type=click.IntRange(2, 50),
              help="Cross-validation folds (contiguous time blocks).")
@click.option("--min-reduction", default=DEFAULT_MIN_REDUCTION, show_default=True,
              type=click.FloatRange(0, 1),
              help="Smallest fraction of the held-out error a candidate must remove to count as significant.")
@click.option("--top", default=3, show_default=True, type=click.IntRange(1, 100),
              help="Candidates shown per joint in the text output.")
@click.option("--effect-file", "effect_files", multiple=True, type=click.Path(dir_okay=False),
              help="A Python file defining extra effects to try as candidates (repeatable).")
@cli_errors
def diagnose(model_dir, sessions, as_json, folds, min_reduction, top, effect_files):
    """Rank the library's effects by how much of MODEL_DIR's error on SESSION(s) each one removes."""
    from crane_io.effects import load_effect_file

    from .diagnose import diagnose as run_diagnosis
    from .heldout import diagnosis_data, model_settings
    from .models.registry import load_model
    from .preprocess import read_preprocessed
    from .progress import show_progress

    for path in effect_files:
        load_effect_file(path)
    model = load_model(model_dir)
    pconf = model_settings(model, model_dir)[0]
    ds, judged = diagnosis_data(model, read_preprocessed(list(sessions), pconf), model_dir)  # model's arm
    result = run_diagnosis(model, ds, folds=folds, min_reduction=min_reduction,
                           progress=show_progress(not as_json))
    result.settings["judged_on"] = judged
    if as_json:
        doc = result.to_json()
        doc.update(model=str(model_dir), sessions=list(sessions))
        click.echo(json.dumps(doc, indent=2))
        return
    click.echo(f"Diagnosis of {model_dir} ({model.method}) on {judged} of {', '.join(sessions)}; "
               f"{folds}-fold cross-validation over contiguous time blocks of each joint's moving samples.")
    for joint in result.joints:
        click.echo("")
        click.echo(result.summary[joint])
        for c in result.for_joint(joint)[:top]:
            mark = "*" if c.significant else " "
            click.echo(f"  {mark}{c.rank}. {c.effect:<22} removes {100 * c.error_reduction:5.1f}% "
                       f"(better in {c.folds_improved}/{len(c.fold_reductions)} folds)  "
                       f"{_params_text(c.parameters)}")
    click.echo("")
    click.echo("* significant. Add an effect with: crane-train fit SESSION... --model rigid-body "
               "--effect NAME:joint=JOINT -o NEW_MODEL_DIR")
