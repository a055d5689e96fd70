"""`crane-collect sim-serve`: serve a simulated CRANE-X7 on a pseudo-terminal until stopped.

Any Dynamixel tool that opens a serial port (the SDK, Dynamixel Wizard 2.0, `crane-collect run`
with `--port`) can then talk Protocol 2.0 to eight emulated servos (IDs 2..9, 3 Mbps) at the link.
"""

from __future__ import annotations

import importlib.util
import signal
import sys
import threading

import click

from crane_io.errors import ConfigError, HardwareError, cli_errors


def status_line(chain) -> str:
    """The live status: simulated time, traffic, and how much simulated time slipped so far."""
    s = chain.stats
    line = (f"sim time {chain.time:9.2f} s  packets {s.packets_received:9d}  replies {s.replies_sent:9d}  "
            f"CRC errors {s.crc_errors:5d}")
    if chain.clock == "wall":
        line += f"  slipped {s.slip_s:7.2f} s ({s.slips} times)"
    return line


def slip_summary(chain) -> str:
    """One sentence on simulated time that was skipped because the plant could not keep up."""
    s = chain.stats
    if not s.slips:
        return "Simulated time never slipped: the plant kept up with real time."
    times = "once" if s.slips == 1 else f"{s.slips} times"
    return (f"Simulated time slipped {times}, {s.slip_s:.2f} s in all (largest {s.max_slip_s:.3f} s): the "
            "plant could not keep up with real time (a busy or slow machine), so it skipped ahead "
            "instead of holding up the replies.")


def _has_arm_plant() -> bool:
    return importlib.util.find_spec("crane_io.arm_plant") is not None and \
        importlib.util.find_spec("crane_io.plant_config") is not None


def build_plant(name: str | None, seed: int, arm):
    """The plant for `--plant`: "simple" (SimplePlant) or a preset / TOML path of the arm plant."""
    from crane_io.sim.simple_plant import SimplePlant

    if name is None:
        name = "crane-x7" if _has_arm_plant() else "simple"
    if name == "simple":
        return SimplePlant.from_arm(arm)
    if not _has_arm_plant():
        raise ConfigError(f"plant {name!r} needs crane_io.arm_plant, which is not available; "
                          "use --plant simple")
    from crane_io import arm_plant, plant_config

    return arm_plant.ArmPlant(plant_config.load_plant_config(name), seed=seed)


@click.command("sim-serve")
@click.option("--link", "link", required=True, type=click.Path(dir_okay=False),
              help="Path of the symlink to the pseudo-terminal, e.g. /tmp/crane_x7.")
@click.option("--plant", "plant_name", default=None, metavar="PRESET_OR_TOML",
              help="Physics behind the servos: 'simple' (independent joints) or an arm-plant preset "
                   "or TOML file. Default: the arm plant's 'crane-x7' preset when available, else 'simple'.")
@click.option("--clock", type=click.Choice(["wall", "lockstep"]), default="wall", show_default=True,
              help="'wall': physics follows real time. 'lockstep': one control period per Goal "
                   "Current sync write.")
@click.option("--period", "period_s", type=float, default=0.002, show_default=True,
              help="Lockstep control period in seconds.")
@click.option("--seed", type=int, default=0, show_default=True, help="Seed of the plant's sensor noise.")
@click.option("--no-fast-sync-read", is_flag=True, help="Servos ignore Fast Sync Read (old firmware).")
@click.option("--return-delay", type=click.IntRange(0, 254), default=None,
              help="Return Delay Time register of every servo (2 us/LSB). Default: factory 250.")
@click.option("--truth", "truth_path", type=click.Path(dir_okay=False), default=None, metavar="JSON",
              help="Also write the arm plant's hidden truth (effects, parameters, seed) to this file. "
                   "Nothing else ever records it.")
@cli_errors
def sim_serve(link, plant_name, clock, period_s, seed, no_fast_sync_read, return_delay, truth_path):
    """Serve a simulated CRANE-X7 on a pseudo-terminal linked at LINK until Ctrl+C or SIGTERM."""
    from crane_io.description import default_arm
    from crane_io.sim.chain import SimulatedChain
    from crane_io.sim.transport import PtyServer

    if not period_s > 0:
        raise ConfigError(f"--period must be positive, got {period_s}")
    arm = default_arm()
    plant = build_plant(plant_name, seed, arm)
    if truth_path is not None:
        if not hasattr(plant, "write_truth"):
            raise ConfigError("--truth needs an arm plant (a preset or TOML file), not --plant simple")
        try:
            plant.write_truth(truth_path)
        except OSError as exc:
            raise ConfigError(f"cannot write the truth file {truth_path}: {exc.strerror or exc}") from None
    chain = SimulatedChain.for_arm(arm, plant, clock=clock, period_s=period_s,
                                   fast_sync_read=not no_fast_sync_read, return_delay_time=return_delay)
    stop = threading.Event()
    previous = signal.signal(signal.SIGTERM, lambda *_: stop.set())
    server = PtyServer(chain, link)
    try:
        server.start()
        click.echo(f"Simulated CRANE-X7 ({type(plant).__name__}, {clock} clock) on {link} -> "
                   f"{server.slave_path}")
        click.echo(f"Point the SDK or Dynamixel Wizard 2.0 at {link} (Protocol 2.0, 3,000,000 bps, "
                   f"IDs 2-9), e.g. `crane-collect check --port {link}`. Ctrl+C stops.")
        live = sys.stdout.isatty()
        while not stop.wait(1.0):
            if server.error is not None:
                raise HardwareError(f"the simulator stopped unexpectedly: {server.error}")
            if live:
                click.echo("\r" + status_line(chain), nl=False)
    except KeyboardInterrupt:
        pass
    finally:
        server.stop()
        signal.signal(signal.SIGTERM, previous)
    s = chain.stats
    click.echo(f"\nStopped after {chain.time:.2f} s of simulated time: {s.packets_received} packets, "
               f"{s.replies_sent} replies, {s.crc_errors} CRC errors. Removed {link}.")
    if clock == "wall":
        click.echo(slip_summary(chain))
