"""`crane-collect excite`: one arm runs an exciting trajectory on its own and is recorded
(collect/excitation.py; docs/excitation.md)."""

from __future__ import annotations

import click

from crane_io.cli_support import SEED, Number, cli_errors, plant_presets

from ..config import MAX_RATE_HZ, MIN_RATE_HZ


@click.command("excite")
@click.option("-o", "--output", required=True, type=click.Path(dir_okay=False),
              help="Session file to write (HDF5, format crane-session, marked as excitation data). Never "
                   "overwritten without --force.")
@click.option("--sim", is_flag=True, help="Drive two simulated arms instead of hardware.")
@click.option("--plant", default=None, metavar="PRESET_OR_TOML",
              help="Physics of the simulated arms, as for `run` (only with --sim). "
                   f"Presets: {', '.join(plant_presets())}.")
@click.option("--arm", type=click.Choice(["leader", "follower"]), default="follower", show_default=True,
              help="The arm that runs the trajectory; the other one is held still.")
@click.option("--joints", default=None, metavar="LIST",
              help="The joints the trajectory moves, as `run --joints` (default: bilateral.joints of the "
                   "configuration, joint1,joint2,joint4); the others are held at [held].")
@click.option("--duration", type=Number(float, 0, low_open=True, what="a positive number of seconds"),
              default=None, metavar="S",
              help="Seconds of trajectory (whole periods of about 10 s, from 113 s on played at five speeds "
                   "in turn; default 20, or the file's with --trajectory). The approach before and a short "
                   "rest after are recorded too.")
@click.option("--seed", type=SEED, default=0, show_default=True,
              help="Seed of the optimiser's start and of the simulated plants.")
@click.option("--budget", type=Number(int, 1), default=1000, show_default=True, metavar="N",
              help="The optimiser's budget in cost evaluations.")
@click.option("--budget-seconds", type=Number(float, 0, low_open=True, unit="s"), default=None, metavar="S",
              help="Also stop the optimiser after this many seconds.")
@click.option("--trajectory", "trajectory", type=click.Path(dir_okay=False), default=None, metavar="JSON",
              help="Replay a saved trajectory instead of designing one (checked against this run's limits).")
@click.option("--save-trajectory", "save", type=click.Path(dir_okay=False), default=None, metavar="JSON",
              help="Where the trajectory is saved (default: the session's name with .trajectory.json).")
@click.option("--rate", type=Number(float, MIN_RATE_HZ, MAX_RATE_HZ, unit="Hz"), default=None, metavar="HZ",
              help="Control rate, 100..2000 Hz (default: loop.rate_hz of the configuration, 500).")
@click.option("--config", "config_path", type=click.Path(dir_okay=False), default=None, metavar="TOML",
              help="Configuration overriding collect/config/bilateral.toml.")
@click.option("--realtime", is_flag=True, help="With --sim: simulate in real time instead of lockstep.")
@click.option("--leader-port", default=None, metavar="PORT", help="Serial port of the leader's U2D2.")
@click.option("--follower-port", default=None, metavar="PORT", help="Serial port of the follower's U2D2.")
@click.option("--leader-calibration", type=click.Path(dir_okay=False), default=None, metavar="TOML",
              help="The leader's calibration file (default: the stored one of its adapter, if any).")
@click.option("--follower-calibration", type=click.Path(dir_okay=False), default=None, metavar="TOML",
              help="The same for the follower.")
@click.option("--no-calibration", is_flag=True,
              help="Use the angles as the servos read them, not the adapters' stored calibrations.")
@click.option("--force", is_flag=True, help="Overwrite the session and trajectory files that exist.")
@click.option("--quiet", is_flag=True, help="No progress, status line or summary.")
@cli_errors
def excite(output, sim, plant, arm, joints, duration, seed, budget, budget_seconds, trajectory, save, rate,
           config_path, realtime, leader_port, follower_port, leader_calibration, follower_calibration,
           no_calibration, force, quiet):
    """Run an exciting trajectory on one arm (for identification) and record it as a session.

    The trajectory (a Fourier series per joint) is optimised for a low condition number of the
    base-parameter + friction regressor within the joint, speed and acceleration limits and clear of
    the table and the arm's own links, or replayed from --trajectory; it is saved as JSON and stored in
    the session. Start-up, safety and endings (Ctrl+C, limits, faults) are those of `run`.
    """
    from ..excitation import ExcitationOptions, run_excitation
    from ..run_options import RunOptions

    if plant is not None and not sim:
        raise click.UsageError("--plant only applies to --sim")
    opts = RunOptions(output=output, sim=sim, plant=plant, seed=seed, duration=duration, rate=rate,
                      config=config_path, realtime=realtime, leader_port=leader_port,
                      follower_port=follower_port, force=force, status=not quiet, joints=joints,
                      leader_calibration=leader_calibration, follower_calibration=follower_calibration,
                      calibrate=not no_calibration)
    run_excitation(opts, ExcitationOptions(arm=arm, trajectory=trajectory, save=save, evaluations=budget,
                                           seconds=budget_seconds))
