"""`crane-collect recover SESSION.h5`: a crashed session file made an ordinary HDF5 file."""

from __future__ import annotations

from pathlib import Path

import click

from crane_io.cli_support import cli_errors


@click.command("recover")
@click.argument("session", type=click.Path(path_type=Path))
@click.option("-o", "--output", type=click.Path(path_type=Path), default=None,
              help="Write the recovered file here and leave SESSION untouched (default: recover in place, "
                   "keeping the original as SESSION.crashed). Never SESSION itself; an existing file only "
                   "with --force.")
@click.option("--force", is_flag=True, help="Replace the -o file if it exists (written whole or not at all).")
@cli_errors
def recover(session, output, force):
    """Make a session whose recording crashed (process killed, power lost) an ordinary HDF5 file.

    Such a file still holds every row flushed before the crash (all but at most the last second) but
    only SWMR-aware readers open it. The recovered file opens with any HDF5 tool, keeps every complete
    row (all datasets cut to the same length), and says complete = False and end_reason = "crashed".
    Rows in a chunk that fails its checksum are left out (and named); every other row is kept, so a
    closed session with damaged chunks is recovered too. A file that is complete and undamaged, not a
    crane-session, or still being written is refused."""
    from crane_io.output_files import check_output

    if output is not None:  # never the input (links resolved), an existing file only with --force
        check_output(output, inputs=[session], force=force, what="recovered file")
    r = _recover(session, output)  # a full disk: DiskFullError (exit 3), the input left as it was
    dropped = f", {r.rows_dropped} incomplete rows left out" if r.rows_dropped else ""
    click.echo(f"{r.output}: recovered {r.rows} rows ({r.duration_s:.1f} s){dropped}; "
               f"complete = False, end_reason = {r.end_reason!r}")
    if r.damage_summary():
        click.echo(f"Damaged data: {r.damage_summary()}.")
    if r.backup is not None:
        click.echo(f"The original is kept as {r.backup}; delete it once the recovered file reads well.")


def _recover(session: Path, output: Path | None):
    """collect.recovery.recover_session; an existing `output` (allowed by --force) is replaced only once
    the recovered file is whole: it is written beside it first, then renamed over it."""
    import dataclasses
    import os
    import shutil
    import tempfile

    from crane_io.output_files import write_error

    from ..recovery import recover_session

    if output is None or not os.path.lexists(output):
        return recover_session(session, output)
    stage = Path(tempfile.mkdtemp(prefix=f".{output.name}.", suffix=".part", dir=output.parent))
    try:
        r = recover_session(session, stage / output.name)
        os.replace(stage / output.name, output)
    except OSError as exc:
        raise write_error(exc, output, "recovered file") from None
    finally:
        shutil.rmtree(stage, ignore_errors=True)
    return dataclasses.replace(r, output=output)
