"""`crane-collect sim-serve`: serve a simulated CRANE-X7 on a pseudo-terminal until stopped.

Any Dynamixel tool that opens a serial port (the SDK, Dynamixel Wizard 2.0, `crane-collect run`
with `--leader-port/--follower-port`) can then talk Protocol 2.0 to eight emulated servos (IDs 2..9,
3 Mbps) at the link. `--pair` serves a leader and a follower with a simulated person's hand on one of
them (collect/sim_lab.py), so a `crane-collect run` over the two links records a session to train on.
Every served link is announced in the user's runtime directory (crane_io.dynamixel.link_registry) for
`crane-collect ports`, and withdrawn on exit.
"""

from __future__ import annotations

import os
import signal
import sys
import threading

import click

from crane_io.cli_support import SEED, Number, cli_errors, plant_presets
from crane_io.errors import ConfigError, HardwareError

from ..config import MAX_RATE_HZ, MIN_RATE_HZ
from .selftest import wiring_fault_options, wiring_faults


def status_line(chain) -> str:
    """The live status: simulated time, traffic, and how much simulated time slipped so far."""
    s = chain.stats
    line = (f"sim time {chain.time:9.2f} s  packets {s.packets_received:9d}  replies {s.replies_sent:9d}  "
            f"CRC errors {s.crc_errors:5d}")
    if chain.clock == "wall":
        line += f"  slipped {s.slip_s:7.2f} s ({s.slips} times)"
    return line


def pair_status_line(lab) -> str:
    """The live status of a served pair: each arm's time and traffic, and what the hand does."""
    parts = [f"{name} {c.time:8.2f} s {c.stats.packets_received:8d} pkts"
             for name, c in lab.chains.items()]
    hand = lab.hand
    state = "moving" if hand.holding else ("waiting" if hand.engaged_since is not None else "off")
    return "  ".join(parts) + f"  hand on {lab.hand_on}: {state} ({hand.engagements} takes)"


def slip_summary(chain) -> str:
    """One sentence on simulated time that was skipped because the plant could not keep up."""
    s = chain.stats
    if not s.slips:
        return "Simulated time never slipped: the plant kept up with real time."
    times = "once" if s.slips == 1 else f"{s.slips} times"
    return (f"Simulated time slipped {times}, {s.slip_s:.2f} s in all (largest {s.max_slip_s:.3f} s): the "
            "plant could not keep up with real time (a busy or slow machine), so it skipped ahead "
            "instead of holding up the replies.")


@click.command("sim-serve")
@click.option("--link", "link", default=None, type=click.Path(dir_okay=False),
              help="Path of the symlink to the pseudo-terminal of one arm, e.g. /tmp/crane_x7.")
@click.option("--pair", is_flag=True,
              help="Serve a leader and a follower (--leader-link, --follower-link) with a simulated "
                   "person's hand on one of them: a lab on the wire that `crane-collect run` records from.")
@click.option("--leader-link", default=None, type=click.Path(dir_okay=False),
              help="With --pair: the leader's link.")
@click.option("--follower-link", default=None, type=click.Path(dir_okay=False),
              help="With --pair: the follower's link.")
@click.option("--hand-on", type=click.Choice(["leader", "follower"]), default="leader", show_default=True,
              help="With --pair: the arm the simulated hand moves ('follower': leader data free of a hand, "
                   "for `crane-train fit --arm leader`; record it with `run --hand-on follower`).")
@click.option("--task", type=click.Choice(["free", "contact"]), default=None,
              help="With --pair: the hand's task (default: the --config file's [operator] task, 'free'); "
                   "'contact' presses the follower against its plant's objects (e.g. --plant contact-wall).")
@click.option("--hand-delay", "hand_delay_s", type=Number(float, 0, 60, unit="s"), default=1.0,
              show_default=True,
              metavar="S", help="With --pair: seconds of the arm's time between its bilateral joints coming "
                                "alive (torque on, current mode) and the hand taking hold.")
@click.option("--config", "config_path", type=click.Path(dir_okay=False), default=None, metavar="TOML",
              help="With --pair: a crane-collect configuration whose [operator] section sets the hand.")
@click.option("--encoder-offset", "encoder_offsets", multiple=True, metavar="[ARM:]JOINT=RAD",
              help="That joint's encoder reads RAD more than the truth, as on an uncalibrated arm (for "
                   "`crane-collect calibrate`); with --pair prefix the arm (leader:joint2=0.05). Repeatable.")
@click.option("--joints", default=None, metavar="LIST",
              help="The joints the served arms integrate as bilateral (current-mode) joints with the full "
                   "rigid-body dynamics, comma-separated; 'all' stands for joint1..joint7 (the gripper "
                   "only when named: all,gripper); with --pair also the joints the hand moves. Record with "
                   "the same --joints on `crane-collect run`. Default: bilateral.joints of --config, the "
                   "paper's joint1,joint2,joint4.")
@click.option("--plant", "plant", default=None, metavar="PRESET_OR_TOML",
              help="Physics behind the servos: 'simple' (independent joints) or an arm-plant preset "
                   "or TOML file. Default: the arm plant's 'crane-x7' preset when available (crane-x7-7dof "
                   "when --joints goes beyond joint1,joint2,joint4), else 'simple'. "
                   f"Presets: {', '.join(plant_presets())}.")
@click.option("--clock", type=click.Choice(["wall", "lockstep"]), default=None,
              help="'wall': physics follows real time. 'lockstep': one control period per Goal "
                   "Current sync write: the arms wait for the controller, so a busy machine slows the run "
                   "instead of letting the arms fall between late commands. Default: wall for one arm, "
                   "lockstep for --pair.")
@click.option("--period", "period_s", type=Number(float, 1 / MAX_RATE_HZ, 1 / MIN_RATE_HZ, unit="s"),
              default=0.002, show_default=True,
              help="Lockstep control period in seconds, 0.0005..0.01 (the rates `crane-collect run` takes).")
@click.option("--seed", type=SEED, default=0, show_default=True,
              help="Seed of the plant's sensor noise (--pair: leader 2 SEED, follower 2 SEED + 1, the hand "
                   "SEED).")
@click.option("--no-fast-sync-read", is_flag=True, help="Servos ignore Fast Sync Read (old firmware).")
@click.option("--return-delay", type=Number(int, 0, 254), default=None,
              help="Return Delay Time register of every servo (2 us/LSB). Default: factory 250.")
@click.option("--latency-timer", "latency_timer_ms", type=Number(int, 0, 255, unit="ms"), default=1,
              show_default=True, metavar="MS",
              help="On the wall clock, replies reach the host as through a U2D2: bytes at the servos' baud "
                   "rate, their Return Delay Time, and the adapter's USB packets sent when its latency timer "
                   "expires (1 ms: the udev rule; 16 ms: an unconfigured adapter; docs/rig-timing.md). 0: "
                   "replies as fast as the pseudo-terminal allows. The lockstep clock is never delayed.")
@click.option("--truth", "truth", type=click.Path(dir_okay=False), default=None, metavar="JSON",
              help="Also write the arm plant's hidden truth (effects, parameters, seed; --pair: the "
                   "follower's) to this file (not overwritten without --force). Nothing else ever records "
                   "it.")
@click.option("--force", is_flag=True, help="Overwrite the --truth file if it exists.")
@click.option("--supply-voltage", "supply_voltage", type=Number(float, 1, 30, unit="V"), default=None,
              metavar="V", help="The servos' supply in volts (the arm plant's [supply]; default: the "
                                "plant's, 12.0 V): outside a servo's Min/Max Voltage Limit (9.5..16.0 V) it "
                                "raises its Input Voltage error.")
@wiring_fault_options
@cli_errors
def sim_serve(link, pair, leader_link, follower_link, hand_on, task, hand_delay_s, config_path,
              encoder_offsets, joints, plant, clock, period_s, seed, no_fast_sync_read, return_delay,
              latency_timer_ms, truth, force, supply_voltage, swap_ids, reverse_joints, wrong_models,
              current_sign, current_scale):
    """Serve a simulated CRANE-X7 (or, with --pair, a leader and a follower with a simulated hand) on
    pseudo-terminals until Ctrl+C or SIGTERM."""
    if not period_s > 0:
        raise ConfigError(f"--period must be positive, got {period_s}")
    if clock is None:
        clock = "lockstep" if pair else "wall"
    _check_links(pair, link, leader_link, follower_link, task, config_path)
    faults = wiring_faults(swap_ids, reverse_joints, wrong_models, current_sign, current_scale)
    if faults.any and pair:
        raise ConfigError("the wiring-fault options serve one arm (--link), not --pair")
    if truth is not None:  # never an input nor a link, an existing file only with --force
        from crane_io.output_files import check_output

        plant_file = [plant] if plant is not None and os.path.exists(plant) else []
        check_output(truth, inputs=[config_path, *plant_file], force=force, what="truth file",
                     others=[link, leader_link, follower_link])
    from ..config import load_config
    from ..runner import run_arm
    from ..sim_lab import parse_offsets

    config = load_config(config_path)
    if joints is not None:
        config = config.with_bilateral_joints(joints)
    arm = run_arm(config)
    offsets = parse_offsets(encoder_offsets, arm, arms=("leader", "follower") if pair else ("arm",))
    from crane_io.jit import compile_notice

    from ..kernels import compile_kernels, compile_sentence

    with compile_notice(lambda: click.echo(compile_sentence(), err=True)):  # said when it compiles
        compile_kernels()
    adapter = _adapter(latency_timer_ms, clock)
    if adapter is not None:  # replies are due at set times: the serving threads take turns often
        from crane_io.sim.transport import ADAPTER_SWITCH_INTERVAL_S

        sys.setswitchinterval(ADAPTER_SWITCH_INTERVAL_S)
    stop = threading.Event()
    previous = signal.signal(signal.SIGTERM, lambda *_: stop.set())
    try:
        if pair:
            _serve_pair(stop, leader_link, follower_link, hand_on, task, hand_delay_s, config, arm,
                        plant, clock, period_s, seed, not no_fast_sync_read, return_delay, truth,
                        offsets, adapter, supply_voltage)
        else:
            _serve_one(stop, link, arm, plant, clock, period_s, seed, not no_fast_sync_read,
                       return_delay, truth, offsets.get("arm"), adapter, faults, supply_voltage)
    finally:
        signal.signal(signal.SIGTERM, previous)


def _check_links(pair, link, leader_link, follower_link, task, config_path) -> None:
    """--pair takes a leader and a follower link (and may take --task and --config); one arm, --link."""
    if pair:
        if link is not None:
            raise ConfigError("--pair serves two links: give --leader-link and --follower-link, not --link")
        if leader_link is None or follower_link is None:
            raise ConfigError("--pair needs both --leader-link and --follower-link")
        return
    if link is None:
        raise ConfigError("give --link PATH (one arm), or --pair with --leader-link and --follower-link")
    extra = [o for o, v in (("--leader-link", leader_link), ("--follower-link", follower_link),
                            ("--task", task), ("--config", config_path)) if v is not None]
    if extra:
        raise ConfigError(f"{extra[0]} goes with --pair")


def _adapter(latency_timer_ms: int, clock: str):
    """The U2D2 model of a wall-clock serve (crane_io.sim.adapter_timing), None without one."""
    if clock != "wall" or latency_timer_ms == 0:
        return None
    from crane_io.sim.adapter_timing import AdapterTiming

    return AdapterTiming(latency_timer_s=latency_timer_ms / 1000)


def _adapter_sentence(adapter) -> str:
    if adapter is None:
        return ""
    return (f" Replies reach the link as through a U2D2 with a {adapter.latency_timer_s * 1000:g} ms "
            "latency timer.")


def _write_truth(plant, truth_path) -> None:
    if truth_path is not None:
        from ..sim_arms import write_plant_truth

        write_plant_truth(plant, truth_path)


def _announce(server, arm: str, plant: str, clock: str, hand: bool):
    import os

    from crane_io.cli_support import shown
    from crane_io.dynamixel.link_registry import SimLink, announce, registry_problem

    entry = announce(SimLink(link=os.path.abspath(server.link), pty=server.slave_path, arm=arm, plant=plant,
                             clock=clock, hand=hand, pid=os.getpid()))
    problem = registry_problem() if entry is None else None
    if problem is not None:  # serving goes on; `crane-collect ports` will not list the link
        click.echo(f"Warning: {shown(problem)}; the link is not announced", err=True)
    return entry


def _wait(stop: threading.Event, errors, status) -> None:
    """Until Ctrl+C, SIGTERM or a server thread's error; the status line on a terminal."""
    live = sys.stdout.isatty()
    try:
        while not stop.wait(1.0):
            error = errors()
            if error is not None:
                raise HardwareError(f"the simulator stopped unexpectedly: {error}")
            if live:
                click.echo("\r" + status(), nl=False)
    except KeyboardInterrupt:
        pass


def _serve_one(stop, link, arm, plant_name, clock, period_s, seed, fast_sync_read, return_delay, truth_path,
               offsets=None, adapter=None, faults=None, supply_voltage=None):
    from crane_io.dynamixel.link_registry import withdraw
    from crane_io.sim.chain import SimulatedChain
    from crane_io.sim.transport import PtyServer
    from crane_io.sim.wiring_faults import apply_wiring_faults

    from ..sim_arms import default_plant, make_plant
    from ..sim_lab import OffsetPlant

    plant = make_plant(plant_name, seed, arm, supply_voltage=supply_voltage)
    plant_name = plant_name or default_plant(arm)
    _write_truth(plant, truth_path)
    kind = type(plant).__name__ + (", encoders off" if offsets is not None else "")
    if offsets is not None:
        plant = OffsetPlant(plant, offsets)
    if faults is not None and faults.any:
        kind += f", {faults.describe()}"
    plant, models = apply_wiring_faults(plant, arm, faults)
    chain = SimulatedChain(plant, models, clock=clock, period_s=period_s, fast_sync_read=fast_sync_read,
                           return_delay_time=return_delay)
    server = PtyServer(chain, link, adapter=adapter)
    entry = None
    try:
        server.start()
        entry = _announce(server, "arm", plant_name, clock, hand=False)
        click.echo(f"Simulated CRANE-X7 ({kind}, {clock} clock, bilateral joints "
                   f"{','.join(arm.bilateral_joints)}) on {link} -> {server.slave_path}")
        click.echo(f"Point the SDK or Dynamixel Wizard 2.0 at {link} (Protocol 2.0, 3,000,000 bps, "
                   f"IDs 2-9), e.g. `crane-collect check --port {link}`.{_adapter_sentence(adapter)} "
                   "Ctrl+C stops.")
        _wait(stop, lambda: server.error, lambda: status_line(chain))
    finally:
        server.stop()
        withdraw(entry)
    s = chain.stats
    click.echo(f"\nStopped after {chain.time:.2f} s of simulated time: {s.packets_received} packets, "
               f"{s.replies_sent} replies, {s.crc_errors} CRC errors. Removed {link}.")
    if clock == "wall":
        click.echo(slip_summary(chain))


def _serve_pair(stop, leader_link, follower_link, hand_on, task, hand_delay_s, config, arm, plant_name,
                clock, period_s, seed, fast_sync_read, return_delay, truth_path, offsets, adapter=None,
                supply_voltage=None):
    from crane_io.dynamixel.link_registry import withdraw

    from ..config import PAPER_JOINTS
    from ..sim_lab import SimulatedLab

    lab = SimulatedLab.build(plant=plant_name, seed=seed, hand_on=hand_on, clock=clock, period_s=period_s,
                             config=config, task=task, hand_delay_s=hand_delay_s, arm=arm,
                             fast_sync_read=fast_sync_read, return_delay_time=return_delay,
                             encoder_offsets=offsets, supply_voltage=supply_voltage)
    paper = tuple(arm.bilateral_joints) == PAPER_JOINTS
    joints = "" if paper else f" --joints {','.join(arm.bilateral_joints)}"
    _write_truth(lab.plants["follower"], truth_path)  # (a HandOnPlant passes write_truth through)
    links = {"leader": leader_link, "follower": follower_link}
    entries = []
    try:
        lab.serve(links, adapter=adapter)
        for name, server in lab.servers.items():
            entries.append(_announce(server, name, lab.plant_name, clock, hand=name == hand_on))
        for name, server in lab.servers.items():
            click.echo(f"Simulated {name} ({lab.plant_name}, {clock} clock) on {links[name]} -> "
                       f"{server.slave_path}")
        click.echo(f"The simulated hand is on the {hand_on}; it takes hold {hand_delay_s:g} s after the "
                   f"arm's torque comes on. Record with `crane-collect run --leader-port {leader_link} "
                   f"--follower-port {follower_link}{joints} --skip-selftest -o SESSION.h5`"
                   + (" --hand-on follower" if hand_on == "follower" else "") + "."
                   + _adapter_sentence(adapter) + " Ctrl+C stops.")
        _wait(stop, lab.error, lambda: pair_status_line(lab))
    finally:
        lab.stop()
        for entry in entries:
            withdraw(entry)
    click.echo("")
    for name, chain in lab.chains.items():
        s = chain.stats
        click.echo(f"{name}: stopped after {chain.time:.2f} s of simulated time, {s.packets_received} "
                   f"packets, {s.replies_sent} replies, {s.crc_errors} CRC errors. Removed {links[name]}.")
    click.echo(f"The hand took hold {lab.hand.engagements} time(s).")
    if clock == "wall":
        for name, chain in lab.chains.items():
            click.echo(f"{name}: " + slip_summary(chain))
