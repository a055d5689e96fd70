"""`crane-train import CSV_OR_NPZ -o SESSION.h5 --map KEY=COLUMN...`: another rig's log as a crane-session
(train/data/importer.py)."""

from __future__ import annotations

import click

from crane_io.cli_support import Number, cli_errors


def _torque_constants(items) -> dict[str, float]:
    out = {}
    for item in items:
        for pair in item.split(","):
            name, sep, value = pair.partition("=")
            try:
                out[name.strip()] = float(value)
            except ValueError:
                raise click.BadParameter(f"{pair!r} is not JOINT=N_M_PER_A (e.g. joint2=2.409)",
                                         param_hint="--torque-constant") from None
            if not sep:
                raise click.BadParameter(f"{pair!r} is not JOINT=N_M_PER_A", param_hint="--torque-constant")
    return out


@click.command("import")
@click.argument("input_path", metavar="CSV_OR_NPZ", type=click.Path(dir_okay=False))
@click.option("-o", "--output", required=True, type=click.Path(dir_okay=False),
              help="Session file to write (HDF5, format crane-session). Never overwritten without --force.")
@click.option("--map", "mapping", multiple=True, required=True, metavar="KEY=COLUMN",
              help="Which input column is which signal: t=COL (time), JOINT.q=COL (angle), JOINT.tau=COL "
                   "(torque, N m) or JOINT.current=COL (current, made torque with the torque constant). "
                   "Repeat it or separate pairs with commas. NAME[k] is column k of a 2-D NPZ array.")
@click.option("--angle-unit", type=click.Choice(["rad", "deg", "pulse"]), default="rad", show_default=True,
              help="Unit of the angle columns; pulse: raw Present Position (2048 = 0 rad, 4096 a turn).")
@click.option("--time-unit", type=click.Choice(["s", "ms", "us", "ns"]), default="s", show_default=True,
              help="Unit of the time column.")
@click.option("--current-unit", type=click.Choice(["A", "mA", "raw"]), default="A", show_default=True,
              help="Unit of the current columns; raw: Present Current LSB (2.69 mA).")
@click.option("--torque-constant", "torque_constant", multiple=True, metavar="JOINT=NM_PER_A",
              help="Torque constant for a current column (default: the arm description's, 2.20 N m/A; "
                   "3.60 on joint2).")
@click.option("--rate", type=Number(float, 0, low_open=True, unit="Hz"), default=None, metavar="HZ",
              help="Nominal sample rate to record (default: from the median time step).")
@click.option("--source", default="import", show_default=True,
              help="The session's source attribute: a word naming the rig.")
@click.option("--force", is_flag=True, help="Overwrite the output file if it exists.")
@cli_errors
def import_session(input_path, output, mapping, angle_unit, time_unit, current_unit, torque_constant, rate,
                   source, force):
    """Write another logger's CSV or NPZ columns as a session file that crane-train reads.

    \b
    Example (angles in degrees, currents in mA, time in ms):
      crane-train import log.csv -o s.h5 --angle-unit deg --time-unit ms --current-unit mA \\
        --map t=time --map joint1.q=q1,joint1.current=i1 --map joint2.q=q2,joint2.current=i2

    Anything that cannot be mapped (a missing column, an unknown joint, a time that does not increase, NaNs)
    is refused in one sentence; the input is only read.
    """
    from ..data.importer import ImportUnits, parse_map  # numpy, h5py: not for --help
    from ..data.importer import import_session as run_import

    spec = parse_map(mapping)
    units = ImportUnits(angle=angle_unit, time=time_unit, current=current_unit)
    s = run_import(input_path, output, spec, units, torque_constants=_torque_constants(torque_constant),
                   rate_hz=rate, source=source, force=force)
    click.echo(f"{output}: {len(s.t)} samples, {s.t[-1]:.3f} s at {s.rate_hz:g} Hz, joints "
               f"{', '.join(s.joint_names)} (from {input_path})")
