"""Start-up of `crane-collect run`, everything before the alignment that can refuse a run:

- the options, the output file and its folder (made if missing), the ports: checked before anything
  starts;
- the two ports (simulated or the user's), both buses opened, latency timers checked (a warning),
  every servo pinged and its model checked, servos configured (return delay 0, modes, Bus Watchdog),
  on real ports one cycle's reads timed against the period (collect/link_timing.py: a refusal or a
  warning), torque on; a failure closes what was opened;
- the session file opened with what the run knows about itself (its attributes), after the alignment.
"""

from __future__ import annotations

import datetime as _dt
import math
import os
import sys
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

from crane_io import session_format as sf
from crane_io.description import ArmDescription
from crane_io.errors import ConfigError, CraneError, SessionFileError
from crane_io.toml_config import check_seed, expect

from .arm_pair import ARMS
from .config import Config
from .recorder import SessionRecorder

if TYPE_CHECKING:
    from .run_options import RunOptions


def software_version() -> str:
    try:
        from importlib.metadata import version

        return version("crane-x7")
    except Exception:  # noqa: BLE001 - not installed: still record something
        return "unknown"


def check_options(opts: RunOptions, period_s: float) -> None:
    """One sentence (ConfigError) for options that do not go together, before anything starts."""
    if opts.duration is not None:
        if not (math.isfinite(opts.duration) and opts.duration > 0):
            raise ConfigError(f"`duration` must be a positive number of seconds, got {opts.duration} "
                              "(leave it out to record until Ctrl+C)")
        if round(opts.duration / period_s) < 1:
            raise ConfigError(f"`duration` {opts.duration:g} s is shorter than one control period "
                              f"({period_s:g} s): nothing would be recorded")
    if opts.realtime and not opts.sim:
        raise ConfigError("`realtime` only applies to `sim` (hardware always runs in real time)")
    if opts.truth is not None and not opts.sim:
        raise ConfigError("`truth` only applies to `sim` (real arms have no truth to write)")
    if opts.truth_trace is not None and not opts.sim:  # its path: run_options.check_run_outputs
        raise ConfigError("`truth_trace` only applies to `sim` (real arms have no truth to write)")
    if opts.task is not None and not opts.sim:
        raise ConfigError("`task` only applies to `sim` (it sets what the simulated operator does)")
    if opts.hand_on not in ARMS:
        raise ConfigError(f"the operator's hand is on the leader or the follower, not {opts.hand_on!r}")
    check_seed(opts.seed)
    expect(isinstance(opts.view_every, int) and opts.view_every >= 1, "`view_every`",
           "an integer of at least 1", opts.view_every)
    if not opts.calibrate:
        named = [n for n in ("leader_calibration", "follower_calibration") if getattr(opts, n) is not None]
        if named:
            raise ConfigError(f"`{named[0]}` names a calibration file but `no_calibration` asks for none; "
                              "give one or the other")


def check_ports(sim: bool, leader_port: str | None, follower_port: str | None) -> None:
    """`sim` and the ports exclude each other; hardware needs two different ports."""
    if sim:
        if leader_port or follower_port:
            raise ConfigError("`leader_port`/`follower_port` cannot be combined with `sim`")
    else:
        if not leader_port or not follower_port:
            raise ConfigError("without `sim` both `leader_port` and `follower_port` are needed "
                              "(see `crane-collect ports`)")
        if leader_port == follower_port:
            raise ConfigError("`leader_port` and `follower_port` must be different ports")


def check_output(output: Path, force: bool) -> None:
    """A session file that cannot be written is found out before any torque is on, not after the
    alignment. An existing file needs `force`. Missing folders are not made here (a run refused later
    must not leave them behind): the nearest existing folder must be a writable folder; the session
    file's creation makes the rest."""
    if str(output) in ("", ".") or output.name in ("", ".", ".."):
        raise ConfigError("-o needs the name of a session file, e.g. -o session.h5")
    if output.is_dir():
        raise SessionFileError(f"{output} is a folder, not a session file; give a file name inside it")
    if output.exists() and not force:
        raise CraneError(f"{output} already exists; pass `force` to overwrite it")
    folder = output.parent
    existing = folder
    while not existing.exists() and existing != existing.parent:
        if existing.is_symlink():  # a dangling link in the way
            break
        existing = existing.parent
    if not existing.is_dir():
        what = "a file" if existing.exists() else "a broken link"
        raise SessionFileError(f"cannot create session file {output}: {existing} is {what}, not a folder")
    if not os.access(existing, os.W_OK | os.X_OK):
        if existing == folder:
            raise SessionFileError(f"cannot create session file {output}: folder {folder} is not writable")
        raise SessionFileError(f"cannot create session file {output}: folder {folder} cannot be created "
                               f"({existing} is not writable)")


def open_buses(arm: ArmDescription, config: Config, ports: dict, out, *, simulated: bool = False,
               checkpoint=None, torque_going_on=None) -> tuple[dict, dict]:
    """Both buses open, every servo checked and configured, torque on: (buses, {"infos", "warnings"}).
    `simulated`: the ports are dxlsim:// arms (no latency timers to check). `checkpoint()` is called
    between the steps (it raises to abandon the start-up: a stop request); `torque_going_on()` right
    before the first servo's torque is switched on."""
    checkpoint = checkpoint or (lambda: None)
    from crane_io.dynamixel.bus import DynamixelBus
    from crane_io.dynamixel.ports import port_warnings

    buses: dict = {}
    infos: dict = {}
    warnings_: list[str] = []
    try:
        for name in ARMS:
            port = ports[name]
            if not simulated:
                for w in port_warnings(port):
                    warnings_.append(w)
                    print(f"Warning: {w}", file=out or sys.stderr, flush=True)
            bus = DynamixelBus(port, arm, name=name)
            buses[name] = bus
            bus.open()
        for name in ARMS:
            checkpoint()
            infos[name] = buses[name].ping_all()
        for name in ARMS:
            checkpoint()
            buses[name].configure(watchdog_s=config.safety.watchdog_s)
        checkpoint()
        _check_links(buses, config, warnings_, out, simulated)
        checkpoint()
        if torque_going_on is not None:
            torque_going_on()
        for name in ARMS:
            buses[name].torque_on()
    except BaseException:
        for bus in buses.values():
            bus.close()
        raise
    return buses, {"infos": infos, "warnings": warnings_}


def _check_links(buses: dict, config: Config, warnings_: list, out, simulated: bool) -> None:
    """Real ports: they can carry a cycle in a period (a warning when only just), or LinkTooSlow
    (collect/link_timing.py). Simulated (dxlsim://) arms run in lockstep: nothing to time."""
    if simulated:
        return
    from .link_timing import check_link_timing

    note = check_link_timing(buses, config.loop.period_s)
    if note is not None:
        warnings_.append(note)
        print(f"Warning: {note}", file=out or sys.stderr, flush=True)


def make_recorder(output: Path, config: Config, arm: ArmDescription, hw: dict, *, simulated: bool,
                  lockstep: bool, seed: int, hand_on: str = "leader", force: bool = False,
                  models: dict | None = None, calibrations: dict | None = None,
                  arm_model_toml: str = "", extra_attrs: dict | None = None) -> SessionRecorder:
    """The session file, with the run's attributes (never the simulated plants' truth): also the arm
    the hand moved (`hand_on`), the model in each arm's observer (`leader_model`, `follower_model`) and
    each arm's calibration (`leader_calibration`, `follower_calibration`), and the identified arm model of
    the nominal observers (`arm_model_toml`, "" for the description's). `simulated`: the arms are
    simulated (source "sim", the `seed` recorded); `lockstep`: the rows carry simulated time; `force`:
    an existing file is overwritten; `extra_attrs`: further root attributes (an excitation's)."""
    from .arm_calibration import calibration_attrs
    from .loop_models import session_attrs

    infos = hw["infos"]
    attrs = {
        sf.HAND_ON: hand_on,
        **session_attrs(models or {}),
        **calibration_attrs(calibrations or {}),
        sf.TAU_SOURCE_ATTR: [sf.TAU_FROM_GOAL if n in arm.bilateral_joints else sf.TAU_FROM_PRESENT
                             for n in arm.joint_names],
        sf.TORQUE_CONSTANTS_ATTR: np.array([j.torque_constant for j in arm.joints]),
        sf.SERVO_IDS_ATTR: np.array(arm.servo_ids),
        sf.BILATERAL_JOINTS_ATTR: list(arm.bilateral_joints),
        sf.SOFTWARE_VERSION_ATTR: software_version(),
        sf.START_TIME_ATTR: _dt.datetime.now(_dt.timezone.utc).isoformat(timespec="seconds"),
        sf.CONFIG_TOML_ATTR: config.to_toml(),
        sf.ARM_MODEL_TOML_ATTR: arm_model_toml,
        sf.GRAVITY_MODEL_ATTR: config.controller.gravity_model,
        sf.LOCKSTEP_ATTR: bool(lockstep),
        **(extra_attrs or {}),
    }
    for name in ARMS:
        by_id = infos.get(name, {})
        attrs[sf.firmware_attr(name)] = np.array([by_id[i].firmware if i in by_id else -1
                                                  for i in arm.servo_ids])
    attrs[sf.FIRMWARE_ATTR] = attrs[sf.firmware_attr("follower")]
    # the models the servos reported when pinged (start-up refused any other than the description's)
    reported = infos.get("follower", {})
    attrs[sf.SERVO_MODELS_ATTR] = [reported[i].model if i in reported else j.model
                                   for i, j in zip(arm.servo_ids, arm.joints)]
    if simulated:
        attrs[sf.SEED_ATTR] = int(seed)  # the plant preset is not stored: "hidden-*" names give it away
    # lockstep rows carry simulated time: they are written by recorded rows (whole chunks), never by
    # the wall clock, which keeps the file compact however slowly the loop runs
    return SessionRecorder(output, joint_names=arm.joint_names, rate_hz=config.loop.rate_hz,
                           source="sim" if simulated else "hardware", attrs=attrs, force=force,
                           lockstep=attrs[sf.LOCKSTEP_ATTR], deferred_writes=not attrs[sf.LOCKSTEP_ATTR])
