"""`crane-train view SESSION.h5 [--view-save FILE.rrd] [--every N]`: replay a session in rerun
(train/replay.py; the optional extra `crane-x7[view]`)."""

from __future__ import annotations

import click

from crane_io.cli_support import cli_errors

from .options import force_option


@click.command("view")
@click.argument("session", type=click.Path(dir_okay=False))
@click.option("--view-save", "view_save", type=click.Path(dir_okay=False), default=None, metavar="FILE.rrd",
              help="Write the replay to this rerun file instead of spawning a viewer (an existing one only "
                   "with --force); open it later with `rerun FILE.rrd`.")
@click.option("--every", type=click.IntRange(min=1), default=10, show_default=True, metavar="N",
              help="Show every N-th sample (10: 50 samples a second of a 500 Hz session).")
@force_option("the --view-save file")
@cli_errors
def view(session, view_save, every, force):
    """Replay SESSION in rerun, as `crane-collect run --view` showed it live: both arms' angles, torques,
    tau_dis/tau_res, the tracking error, the loop period and the two arms in 3D, on the session's time
    axis. Needs rerun-sdk (pip install 'crane-x7[view]'); the session file is only read."""
    from crane_io.output_files import check_output

    from ..replay import replay_session  # numpy, h5py, pinocchio, rerun: not for --help

    if view_save is not None:
        check_output(view_save, inputs=[session], force=force, what="rerun file", make_folders=True)
    rep = replay_session(session, save=view_save, every=every)
    where = view_save if view_save is not None else "the rerun viewer"
    shown = ", ".join(rep.arms)
    click.echo(f"{session}: {len(rep.t)} of {rep.rows} samples ({shown}; every {every}) sent to {where}")
