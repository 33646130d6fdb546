"""Safety: the envelope checked on every sample, and the safe shutdown every abort ends with.

Two layers. The instrument's own protections are programmed from the envelope before the output is switched on
(voltage limits, current limits, over-temperature trip where the dialect has one, and the I/O watchdog), so a
breach turns the output off at the instrument's resolution even if the host is slow or dead. The runner checks
every sample against the same envelope and watches the measured current (a drop to zero while a current is
programmed means the output went off: the protection state is read at once and names the cause).

:func:`safe_shutdown` never raises: output off (confirmed if the link allows), current programmed to 0, chamber to
its safe set point; it returns what it could and could not do, for the record.
"""

from __future__ import annotations

import contextlib
import logging
import math
from collections.abc import Collection, Iterator
from dataclasses import dataclass, field
from typing import Any

from battlab.lab.limits import Envelope
from battlab.lab.steps import Sample
from drivers.clock import Clock
from drivers.errors import InstrumentError
from drivers.interfaces import Chamber, Cycler, Instrument

log = logging.getLogger("battlab.lab")

#: relative and absolute tolerance on the current magnitude limit (measurement noise, regulation)
CURRENT_TOL_REL = 0.02
CURRENT_TOL_A = 0.01


@dataclass(frozen=True)
class Violation:
    """A breached limit: ``kind`` (``voltage``, ``current``, ``temperature``), a message, and the sample."""

    kind: str
    message: str
    sample: Sample


def check_sample(s: Sample, env: Envelope) -> Violation | None:
    """The first limit ``s`` breaches, or None."""
    if not math.isfinite(s.v) or s.v < env.voltage_min or s.v > env.voltage_max:
        return Violation(
            "voltage",
            f"voltage {s.v:.4f} V outside the limits [{env.voltage_min:g}, {env.voltage_max:g}] V at t = {s.t:.3f} s",
            s,
        )
    bound = env.current_charge_max if s.i > 0 else env.current_discharge_max
    if abs(s.i) > bound * (1 + CURRENT_TOL_REL) + CURRENT_TOL_A:
        return Violation(
            "current",
            f"current {s.i:.4f} A beyond the {'charge' if s.i > 0 else 'discharge'} limit {bound:g} A "
            f"at t = {s.t:.3f} s",
            s,
        )
    temperature = s.T_K
    if temperature is not None and (not math.isfinite(temperature) or temperature > env.temperature_max_K):
        return Violation(
            "temperature",
            f"surface temperature {s.T_K - 273.15:.2f} degC above the limit "
            f"{env.temperature_max_K - 273.15:.2f} degC at t = {s.t:.3f} s",
            s,
        )
    return None


@dataclass
class Shutdown:
    """What :func:`safe_shutdown` did: output confirmed off, chamber set, and the problems met. Times on the run
    clock / s: when the output-off command was sent and when the shutdown ended."""

    output_off_confirmed: bool = False
    output_off_t_s: float | None = None
    current_after_A: float | None = None
    chamber_set_point_degC: float | None = None
    output_off_sent_t_s: float | None = None
    t_s: float | None = None
    problems: list[str] = field(default_factory=list)

    def to_dict(self) -> dict[str, Any]:
        return {
            "output_off_confirmed": self.output_off_confirmed,
            "output_off_t_s": self.output_off_t_s,
            "current_after_A": self.current_after_A,
            "chamber_set_point_degC": self.chamber_set_point_degC,
            "output_off_sent_t_s": self.output_off_sent_t_s,
            "t_s": self.t_s,
            "problems": list(self.problems),
        }


def safe_shutdown(
    cycler: Cycler,
    chamber: Chamber | None,
    safe_set_point_degC: float | None,
    *,
    clock: Clock | None = None,
    unreachable: Collection[object] = (),
) -> Shutdown:
    """Output off, current 0, chamber to ``safe_set_point_degC`` (None: leave it); never raises.

    An instrument in ``unreachable`` (its link just failed) is spared what would wait out its link's timeouts, so
    the run stops at once: the cycler gets output off sent once (``send_off``: a write without waiting for a
    confirmation), nothing more; the chamber is left as it is. When the cycler's
    link died, the chamber gets its set point in one attempt, without the driver's retries.
    """
    out = Shutdown()
    now = clock.now if clock is not None else (lambda: None)
    cycler_dead = any(d is cycler for d in unreachable)
    if cycler_dead:
        out.output_off_sent_t_s = now()
        try:  # a write: on a dead link there is no confirmation to wait for
            if not cycler.send_off():
                out.problems.append("output off could not be sent")
        except Exception as exc:  # send_off must not raise, but a foreign driver might
            out.problems.append(f"output off: {exc}")
    else:
        out.output_off_sent_t_s = now()
        for attempt in range(2):
            try:
                out.output_off_confirmed = bool(cycler.safe_off())
            except Exception as exc:  # safe_off must not raise, but a foreign driver might
                out.problems.append(f"output off: {exc}")
            if out.output_off_confirmed or attempt:
                break
            try:  # an older error in the queue (e.g. the fault itself) reads as a rejection of 'output off': drain
                for code, message in cycler.errors():
                    out.problems.append(f"cycler error queue: {code},{message}")
            except Exception:
                break
    if not out.output_off_confirmed:
        out.problems.append("output off not confirmed by the cycler (its watchdog turns it off if the link is dead)")
    if not cycler_dead:
        try:
            cycler.set_current(0.0)
        except Exception as exc:
            out.problems.append(f"current to 0: {exc}")
        try:
            m = cycler.measure()
            out.output_off_t_s, out.current_after_A = m.t_s, m.current_A
        except Exception as exc:
            out.problems.append(f"measure after output off: {exc}")
    if chamber is not None and any(d is chamber for d in unreachable):
        out.problems.append("chamber unreachable: its set point is unchanged")
    elif chamber is not None and safe_set_point_degC is not None:
        try:
            # after a dead link the chamber is asked once: it may share the cause (the same host, network or
            # tester process), and the stop must not wait out its retries too
            with _one_attempt(chamber) if unreachable else contextlib.nullcontext():
                chamber.set_point(safe_set_point_degC)
            out.chamber_set_point_degC = safe_set_point_degC
        except (InstrumentError, OSError, ValueError) as exc:
            out.problems.append(f"chamber to {safe_set_point_degC:g} degC: {exc}")
    for p in out.problems:
        log.error("safe shutdown: %s", p)
    out.t_s = now()
    return out


@contextlib.contextmanager
def _one_attempt(device: Instrument) -> Iterator[None]:
    """The driver's link retries off for the duration."""
    retries = device.retries
    if retries == 0:
        yield
        return
    device.retries = 0
    try:
        yield
    finally:
        device.retries = retries


__all__ = ["CURRENT_TOL_A", "CURRENT_TOL_REL", "Shutdown", "Violation", "check_sample", "safe_shutdown"]
