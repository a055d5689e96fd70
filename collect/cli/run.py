"""`crane-collect run`: record one session under 4-channel bilateral control (collect/runner.py)."""

from __future__ import annotations

import click

from crane_io.cli_support import SEED, Number, cli_errors, plant_presets

from ..config import MAX_RATE_HZ, MIN_RATE_HZ


@click.command("run")
@click.option("-o", "--output", required=True, type=click.Path(dir_okay=False),
              help="Session file to write (HDF5, format crane-session). Never overwritten without --force, "
                   "never one of the run's inputs or other outputs (checked before anything starts).")
@click.option("--sim", is_flag=True,
              help="Drive two simulated arms and a simulated operator instead of hardware.")
@click.option("--plant", default=None, metavar="PRESET_OR_TOML",
              help="Physics of the simulated arms: an arm-plant preset (default crane-x7, or crane-x7-7dof "
                   "when --joints goes beyond joint1,joint2,joint4), a plant TOML, "
                   f"or 'simple'. Only with --sim. Presets: {', '.join(plant_presets())}.")
@click.option("--truth", "truth", type=click.Path(dir_okay=False), default=None, metavar="JSON",
              help="With --sim and an arm plant: also write the follower plant's truth (effects, "
                   "parameters, seed) to this JSON file (not overwritten without --force). Never stored in "
                   "the session.")
@click.option("--truth-trace", "truth_trace", type=click.Path(dir_okay=False), default=None, metavar="H5",
              help="With --sim: also write the plants' true external torques (contact on the follower, the "
                   "hand on the leader) for every recorded row to this HDF5 file, for crane-train fidelity. "
                   "Never stored in the session; not overwritten without --force.")
@click.option("--task", type=click.Choice(["free", "contact"]), default=None,
              help="With --sim: what the simulated operator does: free motion, or free motion alternating "
                   "with pressing the follower against the plant's objects (a plant with [[environment]], "
                   "e.g. --plant contact-wall). Default: operator.task of the configuration (free).")
@click.option("--joints", default=None, metavar="LIST",
              help="The joints under bilateral control, comma-separated (joint1,joint2,joint4,joint6); "
                   "'all' stands for joint1..joint7 (the gripper only when named: all,gripper). "
                   "The others are held in position mode at [held]. Default: bilateral.joints of the "
                   "configuration, the paper's joint1,joint2,joint4. With --sim and no --plant, a set beyond "
                   "those three uses the seven-joint plant preset crane-x7-7dof. Recorded in the session "
                   "(bilateral_joints).")
@click.option("--hand-on", type=click.Choice(["leader", "follower"]), default="leader", show_default=True,
              help="The arm the operator's hand moves. 'follower' swaps the roles so that the leader moves "
                   "on its own: leader data free of a hand, for crane-train fit --arm leader. Recorded in "
                   "the session (attribute hand_on).")
@click.option("--model", "model_dir", type=click.Path(file_okay=False), default=None, metavar="MODEL_DIR",
              help="A crane-train model (any method, exported for the loop) in the follower's reaction-force "
                   "observer instead of the nominal model; bilateral joints it does not cover stay nominal.")
@click.option("--leader-model", "leader_model_dir", type=click.Path(file_okay=False), default=None,
              metavar="MODEL_DIR",
              help="The same for the leader's observer: a model fitted on leader data (crane-train fit "
                   "--arm leader).")
@click.option("--arm-model", "arm_model", type=click.Path(dir_okay=False), default=None, metavar="TOML",
              help="An identified arm model (arm_model.toml of `crane-train identify`) as both arms' nominal "
                   "observer model: its bodies in the gravity and inertia terms, its viscous friction as D, "
                   "its Coulomb friction c as c tanh(w / 0.05 rad/s).")
@click.option("--seed", type=SEED, default=0, show_default=True,
              help="Seed of the simulated operator and plants (--sim).")
@click.option("--duration", type=Number(float, 0, low_open=True, what="a positive number of seconds"),
              default=None, metavar="S",
              help="Seconds of bilateral control to record (default: until Ctrl+C).")
@click.option("--rate", type=Number(float, MIN_RATE_HZ, MAX_RATE_HZ, unit="Hz"), default=None, metavar="HZ",
              help="Control rate, 100..2000 Hz (default: loop.rate_hz of the configuration, 500).")
@click.option("--config", "config_path", type=click.Path(dir_okay=False), default=None, metavar="TOML",
              help="Configuration overriding collect/config/bilateral.toml.")
@click.option("--realtime", is_flag=True,
              help="With --sim: simulate in real time (wall clock) instead of lockstep "
                   "(faster than real time).")
@click.option("--leader-port", default=None, metavar="PORT", help="Serial port of the leader's U2D2.")
@click.option("--follower-port", default=None, metavar="PORT", help="Serial port of the follower's U2D2.")
@click.option("--leader-calibration", type=click.Path(dir_okay=False), default=None, metavar="TOML",
              help="The leader's calibration file (default: the one `crane-collect calibrate` stored for the "
                   "leader port's adapter, if any).")
@click.option("--follower-calibration", type=click.Path(dir_okay=False), default=None, metavar="TOML",
              help="The same for the follower.")
@click.option("--no-calibration", is_flag=True,
              help="Use the angles as the servos read them, not the adapters' stored calibrations.")
@click.option("--skip-selftest", is_flag=True,
              help="Hardware ports: run even though an arm has no passing `crane-collect selftest` on record "
                   "for the calibration it runs with.")
@click.option("--force", is_flag=True,
              help="Overwrite the output files that exist (-o, --truth, --truth-trace, --view-save).")
@click.option("--quiet", is_flag=True, help="No live status line and no summary.")
@click.option("--view", is_flag=True,
              help="Live view in rerun (optional extra: pip install 'crane-x7[view]'): both arms' angles, "
                   "torques, tau_dis/tau_res, tracking error, loop period and the arms in 3D.")
@click.option("--view-save", "view_save", type=click.Path(dir_okay=False), default=None, metavar="FILE.rrd",
              help="Write the live view to this rerun file instead of spawning a viewer (implies --view; "
                   "open it later with `rerun FILE.rrd`); not overwritten without --force.")
@click.option("--view-every", "view_every", type=Number(int, 1), default=10, show_default=True,
              metavar="N", help="The view samples every N-th control cycle (50 samples a second at 500 Hz).")
@cli_errors
def run(output, sim, plant, truth, truth_trace, task, joints, hand_on, model_dir, leader_model_dir,
        arm_model, seed,
        duration, rate, config_path, realtime, leader_port, follower_port, leader_calibration,
        follower_calibration, no_calibration, skip_selftest, force, quiet, view, view_save, view_every):
    """Drive leader and follower under 4-channel bilateral control and record a session.

    Start-up checks both ports, every servo's model and the latency timers, brings the arms into
    agreement slowly, then engages bilateral control. Ctrl+C, SIGTERM, the end of --duration or any
    safety breach stop both arms (goal current 0, torque off) and close the file cleanly.
    """
    from ..runner import RunOptions, run_session

    if plant is not None and not sim:
        raise click.UsageError("--plant only applies to --sim")
    if view or view_save is not None:  # without rerun: one sentence, before anything starts
        from crane_io.view import import_rerun

        import_rerun()
    run_session(RunOptions(output=output, sim=sim, plant=plant, seed=seed, duration=duration, rate=rate,
                           config=config_path, realtime=realtime, leader_port=leader_port,
                           follower_port=follower_port, force=force, status=not quiet, truth=truth,
                           truth_trace=truth_trace, task=task, joints=joints, hand_on=hand_on,
                           model=model_dir,
                           leader_model=leader_model_dir, arm_model=arm_model, view=view, view_save=view_save,
                           view_every=view_every, leader_calibration=leader_calibration,
                           follower_calibration=follower_calibration, calibrate=not no_calibration,
                           skip_selftest=skip_selftest))
