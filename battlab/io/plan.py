"""The plan file, shared by design (writes), the lab (runs) and identification (reads the groups).

What to run: a protocol plus run options, expanded into the entries the run engine executes. A plan file is a
protocol file (TOML or JSON, :meth:`protocols.Protocol.load`) with an optional ``[run]``
table of run options (:class:`RunOptions`)::

    name = "OED group 1"
    [run]
    sample_period_s = 1.0        # s between samples (profile steps also sample at every current change)
    ambient_degC = 25.0          # chamber set point
    repeat = 3                   # trials of every profile (for the noise model); each trial repeats the
                                 # steps that prepare it since the previous profile (SOC adjustment, rest)
    stable_hold_s = 600          # the chamber must hold ±stable_tol_K for this long before the run starts
    [limits]
    ...
    [[steps]]
    ...

Plans say *what*; :mod:`battlab.lab.engine` decides how. ``battlab design`` writes the design metadata
(parameter groups and the profiles selected for each) beside the plan in ``<plan>.summary.json``;
:func:`design_groups` reads it back (or its older names ``<plan>.design.json`` and ``summary.json``), and a plan
without it is grouped by its profile steps' labels ('group N: …') with the paper's Table 9 groups.
"""

from __future__ import annotations

import json
import math
from collections.abc import Mapping
from dataclasses import asdict, dataclass, fields
from pathlib import Path
from typing import Any

from battlab.io.paths import summary_path
from protocols.errors import InputError
from protocols.protocol import ProfileStep, Protocol, Step, read_table_file


@dataclass(frozen=True)
class RunOptions:
    """How the engine runs a plan. Times are in the run clock's seconds (virtual seconds on the virtual tester)
    except ``flush_s`` (real seconds: it bounds what a killed runner can lose)."""

    sample_period_s: float = 1.0
    ambient_degC: float = 25.0
    repeat: int = 1
    stable_tol_K: float = 0.5
    stable_timeout_s: float = 4 * 3600.0
    stable_hold_s: float = 600.0
    #: chamber read (and alarm check) period
    chamber_period_s: float = 10.0
    #: protection-state poll period (a trip is also noticed at once when the measured current drops)
    protection_period_s: float = 10.0
    flush_s: float = 1.0
    #: instrument watchdog (None: 60 s, and at least 0.06 s of real time on an accelerated clock)
    watchdog_s: float | None = None
    #: link: retries of a failed instrument call (after the driver's own) and the first back-off
    comm_retries: int = 3
    backoff_s: float = 0.5
    #: CV regulation: fraction of the voltage error corrected per sample (integral gain, ≤ 1)
    cv_gain: float = 0.5

    def __post_init__(self) -> None:
        for f in fields(self):
            v = getattr(self, f.name)
            if f.name == "watchdog_s" and v is None:
                continue
            if isinstance(v, bool) or not isinstance(v, int | float) or not math.isfinite(v):
                raise InputError(f"[run] {f.name} must be a number, got {v!r}")
        if self.repeat < 1 or int(self.repeat) != self.repeat:
            raise InputError(f"[run] repeat must be a whole number >= 1, got {self.repeat!r}")
        if self.comm_retries < 0 or int(self.comm_retries) != self.comm_retries:
            raise InputError(f"[run] comm_retries must be a whole number >= 0, got {self.comm_retries!r}")
        positive = (
            "sample_period_s",
            "stable_tol_K",
            "stable_timeout_s",
            "chamber_period_s",
            "protection_period_s",
            "flush_s",
        )
        for name in positive:
            if getattr(self, name) <= 0:
                raise InputError(f"[run] {name} must be positive, got {getattr(self, name)!r}")
        if self.stable_hold_s < 0 or self.backoff_s < 0:
            raise InputError("[run] stable_hold_s and backoff_s must be >= 0")
        if not 0 < self.cv_gain <= 1:
            raise InputError(f"[run] cv_gain must be in (0, 1], got {self.cv_gain!r}")
        if self.watchdog_s is not None and self.watchdog_s <= 0:
            raise InputError(f"[run] watchdog_s must be positive, got {self.watchdog_s!r}")
        object.__setattr__(self, "repeat", int(self.repeat))
        object.__setattr__(self, "comm_retries", int(self.comm_retries))

    @classmethod
    def from_dict(cls, raw: Any, source: str) -> RunOptions:
        if not isinstance(raw, Mapping):
            raise InputError(f"{source}: [run] must be a table, got {raw!r}")
        names = [f.name for f in fields(cls)]
        unknown = [k for k in raw if k not in names]
        if unknown:
            raise InputError(f"{source}: [run] unknown field(s) {unknown}; allowed: {', '.join(names)}")
        try:
            return cls(**dict(raw))
        except InputError as exc:
            raise InputError(f"{source}: {exc}") from None

    def to_dict(self) -> dict[str, Any]:
        return {k: v for k, v in asdict(self).items() if v is not None}


@dataclass(frozen=True)
class PlanEntry:
    """One step execution: ``entry`` (0-based position in the run), ``step_index`` (1-based, in the protocol),
    ``trial`` (1-based repetition of a profile block)."""

    entry: int
    step_index: int
    trial: int
    step: Step

    @property
    def label(self) -> str:
        base = self.step.label or self.step.kind.value
        return f"{base} (trial {self.trial})" if self.trial > 1 else base


@dataclass(frozen=True)
class Plan:
    """A protocol and how to run it."""

    protocol: Protocol
    options: RunOptions = RunOptions()
    source: str = ""

    def entries(self) -> list[PlanEntry]:
        """The steps in execution order; with ``repeat`` > 1 each profile's block runs ``repeat`` times.

        A profile's block is the profile step and the steps since the previous profile step (its preparation);
        the steps after the last profile run once.
        """
        steps = self.protocol.steps
        out: list[tuple[int, int]] = []  # (step_index, trial)
        block_start = 0
        for k, s in enumerate(steps):
            if isinstance(s, ProfileStep):
                for trial in range(1, self.options.repeat + 1):
                    out.extend((j + 1, trial) for j in range(block_start, k + 1))
                block_start = k + 1
        out.extend((j + 1, 1) for j in range(block_start, len(steps)))
        return [PlanEntry(n, idx, trial, steps[idx - 1]) for n, (idx, trial) in enumerate(out)]

    def to_dict(self) -> dict[str, Any]:
        """The plan as data (profiles inline): what the catalog stores so that a resume runs the same plan."""
        data = self.protocol.to_dict()
        data["run"] = self.options.to_dict()
        return data

    @classmethod
    def from_dict(
        cls, data: Mapping[str, Any], *, source: str = "plan", base_dir: Path | None = None, library: Any = None
    ) -> Plan:
        if not isinstance(data, Mapping):
            raise InputError(f"{source}: expected a table of plan fields")
        body = dict(data)
        options = RunOptions.from_dict(body.pop("run", {}), source)
        protocol = Protocol.from_dict(body, source=source, base_dir=base_dir, library=library)
        return cls(protocol, options, source)

    @classmethod
    def load(cls, path: str | Path, *, library: Any = None) -> Plan:
        """Read a plan (protocol + optional ``[run]``) from TOML or JSON."""
        path = Path(path)
        data = read_table_file(path, "plan")
        return cls.from_dict(data, source=str(path), base_dir=path.parent, library=library)


def sidecar_path(plan: str | Path) -> Path:
    """``<plan>.summary.json``: the design metadata (the design's summary) written beside a plan."""
    return summary_path(plan)


def legacy_sidecar_paths(plan: str | Path) -> tuple[Path, Path]:
    """The design metadata's older names, still read: ``<plan>.design.json``, then a ``summary.json`` beside the
    plan (skipped when it is another command's summary, without 'groups')."""
    plan = Path(plan)
    return plan.with_name(f"{plan.stem}.design.json"), plan.with_name("summary.json")


#: the key under which a run log's metadata holds the design's groups (the runner copies them from the plan's design
#: summary, so that the fit of the log alone finds them)
DESIGN_GROUPS = "design_groups"


@dataclass(frozen=True)
class DesignGroup:
    """One identification group of a design: its parameters and the library ids of its selected profiles."""

    parameters: tuple[str, ...]
    selected: frozenset[str]

    def to_dict(self) -> dict[str, Any]:
        return {"parameters": list(self.parameters), "selected": sorted(self.selected)}


def design_groups(plan: str | Path, *, library: Any = None) -> list[DesignGroup]:
    """The groups of a design plan: from ``<plan>.summary.json`` beside it (else the older ``<plan>.design.json``
    or ``summary.json``), else from the plan's profile steps labelled 'group N' with the paper's Table 9 groups.
    The plan itself must load (with or without a ``[run]`` table)."""
    loaded = Plan.load(Path(plan), library=library)
    found = summary_groups(plan)
    return found if found is not None else label_groups(loaded.protocol)


def summary_groups(plan: str | Path) -> list[DesignGroup] | None:
    """The groups of the design summary beside ``plan`` (``<plan>.summary.json``, else the older
    ``<plan>.design.json`` or a ``summary.json`` with 'groups'), or None when there is none."""
    path = Path(plan)
    fixed = path.with_name("summary.json")
    for meta in (sidecar_path(path), *legacy_sidecar_paths(path)):
        if not meta.is_file():
            continue
        try:
            data = json.loads(meta.read_text())
            if meta == fixed and isinstance(data, dict) and "groups" not in data:
                continue  # the fixed name was shared by every command: this one is not the design's
            return groups_from_dicts(data["groups"])
        except (KeyError, TypeError, json.JSONDecodeError) as exc:
            raise InputError(f"{meta}: expected the design summary with 'groups' ({exc})") from None
    return None


def groups_from_dicts(groups: Any) -> list[DesignGroup]:
    """Groups from their summary form ``[{"parameters": [...], "selected": [ids]}, ...]``."""
    return [DesignGroup(tuple(g["parameters"]), frozenset(str(s) for s in g["selected"])) for g in groups]


def label_groups(protocol: Protocol) -> list[DesignGroup]:
    """The paper's Table 9 groups, each with the profile steps labelled 'group N' (unlabelled ones: group 1)."""
    from battlab.parameters import TABLE9_GROUPS

    found: list[set[str]] = [set() for _ in TABLE9_GROUPS]
    for s in protocol.steps:
        if isinstance(s, ProfileStep):
            label = s.label.lower()
            k = int(label.split("group", 1)[1].split()[0].strip(":")) - 1 if "group" in label else 0
            if 0 <= k < len(found):
                found[k].add(str(s.profile.id))
    return [DesignGroup(tuple(g), frozenset(sel)) for g, sel in zip(TABLE9_GROUPS, found, strict=True)]


__all__ = [
    "DESIGN_GROUPS",
    "DesignGroup",
    "Plan",
    "PlanEntry",
    "RunOptions",
    "design_groups",
    "groups_from_dicts",
    "label_groups",
    "sidecar_path",
    "summary_groups",
]
