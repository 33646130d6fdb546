"""The OED input library: 738 candidate current profiles (540 pulses, 180 sinusoids, 18 drive cycles).

Every profile is L1-normalised to exactly 1 Ah of charge throughput, keeps |I| <= 5C (C = 2.7 A), lasts
600-3600 s and starts from SOC0 in {0.8, 0.6, 0.4, 0.2}. Samples are 1 s apart, plus every pulse edge (the
0.5 s half-pulses of bipolar 1 s and 3 s pulses).

Grid (chosen to reproduce the paper's counts exactly; see ``GRID``)
    pulses   width w in {1, 3, 10, 30, 100, 300, 1000} s (half-decades), rest factor n in {1, 2, 3} (rest
             n w after each pulse), total time T in {600, 900, 1800, 3600} s, direction in {discharge,
             charge, both}, SOC0 in {0.8, 0.6, 0.4, 0.2}: 1008 candidates (see :mod:`protocols.pulses`);
    sines    f in {0.01, 0.05, 0.1} Hz, T in {600, 900, 1200, 1800, 2400, 3600} s, direction, SOC0:
             216 candidates (see :mod:`protocols.sines`);
    drives   6 cycles (UDDS, US06, HWFET, WLTC 3b, naturalistic morning and evening) x SOC0: 24 candidates
             (see :mod:`protocols.drive_cycles`).

Amplitude: the L1 normalisation fixes it (A = 1 Ah / on-time), so Table 6's amplitude axis (0.5C-5C) is not a
grid variable; (w, n, T) set the on-time and hence the amplitude: pulses take 0.67C (w = 1000 s, n = 1,
T = 3600 s: 2000 s on) to 4.44C (300 s on) in eight levels, sinusoids peak at 0.57C-4.44C, drive cycles at
3.2C-4.8C; combinations that would exceed 5C are removed by the current filter.

Filters, applied in this order (``Library.counts`` reports the count after each):
    1. ``fits``: a pulse train needs at least two pulses in T (T >= (2 + n) w); sines and drives always pass;
    2. ``duration``: 600 s <= t_f <= 3600 s (drive cycles after their repeats);
    3. ``current``: max |I| <= 5C;
    4. ``soc_window``: SOC0 + dSOC(t) stays in [0, 1] for all t (coulomb counting, 2.7 Ah), and (the paper's
       rule) no net-discharging profile starts from 20 % and no net-charging one from 80 %.
Result: pulses 1008 -> 816 -> 816 -> 648 -> 540; sines 216 -> 216 -> 216 -> 216 -> 180; drives 24 -> 24 ->
24 -> 24 -> 18: 738 profiles.

Ids (stable: the same id is the same profile in every build) are 1..738 in this order: all pulses, then all
sines, then all drives; within a kind, by SOC0 (0.8, 0.6, 0.4, 0.2), then direction (discharge, charge, both;
drives: cycle in the order above), then (pulses) width, total time, rest factor, or (sines) frequency, total
time, each ascending. The thermal screen (a hook that battlab fills) only *flags* profiles; it never removes
or renumbers them.
"""

from __future__ import annotations

import json
from collections.abc import Callable, Iterable, Iterator
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from protocols.constants import (
    HIGH_SOC,
    L1_CHARGE_AH,
    LOW_SOC,
    MAX_C_RATE,
    MAX_DURATION_S,
    MIN_DURATION_S,
    ONE_C_A,
    RATED_CAPACITY_AH,
    START_SOCS,
)
from protocols.directions import Direction
from protocols.drive_cycles import Cycle, drive_profile
from protocols.errors import InputError
from protocols.ev_model import EVModel
from protocols.profile import Profile
from protocols.pulses import PulseSpec, pulse_profile
from protocols.sines import SineSpec, sine_profile

KINDS = ("pulse", "sine", "drive")
FILTERS = ("grid", "fits", "duration", "current", "soc_window")

GRID: dict[str, Any] = {
    "pulse": {
        "width_s": (1.0, 3.0, 10.0, 30.0, 100.0, 300.0, 1000.0),
        "total_s": (600.0, 900.0, 1800.0, 3600.0),
        "rest_factor": (1, 2, 3),
        "direction": tuple(d.value for d in Direction),
    },
    "sine": {
        "frequency_hz": (0.01, 0.05, 0.1),
        "total_s": (600.0, 900.0, 1200.0, 1800.0, 2400.0, 3600.0),
        "direction": tuple(d.value for d in Direction),
    },
    "drive": {"cycle": tuple(c.value for c in Cycle)},
    "soc0": START_SOCS,
}

ScreenFn = Callable[[Profile], tuple[bool, str | None]]
FORMAT_NAME = "protocols-library"
FORMAT_VERSION = 1


@dataclass(frozen=True)
class FilterCount:
    """Number of candidates of each kind that remain after a filter."""

    filter: str
    pulse: int
    sine: int
    drive: int

    @property
    def total(self) -> int:
        """All kinds together."""
        return self.pulse + self.sine + self.drive


@dataclass(frozen=True)
class ScreenResult:
    """Outcome of the thermal (or any other) screen for one profile."""

    ok: bool
    reason: str | None = None


@dataclass(frozen=True)
class _Candidate:
    kind: str
    soc0: float
    spec: PulseSpec | SineSpec | Cycle


def _candidates() -> list[_Candidate]:
    """Every grid point, in id order (see the module docstring)."""
    g = GRID
    out: list[_Candidate] = []
    for soc0 in g["soc0"]:
        for d in Direction:
            for w in g["pulse"]["width_s"]:
                for total in g["pulse"]["total_s"]:
                    for n in g["pulse"]["rest_factor"]:
                        out.append(_Candidate("pulse", soc0, PulseSpec(w, n, total, d)))
    for soc0 in g["soc0"]:
        for d in Direction:
            for f in g["sine"]["frequency_hz"]:
                for total in g["sine"]["total_s"]:
                    out.append(_Candidate("sine", soc0, SineSpec(f, total, d)))
    for soc0 in g["soc0"]:
        for c in Cycle:
            out.append(_Candidate("drive", soc0, c))
    return out


def _name(c: _Candidate) -> str:
    s = c.spec
    if isinstance(s, PulseSpec):
        return f"pulse w={s.width_s:g}s n={s.rest_factor} T={s.total_s:g}s {s.direction.value}"
    if isinstance(s, SineSpec):
        return f"sine f={s.frequency_hz:g}Hz T={s.total_s:g}s {s.direction.value}"
    return f"drive {s.value}"


def soc_window_ok(
    profile: Profile,
    soc0: float,
    *,
    capacity_ah: float = RATED_CAPACITY_AH,
    low_soc: float = LOW_SOC,
    high_soc: float = HIGH_SOC,
) -> bool:
    """The paper's SOC-window filter (see the module docstring), for start SOC ``soc0``."""
    soc = profile.soc(capacity_ah, soc0)
    if soc.min() < -1e-12 or soc.max() > 1.0 + 1e-12:
        return False
    net = profile.net_charge
    if soc0 <= low_soc + 1e-12 and net < -1e-9:
        return False
    return not (soc0 >= high_soc - 1e-12 and net > 1e-9)


class Library:
    """An ordered, id-addressable collection of library profiles (iterate it, or ``lib[id]``)."""

    def __init__(
        self,
        profiles: Iterable[Profile],
        *,
        counts: Iterable[FilterCount] = (),
        screening: dict[int, ScreenResult] | None = None,
        meta: dict[str, Any] | None = None,
    ) -> None:
        self._profiles = sorted(profiles, key=lambda p: int(p.id))  # type: ignore[arg-type]
        self._index = {int(p.id): k for k, p in enumerate(self._profiles)}  # type: ignore[arg-type]
        if len(self._index) != len(self._profiles):
            raise InputError("library: duplicate profile ids")
        self.counts: tuple[FilterCount, ...] = tuple(counts)
        self.screening: dict[int, ScreenResult] = dict(screening or {})
        self.meta: dict[str, Any] = dict(meta or {})

    # --- building -------------------------------------------------------------------------------------

    @classmethod
    def build(
        cls,
        *,
        ev: EVModel | None = None,
        capacity_ah: float = RATED_CAPACITY_AH,
        one_c_a: float = ONE_C_A,
        max_c_rate: float = MAX_C_RATE,
        min_duration_s: float = MIN_DURATION_S,
        max_duration_s: float = MAX_DURATION_S,
        charge_ah: float = L1_CHARGE_AH,
        screen: ScreenFn | None = None,
        map_fn: Callable[..., Iterable[Any]] = map,
    ) -> Library:
        """Generate, filter and number the library (deterministic; about a second).

        ``screen`` (optional) is applied after numbering and only flags profiles; ``map_fn`` lets the caller
        run it in parallel (e.g. ``executor.map``).
        """
        ev = EVModel() if ev is None else ev
        imax = max_c_rate * one_c_a
        cands = _candidates()
        shapes: dict[Any, Profile] = {}

        def shape(c: _Candidate) -> Profile:
            if c.spec not in shapes:
                if isinstance(c.spec, PulseSpec):
                    shapes[c.spec] = pulse_profile(c.spec, charge_ah=charge_ah)
                elif isinstance(c.spec, SineSpec):
                    shapes[c.spec] = sine_profile(c.spec, charge_ah=charge_ah)
                else:
                    shapes[c.spec] = drive_profile(c.spec, ev, charge_ah=charge_ah, max_current_a=imax)
            return shapes[c.spec]

        def count(name: str, cs: list[_Candidate]) -> FilterCount:
            return FilterCount(name, *(sum(c.kind == k for c in cs) for k in KINDS))

        counts = [count("grid", cands)]
        cands = [c for c in cands if not isinstance(c.spec, PulseSpec) or c.spec.n_pulses >= 2]
        counts.append(count("fits", cands))
        cands = [c for c in cands if min_duration_s - 1e-9 <= shape(c).duration <= max_duration_s + 1e-9]
        counts.append(count("duration", cands))
        cands = [c for c in cands if shape(c).max_abs_current <= imax * (1 + 1e-12)]
        counts.append(count("current", cands))
        cands = [c for c in cands if soc_window_ok(shape(c), c.soc0, capacity_ah=capacity_ah)]
        counts.append(count("soc_window", cands))

        profiles = []
        for k, c in enumerate(cands, start=1):
            p = shape(c)
            params = {"name": _name(c), **dict(p.params)}
            profiles.append(Profile(p.t, p.current, id=k, kind=c.kind, soc0=c.soc0, params=params))
        meta = {
            "capacity_ah": capacity_ah,
            "one_c_a": one_c_a,
            "max_c_rate": max_c_rate,
            "charge_ah": charge_ah,
            "min_duration_s": min_duration_s,
            "max_duration_s": max_duration_s,
            "grid": GRID,
            "ev_model": ev.as_dict(),
        }
        lib = cls(profiles, counts=counts, meta=meta)
        if screen is not None:
            lib.screen(screen, map_fn=map_fn)
        return lib

    # --- access ---------------------------------------------------------------------------------------

    def __len__(self) -> int:
        return len(self._profiles)

    def __iter__(self) -> Iterator[Profile]:
        return iter(self._profiles)

    def __contains__(self, pid: object) -> bool:
        try:
            return int(pid) in self._index  # type: ignore[call-overload]
        except (TypeError, ValueError):
            return False

    def __getitem__(self, pid: int | str) -> Profile:
        try:
            key = int(pid)
        except (TypeError, ValueError):
            raise InputError(f"library: profile id must be an integer, got {pid!r}") from None
        if key not in self._index:
            raise InputError(f"library: no profile with id {key} (ids run 1..{len(self)})")
        return self._profiles[self._index[key]]

    @property
    def ids(self) -> list[int]:
        """All profile ids in order."""
        return [int(p.id) for p in self._profiles]  # type: ignore[arg-type]

    def select(self, *, kind: str | None = None, soc0: float | None = None, **params: Any) -> list[Profile]:
        """Profiles of one kind and/or start SOC whose generating parameters equal ``params``.

        E.g. ``lib.select(kind="pulse", width_s=10.0, direction="charge")`` - the way to compare selections
        with the paper's Table 10 (by parameters, not ids).
        """
        if kind is not None and kind not in KINDS:
            raise InputError(f"library: unknown kind {kind!r}; expected one of {KINDS}")
        return [
            p
            for p in self._profiles
            if (kind is None or p.kind == kind)
            and (soc0 is None or abs(float(p.soc0) - soc0) < 1e-9)
            and all(key in p.params and p.params[key] == value for key, value in params.items())
        ]

    @property
    def total_hours(self) -> float:
        """Sum of all profile durations [h]."""
        return sum(p.duration for p in self._profiles) / 3600.0

    def kind_counts(self) -> dict[str, int]:
        """Number of profiles of each kind."""
        return {k: sum(p.kind == k for p in self._profiles) for k in KINDS}

    # --- screening ------------------------------------------------------------------------------------

    def screen(self, fn: ScreenFn, *, map_fn: Callable[..., Iterable[Any]] = map) -> dict[int, ScreenResult]:
        """Apply ``fn(profile) -> (ok, reason)`` to every profile and store the flags (never renumbers)."""
        results = list(map_fn(fn, self._profiles))
        if len(results) != len(self._profiles):
            raise InputError(f"screen returned {len(results)} results for {len(self._profiles)} profiles")
        for p, r in zip(self._profiles, results, strict=True):
            try:
                ok, reason = r
            except (TypeError, ValueError):
                raise InputError(f"screen must return (ok, reason) for profile {p.id}, got {r!r}") from None
            self.screening[int(p.id)] = ScreenResult(bool(ok), None if reason is None else str(reason))
        return dict(self.screening)

    def flagged(self) -> list[Profile]:
        """Profiles the screen rejected."""
        return [p for p in self._profiles if not self.screening.get(int(p.id), ScreenResult(True)).ok]

    def usable(self) -> list[Profile]:
        """Profiles not rejected by the screen (all of them if no screen ran)."""
        return [p for p in self._profiles if self.screening.get(int(p.id), ScreenResult(True)).ok]

    # --- HDF5 -----------------------------------------------------------------------------------------

    def save(self, path: str | Path) -> Path:
        """Write the library to HDF5: one compressed group per profile under ``/profiles``."""
        import h5py

        path = Path(path)
        with h5py.File(path, "w") as f:
            f.attrs["format"] = FORMAT_NAME
            f.attrs["version"] = FORMAT_VERSION
            f.attrs["meta"] = json.dumps(self.meta)
            f.attrs["counts"] = json.dumps([c.__dict__ for c in self.counts])
            grp = f.create_group("profiles")
            for p in self._profiles:
                g = grp.create_group(f"{int(p.id):04d}")
                for name, arr in (("t", p.t), ("current", p.current)):
                    g.create_dataset(name, data=arr, compression="gzip", compression_opts=4, shuffle=True)
                g.attrs["id"] = int(p.id)
                g.attrs["kind"] = p.kind or ""
                g.attrs["soc0"] = float(p.soc0) if p.soc0 is not None else np.nan
                g.attrs["params"] = json.dumps(dict(p.params))
                s = self.screening.get(int(p.id))
                if s is not None:
                    g.attrs["screen_ok"] = s.ok
                    g.attrs["screen_reason"] = s.reason or ""
        return path

    @classmethod
    def load(cls, path: str | Path) -> Library:
        """Read a library written by :meth:`save`."""
        import h5py

        path = Path(path)
        if not path.is_file():
            raise InputError(f"{path}: no such library file")
        try:
            f = h5py.File(path, "r")
        except OSError:
            raise InputError(f"{path}: not an HDF5 file") from None
        with f:
            if f.attrs.get("format") != FORMAT_NAME or "profiles" not in f:
                raise InputError(f"{path}: not a protocols library (no '{FORMAT_NAME}' format attribute)")
            profiles, screening = [], {}
            for key in f["profiles"]:
                g = f["profiles"][key]
                soc0 = float(g.attrs["soc0"])
                p = Profile(
                    g["t"][()],
                    g["current"][()],
                    id=int(g.attrs["id"]),
                    kind=str(g.attrs["kind"]) or None,
                    soc0=None if np.isnan(soc0) else soc0,
                    params=json.loads(g.attrs["params"]),
                )
                profiles.append(p)
                if "screen_ok" in g.attrs:
                    reason = str(g.attrs["screen_reason"]) or None
                    screening[int(p.id)] = ScreenResult(bool(g.attrs["screen_ok"]), reason)  # type: ignore[arg-type]
            counts = [FilterCount(**c) for c in json.loads(f.attrs["counts"])]
            meta = json.loads(f.attrs["meta"])
        return cls(profiles, counts=counts, screening=screening, meta=meta)


@dataclass(frozen=True)
class LibrarySummary:
    """Counts and hours of a library, for reports."""

    counts: tuple[FilterCount, ...]
    kinds: dict[str, int] = field(default_factory=dict)
    total_hours: float = 0.0


def summarise(lib: Library) -> LibrarySummary:
    """Counts after each filter, profiles per kind and total duration [h]."""
    return LibrarySummary(lib.counts, lib.kind_counts(), lib.total_hours)
