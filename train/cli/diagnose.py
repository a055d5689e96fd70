"""`crane-train diagnose MODEL_DIR SESSION...`: which physical effect is the model missing?

The sessions are preprocessed as the model's training did; the model's error is explained, effect by
effect, with cross-validation over contiguous time blocks (train.diagnosis.diagnose): a physics model is
refitted per fold on all samples, any other model is judged only on the samples it never trained on
(train.evaluation.heldout.diagnosis_data).

With --discover (train/diagnosis/discovery.py), each joint whose residual stays significant after the
library's best candidate (every joint with --discover-all) gets a sparse regression of that residual on a
basis of physical terms; --write-effect-file writes what is significant as an effect-spec file (JSON:
effects as data, nothing in it runs) for `fit --effect-file`.
"""

from __future__ import annotations

import json

import click

from crane_io.cli_support import Number, cli_errors, interval_format

from ..diagnosis.defaults import DEFAULT_FOLDS, DEFAULT_MIN_REDUCTION
from .options import force_option


def _params_text(params: dict) -> str:
    return ", ".join(_param_text(n, p) for n, p in params.items())


def _param_text(name: str, p: dict) -> str:
    ci = p.get("ci95")
    f = interval_format(p["value"], (ci[1] - ci[0]) / 2) if ci else ".3g"
    text = f"{name} = {p['value']:{f}} ± {p['std']:.2g} {p['unit']}".rstrip()
    return text + (f" (95 %: {ci[0]:{f}} to {ci[1]:{f}})" if ci else "")


@click.command()
@click.argument("model_dir", type=click.Path(file_okay=False))
@click.argument("sessions", nargs=-1, required=True, type=click.Path(dir_okay=False))
@click.option("--json", "as_json", is_flag=True, help="Print the diagnosis as JSON (candidates, summary).")
@click.option("--json-out", "json_out", type=click.Path(dir_okay=False), default=None,
              help="Also write the JSON document (the one --json prints) to this file, and print the text.")
@click.option("--folds", default=DEFAULT_FOLDS, show_default=True, type=click.IntRange(2, 50),
              help="Cross-validation folds (contiguous time blocks).")
@click.option("--min-reduction", default=DEFAULT_MIN_REDUCTION, show_default=True,
              type=Number(float, 0, 1),
              help="Smallest fraction of the held-out error a candidate must remove to count as significant.")
@click.option("--top", default=3, show_default=True, type=click.IntRange(1, 100),
              help="Candidates shown per joint in the text output.")
@click.option("--effect-file", "effect_files", multiple=True, type=click.Path(dir_okay=False),
              help="An effect-spec file (.json) or a Python file (.py, run) defining extra effects to try as "
                   "candidates (repeatable); also the Python file of a user effect the model needs (run "
                   "only if its SHA-256 is the one the model records).")
@click.option("--discover", is_flag=True,
              help="Also propose the missing term: sparse regression of the residual on a basis of physical "
                   "terms, for each joint whose residual stays significant after the library's best.")
@click.option("--discover-all", is_flag=True,
              help="Discovery on every joint, from the model alone (implies --discover).")
@click.option("--write-effect-file", "effect_out", type=click.Path(dir_okay=False), default=None,
              help="Write the significant discovered terms as an effect-spec file PATH.json (data) for "
                   "`fit --effect-file` (implies --discover).")
@force_option("the --json-out and --write-effect-file files")
@cli_errors
def diagnose(model_dir, sessions, as_json, json_out, folds, min_reduction, top, effect_files, discover,
             discover_all, effect_out, force):
    """Rank the library's effects by how much of MODEL_DIR's error on SESSION(s) each one removes."""
    from crane_io.output_files import write_text_atomic

    _check_outputs(json_out, effect_out, [model_dir, *sessions, *effect_files], force)

    from ..api import diagnosis_inputs
    from ..diagnosis.diagnose import diagnose as run_diagnosis
    from ..progress import show_progress

    model, ds, judged = diagnosis_inputs(model_dir, list(sessions), effect_files)  # the model's arm
    result = run_diagnosis(model, ds, folds=folds, min_reduction=min_reduction,
                           progress=show_progress(not as_json))
    result.settings["judged_on"] = judged
    found, written = None, None
    if discover or discover_all or effect_out:
        found, written = _discover(model, ds, result, discover_all, folds, min_reduction, effect_out,
                                   model_dir, sessions, show_progress(not as_json))
    if as_json or json_out is not None:
        text = json.dumps(_json_doc(result, model_dir, sessions, found, written), indent=2)
        if json_out is not None:
            write_text_atomic(json_out, text + "\n", "JSON file")
        if as_json:
            click.echo(text)
            return
    _echo_ranking(result, model, model_dir, sessions, judged, folds, top)
    if found is not None:
        _echo_discovery(found, written, effect_out)


def _check_outputs(json_out, effect_out, inputs, force) -> None:
    """The JSON and effect-spec outputs are usable paths, neither an input nor the other."""
    from crane_io.output_files import check_output

    if effect_out:
        from ..diagnosis.effect_writer import check_suffix

        check_suffix(effect_out)
    for out, what, other in ((json_out, "JSON file", effect_out), (effect_out, "effect-spec file", json_out)):
        if out is not None:
            check_output(out, inputs=inputs, force=force, what=what, others=[other], make_folders=True)


def _discover(model, ds, result, discover_all, folds, min_reduction, effect_out, model_dir, sessions,
              progress):
    """(discovery, (path, added effects) of the written effect-spec file or None)."""
    from ..diagnosis.discovery import discover as run_discovery

    found = run_discovery(model, ds, result, every_joint=discover_all, folds=folds,
                          min_reduction=min_reduction, progress=progress)
    written = None
    if effect_out and any(d.significant for d in found.discovered):
        from ..diagnosis.effect_writer import write_effect_file

        written = write_effect_file(effect_out, found, model_dir, sessions)
    return found, written


def _json_doc(result, model_dir, sessions, found, written) -> dict:
    doc = result.to_json()
    doc.update(model=str(model_dir), sessions=list(sessions))
    if found is not None:
        disc = found.to_json()
        doc.update(discovered=disc["discovered"], discovery={"summary": disc["summary"],
                                                             "settings": disc["settings"]},
                   effect_file=None if written is None else str(written[0]))
    return doc


def _echo_ranking(result, model, model_dir, sessions, judged, folds, top) -> None:
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


def _echo_discovery(found, written, effect_out) -> None:
    click.echo("")
    click.echo("Discovery: sparse regression of each joint's residual on a basis of physical terms "
               "(held-out error: selected and fitted without the block it is scored on).")
    for d in found.discovered:
        click.echo("")
        click.echo(d.sentence)
        for t in d.terms:
            click.echo(f"  {t.coefficient:>10.4g} ± {t.stderr:<8.2g} {t.unit:<16} {t.term}")
    click.echo("")
    if not any(d.significant for d in found.discovered):
        tail = ": no effect file written." if effect_out else "."
        click.echo("No significant discovery on any joint" + tail)
    elif written is not None:
        path, added = written
        flags = " ".join(f"--effect {name}:joint={joint}" + (f" --effect {lib}:joint={joint}" if lib else "")
                         for name, joint, lib in added)
        click.echo(f"Effect-spec file written to {path}. Refit with: crane-train fit SESSION... --model "
                   f"rigid-body --effect-file {path} {flags} (plus the model's own effects) -o NEW_MODEL_DIR")
