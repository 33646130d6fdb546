"""Where the campaign's experiments run: the in-process virtual tester in lock-step, or real instruments.

The campaign drives every experiment through battlab's run engine (:class:`battlab.lab.engine.RunEngine`: the
same state machine, CCCV regulation, end conditions, safety checks and HDF5 run log as ``battlab run``).

On the virtual tester the engine talks to the simulated instruments of :mod:`drivers.virtual` (the DFN cell of
the hidden truth, the physical measurement noise, the chamber) in-process and in **lock-step**: the clock is
virtual time that advances only when the engine sleeps, and sleeping steps the instruments to the new time. The
clock therefore never runs ahead of the physics, so no sample is late or missed by construction, and the tester
runs as fast as the model computes (a C/20 cycle in seconds rather than the 2.5 minutes of the served tester at
1000x, which also loses samples when the host is busy). The served, free-running virtual tester
(``battlab virtual-tester serve``) stays the one for watchdog and fault tests; a lock-step mode of
``drivers.virtual`` itself would replace the adapters here.

Real instruments (``--cycler URL --chamber URL``) go through :func:`battlab.lab.session.start_run` unchanged.
"""

from __future__ import annotations

import logging
import math
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from battlab.cell import Cell
from drivers.clock import Clock
from drivers.defaults import ChamberDefaults, CyclerDefaults
from drivers.errors import InstrumentFault, NotSupported
from drivers.interfaces import CyclerCapabilities, Measurement, ProtectionState
from drivers.virtual.instruments import (
    INH,
    LIM_POS,
    MODEL,
    OT,
    OV,
    PROT,
    VLIM_NEG,
    WDOG,
    ChamberConfig,
    ExecutionError,
    SimulatedChamber,
    SimulatedCycler,
)
from drivers.virtual.noise import NoiseModel as InstrumentNoise
from protocols.errors import InputError

log = logging.getLogger("battlab.campaign")

_CAUSES = {OV: "OV", OT: "OT", LIM_POS: "VLIM+", INH: "INH", PROT: "PROT", VLIM_NEG: "VLIM-", WDOG: "WDOG"}
_CAUSES[MODEL] = "MODEL"
#: a reading right after the current changed is taken this long after it [s] (the right limit of the voltage)
SETTLE_S = 1e-3


class LockstepClock:
    """Virtual time [s] that moves only in :meth:`sleep`, which steps the lab's instruments to the new time.

    ``speed`` is reported as infinite-like (1e9) so that the engine waits for a sample in one sleep and its
    real-time budgets (retries, heartbeats) never trigger on virtual time."""

    speed = 1e9

    def __init__(self, lab: LockstepLab) -> None:
        self._lab = lab

    def now(self) -> float:
        return self._lab.t

    def sleep(self, dt_s: float) -> None:
        if dt_s > 0:
            self._lab.advance(self._lab.t + dt_s)

    def sleep_until(self, t_s: float) -> None:
        self.sleep(t_s - self.now())


class LockstepLab:
    """A simulated cycler on a cell and a simulated chamber, advanced together by :class:`LockstepClock`."""

    def __init__(
        self,
        cell: Cell,
        *,
        soc0: float,
        ambient_degC: float,
        seed: int,
        max_step_s: float = 1.0,
        noise: InstrumentNoise | None = None,
        t0_s: float = 0.0,
    ) -> None:
        from battlab.lab.virtual import make_cell_physics

        rng = np.random.default_rng(seed)
        self.t = t0_s
        self.chamber_sim = SimulatedChamber(
            ChamberConfig(T0_K=ambient_degC + 273.15), rng=np.random.default_rng(rng.integers(2**63)), t0_s=t0_s
        )
        self.cycler_sim = SimulatedCycler(
            make_cell_physics(cell),
            noise=noise or InstrumentNoise(),
            rng=np.random.default_rng(rng.integers(2**63)),
            max_step_s=max_step_s,
            t0_s=t0_s,
        )
        self.cycler_sim.reset_cell(soc0, self.chamber_sim.T_air_K)
        self.clock = LockstepClock(self)
        self.cycler = LockstepCycler(self)
        self.chamber = LockstepChamber(self)

    def advance(self, t: float) -> None:
        if t <= self.t:
            return
        T_start = self.chamber_sim.T_air_K
        self.chamber_sim.advance(t)
        self.cycler_sim.advance(t, 0.5 * (T_start + self.chamber_sim.T_air_K))
        if self.chamber_sim.alarm_codes:
            self.cycler_sim.inhibit(f"chamber alarm {self.chamber_sim.alarm_codes}")
        self.t = t

    def stop(self) -> None:
        """Nothing runs in the background."""


class LockstepCycler(CyclerDefaults):
    """:class:`drivers.interfaces.Cycler` on the simulated cycler, called in-process (no link: no retries, no link
    timeout, nothing to resync)."""

    name = "virtual cycler (lock-step)"
    capabilities = CyclerCapabilities(
        clock=True,
        timestamps=True,
        low_voltage_cutoff=True,
        temperature_limit=True,
        watchdog=True,
        clear_protection=True,
    )

    def __init__(self, lab: LockstepLab) -> None:
        self._lab = lab
        self._c = lab.cycler_sim

    def _io(self) -> SimulatedCycler:
        self._c.note_io(self._lab.t)
        return self._c

    def identify(self) -> str:
        return "battlab,virtual cycler (lock-step, in-process),0,1"

    def clock(self) -> Clock:
        return self._lab.clock

    def initialize(self) -> None:
        c = self._io()
        c.set_output(False)
        c.set_current(0.0)
        c.clear_protection()
        c.errors.clear()

    def set_current(self, current_A: float) -> None:
        try:
            self._io().set_current(float(current_A))
        except ExecutionError as exc:
            raise InputError(f"{self.name}: current {current_A} A refused ({exc.message})") from None

    def output(self, on: bool) -> None:
        try:
            self._io().set_output(bool(on))
        except ExecutionError as exc:
            raise InstrumentFault(self.name, f"output on refused ({exc.message})") from None

    def measure(self) -> Measurement:
        """A reading now; right after the current changed, a reading :data:`SETTLE_S` later (the right limit).

        The sample-time jitter error (jitter × dV/dt) is taken on the slope of the last physics step; after a settle
        that step is the jump itself (1 ms), whose slope is no slope of the voltage between samples, so the reading
        then carries the white, current-dependent and quantisation noise only."""
        c = self._io()
        flowing = c.current if c.output_on else 0.0
        if flowing == c.i_true:
            v = c.measure_voltage()
        else:
            self._lab.advance(self._lab.t + SETTLE_S)
            v = c.noise.voltage(c.v_true, c.i_true, 0.0, c.rng, max_slew_error_V=0.0)
        return Measurement(v, c.measure_current(), c.measure_temperature_K(), self._lab.t)

    def set_voltage_limits(self, low_V: float | None, high_V: float) -> None:
        c = self._io()
        c.voltage_limit_low, c.voltage_limit = low_V, float(high_V)
        c.ovp = float(high_V) + 0.3

    def set_current_limits(self, charge_A: float, discharge_A: float) -> None:
        c = self._io()
        c.current_limit, c.current_limit_neg = float(charge_A), -float(discharge_A)

    def set_temperature_limit(self, T_max_K: float) -> None:
        self._io().temperature_protection_K = float(T_max_K)

    def protection(self) -> ProtectionState:
        c = self._io()
        causes = frozenset(name for bit, name in _CAUSES.items() if c.status >> bit & 1 and bit != PROT)
        return ProtectionState(c.tripped, causes, c.status)

    def clear_protection(self) -> None:
        self._io().clear_protection()

    def errors(self) -> list[tuple[int, str]]:
        c = self._io()
        out = []
        while c.errors:
            out.append(c.pop_error())
        return out

    def set_watchdog(self, timeout_s: float | None) -> None:
        c = self._io()
        c.watchdog_enabled = timeout_s is not None
        if timeout_s is not None:
            c.watchdog_delay_s = int(math.ceil(timeout_s))

    def safe_off(self) -> bool:
        self._io().set_output(False)
        return True

    def close(self) -> None:
        """Nothing to release."""


class LockstepChamber(ChamberDefaults):
    """:class:`drivers.interfaces.Chamber` on the simulated chamber, called in-process."""

    name = "virtual chamber (lock-step)"

    def __init__(self, lab: LockstepLab) -> None:
        self._lab = lab
        self._ch = lab.chamber_sim

    def identify(self) -> str:
        return "battlab virtual chamber (lock-step, in-process)"

    def set_point(self, T_degC: float) -> None:
        try:
            self._ch.set_point_C(float(T_degC))
        except ExecutionError as exc:
            raise InputError(f"{self.name}: {exc.message}") from None
        self._ch.running = True

    def read(self) -> float:
        if self._ch.alarm_codes:
            raise InstrumentFault(self.name, f"alarm {self._ch.alarm_codes}")
        return self._ch.read_C()

    def alarms(self) -> list[str]:
        return [f"alarm {c}" for c in self._ch.alarm_codes]

    def wait_stable(
        self, tol: float, timeout: float, clock: Any, *, hold_s: float = 60.0, poll_s: float = 5.0
    ) -> float:
        from drivers.chambers.base import wait_stable

        return wait_stable(self, self._ch.sp_K - 273.15, tol, timeout, clock, hold_s=hold_s, poll_s=poll_s)

    def close(self) -> None:
        """Nothing to release."""


@dataclass(frozen=True)
class Tester:
    """Where plans run: ``virtual`` (in-process, lock-step, the ``truth`` cell hidden inside) or instrument URLs.

    ``max_step_s``: the virtual cell's longest physics step [s] (the engine samples at least this often anyway).
    """

    cycler_url: str = "virtual"
    chamber_url: str = "virtual"
    truth: str = "nca18650-true"
    seed: int = 0
    limits_path: str | None = None
    max_step_s: float = 10.0

    @property
    def virtual(self) -> bool:
        return self.cycler_url == "virtual" and self.chamber_url == "virtual"

    def preflight(self, timeout_s: float = 5.0) -> None:
        """Before anything runs on real instruments: the limits file loads, and both instruments answer their
        identification query at their URLs; raises InputError naming which one and why (nothing to check for the
        in-process virtual tester)."""
        if self.virtual:
            return
        from battlab.lab.bench import RunSettings, dialect_name, resolve_limits
        from drivers.factory import open_chamber, open_cycler
        from drivers.scpi.dialects import dialect_by_name

        settings = RunSettings(self.cycler_url, self.chamber_url, limits_path=self.limits_path)
        limits = resolve_limits(settings)
        dialect = dialect_by_name(dialect_name(settings, limits))
        for role, url, opener in (
            ("cycler", self.cycler_url, lambda u: open_cycler(u, dialect=dialect, timeout_s=timeout_s, retries=0)),
            ("chamber", self.chamber_url, lambda u: open_chamber(u, timeout_s=timeout_s, retries=0)),
        ):
            try:
                dev = opener(url)
            except (InputError, NotSupported):  # a user's mistake, or an instrument without what was asked
                raise
            except Exception as exc:
                why = " ".join(str(exc).split()) or type(exc).__name__
                raise InputError(f"{role} unreachable: {why if url in why else f'{url}: {why}'}") from exc
            try:
                dev.identify()
            except Exception as exc:
                raise InputError(f"{role} {url}: no answer to its identification query ({exc})") from exc
            finally:
                dev.close()

    def describe(self) -> dict[str, Any]:
        if self.virtual:
            return {"kind": "virtual (in-process, lock-step)", "truth": self.truth, "seed": self.seed}
        return {"kind": "instruments", "cycler": self.cycler_url, "chamber": self.chamber_url}


@dataclass
class RunOutcome:
    """A finished run: status (``completed`` | ``aborted`` | ``stopped``), reason, log, the engine's stats,
    safety events, and the test time [h]."""

    status: str
    reason: str | None
    log_path: Path
    stats: dict[str, Any] = field(default_factory=dict)
    shutdown: dict[str, Any] | None = None
    hours: float = 0.0

    def health(self) -> dict[str, Any]:
        """Run-log health: samples, late samples, gaps (missed samples) and safety events."""
        s = self.stats
        return {
            "log": self.log_path.name,
            "status": self.status,
            "reason": self.reason,
            "samples": int(s.get("samples", 0)),
            "late_samples": int(s.get("late_samples", 0)),
            "gaps": int(s.get("gaps", 0)),
            "max_gap_s": float(s.get("max_gap_s", 0.0)),
            "retries": int(s.get("retries", 0)),
            "safety_events": [] if self.status == "completed" else [self.reason or self.status],
            "hours": self.hours,
        }


class VirtualBench:
    """One virtual cell kept across the campaign's runs (its state of charge and temperature carry over from run
    to run, as on a real bench), created on first use."""

    def __init__(self, tester: Tester, ambient_degC: float) -> None:
        self.tester = tester
        self.ambient_degC = ambient_degC
        self.lab: LockstepLab | None = None

    def restart_if_failed(self) -> str | None:
        """After the virtual cell's model failed (its output stays latched off, as the served tester's does), a new
        virtual cell at the same SOC estimate replaces it; returns a note saying so, else None."""
        if self.lab is None or not self.lab.cycler_sim.model_failed:
            return None
        t = self.lab.t
        self.lab = None
        self.get(0.5, t0_s=t)
        return f"the virtual cell's model failed; a new virtual cell (SOC 0.5) replaced it at t = {t:.0f} s"

    def get(self, soc0: float, t0_s: float = 0.0) -> LockstepLab:
        if self.lab is None:
            self.lab = LockstepLab(
                Cell.load(self.tester.truth),
                soc0=soc0,
                ambient_degC=self.ambient_degC,
                seed=self.tester.seed + int(t0_s),
                max_step_s=self.tester.max_step_s,
                t0_s=t0_s,
            )
        return self.lab


def run_plan(
    plan: Any,
    tester: Tester,
    log_path: str | Path,
    *,
    cell: str,
    bench: VirtualBench | None = None,
    soc0: float = 0.5,
) -> RunOutcome:
    """Run ``plan`` (a :class:`battlab.io.plan.Plan`) on ``tester``, logging to ``log_path`` (a new file).

    ``cell``: the cell the plan is checked against (the start cell: the limits are the cell's window). On the
    virtual tester ``bench`` keeps the cell's state between runs (``soc0``: the virtual cell's state when the
    bench is first used)."""
    log_path = Path(log_path).resolve()
    if log_path.exists():
        raise InputError(f"{log_path}: already exists; a run log is never overwritten")
    if not tester.virtual:
        from battlab.lab.session import RunSettings, start_run

        settings = RunSettings(tester.cycler_url, tester.chamber_url, cell=cell, limits_path=tester.limits_path)
        r = start_run(plan, settings, log_path, display=False)
        stats = dict(r.summary.get("stats") or {})
        return RunOutcome(r.status, r.reason, log_path, stats, r.summary.get("shutdown"), _hours(log_path))
    return _run_virtual(plan, tester, log_path, cell, bench or VirtualBench(tester, plan.options.ambient_degC), soc0)


def _hours(log_path: Path) -> float:
    from battlab.campaign.data import load

    try:
        d = load(log_path)
    except Exception:  # a log without rows: no time passed
        return 0.0
    return float(d.t[-1] - d.t[0]) / 3600.0 if len(d) else 0.0


def _run_virtual(
    plan: Any, tester: Tester, log_path: Path, cell_spec: str, bench: VirtualBench, soc0: float
) -> RunOutcome:
    from battlab.io.logs import run_meta
    from battlab.lab import logfile
    from battlab.lab.documents import LogSink
    from battlab.lab.engine import EngineConfig, RunEngine
    from battlab.lab.limits import VIRTUAL_LIMITS, CellWindow
    from battlab.lab.preflight import check_plan

    cell = Cell.load(cell_spec)
    limits = VIRTUAL_LIMITS
    envelope = check_plan(plan, CellWindow.of(cell), limits)
    lab = bench.get(soc0)
    meta = run_meta(
        cell=cell,
        plan=plan.to_dict(),
        instruments={"cycler": {"url": "virtual", "mode": "lock-step"}, "chamber": {"url": "virtual"}},
        run_id=None,
        settings={"tester": tester.describe()},
        soc0=None,
        sample_period_s=plan.options.sample_period_s,
        resumes=[],
        interrupted=[],
    )
    config = EngineConfig(
        envelope=envelope,
        clock=lab.clock,
        meta={**meta, "limits": limits.to_dict(), "clock_speed": "lock-step"},
        watchdog_s=plan.options.watchdog_s or max(60.0, 3 * plan.options.sample_period_s),
        safe_set_point_degC=limits.chamber.safe_set_point,
        soc_from_voltage=cell.soc_from_voltage,
    )
    sink = LogSink(lambda columns, m: logfile.create(log_path, columns, m), plan.options.flush_s)
    engine = RunEngine(plan, lab.cycler, lab.chamber, config, [sink])
    state = engine.run()
    stats = engine.stats.to_dict()
    note = bench.restart_if_failed()
    if note:
        stats.setdefault("notes", []).append(note)
    shutdown = engine.shutdown.to_dict() if engine.shutdown else None
    return RunOutcome(state.value, engine.reason, log_path, stats, shutdown, _hours(log_path))
