"""Simulated instruments, independent of any wire protocol (the servers translate to SCPI, Modbus, text).

Both are stepped along the lab's virtual clock under the lab's lock; every method takes virtual times in s.
"""

from __future__ import annotations

import logging
import math
import time
from collections import deque
from dataclasses import dataclass

import numpy as np

from drivers.virtual.noise import NoiseModel
from drivers.virtual.physics import CellPhysics, open_circuit_current

log = logging.getLogger("drivers.virtual")


class ExecutionError(Exception):
    """A command the simulated instrument refuses: SCPI error ``code`` with ``message``."""

    def __init__(self, code: int, message: str) -> None:
        super().__init__(f"{code},{message}")
        self.code = code
        self.message = message


# -- chamber -------------------------------------------------------------------------------------
@dataclass(frozen=True)
class ChamberConfig:
    """First-order air dynamics: dT/dt = (T_target − T)/tau; ``room_K`` when not controlling."""

    tau_s: float = 300.0
    T0_K: float = 298.15
    room_K: float = 296.15
    sp_min_C: float = -40.0
    sp_max_C: float = 150.0
    reading_noise_K: float = 0.02


class SimulatedChamber:
    """A thermal chamber: set point, first-order air temperature, alarm (an alarm stops control)."""

    def __init__(
        self, config: ChamberConfig | None = None, rng: np.random.Generator | None = None, t0_s: float = 0.0
    ) -> None:
        self.config = config or ChamberConfig()
        if not self.config.tau_s > 0:
            raise ValueError(f"chamber tau_s must be > 0, got {self.config.tau_s}")
        self.rng = rng or np.random.default_rng(0)
        self.t = t0_s
        self.T_air_K = self.config.T0_K
        self.sp_K = self.config.T0_K
        self.running = True
        self.alarm_codes: list[int] = []

    @property
    def target_K(self) -> float:
        return self.sp_K if self.running and not self.alarm_codes else self.config.room_K

    def advance(self, t: float) -> None:
        if t <= self.t:
            return
        target = self.target_K
        self.T_air_K = target + (self.T_air_K - target) * math.exp(-(t - self.t) / self.config.tau_s)
        self.t = t

    def set_point_C(self, T_C: float) -> None:
        c = self.config
        if not (math.isfinite(T_C) and c.sp_min_C <= T_C <= c.sp_max_C):
            raise ExecutionError(-222, f"set point {T_C} degC outside [{c.sp_min_C}, {c.sp_max_C}]")
        self.sp_K = T_C + 273.15

    def read_C(self) -> float:
        return self.T_air_K - 273.15 + self.config.reading_noise_K * float(self.rng.standard_normal())

    def trigger_alarm(self, code: int = 1) -> None:
        if code not in self.alarm_codes:
            self.alarm_codes.append(code)
        log.warning("virtual chamber: alarm %d at t=%.1f s", code, self.t)

    def clear_alarm(self) -> None:
        self.alarm_codes.clear()


# -- cycler --------------------------------------------------------------------------------------
# Status bits (see drivers.scpi.dialects): the virtual instrument sets these.
OV, OT, LIM_POS, INH, PROT, VLIM_NEG, WDOG, MODEL = 0, 4, 7, 9, 11, 13, 14, 15


@dataclass
class Trip:
    """A protection trip: virtual time / s, status bits, reason."""

    t_s: float
    bits: frozenset[int]
    reason: str


class SimulatedCycler:
    """A current-priority bidirectional supply connected to a simulated cell.

    Positive instrument current charges the cell (the cell's + is wired to the supply's +). Simplification:
    reaching a voltage limit turns the output off (status bit LIM+ or VLIM−) instead of regulating in CV.
    A trip programs the output off (a real Keysight keeps the programmed state and restores it on clear).
    """

    def __init__(
        self,
        physics: CellPhysics,
        *,
        noise: NoiseModel,
        rng: np.random.Generator,
        max_step_s: float = 1.0,
        t0_s: float = 0.0,
        speed: float = 1.0,
    ) -> None:
        if not max_step_s > 0:
            raise ValueError(f"max_step_s must be > 0, got {max_step_s}")
        self.physics = physics
        self.noise = noise
        self.rng = rng
        self.max_step_s = max_step_s
        self.speed = speed
        self.t = t0_s
        self.last_io_t = t0_s
        limits = physics.limits
        self.output_on = False
        self.function = "CURR"
        self.current = 0.0
        self.current_limit = limits.i_charge_max_A
        self.current_limit_neg = -limits.i_discharge_max_A
        self.voltage_limit = limits.v_max_V
        self.voltage_limit_low: float | None = limits.v_min_V
        self.ovp = limits.v_max_V + 0.3
        self.temperature_protection_K = limits.T_max_K
        self.watchdog_enabled = False
        self.watchdog_delay_s = 60
        self.status = 0
        self.errors: deque[tuple[int, str]] = deque()
        self.trips: list[Trip] = []
        self.model_failed = False
        self.forced_T_K: float | None = None
        self.v_true = physics.voltage
        self.i_true = 0.0
        self.T_cell_K = float("nan")
        self._dvdt = 0.0
        self._dv = 0.0  # the true voltage's change over the last physics step / V
        #: cost of the physics: number of steps and the real seconds spent in them
        self.physics_steps = 0
        self.physics_wall_s = 0.0

    # -- state ------------------------------------------------------------------------------------
    @property
    def tripped(self) -> bool:
        return self.status != 0

    @property
    def T_probe_K(self) -> float:
        return self.T_cell_K if self.forced_T_K is None else max(self.T_cell_K, self.forced_T_K)

    def reset_cell(self, soc0: float, T_K: float) -> None:
        self.physics.reset(soc0, T_K)
        self.v_true, self.T_cell_K, self._dvdt, self._dv = self.physics.voltage, T_K, 0.0, 0.0

    def note_io(self, t: float) -> None:
        """Any received message resets the watchdog."""
        self.last_io_t = max(self.last_io_t, t)

    def push_error(self, code: int, message: str) -> None:
        if len(self.errors) >= 30:
            self.errors[-1] = (-350, "Queue overflow")
            return
        self.errors.append((code, message))

    def pop_error(self) -> tuple[int, str]:
        return self.errors.popleft() if self.errors else (0, "No error")

    def trip(self, bits: set[int], reason: str, t: float | None = None) -> None:
        t = self.t if t is None else t
        bits = set(bits) | {PROT}
        self.status |= sum(1 << b for b in bits)
        was_on = self.output_on
        self.output_on = False
        self.trips.append(Trip(t, frozenset(bits), reason))
        log.warning("virtual cycler: output off at t=%.3f s (%s)%s", t, reason, "" if was_on else ", was off")

    def clear_protection(self) -> None:
        """Clear the latched trips, a cell-model failure included (the physics is left at its last good state)."""
        self.status = 0
        self.model_failed = False

    # -- time -------------------------------------------------------------------------------------
    def advance(self, t: float, ambient_K: float) -> None:
        """Step the cell to virtual time ``t``, enforcing watchdog and limits at sub-step resolution."""
        while self.t < t - 1e-12:
            t_next = min(t, self.t + self.max_step_s)
            on = self.output_on
            if on and self.watchdog_enabled:
                t_wd = self.last_io_t + self.watchdog_delay_s
                if t_wd <= self.t + 1e-12:
                    self.trip({WDOG}, f"watchdog: no I/O for {self.watchdog_delay_s} s", self.t)
                    on = False
                elif t_wd < t_next:
                    t_next = t_wd
            current = self.current if on else open_circuit_current(self.physics)
            dt = t_next - self.t
            if not self.model_failed:
                try:
                    w0 = time.perf_counter()
                    v, T = self.physics.step(current, dt, ambient_K)
                    self.physics_wall_s += time.perf_counter() - w0
                    self.physics_steps += 1
                except Exception as exc:  # the model is foreign code: any failure → output off
                    self.model_failed = True
                    detail = str(exc) if str(exc).startswith("cell model") else f"cell model: {exc}"
                    self.trip({MODEL}, f"cell model failed: {detail}", t_next)
                    self.push_error(-310, f"System error; {detail}"[:120])
                    self.t = t_next
                    continue
                if current != self.i_true:  # the step began with a current step: its voltage change is
                    # mostly the instantaneous jump, no slope of the voltage at the reading (which would add
                    # jitter × jump / dt: a third of a 5 A jump 10 ms after it), so the step gives no slope
                    self._dv = self._dvdt = 0.0
                else:
                    self._dv = v - self.v_true
                    self._dvdt = self._dv / dt if dt > 0 else 0.0
                self.v_true, self.T_cell_K = v, T
            self.i_true = current
            self.t = t_next
            self._check_limits()

    def _check_limits(self) -> None:
        if self.T_probe_K >= self.temperature_protection_K and (self.output_on or not self.status >> OT & 1):
            self.trip({OT}, f"over-temperature {self.T_probe_K - 273.15:.1f} degC")
        if not self.output_on:
            return
        if self.v_true >= self.ovp:
            self.trip({OV}, f"over-voltage {self.v_true:.4f} V")
        elif self.i_true > 0 and self.v_true >= self.voltage_limit:
            self.trip({LIM_POS}, f"voltage limit {self.voltage_limit} V reached on charge")
        elif self.i_true < 0 and self.voltage_limit_low is not None and self.v_true <= self.voltage_limit_low:
            self.trip({VLIM_NEG}, f"voltage limit {self.voltage_limit_low} V reached on discharge")

    def inhibit(self, reason: str) -> None:
        """External interlock (e.g. chamber alarm)."""
        if self.output_on or not self.status >> INH & 1:
            self.trip({INH}, f"interlock: {reason}")

    # -- readings ---------------------------------------------------------------------------------
    def measure_voltage(self) -> float:
        return self.noise.voltage(self.v_true, self.i_true, self._dvdt, self.rng, max_slew_error_V=abs(self._dv))

    def measure_current(self) -> float:
        return self.noise.current(self.i_true, self.rng)

    def measure_temperature_K(self) -> float:
        return self.noise.temperature(self.T_probe_K, self.rng)

    # -- settings (instrument units; the server has checked the dialect's ranges) -----------------------
    def set_function(self, value: str) -> None:
        if not value.upper().startswith("CURR"):
            raise ExecutionError(-221, "Settings conflict; only current priority is simulated")
        self.function = "CURR"

    def set_current(self, value: float) -> None:
        if not self.current_limit_neg <= value <= self.current_limit:
            raise ExecutionError(-222, "Data out of range; beyond CURR:LIM")
        self.current = value

    def set_output(self, on: bool) -> None:
        if on and self.tripped:
            raise ExecutionError(-221, "Settings conflict; protection latched, clear it first")
        if on and self.model_failed:
            raise ExecutionError(-221, "Settings conflict; cell model failed")
        if on and not self.output_on:
            log.info("virtual cycler: output on at t=%.3f s, %.4f A", self.t, self.current)
        self.output_on = on
