"""`crane-collect recover SESSION.h5`: a crashed session file made an ordinary HDF5 file."""

from __future__ import annotations

from pathlib import Path

import click

from crane_io.cli_support import cli_errors


@click.command("recover")
@click.argument("session", type=click.Path(path_type=Path))
@click.option("-o", "--output", type=click.Path(path_type=Path), default=None,
              help="Write the recovered file here and leave SESSION untouched (default: recover in place, "
                   "keeping the original as SESSION.crashed).")
@cli_errors
def recover(session, output):
    """Make a session whose recording crashed (process killed, power lost) an ordinary HDF5 file.

    Such a file still holds every row flushed before the crash (all but at most the last second) but
    only SWMR-aware readers open it. The recovered file opens with any HDF5 tool, keeps every complete
    row (all datasets cut to the same length), and says complete = False and end_reason = "crashed".
    Rows in a chunk that fails its checksum are left out (and named); every other row is kept, so a
    closed session with damaged chunks is recovered too. A file that is complete and undamaged, not a
    crane-session, or still being written is refused."""
    from ..recovery import recover_session

    r = recover_session(session, output)
    dropped = f", {r.rows_dropped} incomplete rows left out" if r.rows_dropped else ""
    click.echo(f"{r.output}: recovered {r.rows} rows ({r.duration_s:.1f} s){dropped}; "
               f"complete = False, end_reason = {r.end_reason!r}")
    if r.damage_summary():
        click.echo(f"Damaged data: {r.damage_summary()}.")
    if r.backup is not None:
        click.echo(f"The original is kept as {r.backup}; delete it once the recovered file reads well.")
