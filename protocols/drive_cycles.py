"""Drive-cycle profiles of the input library (stand-ins for the paper's Table 8).

Six cycles, from the speed traces shipped as package data (``protocols/data``):

* ``udds``, ``us06``, ``hwfet`` (EPA) and ``wltc3b`` (UNECE WLTC class 3b), 1 Hz regulatory schedules;
* ``dc1`` - naturalistic *morning* drive: the first trip of 2007-05-24 that starts before noon
  (06:35:12-06:48:47, 815 s);
* ``dc2`` - naturalistic *evening* drive: the trips of 2007-05-24 starting after 18:00, joined in order
  from the first one until the joined trace lasts >= 600 s (every evening trip alone is shorter); this gives
  19:12:23-19:19:29 + 19:59:08-20:03:45 (703 s). Trips are joined end to start at standstill (the parked time
  between them is removed).

The paper's DC1/DC2 are not public and LA92 and SC04 are not available, so HWFET and WLTC 3b take their
places. Naturalistic traces are resampled at 1 s by linear interpolation across logging gaps.

Each trace goes through :class:`protocols.ev_model.EVModel` to a cell current, is L1-normalised to 1 Ah, and,
if its peak then exceeds 5C, is repeated k times (the L1 norm of k repeats is k times larger, so the peak
falls by k) with the smallest k that meets 5C. The library's duration filter drops a cycle whose k repeats
exceed 3600 s (none does with the default vehicle).
"""

from __future__ import annotations

import csv
import math
from dataclasses import dataclass
from datetime import datetime
from enum import Enum
from functools import cache
from importlib import resources
from typing import Any

import numpy as np

from protocols.constants import L1_CHARGE_AH, MAX_C_RATE, ONE_C_A
from protocols.errors import InputError
from protocols.ev_model import EVModel
from protocols.profile import Profile
from protocols.pulses import normalise_l1

MPH_TO_MPS = 0.44704
NATURALISTIC_DAY = "naturalistic_2007-05-24.csv"
NATURALISTIC_TRIPS = "naturalistic_trips.csv"
EVENING_STARTS_AT = "18:00:00"
NOON = "12:00:00"
MIN_JOINED_S = 600.0


class Cycle(Enum):
    """The six drive cycles of the library, in library order."""

    UDDS = "udds"
    US06 = "us06"
    HWFET = "hwfet"
    WLTC3B = "wltc3b"
    DC1 = "dc1"
    DC2 = "dc2"


REGULATORY_FILES = {
    Cycle.UDDS: "udds.csv",
    Cycle.US06: "us06.csv",
    Cycle.HWFET: "hwfet.csv",
    Cycle.WLTC3B: "wltc_3b.csv",
}


@dataclass(frozen=True, eq=False)
class SpeedTrace:
    """Vehicle speed vs time (s, m/s, grade as rise/run) and where it came from."""

    name: str
    t: np.ndarray
    speed_mps: np.ndarray
    grade: np.ndarray
    source: str

    @property
    def duration(self) -> float:
        """Duration [s]."""
        return float(self.t[-1] - self.t[0])


def _data_text(name: str) -> str:
    return resources.files("protocols").joinpath("data", name).read_text(encoding="utf-8-sig")


@cache
def _regulatory(cycle: Cycle) -> SpeedTrace:
    name = REGULATORY_FILES[cycle]
    rows = list(csv.DictReader(_data_text(name).splitlines()))
    try:
        t = np.array([float(r["cycSecs"]) for r in rows])
        v = np.array([float(r["cycMps"]) for r in rows])
        g = np.array([float(r["cycGrade"]) for r in rows])
    except (KeyError, ValueError) as exc:
        raise InputError(f"protocols/data/{name}: expected columns cycSecs, cycMps, cycGrade ({exc})") from None
    return SpeedTrace(cycle.value, t - t[0], v, g, f"protocols/data/{name}")


@dataclass(frozen=True)
class Trip:
    """One logged trip of the naturalistic day (local timestamps)."""

    start: datetime
    end: datetime

    def label(self) -> str:
        """``YYYY-MM-DD HH:MM:SS-HH:MM:SS``."""
        return f"{self.start:%Y-%m-%d %H:%M:%S}-{self.end:%H:%M:%S}"


def _ts(text: str) -> datetime:
    return datetime.strptime(text.strip(), "%Y-%m-%d %H:%M:%S")


@cache
def naturalistic_trips() -> tuple[Trip, ...]:
    """Trips of the naturalistic day, in time order (from the trip summary file)."""
    day = NATURALISTIC_DAY.removeprefix("naturalistic_").removesuffix(".csv")
    trips = [
        Trip(_ts(r["start_ts"]), _ts(r["end_ts"]))
        for r in csv.DictReader(_data_text(NATURALISTIC_TRIPS).splitlines())
        if r["start_ts"].startswith(day)
    ]
    return tuple(sorted(trips, key=lambda trip: trip.start))


@cache
def _naturalistic_samples() -> tuple[np.ndarray, np.ndarray]:
    rows = list(csv.DictReader(_data_text(NATURALISTIC_DAY).splitlines()))
    epoch = np.array([_ts(r["timestamp"]).timestamp() for r in rows])
    v = np.array([float(r["speed_mph"]) for r in rows]) * MPH_TO_MPS
    return epoch, v


def trip_trace(trip: Trip) -> tuple[np.ndarray, np.ndarray]:
    """Speed [m/s] of one trip at 1 s, starting at t = 0 (linear interpolation across logging gaps)."""
    epoch, v = _naturalistic_samples()
    sel = (epoch >= trip.start.timestamp()) & (epoch <= trip.end.timestamp())
    if sel.sum() < 2:
        raise InputError(f"naturalistic data: no samples for trip {trip.label()}")
    te, ve = epoch[sel] - epoch[sel][0], v[sel]
    t = np.arange(0.0, math.floor(te[-1]) + 1.0)
    return t, np.interp(t, te, ve)


def join_trips(trips: tuple[Trip, ...], name: str) -> SpeedTrace:
    """Join trips end to start (parked time removed) into one trace."""
    ts: list[np.ndarray] = []
    vs: list[np.ndarray] = []
    offset = 0.0
    for k, trip in enumerate(trips):
        t, v = trip_trace(trip)
        if k:
            t, v = t[1:], v[1:]  # the first sample coincides with the previous trip's last (standstill)
        ts.append(t + offset)
        vs.append(v)
        offset = float(ts[-1][-1])
    t_all, v_all = np.concatenate(ts), np.concatenate(vs)
    source = f"protocols/data/{NATURALISTIC_DAY}, trips " + " + ".join(trip.label() for trip in trips)
    return SpeedTrace(name, t_all, v_all, np.zeros_like(v_all), source)


def _select(trips: tuple[Trip, ...]) -> tuple[Trip, ...]:
    chosen: list[Trip] = []
    total = 0.0
    for trip in trips:
        chosen.append(trip)
        total += (trip.end - trip.start).total_seconds()
        if total >= MIN_JOINED_S:
            return tuple(chosen)
    raise InputError(f"naturalistic data: trips {[t.label() for t in trips]} last less than {MIN_JOINED_S} s")


@cache
def speed_trace(cycle: Cycle) -> SpeedTrace:
    """The speed trace of ``cycle``."""
    if cycle in REGULATORY_FILES:
        return _regulatory(cycle)
    trips = naturalistic_trips()
    if cycle is Cycle.DC1:
        return join_trips(_select(tuple(t for t in trips if f"{t.start:%H:%M:%S}" < NOON)), cycle.value)
    evening = tuple(t for t in trips if f"{t.start:%H:%M:%S}" >= EVENING_STARTS_AT)
    return join_trips(_select(evening), cycle.value)


def repeats_for_limit(peak_a: float, max_current_a: float) -> int:
    """Smallest number of repeats k >= 1 with peak / k <= max_current_a."""
    return max(1, math.ceil(peak_a / max_current_a - 1e-12))


def drive_profile(
    cycle: Cycle,
    ev: EVModel | None = None,
    *,
    charge_ah: float = L1_CHARGE_AH,
    max_current_a: float = MAX_C_RATE * ONE_C_A,
    **meta: Any,
) -> Profile:
    """Cell-current profile of ``cycle`` through ``ev``, L1-normalised to ``charge_ah`` [Ah].

    Repeated whole as often as needed to keep |I| <= ``max_current_a`` (see the module docstring); the
    number of repeats is in ``params["repeats"]``.
    """
    ev = EVModel() if ev is None else ev
    trace = speed_trace(cycle)
    i_cell = ev.cell_current(trace.t, trace.speed_mps, trace.grade)
    dt = np.diff(trace.t)
    one = Profile(trace.t, np.concatenate([i_cell, i_cell[-1:]]))
    peak_once = float(np.max(np.abs(i_cell))) * charge_ah / one.charge_throughput
    k = repeats_for_limit(peak_once, max_current_a)
    i_rep = np.tile(i_cell, k)
    t_rep = np.concatenate([[0.0], np.cumsum(np.tile(dt, k))])
    meta.setdefault("kind", "drive")
    params = {
        "cycle": cycle.value,
        "repeats": k,
        "cycle_duration_s": trace.duration,
        "source": trace.source,
        "raw_peak_a": float(np.max(np.abs(i_cell))),
        **{f"ev_{key}": value for key, value in ev.as_dict().items()},
        **dict(meta.pop("params", {})),
    }
    return normalise_l1(Profile(t_rep, np.concatenate([i_rep, i_rep[-1:]]), params=params, **meta), charge_ah)
