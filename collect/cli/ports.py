"""`crane-collect ports`: the candidate U2D2 ports, their stable names and latency timers, and the links
of simulated arms that `crane-collect sim-serve` announced (crane_io.dynamixel.link_registry)."""

from __future__ import annotations

import click

from crane_io.cli_support import cli_errors, shown


@click.command("ports")
@click.option("--all", "all_ports", is_flag=True, help="Also list serial ports that are not FTDI FT232H.")
@cli_errors
def ports(all_ports):
    """List U2D2 adapters (FTDI 0403:6014: device, by-id path, USB serial, latency timer) and the links of
    running `crane-collect sim-serve` processes (marked simulated)."""
    from crane_io.dynamixel.link_registry import live_links, registry_problem
    from crane_io.dynamixel.ports import list_u2d2_ports

    found = list_u2d2_ports(all_ports=all_ports)
    problem = registry_problem()
    if problem is not None:
        click.echo(f"Warning: {shown(problem)}", err=True)
    links = live_links()
    if not found and not links:
        click.echo("no U2D2 found (is it plugged in? `lsusb` should show 0403:6014 Future Technology "
                   "Devices FT232H) and no simulated arm is being served (`crane-collect sim-serve`)")
        return
    for p in found:
        latency = "unknown" if p.latency_timer_ms is None else f"{p.latency_timer_ms} ms"
        click.echo(shown(f"{p.device}  serial {p.serial_number or '?'}  latency timer {latency}  "
                         f"{p.description}"))
        if p.by_id:
            click.echo(shown(f"    stable name: {p.by_id}"))
        if p.warning:
            click.echo(shown(f"    Warning: {p.warning}"))
    if not found:
        click.echo("no U2D2 found")
    for link in links:
        role = "" if link.arm == "arm" else f" {link.arm}"
        hand = ", hand on it" if link.hand else ""
        click.echo(shown(f"{link.link}  simulated{role} ({link.plant}, {link.clock} clock{hand}) -> "
                         f"{link.pty}  sim-serve pid {link.pid}"))
