"""Logged data in memory: named BDF columns plus metadata (the value every reader returns).

Columns are named as in the Battery Data Format (``Test Time / s``, ``Voltage / V``, ``Current / A``, …);
current is positive on charge; temperatures are in °C as logged.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from protocols.errors import InputError
from protocols.profile import Profile

TIME = "Test Time / s"
VOLTAGE = "Voltage / V"
CURRENT = "Current / A"
AMBIENT = "Ambient Temperature / degC"
SURFACE = "Surface Temperature T1 / degC"
STEP = "Step Count / 1"
NET_CAPACITY = "Net Capacity / Ah"
#: the runner's step position in the plan (1-based) and trial of a repeated profile (battlab.lab.logfile)
STEP_INDEX = "Step Index / 1"
CYCLE = "Cycle Count / 1"
REQUIRED = (TIME, VOLTAGE, CURRENT)


@dataclass(frozen=True, eq=False)
class LoggedData:
    """One logged test: ``columns`` (BDF name → 1-D array, equal lengths), ``meta`` (JSON-able) and where from."""

    name: str
    columns: Mapping[str, np.ndarray]
    meta: Mapping[str, Any] = field(default_factory=dict)
    source: str = ""

    def __post_init__(self) -> None:
        cols = {k: np.asarray(v, dtype=float).reshape(-1) for k, v in self.columns.items()}
        missing = [c for c in REQUIRED if c not in cols]
        where = self.source or self.name
        if missing:
            raise InputError(
                f"{where}: missing column(s) {missing}; expected BDF columns {list(REQUIRED)}, found {list(cols)}"
            )
        sizes = {k: v.size for k, v in cols.items()}
        if len(set(sizes.values())) != 1:
            raise InputError(f"{where}: columns have different lengths {sizes}")
        object.__setattr__(self, "columns", cols)
        object.__setattr__(self, "meta", dict(self.meta))

    def __len__(self) -> int:
        return int(self.columns[TIME].size)

    @property
    def t(self) -> np.ndarray:
        """Test time [s]."""
        return self.columns[TIME]

    @property
    def voltage(self) -> np.ndarray:
        """Terminal voltage [V]."""
        return self.columns[VOLTAGE]

    @property
    def current(self) -> np.ndarray:
        """Current [A], positive = charge."""
        return self.columns[CURRENT]

    def temperature_K(self, column: str = SURFACE) -> np.ndarray | None:
        """A temperature column in K, or None when it is not logged."""
        v = self.columns.get(column)
        return None if v is None else v + 273.15

    def ambient_K(self, default: float | None = None) -> float:
        """The mean ambient (chamber) temperature [K], else ``meta["ambient_K"]``, else ``default``; without any
        an :class:`InputError` (a test simulated at a guessed ambient is a wrong prediction, not a warning)."""
        amb = self.temperature_K(AMBIENT)
        if amb is not None and np.isfinite(amb).any():
            return float(np.nanmean(amb))
        if "ambient_K" in self.meta:
            return float(self.meta["ambient_K"])
        if default is not None:
            return float(default)
        column = "empty" if amb is not None else "missing"
        raise InputError(
            f"{self.source or self.name}: no ambient temperature logged (column {AMBIENT!r} {column}): give it "
            "(--ambient FILE=DEGC, or ambient= in Python)"
        )

    def select(self, mask: np.ndarray | slice, name: str | None = None) -> LoggedData:
        """A subset of the samples (e.g. one step) as new data."""
        return LoggedData(name or self.name, {k: v[mask] for k, v in self.columns.items()}, self.meta, self.source)

    def to_profile(self, **meta: Any) -> Profile:
        """The logged current as a zero-order-hold :class:`protocols.Profile` (time from 0)."""
        return Profile(self.t - self.t[0], self.current, **meta)
