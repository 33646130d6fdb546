"""Shared pieces of the exporters: format rules (resolution, limits), checks and the re-import result."""

from __future__ import annotations

import math
import re
from collections.abc import Sequence
from dataclasses import dataclass, replace
from enum import Enum
from pathlib import Path

from protocols.errors import InputError
from protocols.export.program import Canonical, Item, Repeat, count_steps, expand, profile_items
from protocols.profile import Profile
from protocols.protocol import ProfileStep, Protocol, Quantity, SafetyLimits, Step


class Format(Enum):
    """Export formats."""

    MACCOR = "maccor"
    ARBIN = "arbin"
    BIOLOGIC = "biologic"
    NEWARE = "neware"
    PYBAMM = "pybamm"
    CSV = "csv"

    @classmethod
    def parse(cls, text: str | Format) -> Format:
        """Format from its name; an unknown name is an InputError listing the known ones."""
        if isinstance(text, Format):
            return text
        try:
            return cls(str(text).lower())
        except ValueError:
            names = ", ".join(f.value for f in cls)
            raise InputError(f"unknown export format {text!r}; expected one of {names}") from None


@dataclass(frozen=True)
class FormatRules:
    """What a format can represent.

    ``time_resolution_s``: every duration must be a whole multiple of it (the file's time quantum);
    ``min_duration_s``: the shortest step/segment the instrument runs; ``current_resolution_a``: currents
    are written rounded to this; ``max_steps``: the most steps (looping formats, after loop compression) or
    waveform segments (flat formats) one file may hold, None if unlimited; ``loops``: whether repeats are
    written as loops.
    """

    label: str
    time_resolution_s: float
    min_duration_s: float
    current_resolution_a: float
    max_steps: int | None
    loops: bool

    def with_max_steps(self, max_steps: int | None) -> FormatRules:
        """The same rules with another step limit (None keeps the default)."""
        return self if max_steps is None else replace(self, max_steps=max_steps)


@dataclass(frozen=True)
class ExportResult:
    """Files written (the main file first) and notes on what a format could not carry."""

    files: tuple[Path, ...]
    notes: tuple[str, ...] = ()

    @property
    def path(self) -> Path:
        """The main file."""
        return self.files[0]


@dataclass(frozen=True)
class ReadBack:
    """A re-imported export: the canonical step list, and the safety limits found (None where absent)."""

    items: list[Canonical]
    voltage_min: float | None = None
    voltage_max: float | None = None
    current_max: float | None = None
    temperature_max: float | None = None

    def profile(self, **meta: object) -> Profile:
        """The holds as one profile (for exports of a single profile)."""
        from protocols.export.program import holds_profile

        return holds_profile(self.items, **meta)


def as_protocol(source: Profile | Protocol, limits: SafetyLimits | None = None) -> Protocol:
    """A protocol for ``source`` (a profile becomes a one-step protocol)."""
    if isinstance(source, Protocol):
        return source
    if isinstance(source, Profile):
        return Protocol.from_profile(source, limits=limits)
    raise InputError(f"can only export a Profile or a Protocol, got {type(source).__name__}")


def safe_name(name: str, max_len: int = 40) -> str:
    """File-name-safe version of ``name`` (letters, digits, '-', '_'), at most ``max_len`` characters."""
    s = re.sub(r"[^A-Za-z0-9_-]+", "_", name).strip("_") or "protocol"
    return s[:max_len]


def _multiple(x: float, q: float) -> bool:
    k = round(x / q)
    return k >= 1 and math.isclose(x, k * q, rel_tol=1e-9, abs_tol=1e-9 * q)


def where(protocol: Protocol, k: int, step: Step) -> str:
    """``protocol 'name', step k (kind)`` for messages."""
    return f"protocol {protocol.name!r}, step {k} ({step.kind.value})"


def check_times(protocol: Protocol, rules: FormatRules) -> None:
    """Refuse time ends that are not whole multiples of the format's time resolution."""
    for k, s in enumerate(protocol.steps, start=1):
        for e in s.ends:
            if e.quantity is Quantity.TIME and not _multiple(e.value, rules.time_resolution_s):
                raise InputError(
                    f"{where(protocol, k, s)}: end '{e}' is finer than the {rules.label} time resolution of "
                    f"{rules.time_resolution_s:g} s; round it to a multiple of {rules.time_resolution_s:g} s"
                )


def profile_plan(protocol: Protocol, k: int, step: ProfileStep, rules: FormatRules) -> tuple[Item, ...]:
    """Holds/repeats of a profile step, refusing durations the format cannot time."""
    items = profile_items(step.profile, loops=rules.loops, current_quantum=rules.current_resolution_a)
    t = step.profile.t[0]
    quantum = max(rules.time_resolution_s, rules.min_duration_s)
    for h in expand(items):
        if h.duration < rules.min_duration_s - 1e-12 or not _multiple(h.duration, rules.time_resolution_s):
            raise InputError(
                f"{where(protocol, k, step)}: profile {step.profile.id} holds {h.current:.6g} A for "
                f"{h.duration:g} s at t = {t:g} s, finer than {rules.label}'s {quantum:g} s timing; "
                f"resample the profile on a {quantum:g} s grid or export to maccor, pybamm or csv"
            )
        t += h.duration
    return items


def check_step_count(protocol: Protocol, n_steps: int, rules: FormatRules, what: str = "steps") -> None:
    """Refuse more steps (or waveform segments) than the format takes."""
    if rules.max_steps is not None and n_steps > rules.max_steps:
        raise InputError(
            f"protocol {protocol.name!r} needs {n_steps} {what} in {rules.label} (after loop compression), "
            f"more than its {rules.max_steps}; export the drive cycle to maccor (FastWave) or pybamm/csv, "
            f"split the protocol, or raise the limit (--max-steps) if your tester takes more"
        )


def items_steps(items: Sequence[Item]) -> int:
    """Steps a looping format needs for ``items``."""
    return count_steps(items)


def has_repeat(items: Sequence[Item]) -> bool:
    """Whether any item is a loop."""
    return any(isinstance(i, Repeat) for i in items)


def fmt_num(x: float, decimals: int) -> str:
    """Fixed-point text with ``decimals`` decimals and no negative zero."""
    s = f"{x:.{decimals}f}"
    return "0." + "0" * decimals if float(s) == 0 and decimals else ("0" if float(s) == 0 else s)


def check_cycler_current(protocol: Protocol, max_current_a: float) -> None:
    """Refuse a step whose current exceeds the cycler's ``max_current_a`` [A]."""
    for k, s in enumerate(protocol.steps, start=1):
        peak = s.profile.max_abs_current if isinstance(s, ProfileStep) else abs(getattr(s, "current", 0.0))
        if peak > max_current_a * (1 + 1e-12):
            raise InputError(
                f"{where(protocol, k, s)}: needs {peak:.4g} A, beyond the cycler's {max_current_a:g} A "
                "(--max-current); scale the step down or use a channel with a larger current range"
            )
