"""``battlab virtual-tester serve``: the virtual tester's instruments on loopback sockets.

It serves a SCPI cycler (battlab's virtual dialect, Keysight N7900-like), a Watlow F4T over Modbus TCP (and
optionally with RTU framing over TCP) and an Espec P-300 text protocol, all on one virtual clock that runs at
``--speed`` × real time by itself. Cell physics: ``battlab.lab.virtual.make_cell_physics(cell)`` when battlab
provides it (the DFN model); otherwise the drivers' stand-in equivalent-circuit cell, and the banner says so.
"""

from __future__ import annotations

import importlib
import importlib.util
import json
import signal
import sys
import time
from collections.abc import Callable
from typing import Any

import click

from battlab.cli.options import ambient_option, physics_option, soc0_option
from drivers.scpi.dialects import DIALECTS
from drivers.virtual.instruments import ChamberConfig
from drivers.virtual.lab import LOOPBACK, VirtualLab, VirtualLabConfig
from drivers.virtual.physics import CellPhysics, EquivalentCircuitCell
from protocols.errors import InputError

PHYSICS_MODULE = "battlab.lab.virtual"
STANDIN = "stand-in equivalent-circuit cell (battlab.lab.virtual.make_cell_physics not available)"


def load_cell_physics(cell: str) -> tuple[CellPhysics, str]:
    """battlab's physics for ``cell`` if ``battlab.lab.virtual.make_cell_physics`` exists, else the stand-in."""
    module = sys.modules.get(PHYSICS_MODULE)
    if module is None and importlib.util.find_spec(PHYSICS_MODULE) is not None:
        module = importlib.import_module(PHYSICS_MODULE)
    factory = getattr(module, "make_cell_physics", None) if module is not None else None
    if factory is None:
        return EquivalentCircuitCell(), STANDIN
    return factory(cell), f"{PHYSICS_MODULE}.make_cell_physics({cell!r})"


@click.group(name="virtual-tester")
def virtual_tester() -> None:
    """The virtual tester: simulated cycler and chambers serving the real wire protocols."""


@virtual_tester.command("serve")
@click.option(
    "--cycler-port",
    default=5025,
    show_default=True,
    type=click.IntRange(0, 65535),
    help="SCPI cycler (raw socket); 0 picks a free port.",
)
@click.option(
    "--chamber-port",
    default=5020,
    show_default=True,
    type=click.IntRange(0, 65535),
    help="Watlow F4T over Modbus TCP.",
)
@click.option(
    "--rtu-port",
    default=None,
    type=click.IntRange(0, 65535),
    help="Watlow F4T with Modbus RTU framing over TCP (off unless given).",
)
@click.option(
    "--espec-port",
    default=10001,
    show_default=True,
    type=click.IntRange(0, 65535),
    help="Espec P-300 text protocol.",
)
@click.option("--host", default=LOOPBACK, show_default=True, help="Interface to listen on (loopback by default).")
@click.option(
    "--speed",
    default=1000.0,
    show_default=True,
    type=click.FloatRange(min=1e-3, max=1e6),
    help="Virtual seconds per real second.",
)
@click.option("--cell", default="nca18650", show_default=True, help="Cell for battlab's physics factory.")
@physics_option(auto=True, default="auto")
@soc0_option("Initial SOC", default=0.5)
@ambient_option("Initial chamber air [degC]")
@click.option(
    "--air-tau",
    default=300.0,
    show_default=True,
    type=click.FloatRange(min=1e-3),
    help="Chamber air time constant / s.",
)
@click.option(
    "--dialect",
    default="battlab-virtual",
    show_default=True,
    type=click.Choice(sorted(DIALECTS)),
    help="SCPI dialect the cycler serves.",
)
@click.option("--seed", default=0, show_default=True, type=int, help="Noise seed.")
@click.option(
    "--duration",
    default=None,
    type=click.FloatRange(min=0.0),
    help="Stop after this many real seconds (default: until Ctrl-C).",
)
@click.option("--json", "as_json", is_flag=True, help="Print the URLs as one JSON line.")
def serve(
    cycler_port: int,
    chamber_port: int,
    rtu_port: int | None,
    espec_port: int,
    host: str,
    speed: float,
    cell: str,
    physics: str,
    soc0: float,
    ambient: float,
    air_tau: float,
    dialect: str,
    seed: int,
    duration: float | None,
    as_json: bool,
) -> None:
    """Serve the virtual instruments until Ctrl-C (or --duration)."""
    try:
        if physics == "standin":
            cell_physics, physics_name = EquivalentCircuitCell(), "stand-in (requested)"
        else:
            cell_physics, physics_name = load_cell_physics(cell)
            if physics == "dfn" and physics_name == STANDIN:
                raise InputError(f"--physics dfn: {STANDIN}; use --physics standin or auto")
    except InputError as exc:
        raise click.ClickException(str(exc)) from None
    T0 = ambient + 273.15
    config = VirtualLabConfig(
        speed=speed,
        host=host,
        cycler_port=cycler_port,
        modbus_port=chamber_port,
        modbus_rtu_port=rtu_port,
        espec_port=espec_port,
        dialect=DIALECTS[dialect],
        soc0=soc0,
        seed=seed,
        chamber=ChamberConfig(tau_s=air_tau, T0_K=T0),
    )
    if host != LOOPBACK:
        click.echo(f"warning: listening on {host}, not loopback: reachable from the network", err=True)
    lab = VirtualLab(cell_physics, config)
    try:
        lab.start()
    except (OSError, RuntimeError) as exc:
        raise click.ClickException(f"cannot start the virtual tester on {host}: {exc}") from None
    urls: dict[str, Any] = {"cycler": lab.cycler_url, "chamber": lab.chamber_url, "espec": lab.espec_url}
    if rtu_port is not None:
        urls["chamber_rtu"] = lab.rtu_url

    def announce() -> None:
        if as_json:
            click.echo(json.dumps({**urls, "speed": speed, "physics": physics_name, "dialect": dialect}))
        else:
            click.echo(f"virtual tester at {speed:g}x real time, physics: {physics_name}")
            for name, url in urls.items():
                click.echo(f"  {name:<12}{url}")
            click.echo("Ctrl-C stops it.")

    _serve_until_stopped(lab, duration, announce)
    click.echo(f"stopped after {lab.clock.now():.0f} virtual s")


def _serve_until_stopped(lab: VirtualLab, duration: float | None, announce: Callable[[], None]) -> None:
    """``announce()`` the lab, then serve it until Ctrl-C (SIGINT), SIGTERM or ``duration`` real seconds.

    Both signals are handled here, from before the announcement, not left to Python's default: a process started
    from a background job of a non-interactive shell inherits SIGINT ignored, and Python then installs no
    KeyboardInterrupt for it, so the served lab ran on through the Ctrl-C of whoever started it."""

    def on_stop(signum: int, frame: object) -> None:
        raise KeyboardInterrupt

    previous = {s: signal.signal(s, on_stop) for s in (signal.SIGINT, signal.SIGTERM)}
    deadline = None if duration is None else time.monotonic() + duration
    try:
        announce()
        while deadline is None or time.monotonic() < deadline:
            time.sleep(0.05 if deadline is None else max(0.0, min(0.05, deadline - time.monotonic())))
    except KeyboardInterrupt:
        pass
    finally:
        for s, h in previous.items():
            signal.signal(s, h)
        lab.stop()


__all__ = ["load_cell_physics", "serve", "virtual_tester"]
