"""``battlab virtual-tester serve``: a real process serving on free loopback ports, stopped by Ctrl-C."""

from __future__ import annotations

import json
import signal
import socket
import subprocess
import sys
import types

import pytest
from click.testing import CliRunner

from battlab.cli.virtual_tester import STANDIN, load_cell_physics, virtual_tester
from drivers.chambers.espec import EspecP300
from drivers.chambers.watlow_f4t import WatlowF4T
from drivers.scpi.cycler import ScpiCycler
from drivers.virtual.physics import EquivalentCircuitCell


def test_help() -> None:
    result = CliRunner().invoke(virtual_tester, ["serve", "--help"])
    assert result.exit_code == 0
    for option in ("--cycler-port", "--chamber-port", "--espec-port", "--host", "--speed"):
        assert option in result.output


def test_serve_in_a_process_then_ctrl_c() -> None:
    """Started with SIGINT ignored, as from a background job of a script (and so inside a test suite started that
    way): Ctrl-C still stops it."""
    cmd = [
        "sh",
        "-c",
        'trap "" INT; exec "$@"',  # SIGINT ignored, and inherited through exec
        "sh",
        sys.executable,
        "-c",
        "from battlab.cli import main; main()",
        "virtual-tester",
        "serve",
        "--cycler-port",
        "0",
        "--chamber-port",
        "0",
        "--espec-port",
        "0",
        "--rtu-port",
        "0",
        "--speed",
        "1000",
        "--json",
        "--duration",
        "60",
    ]
    proc = subprocess.Popen(cmd, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    try:
        assert proc.stdout is not None
        urls = json.loads(proc.stdout.readline())
        assert urls["physics"] in (STANDIN, "battlab.lab.virtual.make_cell_physics('nca18650')")
        for key in ("cycler", "chamber", "chamber_rtu", "espec"):
            assert "127.0.0.1:" in urls[key]
        cyc = ScpiCycler.open(urls["cycler"])
        assert cyc.identify().startswith("battlab,")
        cyc.set_current(1.0)
        cyc.output(True)
        assert cyc.measure().current_A == pytest.approx(1.0, abs=0.01)
        f4t, espec = WatlowF4T.open(urls["chamber_rtu"]), EspecP300.open(urls["espec"])
        assert 20.0 < f4t.read() < 30.0 and 20.0 < espec.read() < 30.0
        for d in (cyc, f4t, espec):
            d.close()
        proc.send_signal(signal.SIGINT)
        # alone it stops within 0.2 s; when serve left Ctrl-C to Python's default, a lab started with SIGINT ignored
        # ran on to its --duration
        out, err = proc.communicate(timeout=30)
        assert proc.returncode == 0, err
        assert "stopped after" in out
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.wait(5)


def test_port_in_use_is_a_one_line_error() -> None:
    with socket.socket() as busy:
        busy.bind(("127.0.0.1", 0))
        busy.listen()
        port = busy.getsockname()[1]
        result = CliRunner().invoke(
            virtual_tester,
            [
                "serve",
                "--cycler-port",
                str(port),
                "--chamber-port",
                "0",
                "--espec-port",
                "0",
                "--duration",
                "0",
            ],
        )
    assert result.exit_code == 1
    assert "Error: cannot start the virtual tester on 127.0.0.1" in result.output
    assert len(result.output.strip().splitlines()) == 1


def test_physics_comes_from_battlab_when_it_provides_a_factory(monkeypatch: pytest.MonkeyPatch) -> None:
    fake = types.ModuleType("battlab.lab.virtual")
    made: list[str] = []

    def make_cell_physics(cell: str) -> EquivalentCircuitCell:
        made.append(cell)
        return EquivalentCircuitCell()

    fake.make_cell_physics = make_cell_physics  # type: ignore[attr-defined]
    monkeypatch.setitem(sys.modules, "battlab.lab.virtual", fake)
    physics, name = load_cell_physics("nca18650-true")
    assert made == ["nca18650-true"] and "make_cell_physics('nca18650-true')" in name
    monkeypatch.setitem(sys.modules, "battlab.lab.virtual", types.ModuleType("battlab.lab.virtual"))
    physics, name = load_cell_physics("nca18650")
    assert isinstance(physics, EquivalentCircuitCell) and name == STANDIN
