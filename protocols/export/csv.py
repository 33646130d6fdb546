"""Plain CSV export: the profile's samples with Battery Data Format column names.

Conventions: columns ``Test Time / s`` and ``Current / A``; current positive = charge (BDF); one row per
sample, zero-order hold (the current of a row flows until the next row's time); values written with 10
significant digits (1 us up to an hour, 10 nA below 100 A). Only timed currents can be written: a rest or
CC step that ends on time alone becomes samples, any other step (voltage, current or capacity ends, CV,
CCCV) is refused. Consecutive steps are joined on one time axis starting at 0. No segment limit.
"""

from __future__ import annotations

from pathlib import Path

from protocols.errors import InputError
from protocols.export.base import ExportResult, FormatRules, ReadBack, check_times, safe_name, where
from protocols.export.program import Hold, canonical, holds_profile, merge_holds
from protocols.profile import Profile
from protocols.protocol import Protocol

RULES = FormatRules(
    label="CSV",
    time_resolution_s=1e-6,
    min_duration_s=1e-6,
    current_resolution_a=1e-8,
    max_steps=None,
    loops=False,
)


def write(protocol: Protocol, out_dir: Path, *, name: str | None = None, rules: FormatRules = RULES) -> ExportResult:
    """Write ``<name>.csv``."""
    check_times(protocol, rules)
    items = canonical(protocol)
    for x in items:
        if not isinstance(x, Hold):
            k = next(i for i, s in enumerate(protocol.steps, start=1) if s is x)
            raise InputError(
                f"{where(protocol, k, x)}: a CSV profile holds current vs time only, and this step has "
                "no fixed duration and current; export to maccor, arbin, biologic, neware or pybamm"
            )
    first = protocol.steps[0]
    meta = {}
    if len(protocol.steps) == 1 and hasattr(first, "profile"):
        p: Profile = first.profile  # type: ignore[union-attr]
        meta = {"id": p.id, "kind": p.kind, "soc0": p.soc0}
    profile = holds_profile(items, **meta)
    path = Path(out_dir) / f"{safe_name(name or protocol.name)}.csv"
    profile.to_csv(path)
    return ExportResult((path,))


def read(path: str | Path) -> ReadBack:
    """Re-import a CSV written by :func:`write`."""
    p = Profile.from_csv(path)
    d, c = p.segments()
    return ReadBack(merge_holds(Hold(float(x), float(y)) for x, y in zip(d, c, strict=True)))
