"""What every chamber driver shares: waiting for a stable temperature on a given clock."""

from __future__ import annotations

import math
from typing import Protocol

from drivers.clock import Clock
from drivers.errors import InstrumentFault
from protocols.errors import InputError


class _Readable(Protocol):
    name: str

    def read(self) -> float: ...


def wait_stable(
    chamber: _Readable,
    set_point_C: float,
    tol: float,
    timeout: float,
    clock: Clock,
    *,
    hold_s: float = 60.0,
    poll_s: float = 5.0,
) -> float:
    """Poll ``chamber.read()`` every ``poll_s`` until it stays within ``tol`` K of the set point for
    ``hold_s``.

    All times in ``clock`` seconds. Raises :class:`InstrumentFault` (naming chamber, set point and last
    reading) after ``timeout``; an alarm raised by ``read()`` propagates. Returns the last reading / °C.
    """
    if not (tol > 0 and timeout > 0 and poll_s > 0 and hold_s >= 0):
        raise InputError(
            f"{chamber.name}: wait_stable needs tol, timeout, poll_s > 0 and hold_s >= 0 "
            f"(got tol={tol}, timeout={timeout}, poll_s={poll_s}, hold_s={hold_s})"
        )
    t_start = clock.now()
    t_in_band: float | None = None
    T = math.nan
    for _ in range(int(timeout / poll_s) + 100):  # bounded even if the clock misbehaves
        T = chamber.read()
        now = clock.now()
        if abs(T - set_point_C) <= tol:
            t_in_band = now if t_in_band is None else t_in_band
            if now - t_in_band >= hold_s:
                return T
        else:
            t_in_band = None
        if now - t_start >= timeout:
            break
        clock.sleep(poll_s)
    raise InstrumentFault(
        chamber.name,
        f"not stable within ±{tol:g} K of {set_point_C:g} degC for {hold_s:g} s "
        f"after {timeout:g} s (last reading {T:.2f} degC)",
    )
