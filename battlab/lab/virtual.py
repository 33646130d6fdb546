"""The virtual tester's cell: battlab's DFN–thermal model behind the drivers' ``CellPhysics`` protocol."""

from __future__ import annotations

import contextlib
import json
import signal
import subprocess
import sys
from collections.abc import Iterator

from battlab.cell import Cell
from battlab.model.live import LiveCell
from drivers.virtual.physics import CellLimits


class DFNPhysics:
    """``drivers.virtual.physics.CellPhysics`` backed by :class:`battlab.model.live.LiveCell`.

    Current positive = charge, temperatures in K. The limits come from the cell: V_min/V_max, 5C each way
    (the library's bound), T_max.
    """

    def __init__(self, cell: Cell, *, isothermal: bool = False) -> None:
        self.cell = cell
        self._isothermal = isothermal
        self._live: LiveCell | None = None
        c5 = 5.0 * float(cell["Q_nom"])
        self._limits = CellLimits(float(cell["V_min"]), float(cell["V_max"]), c5, c5, float(cell["T_max"]))

    @property
    def limits(self) -> CellLimits:
        return self._limits

    @property
    def open_circuit_current_A(self) -> float:
        """The current [A] the cell model takes as input when none flows through the cell (the cycler's output
        off): the model's input is the logged current, and a cell whose current sensor reads an offset carries
        I_cell = (I_log − offset)/(1 + gain), so an open circuit is I_log = offset (else 0). Stepping it at 0 A would
        drain a disconnected cell by the offset (a 15 mA offset: 55 mV in 10 h)."""
        if "current_sensor" in self.cell.extensions:
            return float(self.cell.value("current_sensor.offset"))
        return 0.0

    @property
    def voltage(self) -> float:
        if self._live is None:
            self.reset(1.0, float(self.cell["T_ref"]))
        return self._live.voltage

    def reset(self, soc0: float, T_amb_K: float) -> None:
        if self._live is None:
            self._live = LiveCell(self.cell, soc0, T_amb_K, isothermal=self._isothermal)
        else:
            self._live.reset(soc0, T_amb_K)

    def step(self, current_A: float, dt_s: float, ambient_K: float) -> tuple[float, float]:
        if self._live is None:
            self.reset(1.0, ambient_K)
        return self._live.step(current_A, dt_s, ambient_K)


def make_cell_physics(cell: str | Cell) -> DFNPhysics:
    """The DFN-backed physics of a built-in cell name, a BPX/TOML cell file, or a :class:`Cell`."""
    return DFNPhysics(cell if isinstance(cell, Cell) else Cell.load(cell))


@contextlib.contextmanager
def served(*options: str) -> Iterator[dict[str, str]]:
    """``battlab virtual-tester serve --json OPTIONS…`` in another process, on free ports unless ``options`` name
    them; yields its URLs (``{"cycler", "chamber", "espec", "physics", …}``) and stops it with Ctrl-C (SIGINT)
    on exit, killing it if it does not stop within 10 s."""
    ports = [a for a in ("--cycler-port", "--chamber-port", "--espec-port") if a not in options]
    cmd = [
        sys.executable,
        "-c",
        "from battlab.cli import main; main()",
        "virtual-tester",
        "serve",
        "--json",
        *(x for a in ports for x in (a, "0")),
        *options,
    ]
    proc = subprocess.Popen(cmd, stdout=subprocess.PIPE, text=True)
    try:
        assert proc.stdout is not None
        yield json.loads(proc.stdout.readline())
    finally:
        proc.send_signal(signal.SIGINT)
        try:
            proc.wait(10)
        except subprocess.TimeoutExpired:
            proc.kill()
            proc.wait(5)
