"""The virtual lab: one virtual clock, a simulated cycler on a cell, a simulated chamber, their servers.

Concurrency model: threads and blocking sockets. One ``threading.RLock`` (``lab.lock``) guards all simulated
state; on a free-running clock a ticker thread advances the instruments along the clock whenever nothing has for
``tick_real_s`` real seconds, so time, the cell, the chamber air and the instrument watchdog move on while the host
is silent or dead. Each server handler takes the lock and advances to "now" before it answers, so a current set at
virtual time t flows from exactly t (zero-order hold). pymodbus's asyncio server runs in its own thread with its
own loop.

Clock modes (``VirtualLabConfig.clock``, :mod:`drivers.virtual.clock`):

- ``free`` (the default): virtual time runs at ``speed`` × real time by itself, as on a real bench. A host or a
  physics that cannot keep up leaves samples late (the runner marks the gaps), and a silent host trips the
  instrument watchdog. Watchdog, fault-injection, interlock and timing tests need this mode.
- ``lockstep``: virtual time moves only when the host sleeps on ``lab.clock`` (the host must run in this process and
  sleep on that clock: the in-process virtual tester of ``battlab run --cycler virtual``), and at most at ``speed``.
  The physics is computed in the sleeps (in ``max_step_s`` pieces), and each message to an instrument takes a fixed
  ``exchange_s`` (10 ms): every sample is taken 20 ms after its scheduled time and every current set applies 10 ms
  before it, whatever the machine's load. The price is a slower clock when the computer cannot keep up, and no
  time passing while the host is silent (no watchdog; in one process a dead host takes the tester with it).
  Campaigns and any run whose data are fitted should use this mode.
"""

from __future__ import annotations

import logging
import math
import threading
import time
from collections.abc import Sequence
from dataclasses import dataclass, field

import numpy as np

from drivers.scpi.dialects import BATTLAB_VIRTUAL, ScpiDialect
from drivers.virtual.clock import LockStepClock, VirtualClock
from drivers.virtual.cycler_server import ScpiCyclerServer
from drivers.virtual.espec_server import EspecServer
from drivers.virtual.faults import DeviceFaultPlan, FaultConfig, FaultInjector
from drivers.virtual.instruments import ChamberConfig, SimulatedChamber, SimulatedCycler
from drivers.virtual.modbus_server import F4TModbusServer
from drivers.virtual.noise import NoiseModel
from drivers.virtual.physics import CellPhysics, Effect, EquivalentCircuitCell, apply_effects

log = logging.getLogger("drivers.virtual")

LOOPBACK = "127.0.0.1"
#: [s] virtual time advanced in one piece: between pieces a stopping lab's ticker gives up its catch-up
CATCH_UP_PIECE_S = 10.0
CLOCK_MODES = ("free", "lockstep")


@dataclass
class VirtualLabConfig:
    """Everything about a virtual lab except its physics. Ports: 0 = any free port, None = no server."""

    speed: float = 1000.0
    host: str = LOOPBACK
    cycler_port: int | None = 0
    modbus_port: int | None = 0
    modbus_rtu_port: int | None = 0
    espec_port: int | None = 0
    dialect: ScpiDialect = BATTLAB_VIRTUAL
    soc0: float = 0.5
    chamber: ChamberConfig = field(default_factory=ChamberConfig)
    noise: NoiseModel = field(default_factory=NoiseModel)
    seed: int = 0
    max_step_s: float = 1.0
    tick_real_s: float = 0.01
    #: a chamber alarm turns the cycler output off (status bit INH), as a hard-wired interlock would
    interlock: bool = True
    #: ``free``: time runs by itself; ``lockstep``: time moves only as the in-process host sleeps (module docstring)
    clock: str = "free"
    #: on a lock-step clock, the virtual time / s each message to an instrument takes, as over a LAN (a setting and
    #: the reading after it, or the last sample of a step and the first of the next, are never at the same instant;
    #: and a reading right after a current step is 10 ms into it, not within the instrument's 2 ms sample jitter)
    exchange_s: float = 0.01
    scpi_faults: FaultConfig = field(default_factory=FaultConfig)
    modbus_faults: FaultConfig = field(default_factory=FaultConfig)
    espec_faults: FaultConfig = field(default_factory=FaultConfig)
    device_faults: DeviceFaultPlan = field(default_factory=DeviceFaultPlan)


class VirtualLab:
    """A running virtual tester. Use as a context manager, or call :meth:`start` and :meth:`stop`.

    ``physics`` defaults to the stand-in :class:`EquivalentCircuitCell`; ``effects`` wrap it (hidden effects).
    """

    def __init__(
        self,
        physics: CellPhysics | None = None,
        config: VirtualLabConfig | None = None,
        effects: Sequence[Effect] = (),
    ) -> None:
        self.config = cfg = config or VirtualLabConfig()
        if cfg.host != LOOPBACK:
            log.warning("virtual lab serving on %s, not loopback", cfg.host)
        self.lock = threading.RLock()
        if cfg.clock not in CLOCK_MODES:
            raise ValueError(f"virtual lab clock {cfg.clock!r}: expected one of {', '.join(CLOCK_MODES)}")
        if not cfg.exchange_s > 0:
            raise ValueError(f"virtual lab exchange_s must be > 0, got {cfg.exchange_s}")
        self.clock: VirtualClock | LockStepClock = (
            LockStepClock(cfg.speed) if cfg.clock == "lockstep" else VirtualClock(cfg.speed)
        )
        rng = np.random.default_rng(cfg.seed)
        self.physics = apply_effects(physics if physics is not None else EquivalentCircuitCell(), effects)
        self.chamber = SimulatedChamber(cfg.chamber, rng=np.random.default_rng(rng.integers(2**63)))
        self.cycler = SimulatedCycler(
            self.physics,
            noise=cfg.noise,
            rng=np.random.default_rng(rng.integers(2**63)),
            max_step_s=cfg.max_step_s,
            speed=cfg.speed,
        )
        self.cycler.reset_cell(cfg.soc0, self.chamber.T_air_K)
        self.scpi_faults = FaultInjector(cfg.scpi_faults)
        self.modbus_faults = FaultInjector(cfg.modbus_faults)
        self.espec_faults = FaultInjector(cfg.espec_faults)
        self.cycler_server = (
            ScpiCyclerServer(self, cfg.dialect, host=cfg.host, port=cfg.cycler_port, faults=self.scpi_faults)
            if cfg.cycler_port is not None
            else None
        )
        self.modbus_server = (
            F4TModbusServer(
                self,
                host=cfg.host,
                tcp_port=cfg.modbus_port,
                rtu_port=cfg.modbus_rtu_port,
                faults=self.modbus_faults,
            )
            if cfg.modbus_port is not None or cfg.modbus_rtu_port is not None
            else None
        )
        self.espec_server = (
            EspecServer(self, host=cfg.host, port=cfg.espec_port, faults=self.espec_faults)
            if cfg.espec_port is not None
            else None
        )
        self._t = 0.0
        self._advanced_mono = -math.inf  # when advance() last ran (time.monotonic)
        self._events = self._device_events(cfg.device_faults)
        if isinstance(self.clock, LockStepClock):
            self.clock.bind(self._step_to)
        self._stop = threading.Event()
        self._ticker: threading.Thread | None = None
        self.started = False

    # -- life cycle ---------------------------------------------------------------------------------------
    def start(self) -> VirtualLab:
        try:
            for server in (self.cycler_server, self.modbus_server, self.espec_server):
                if server is not None:
                    server.start()
        except BaseException:
            self.stop()
            raise
        # Time starts when the instruments are served: building the cell (compiling a model, analysing its
        # first state) and opening sockets take real time that would otherwise be owed to the physics as
        # hundreds of virtual seconds, computed under the lock while the first replies wait.
        with self.lock:
            self.clock.restart(self._t)
        if not self.clock.lockstep:  # a lock-step clock stands still between the host's sleeps: nothing to tick
            self._ticker = threading.Thread(target=self._tick_loop, name="virtual-lab-ticker", daemon=True)
            self._ticker.start()
        self.started = True
        return self

    def stop(self) -> None:
        self._stop.set()
        for server in (self.cycler_server, self.modbus_server, self.espec_server):
            if server is not None:
                server.stop()
        if self._ticker is not None:
            self._ticker.join(2.0)
        self.started = False

    def __enter__(self) -> VirtualLab:
        return self.start()

    def __exit__(self, *exc: object) -> None:
        self.stop()

    # -- URLs ---------------------------------------------------------------------------------------------
    @property
    def cycler_url(self) -> str:
        assert self.cycler_server is not None, "no cycler server"
        return self.cycler_server.url

    @property
    def chamber_url(self) -> str:
        """The Watlow F4T over Modbus TCP."""
        assert self.modbus_server is not None, "no Modbus server"
        return self.modbus_server.tcp_url

    @property
    def rtu_url(self) -> str:
        """The Watlow F4T with RTU framing over TCP."""
        assert self.modbus_server is not None, "no Modbus server"
        return self.modbus_server.rtu_url

    @property
    def espec_url(self) -> str:
        assert self.espec_server is not None, "no Espec server"
        return self.espec_server.url

    # -- time ---------------------------------------------------------------------------------------------
    def _tick_loop(self) -> None:
        warned_at = -1e9
        while not self._stop.wait(self.config.tick_real_s):
            try:
                self.tick()
                load = self.physics_load()
                if load > 0.8 and time.monotonic() - warned_at > 60.0:
                    warned_at = time.monotonic()
                    log.warning(
                        "virtual lab: the cell physics uses %.0f%% of real time at %gx: lower the speed "
                        "or raise max_step_s, or replies will lag",
                        100 * load,
                        self.clock.speed,
                    )
            except Exception:
                log.exception("virtual lab: advance failed")

    def physics_load(self) -> float:
        """Real seconds spent in the physics per real second elapsed (> 1: the physics cannot keep up)."""
        elapsed_real = self._t / self.clock.speed
        return self.cycler.physics_wall_s / elapsed_real if elapsed_real > 0 else 0.0

    def tick(self) -> bool:
        """The ticker's turn: advance to now only if nothing has for ``tick_real_s`` real seconds (the host is
        silent); returns whether it advanced.

        While a host talks to the instruments its own queries advance them; a tick in between would only split
        the physics into extra partial steps and hold the lock while the next query waits.
        """
        with self.lock:
            if time.monotonic() - self._advanced_mono < self.config.tick_real_s:
                return False
            self.advance()
            return True

    def advance(self) -> float:
        """Advance every simulated instrument to the clock's now (call with ``lock`` held); returns now."""
        with self.lock:
            self._advance_through(self.clock.now())
            self._advanced_mono = time.monotonic()
            return self._t

    def exchange(self) -> float:
        """A message arrived at a server: advance to now; a lock-step clock first moves on by ``exchange_s``."""
        with self.lock:
            if self.clock.lockstep:
                self._step_to(self.clock.now() + self.config.exchange_s)
            return self.advance()

    def _step_to(self, t: float) -> None:
        """The lock-step clock's sleep: compute the instruments to ``t``, then set the clock there."""
        with self.lock:
            self._advance_through(t)
            self.clock.set(t)  # type: ignore[union-attr]

    def _advance_through(self, t: float) -> None:
        """Advance to ``t``, firing the device faults scheduled on the way at their times."""
        while self._events and self._events[0][0] <= t:
            t_event, action = self._events.pop(0)
            self._advance_to(max(t_event, self._t))
            action()
        self._advance_to(t)

    def _advance_to(self, t: float) -> None:
        """Advance to ``t`` in pieces of at most :data:`CATCH_UP_PIECE_S`; the ticker gives up between two pieces
        once the lab is stopping (a physics slower than the clock owes ever more: a catch-up could outlast stop())."""
        while self._t < t:
            if self._stop.is_set() and threading.current_thread() is self._ticker:
                return
            self._advance_piece(min(t, self._t + CATCH_UP_PIECE_S))

    def _advance_piece(self, t: float) -> None:
        T_start = self.chamber.T_air_K
        self.chamber.advance(t)
        self.cycler.advance(t, 0.5 * (T_start + self.chamber.T_air_K))
        if self.config.interlock and self.chamber.alarm_codes:
            self.cycler.inhibit(f"chamber alarm {self.chamber.alarm_codes}")
        self._t = t

    def _device_events(self, plan: DeviceFaultPlan) -> list[tuple[float, object]]:
        events: list[tuple[float, object]] = []
        if plan.chamber_alarm_at_s is not None:
            events.append((plan.chamber_alarm_at_s, lambda: self._alarm(plan.chamber_alarm_code)))
        if plan.cell_over_temperature_at_s is not None:
            events.append(
                (
                    plan.cell_over_temperature_at_s,
                    lambda: self.force_cell_temperature(plan.over_temperature_K),
                )
            )
        return sorted(events, key=lambda e: e[0])

    # -- device faults ------------------------------------------------------------------------------------
    def _alarm(self, code: int) -> None:
        self.chamber.trigger_alarm(code)
        if self.config.interlock:
            self.cycler.inhibit(f"chamber alarm {code}")

    def trigger_chamber_alarm(self, code: int = 1) -> None:
        with self.lock:
            self.advance()
            self._alarm(code)

    def clear_chamber_alarm(self) -> None:
        with self.lock:
            self.chamber.clear_alarm()

    def force_cell_temperature(self, T_K: float | None) -> None:
        """Cell over-temperature fault: the surface probe reads at least ``T_K`` from now (None: clear)."""
        with self.lock:
            self.cycler.forced_T_K = T_K
            if T_K is not None:
                self.cycler._check_limits()

    def snapshot(self) -> dict[str, float | bool]:
        """The true state (for tests and reports): virtual time, voltage, current, temperatures, output."""
        with self.lock:
            self.advance()
            c = self.cycler
            return {
                "t_s": self._t,
                "voltage_V": c.v_true,
                "current_A": c.i_true,
                "T_cell_K": c.T_cell_K,
                "T_air_K": self.chamber.T_air_K,
                "output_on": c.output_on,
                "status": c.status,
            }
