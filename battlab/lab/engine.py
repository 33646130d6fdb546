"""The run engine: executes a plan's entries on a Cycler and a Chamber through an explicit state machine.

States (:class:`RunState`)::

    IDLE → PREFLIGHT → RUNNING → COMPLETED
               │          │
               └──────────┴──→ STOPPING → ABORTED | STOPPED

PREFLIGHT: identities (compared with the recorded ones on a resume), the instrument reset, the instrument's own
protections programmed from the envelope (voltage and current limits, over-temperature trip, I/O watchdog), the
cell's rest voltage within the envelope, the chamber free of alarms, at its set point and stable. RUNNING: every
entry in turn (:mod:`battlab.lab.steps`), one sample per tick on the instrument's clock, each sample emitted as an
event *before* it is checked, so the sample that breaches a limit is logged. STOPPING: :func:`safe_shutdown`, then
the stop document with the reason. Every failure ends in STOPPING: a breached limit, a protection trip, a chamber
alarm, a persistent link failure (after ``comm_retries`` retries with doubling back-off on top of the driver's own),
an instrument fault, Ctrl-C (a stop request, honoured at the next tick), or a bug.

Concurrency: one thread, blocking I/O (as the drivers). Times are the instrument's (``Measurement.t_s``) where it
has a clock, else the run clock's; ``Test Time / s`` counts from the run's origin ``t0_s``.
"""

from __future__ import annotations

import logging
import math
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from typing import Any, TypeVar

from battlab.lab.calls import InstrumentCalls
from battlab.lab.documents import (
    Gap,
    RunOrigin,
    RunStart,
    RunStop,
    StepRecords,
    StepStart,
    StepStop,
    Subscriber,
    emit,
)
from battlab.lab.limits import Envelope
from battlab.lab.logfile import COLUMNS
from battlab.lab.plan import Plan, PlanEntry
from battlab.lab.prepare import prepare_bench
from battlab.lab.run_state import TRANSITIONS, Abort, RunState, RunStats, StopRequested
from battlab.lab.safety import Shutdown, check_sample, safe_shutdown
from battlab.lab.steps import ResistanceEstimate, Sample, executor_for
from drivers.clock import Clock
from drivers.errors import InstrumentError
from drivers.interfaces import Chamber, Cycler
from protocols.errors import InputError

log = logging.getLogger("battlab.lab")
T = TypeVar("T")

#: a programmed current counts as changed above this (A); below, the instrument is not asked again
CURRENT_RESOLUTION_A = 1e-5
#: measured vs programmed current: beyond max(abs, rel × |I|) the output is suspected off
MISMATCH_A, MISMATCH_REL = 0.05, 0.05
#: consecutive samples further apart than this many sample periods are a gap in the data, marked in the log
GAP_PERIODS = 1.5
#: while waiting for the next sample longer than this / real s, the engine watches the instruments this often (the
#: cycler's protection state, the chamber's alarms): a dead link, a trip or an alarm stops the run within about a
#: second of it at 1x, not at the next sample or chamber read
HEARTBEAT_S = 0.2


@dataclass
class EngineConfig:
    """What the engine needs besides the plan and the instruments."""

    envelope: Envelope
    clock: Clock
    run_id: int | None = None
    meta: dict[str, Any] = field(default_factory=dict)
    start_entry: int = 0
    step_count0: int = 0
    row0: int = 0
    net_capacity0_Ah: float = 0.0
    #: resume: the run's time origin and the last logged test time (None: a new run)
    t0_s: float | None = None
    last_test_time_s: float | None = None
    expected_identities: dict[str, str] | None = None
    previous_steps: list[dict[str, Any]] = field(default_factory=list)
    watchdog_s: float = 60.0
    safe_set_point_degC: float | None = 25.0
    soc_from_voltage: Callable[[float], float] | None = None
    #: the plan's SOC and voltage window checked at the rest voltage [V] (an InputError: the reason to abort)
    window_check: Callable[[float], None] | None = None


class RunEngine:
    """Runs ``plan`` on ``cycler`` and ``chamber``, emitting documents to ``subscribers``."""

    def __init__(
        self,
        plan: Plan,
        cycler: Cycler,
        chamber: Chamber,
        config: EngineConfig,
        subscribers: Sequence[Subscriber] = (),
    ) -> None:
        self.plan = plan
        self.options = plan.options
        self.cycler = cycler
        self.chamber = chamber
        self.config = config
        self.env = config.envelope
        self.clock = config.clock
        self.records = StepRecords(config.previous_steps)
        self.subscribers = [*subscribers, self.records]
        self.entries = plan.entries()
        self.state = RunState.IDLE
        self.stats = RunStats()
        self.calls = InstrumentCalls(self.options.comm_retries, self.options.backoff_s, self.clock, self.stats)
        self.reason: str | None = None
        self.shutdown: Shutdown | None = None
        self.resistance = ResistanceEstimate()
        self.identities: dict[str, str] = {}
        self._stop_reason: str | None = None
        self._output_on = False
        self._i_cmd = 0.0
        self._last: Sample | None = None
        self._T_amb_C = math.nan
        self._t0 = 0.0
        #: a new run's origin is its first step's start, fixed at that step's first sample
        self._origin_pending = config.t0_s is None
        self._prev_test_time = config.last_test_time_s
        self._step_count = config.step_count0
        self._rows = config.row0
        self._q_Ah = config.net_capacity0_Ah
        self._rest_voltage = math.nan
        self._current: tuple[PlanEntry, int, Any, int] | None = None  # entry, step count, executor, first row
        self._current_announced = False
        self._pending_stop: tuple[PlanEntry, int, str | None, float | None, int] | None = None
        self._next_chamber = -math.inf
        self._next_protection = -math.inf
        self._mismatches = 0
        self._has_T = True
        self._t_applied: float | None = None
        #: samples carry the instrument's time stamps (else the run clock's time at reading)
        self._stamped = cycler.capabilities.timestamps

    # -- state machine -----------------------------------------------------------------------------------
    def _to(self, new: RunState) -> None:
        if new not in TRANSITIONS[self.state]:
            raise RuntimeError(f"run engine: illegal transition {self.state.value} -> {new.value}")
        log.info("run state: %s -> %s", self.state.value, new.value)
        self.state = new

    def request_stop(self, reason: str = "stopped by the operator (Ctrl-C)") -> None:
        """Ask for a safe stop at the next tick (signal-handler safe)."""
        if self._stop_reason is None:
            self._stop_reason = reason

    @property
    def stop_requested(self) -> bool:
        return self._stop_reason is not None

    def run(self) -> RunState:
        """Run to the end; returns the final state (COMPLETED, ABORTED or STOPPED). Never leaves the output on."""
        self._to(RunState.PREFLIGHT)
        status, reason, unreachable = RunState.COMPLETED, None, ()
        try:
            self._preflight()
            self._to(RunState.RUNNING)
            self._emit("start", RunStart(self.config.run_id, self._columns(), self._start_meta()))
            for entry in self.entries[self.config.start_entry :]:
                self._run_entry(entry)
            self._finish_ok()
            self._flush_pending_stop()
        except Abort as exc:
            status, reason = RunState.ABORTED, str(exc)
            if exc.device is not None:
                unreachable = (exc.device,)
        except (StopRequested, KeyboardInterrupt):
            status, reason = RunState.STOPPED, self._stop_reason or "stopped by the operator (Ctrl-C)"
        except Exception as exc:  # a bug must still end in a safe state
            log.exception("run engine: internal error")
            status, reason = RunState.ABORTED, f"internal: {type(exc).__name__}: {exc}"
        if status is RunState.COMPLETED:
            self._to(RunState.COMPLETED)
            self._emit("stop", RunStop("completed", None, self._summary()))
            return self.state
        self.reason = reason
        log.error("run %s: %s", status.value, reason)
        self._to(RunState.STOPPING)
        self.shutdown = safe_shutdown(
            self.cycler, self.chamber, self.config.safe_set_point_degC, clock=self.clock, unreachable=unreachable
        )
        self._output_on = False
        try:
            self._announce_current()
            if self._current is not None:
                entry, count, _, _ = self._current
                t_last = self._last.t if self._last else None
                self._record_step_stop(entry, count, status.value, reason, t_last, self._rows)
                self._current = None
        except Abort:
            log.exception("run engine: recording the interrupted step failed")
        self._to(status)
        self._emit("stop", RunStop(status.value, reason, self._summary()))
        return self.state

    def _emit(self, name: str, doc: Any) -> None:
        w0 = time.perf_counter()
        try:
            emit(self.subscribers, name, doc)
        except Exception as exc:
            if name == "stop":
                log.exception("run engine: a subscriber failed on stop")
                return
            raise Abort("internal", f"recording failed ({name}): {type(exc).__name__}: {exc}") from exc
        finally:
            self.stats.sink_wall_s += time.perf_counter() - w0

    # -- PREFLIGHT ---------------------------------------------------------------------------------------
    def _preflight(self) -> None:
        ready = prepare_bench(self.calls, self.cycler, self.chamber, self.env, self.options, self.config, self.clock)
        self.identities, self._has_T, self._rest_voltage = ready.identities, ready.has_T, ready.rest_voltage
        self._T_amb_C, self._t0 = ready.ambient_stable_degC, ready.t0
        self.stats.notes.extend(ready.notes)

    def _columns(self) -> tuple[str, ...]:
        return COLUMNS

    def _start_meta(self) -> dict[str, Any]:
        meta = dict(self.config.meta)
        soc = None
        if self.config.soc_from_voltage is not None:
            try:
                soc = self.config.soc_from_voltage(self._rest_voltage)
            except (InputError, ValueError) as exc:
                self.stats.notes.append(f"SOC from the rest voltage: {exc}")
        meta.update(
            t0_s=None if self._origin_pending else self._t0,
            identities=self.identities,
            envelope=self.env.to_dict(),
            rest_voltage_V=self._rest_voltage,
            soc_from_rest_voltage=soc,
            ambient_K=self.options.ambient_degC + 273.15,
            ambient_stable_degC=self._T_amb_C,
            watchdog_s=self.config.watchdog_s,
            start_entry=self.config.start_entry,
            n_entries=len(self.entries),
            surface_temperature_logged=self._has_T,
        )
        return meta

    # -- RUNNING -----------------------------------------------------------------------------------------
    def _program(self, current: float) -> float | None:
        """Program ``current``; returns the instrument time it took effect (if the instrument says)."""
        self.calls.call("set current", self.cycler.set_current, current)
        self._i_cmd = current
        self.stats.current_sets += 1
        self._t_applied = self.cycler.last_applied_t_s
        return self._t_applied

    def _run_entry(self, entry: PlanEntry) -> None:
        """Program the step's first current at once (the previous step's bookkeeping waits until this step's
        first sample is taken, so no current flows unplanned while records are written), then sample to its end."""
        o = self.options
        ex = executor_for(entry.step, o.sample_period_s, self.env, gain=o.cv_gain, resistance=self.resistance)
        self._step_count += 1
        count = self._step_count
        t_begin = self.clock.now()
        ex.begin(t_begin, self._last)
        self._current = (entry, count, ex, self._rows)
        self._current_announced = False
        t_applied = self._program(ex.command(t_begin))
        if not self._output_on:
            self.calls.call("output on", self.cycler.output, True)
            self._output_on = True
            t_applied = None  # the step starts when the output is on: at the first sample
        if t_applied is not None:
            ex.rebase(t_applied)
        first = True
        self._mismatches = 0
        t_sched = ex.t0
        loop0 = time.perf_counter()
        self.calls.timing = True
        try:
            while True:
                s = self._measure(t_sched)
                if first and t_applied is None:
                    ex.rebase(s.t)
                if self._origin_pending:  # test time 0 is the first step's start: the log starts with the step
                    self._t0 = ex.t0
                    self._origin_pending = False
                    self._emit("origin", RunOrigin(self._t0))
                self._record(s, entry, count, ex)
                if first:
                    first = False
                    self._announce_current()
                ended = ex.observe(s)
                if ended is not None:
                    break
                if self._stop_reason is not None:
                    raise StopRequested
                self._housekeeping(s.t)
                t_sched = ex.next_tick(s.t)
                self._wait_until(t_sched)
                if self._stop_reason is not None:
                    raise StopRequested
                i_new = ex.command(max(t_sched, self.clock.now()))
                if abs(i_new - self._i_cmd) > CURRENT_RESOLUTION_A:
                    self._program(i_new)
        finally:
            self.calls.timing = False
            self.stats.loop_wall_s += time.perf_counter() - loop0
        self._current = None
        self._pending_stop = (entry, count, ended, self._last.t if self._last else None, self._rows)

    def _wait_until(self, t_sched: float) -> None:
        """Sleep until ``t_sched`` (run clock); on a slow clock watch the instruments meanwhile
        (:meth:`_heartbeat`), evenly spaced at most ``HEARTBEAT_S`` real seconds apart and from the sample on
        either side, so that no stretch without I/O is longer. Returns early on a stop request."""
        step = HEARTBEAT_S * float(self.clock.speed)
        while True:
            remaining = t_sched - self.clock.now()
            intervals = math.ceil(remaining / step) if remaining > 0 else 0
            if intervals <= 1 or self._stop_reason is not None:
                break
            w0 = time.perf_counter()
            self.clock.sleep(remaining / intervals)
            self.stats.sleep_wall_s += time.perf_counter() - w0
            self._heartbeat()
        w0 = time.perf_counter()
        self.clock.sleep(t_sched - self.clock.now())
        self.stats.sleep_wall_s += time.perf_counter() - w0

    def _heartbeat(self) -> None:
        """Between samples: the cycler's protection state and the chamber's alarms (either link dead: an abort)."""
        self.stats.heartbeats += 1
        self._check_protection()
        alarms = self.calls.call("chamber alarms", self.chamber.alarms)
        if alarms:
            raise Abort("chamber", f"{self.chamber_name}: chamber alarm: {', '.join(alarms)}")

    @property
    def chamber_name(self) -> str:
        return self.chamber.name

    def _announce_current(self) -> None:
        """Close the previous step's record (completed) and open the current one's (documents in order)."""
        self._flush_pending_stop()
        if self._current is not None and not self._current_announced:
            entry, count, ex, row = self._current
            self._emit("step_start", StepStart(entry, count, ex.t0, row, entry.step.kind.value, ex.duration_s))
            self._current_announced = True

    def _flush_pending_stop(self) -> None:
        if self._pending_stop is not None:
            entry, count, ended, t_end, row_end = self._pending_stop
            self._pending_stop = None
            self._record_step_stop(entry, count, "completed", ended, t_end, row_end)

    def _record_step_stop(
        self, entry: PlanEntry, count: int, status: str, ended_by: str | None, t_s: float | None, row_end: int
    ) -> None:
        self._emit("step_stop", StepStop(entry, count, status, ended_by, t_s, row_end))

    def _measure(self, t_sched: float) -> Sample:
        m = self.calls.call("measure", self.cycler.measure)
        t = m.t_s if self._stamped and m.t_s is not None else self.clock.now()
        if self._t_applied is not None:
            d = t - self._t_applied
            self._t_applied = None
            st = self.stats
            st.set_to_sample_n += 1
            st.sum_set_to_sample_s += d
            st.max_set_to_sample_s = max(st.max_set_to_sample_s, d)
        late = t - t_sched
        if late > 0.5 * self.options.sample_period_s:
            self.stats.late_samples += 1
        if late > 0:
            self.stats.sum_late_s += late
            self.stats.max_late_s = max(self.stats.max_late_s, late)
        return Sample(t, m.voltage_V, m.current_A, m.temperature_K)

    def _net_Ah(self, s: Sample) -> float:
        """Charge passed since the run's start / Ah: the previous sample's current held until this one (the log's
        zero-order hold); nothing is counted across an interruption (a resume starts from the last logged value)."""
        last = self._last
        if last is not None:
            self._q_Ah += last.i * max(0.0, s.t - last.t) / 3600.0
        return self._q_Ah

    def _record(self, s: Sample, entry: PlanEntry, count: int, ex: Any) -> None:
        """Emit the sample (logged first), then check it against the envelope and the programmed current."""
        t = s.t
        T_C = s.T_K - 273.15 if s.T_K is not None else math.nan
        test_time = t - self._t0
        prev = self._prev_test_time
        if prev is not None and test_time - prev > GAP_PERIODS * self.options.sample_period_s:
            st = self.stats
            st.gaps += 1
            st.sum_gap_s += test_time - prev
            st.max_gap_s = max(st.max_gap_s, test_time - prev)
            self._emit("gap", Gap(self._rows, prev, test_time))
        self._prev_test_time = test_time
        row = (
            test_time,
            time.time(),
            ex.step_time(t),
            s.v,
            s.i,
            T_C,
            self._T_amb_C,
            float(count),
            float(entry.step_index),
            float(entry.trial),
            self._net_Ah(s),
        )
        self._rows += 1
        self.stats.samples += 1
        self._emit("event", row)
        self._last = s
        self.resistance.observe(s)
        bad = check_sample(s, self.env)
        if bad is not None:
            raise Abort("safety", bad.message)
        tol = max(MISMATCH_A, MISMATCH_REL * abs(self._i_cmd))
        if self._output_on and abs(s.i - self._i_cmd) > tol:
            self._mismatches += 1
            self._check_protection(force=True)
            if self._mismatches >= 3:
                raise Abort(
                    "regulation",
                    f"measured current {s.i:.4f} A, programmed {self._i_cmd:.4f} A, for 3 samples (t = {t:.3f} s)",
                )
        else:
            self._mismatches = 0

    def _check_protection(self, force: bool = False) -> None:
        p = self.calls.call("protection state", self.cycler.protection)
        if p.tripped:
            causes = ", ".join(sorted(p.causes)) or f"status {p.raw}"
            raise Abort("protection", f"the cycler turned its output off: {causes}{self._context(p.causes)}")

    def _context(self, causes: frozenset[str] = frozenset()) -> str:
        """What the instruments say now, for an abort reason (never raises). The cycler's error queue is read (and so
        emptied): it may say why the output went off, and an error left in it would be taken for the answer to the
        safe shutdown's output-off command."""
        parts = []
        try:
            errors = self.cycler.errors()
            if errors:
                parts.append("cycler errors: " + "; ".join(f"{code} {message}" for code, message in errors))
        except (InstrumentError, OSError):
            pass
        try:
            m = self.cycler.measure()
            T = f", T {m.temperature_K - 273.15:.1f} degC" if m.temperature_K is not None else ""
            parts.append(f"after it: V {m.voltage_V:.4f} V, I {m.current_A:+.4f} A{T}")
        except (InstrumentError, OSError):
            pass
        if "INH" in causes:
            try:
                alarms = self.chamber.alarms()
                if alarms:
                    parts.append(f"chamber alarms: {alarms}")
            except (InstrumentError, OSError):
                pass
        return f" ({'; '.join(parts)})" if parts else ""

    def _housekeeping(self, t: float) -> None:
        if t >= self._next_chamber:
            self._next_chamber = t + self.options.chamber_period_s
            try:
                self._T_amb_C = self.calls.call("chamber read", self.chamber.read)
            except Abort as exc:
                if exc.kind != "instrument":
                    raise
                extra = ""
                try:
                    p = self.cycler.protection()
                    if p.tripped:
                        extra = f"; the cycler turned its output off: {', '.join(sorted(p.causes))}"
                except (InstrumentError, OSError):
                    pass
                raise Abort("chamber", exc.message + extra) from None
        if t >= self._next_protection:
            self._next_protection = t + self.options.protection_period_s
            self._check_protection()

    def _finish_ok(self) -> None:
        self.calls.call("output off", self.cycler.output, False)
        self._output_on = False
        self.calls.call("current 0", self.cycler.set_current, 0.0)

    def _summary(self) -> dict[str, Any]:
        self.stats.resistance_ohm = self.resistance.r_ohm
        out: dict[str, Any] = {
            "steps": [dict(r) for r in self.records.records],
            "stats": self.stats.to_dict(),
            "identities": self.identities,
            "rows": self._rows,
        }
        if self.shutdown is not None:
            out["shutdown"] = self.shutdown.to_dict()
        return out


__all__ = ["Abort", "EngineConfig", "RunEngine", "RunState", "RunStats", "StopRequested"]
