"""A sampled current profile: the unit of the OED input library and of everything the bench executes."""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass, field
from pathlib import Path
from types import MappingProxyType
from typing import Any

import numpy as np

from protocols.errors import InputError

TIME_COLUMN = "Test Time / s"
CURRENT_COLUMN = "Current / A"


@dataclass(frozen=True, eq=False)
class Profile:
    """Current vs time, positive = charge (BDF convention), zero-order hold.

    ``current[k]`` [A] flows from ``t[k]`` to ``t[k+1]`` [s]; the last value has no duration and is kept only
    so that the arrays have equal length (it is the value "at" the end time).
    """

    t: np.ndarray
    current: np.ndarray
    id: int | str | None = None
    kind: str | None = None
    soc0: float | None = None
    params: Mapping[str, Any] = field(default_factory=dict)

    def __post_init__(self) -> None:
        t = np.array(self.t, dtype=float).reshape(-1)
        i = np.array(self.current, dtype=float).reshape(-1)
        where = f"profile {self.id}" if self.id is not None else "profile"
        if t.size != i.size:
            raise InputError(f"{where}: time has {t.size} samples but current has {i.size}")
        if t.size < 2:
            raise InputError(f"{where}: needs at least 2 samples, got {t.size}")
        bad = np.flatnonzero(~np.isfinite(t))
        if bad.size:
            raise InputError(f"{where}: time is not finite at sample {bad[0]}")
        bad = np.flatnonzero(~np.isfinite(i))
        if bad.size:
            raise InputError(f"{where}: current is NaN or infinite at sample {bad[0]} (t = {t[bad[0]]:g} s)")
        bad = np.flatnonzero(np.diff(t) <= 0)
        if bad.size:
            k = bad[0] + 1
            raise InputError(
                f"{where}: time must increase strictly; sample {k} (t = {t[k]:g} s) follows t = {t[k - 1]:g} s"
            )
        if self.soc0 is not None and not 0.0 <= float(self.soc0) <= 1.0:
            raise InputError(f"{where}: start SOC must be in [0, 1], got {self.soc0}")
        t.flags.writeable = False
        i.flags.writeable = False
        object.__setattr__(self, "t", t)
        object.__setattr__(self, "current", i)
        object.__setattr__(self, "params", MappingProxyType(dict(self.params)))

    def __reduce__(self) -> tuple:
        """Profiles pickle (for worker processes and Dask) as plain arrays and metadata."""
        return (_rebuild, (np.array(self.t), np.array(self.current), self.id, self.kind, self.soc0, dict(self.params)))

    @property
    def duration(self) -> float:
        """Total duration [s]."""
        return float(self.t[-1] - self.t[0])

    @property
    def charge_throughput(self) -> float:
        """∫|I| dt over the profile [Ah] (zero-order hold)."""
        return float(np.sum(np.abs(self.current[:-1]) * np.diff(self.t)) / 3600.0)

    @property
    def net_charge(self) -> float:
        """∫I dt [Ah], positive when the profile charges the cell on balance."""
        return float(np.sum(self.current[:-1] * np.diff(self.t)) / 3600.0)

    @classmethod
    def from_csv(cls, path: str | Path, **meta: Any) -> Profile:
        """Read a profile CSV with the columns ``Test Time / s`` and ``Current / A`` (BDF names)."""
        path = Path(path)
        if not path.is_file():
            raise InputError(f"{path}: no such profile file")
        import csv
        import io

        try:
            # read whole so that a binary file (an HDF5 or .mat renamed .csv) fails here, as one error
            text = path.read_text(encoding="utf-8-sig")
        except UnicodeDecodeError:
            raise InputError(f"{path}: not a text CSV (binary content); expected a profile CSV") from None
        if "\0" in text:
            raise InputError(f"{path}: not a text CSV (NUL bytes); expected a profile CSV")
        with io.StringIO(text, newline="") as fh:
            reader = csv.reader(fh)
            try:
                header = [h.strip() for h in next(reader)]
            except StopIteration:
                raise InputError(f"{path}: file is empty") from None
            missing = [c for c in (TIME_COLUMN, CURRENT_COLUMN) if c not in header]
            if missing:
                raise InputError(
                    f"{path}: missing column(s) {missing}; expected {TIME_COLUMN!r} and {CURRENT_COLUMN!r}, the "
                    f"header has {header}"
                )
            it, ii = header.index(TIME_COLUMN), header.index(CURRENT_COLUMN)
            ts: list[float] = []
            cs: list[float] = []
            for line, row in enumerate(reader, start=2):
                if not row or all(not c.strip() for c in row):
                    continue
                try:
                    ts.append(float(row[it]))
                    cs.append(float(row[ii]))
                except (ValueError, IndexError):
                    raise InputError(
                        f"{path}, line {line}: expected numbers in {TIME_COLUMN!r} and {CURRENT_COLUMN!r}, got {row}"
                    ) from None
        try:
            return cls(np.array(ts), np.array(cs), **meta)
        except InputError as exc:
            raise InputError(f"{path}: {exc}") from None

    def to_csv(self, path: str | Path) -> Path:
        """Write ``Test Time / s``, ``Current / A`` (BDF names, positive = charge)."""
        path = Path(path)
        data = np.column_stack([self.t, self.current])
        np.savetxt(path, data, delimiter=",", header=f"{TIME_COLUMN},{CURRENT_COLUMN}", comments="", fmt="%.10g")
        return path

    @classmethod
    def constant(cls, current: float, duration: float, dt: float = 1.0, **meta: Any) -> Profile:
        """A constant current [A] for ``duration`` [s] sampled every ``dt`` [s]."""
        n = max(int(np.ceil(duration / dt - 1e-9)), 1)
        t = np.linspace(0.0, duration, n + 1)
        return cls(t, np.full(n + 1, float(current)), **meta)

    # --- derived quantities used by the library and the exporters ---

    @property
    def max_abs_current(self) -> float:
        """Largest |I| applied over the profile [A] (the last sample has no duration and is ignored)."""
        return float(np.max(np.abs(self.current[:-1])))

    def soc(self, capacity_ah: float, soc0: float | None = None) -> np.ndarray:
        """State of charge at every sample time by coulomb counting (rated ``capacity_ah`` [Ah]).

        Starts from ``soc0`` (default: the profile's own ``soc0``, or 0 when it has none).
        """
        if capacity_ah <= 0:
            raise InputError(f"capacity must be positive, got {capacity_ah} Ah")
        start = self.soc0 if soc0 is None else soc0
        start = 0.0 if start is None else float(start)
        dq = np.concatenate([[0.0], np.cumsum(self.current[:-1] * np.diff(self.t))]) / 3600.0
        return start + dq / capacity_ah

    def segments(self) -> tuple[np.ndarray, np.ndarray]:
        """Run-length form: (durations [s], currents [A]) of the zero-order-hold pieces.

        Consecutive samples with bit-identical current are merged, so a pulse is one segment whatever the
        sampling.
        """
        i = self.current[:-1]
        if i.size == 0:
            return np.zeros(0), np.zeros(0)
        starts = np.concatenate([[0], np.flatnonzero(np.diff(i) != 0) + 1])
        edges = np.concatenate([self.t[starts], [self.t[-1]]])
        return np.diff(edges), i[starts].copy()

    @classmethod
    def from_segments(cls, durations: np.ndarray, currents: np.ndarray, *, t0: float = 0.0, **meta: Any) -> Profile:
        """Build a profile from zero-order-hold pieces (durations [s], currents [A])."""
        d = np.asarray(durations, dtype=float).reshape(-1)
        c = np.asarray(currents, dtype=float).reshape(-1)
        if d.size == 0 or d.size != c.size:
            raise InputError(f"need as many durations as currents (got {d.size} and {c.size}), at least one")
        t = t0 + np.concatenate([[0.0], np.cumsum(d)])
        return cls(t, np.concatenate([c, c[-1:]]), **meta)

    def value_at(self, times: np.ndarray) -> np.ndarray:
        """Current [A] at ``times`` [s] under the zero-order hold (right limit at sample times)."""
        k = np.searchsorted(self.t, np.asarray(times, dtype=float), side="right") - 1
        return self.current[np.clip(k, 0, self.t.size - 1)]

    def with_meta(self, **meta: Any) -> Profile:
        """A copy with some metadata fields (``id``, ``kind``, ``soc0``, ``params``) replaced."""
        fields = {"id": self.id, "kind": self.kind, "soc0": self.soc0, "params": dict(self.params)}
        unknown = set(meta) - set(fields)
        if unknown:
            raise InputError(f"unknown profile field(s) {sorted(unknown)}; expected {sorted(fields)}")
        fields.update(meta)
        return type(self)(self.t, self.current, **fields)


def _rebuild(t: np.ndarray, current: np.ndarray, id: Any, kind: Any, soc0: Any, params: dict) -> Profile:  # noqa: A002
    return Profile(t, current, id=id, kind=kind, soc0=soc0, params=params)
