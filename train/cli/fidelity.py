"""`crane-train fidelity SESSION [--truth-trace T.h5] [--json] [--settle S] [--contact-guard S]`: how much
false force the operator felt in free motion, how well contact was estimated, how well the arms tracked
(train.evaluation.fidelity)."""

from __future__ import annotations

import json

import click

from crane_io.cli_support import Number, cli_errors


@click.command()
@click.argument("session", type=click.Path(dir_okay=False))
@click.option("--truth-trace", type=click.Path(dir_okay=False), default=None,
              help="The simulated plants' true external torques (crane-collect run --sim --truth-trace); "
                   "without it every sample counts as free motion.")
@click.option("--settle", "settle_s", type=Number(float, 0, unit="s"), default=1.0, show_default=True,
              help="Seconds dropped at the start (the controllers settling).")
@click.option("--contact-guard", "guard_s", type=Number(float, 0, unit="s"), default=0.3, show_default=True,
              help="Seconds around every contact sample that do not count as free motion.")
@click.option("--json", "as_json", is_flag=True, help="Print the metrics as JSON.")
@cli_errors
def fidelity(session, truth_trace, settle_s, guard_s, as_json):
    """Measure the force channel of a bilateral SESSION: false force in free motion, contact-estimate
    error, leader + follower force sum and tracking, per bilateral joint."""
    from ..evaluation.fidelity import fidelity_text, measure_fidelity

    result = measure_fidelity(session, truth_trace, settle_s=settle_s, contact_guard_s=guard_s)
    if as_json:
        click.echo(json.dumps(result.to_json(), indent=2))
        return
    click.echo(fidelity_text(result))
