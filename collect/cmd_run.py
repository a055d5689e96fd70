"""`crane-collect run`: record one session under 4-channel bilateral control (see collect/runner.py)."""

from __future__ import annotations

import click

from crane_io.errors import cli_errors


@click.command("run")
@click.option("-o", "--output", required=True, type=click.Path(dir_okay=False),
              help="Session file to write (HDF5, format crane-session). Never overwritten without --force.")
@click.option("--sim", is_flag=True,
              help="Drive two simulated arms and a simulated operator instead of hardware.")
@click.option("--plant", default=None, metavar="PRESET_OR_TOML",
              help="Physics of the simulated arms: an arm-plant preset (default crane-x7), a plant TOML, "
                   "or 'simple'. Only with --sim.")
@click.option("--truth", "truth_path", type=click.Path(dir_okay=False), default=None, metavar="JSON",
              help="With --sim and an arm plant: also write the follower plant's truth (effects, "
                   "parameters, seed) to this JSON file, overwriting it. Never stored in the session.")
@click.option("--seed", type=int, default=0, show_default=True,
              help="Seed of the simulated operator and plants (--sim).")
@click.option("--duration", type=float, default=None, metavar="S",
              help="Seconds of bilateral control to record (default: until Ctrl+C).")
@click.option("--rate", type=float, default=None, metavar="HZ",
              help="Control rate (default: loop.rate_hz of the configuration, 500).")
@click.option("--config", "config_path", type=click.Path(dir_okay=False), default=None, metavar="TOML",
              help="Configuration overriding collect/config/bilateral.toml.")
@click.option("--realtime", is_flag=True,
              help="With --sim: simulate in real time (wall clock) instead of lockstep "
                   "(faster than real time).")
@click.option("--leader-port", default=None, metavar="PORT", help="Serial port of the leader's U2D2.")
@click.option("--follower-port", default=None, metavar="PORT", help="Serial port of the follower's U2D2.")
@click.option("--force", is_flag=True, help="Overwrite the output file if it exists.")
@click.option("--quiet", is_flag=True, help="No live status line and no summary.")
@cli_errors
def run(output, sim, plant, truth_path, seed, duration, rate, config_path, realtime, leader_port,
        follower_port, force, quiet):
    """Drive leader and follower under 4-channel bilateral control and record a session.

    Start-up checks both ports, every servo's model and the latency timers, brings the arms into
    agreement slowly, then engages bilateral control. Ctrl+C, SIGTERM, the end of --duration or any
    safety breach stop both arms (goal current 0, torque off) and close the file cleanly.
    """
    from .runner import RunOptions, run_session

    if plant is not None and not sim:
        raise click.UsageError("--plant only applies to --sim")
    run_session(RunOptions(output=output, sim=sim, plant=plant, seed=seed, duration=duration, rate=rate,
                           config=config_path, realtime=realtime, leader_port=leader_port,
                           follower_port=follower_port, force=force, status=not quiet, truth=truth_path))
