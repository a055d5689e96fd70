"""`crane-collect selftest --port P`: check one arm's wiring and conventions before bilateral control
(collect/selftest.py), print one finding per line, keep the result beside the arm's calibration
(collect/selftest_record.py) and exit 1 when a check failed. `--sim` tests an in-process simulated arm,
with the wiring faults of crane_io/sim/wiring_faults.py planted on request (nothing is recorded)."""

from __future__ import annotations

import click

from crane_io.cli_support import SEED, Number, cli_errors
from crane_io.errors import ConfigError

SIM_PERIOD_S = 0.01  # the in-process simulated arm: one goal per 10 ms of its time


def wiring_fault_options(func):
    """The options that plant wiring faults in a simulated arm (also `crane-collect sim-serve`'s)."""
    options = [
        click.option("--swap-ids", default=None, metavar="A,B",
                     help="Simulated wiring fault: the servos of two joints carry each other's IDs."),
        click.option("--reverse-joint", "reverse_joints", multiple=True, metavar="JOINT",
                     help="Simulated wiring fault: the joint's motor and encoder turn the other way than "
                          "the description says. Repeatable."),
        click.option("--wrong-model", "wrong_models", multiple=True, metavar="ID=MODEL",
                     help="Simulated wiring fault: the servo with this ID reports another model "
                          "(e.g. 5=XM540-W270). Repeatable."),
        click.option("--current-sign", type=click.Choice(["1", "-1"]), default="1",
                     help="Simulated wiring fault: -1 makes every current sensor read the wrong sign."),
        click.option("--current-scale", type=Number(float, 0, low_open=True), default=1.0, metavar="X",
                     help="Simulated wiring fault: every current sensor reads X times the current (2 stands "
                          "for a torque constant off by a factor 2)."),
    ]
    for option in reversed(options):
        func = option(func)
    return func


def wiring_faults(swap_ids, reverse_joints, wrong_models, current_sign, current_scale):
    """The WiringFaults of the options above."""
    from crane_io.sim.wiring_faults import WiringFaults, parse_id_pair, parse_model_entry

    return WiringFaults(swap_ids=parse_id_pair(swap_ids) if swap_ids is not None else None,
                        reversed_joints=tuple(reverse_joints),
                        wrong_models=tuple(parse_model_entry(e) for e in wrong_models),
                        current_sign=float(current_sign), current_scale=float(current_scale))


def simulated_selftest_arm(arm, seed: int, faults, plant: str | None = None):
    """An in-process simulated arm (lockstep) whose plant integrates every arm joint, `faults` planted."""
    from dataclasses import replace

    from crane_io.sim import simulated_arm

    from ..sim_arms import DEFAULT_PLANT_7DOF, make_plant

    every = replace(arm, bilateral_joints=tuple(n for n in arm.joint_names if n != "gripper"))
    return simulated_arm(plant=make_plant(plant or DEFAULT_PLANT_7DOF, seed, every), arm=arm,
                         period_s=SIM_PERIOD_S, wiring=faults)


@click.command("selftest")
@click.option("--port", default=None, metavar="PORT",
              help="Serial port of the arm's U2D2 (or a sim-serve link).")
@click.option("--sim", is_flag=True, help="Test an in-process simulated arm instead of hardware.")
@click.option("--arm", "arm_name", default=None, metavar="NAME",
              help="What to call the arm in the record (default: its calibration's name, else 'arm').")
@click.option("--calibration", "calibration_path", type=click.Path(dir_okay=False), default=None,
              metavar="TOML", help="The calibration to test with (default: the one stored for the port's "
                                   "adapter by `crane-collect calibrate`, if any).")
@click.option("--no-calibration", is_flag=True, help="Test the angles as the servos read them.")
@click.option("--seed", type=SEED, default=0, show_default=True, help="With --sim: the plant's seed.")
@wiring_fault_options
@cli_errors
def selftest(port, sim, arm_name, calibration_path, no_calibration, seed, swap_ids, reverse_joints,
             wrong_models, current_sign, current_scale):
    """Check one arm before bilateral control: servo IDs, models and firmware; encoders against the
    calibration; each joint's direction of position, velocity and current; the current that holds the
    arm at three poses against the model's gravity torque. Torque on in position mode only, slowly and
    with low current limits. Exit 1 when a check fails."""
    from crane_io.description import default_arm

    from ..selftest import run_selftest
    from ..selftest_checks import table

    faults = wiring_faults(swap_ids, reverse_joints, wrong_models, current_sign, current_scale)
    if sim == (port is not None):
        raise ConfigError("give --port PORT (an arm or a sim-serve link), or --sim")
    if faults.any and not sim:
        raise ConfigError("the wiring-fault options go with --sim (for a served link: "
                          "`crane-collect sim-serve` takes them)")
    if no_calibration and calibration_path is not None:
        raise ConfigError("--calibration and --no-calibration exclude each other")
    if arm_name is not None:
        from crane_io.dynamixel.calibration import check_arm_name

        check_arm_name(arm_name)  # stored in the record and shown on terminals
    arm = default_arm()
    cal = _calibration(port, calibration_path, no_calibration or sim)
    if sim:
        with simulated_selftest_arm(arm, seed, faults) as simulated:
            click.echo(f"Self-test of a simulated arm ({faults.describe()}).")
            result = run_selftest(simulated.url, arm, cal, period_s=SIM_PERIOD_S, paced=False)
    else:
        _check_record_target(port, cal)
        click.echo(f"Self-test of the arm on {port}: torque goes on in position mode, slowly, with low "
                   "current limits; keep clear of the arm (Ctrl+C stops it).")
        result = run_selftest(port, arm, cal, name=arm_name or "arm")
    click.echo(table(result.findings))
    verdict = "PASSED" if result.passed else "FAILED"
    click.echo(f"Self-test {verdict} ({sum(f.failed for f in result.findings)} failing of "
               f"{len(result.findings)} findings, {result.duration_s:.1f} s of the arm's time).")
    if not sim:
        from crane_io.dynamixel.calibration import adapter_key

        from ..selftest_record import record_path, save_record

        name = arm_name or (cal.name if cal is not None else "arm")
        path = save_record(result, record_path(port, cal), arm_name=name, key=adapter_key(port),
                           calibration=cal)
        click.echo(f"Recorded in {path}" + ("; `crane-collect run` accepts this arm with this calibration."
                                            if result.passed else "."))
    if not result.passed:
        raise click.exceptions.Exit(1)


def _calibration(port, calibration_path, none: bool):
    from crane_io.dynamixel.calibration import find_calibration, load_calibration

    if calibration_path is not None:
        return load_calibration(calibration_path)
    return None if none else find_calibration(port)


def _check_record_target(port, cal) -> None:
    """The record's file: never the port, its folder made if needed (before the arm is touched)."""
    import os

    from crane_io.output_files import check_output

    from ..selftest_record import record_path

    check_output(record_path(port, cal), inputs=[port] if os.path.exists(port) else [], force=True,
                 what="self-test record", make_folders=True)
