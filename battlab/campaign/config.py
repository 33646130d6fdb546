"""Campaign settings: a TOML file of sections, each a frozen dataclass with defaults for the full campaign and a
reduced ``--quick`` variant for a demonstration.

Example (every key optional)::

    [campaign]
    start = "nca18650"            # the cell the fits start from (built-in name or BPX file)
    truth = "nca18650-true"       # the virtual lab's hidden cell (ignored on real instruments)
    ambient_degC = 25.0
    seed = 0
    [library]
    ids = []                      # library profile ids to sweep (empty: all); --quick takes a small subset
    [design]
    criterion = "D"               # D | A | E
    profiles_per_group = 5        # M
    groups = "computed"           # computed | table9
    [noise]
    repeats = 3                   # repeated trials of the noise profiles (eqs. 36-40)
    profiles_per_direction = 3    # charge-only and discharge-only pulse profiles, spread over intensity
    max_duration_s = 3600.0       # the longest noise profile [s] (--quick: 900)
    [fit]
    max_evaluations = 40          # per stage (the optimiser's function evaluations)
    polish = 8                    # Gauss-Newton polish simulations after an optimiser stopped by max_evaluations
    [conventional]
    c_rates = []                  # constant-current tests (C; < 0 discharge from full, > 0 charge from empty),
                                  # run with UDDS from SOC 0.8; empty: the paper's set (--quick: -1/3, -2)
    [validation]
    c_rates = []                  # discharges from full (C, > 0), with US06 from SOC 0.8; empty: 0.5, 1 (--quick: 1)
    [diagnosis]
    decide = true                 # run the experiment that separates causes the data cannot tell apart
    budget_hours = 24.0           # lab hours those experiments may take
    ambients_degC = [10.0, 25.0, 40.0]   # what the chamber reaches ([25.0]: no chamber range)
    max_evaluations = 20          # per held-out fit of a cause
    [stages]
    skip = []                     # stage names to leave out (e.g. ["conventional"])

Unknown sections, keys or stage names are one clear error naming the file and the key, before anything runs.
"""

from __future__ import annotations

import dataclasses
import tomllib
from dataclasses import dataclass, field, fields, replace
from pathlib import Path
from typing import Any

from protocols.errors import InputError
from protocols.steps import did_you_mean


@dataclass(frozen=True)
class CampaignSection:
    start: str = "nca18650"
    truth: str = "nca18650-true"
    ambient_degC: float = 25.0
    seed: int = 0


@dataclass(frozen=True)
class LibrarySection:
    ids: tuple[int, ...] = ()


@dataclass(frozen=True)
class DesignSection:
    criterion: str = "D"
    profiles_per_group: int = 5
    groups: str = "computed"


@dataclass(frozen=True)
class NoiseSection:
    repeats: int = 3
    profiles_per_direction: int = 3
    max_duration_s: float = 3600.0


@dataclass(frozen=True)
class FitSection:
    max_evaluations: int = 40
    polish: int = 8


@dataclass(frozen=True)
class ConventionalSection:
    c_rates: tuple[float, ...] = ()


@dataclass(frozen=True)
class ValidationSection:
    c_rates: tuple[float, ...] = ()


@dataclass(frozen=True)
class DiagnosisSection:
    decide: bool = True
    budget_hours: float = 24.0
    ambients_degC: tuple[float, ...] = (10.0, 25.0, 40.0)
    max_evaluations: int = 20


@dataclass(frozen=True)
class StagesSection:
    skip: tuple[str, ...] = ()


@dataclass(frozen=True)
class CampaignConfig:
    """All campaign settings; ``quick`` marks the reduced demonstration."""

    campaign: CampaignSection = field(default_factory=CampaignSection)
    library: LibrarySection = field(default_factory=LibrarySection)
    design: DesignSection = field(default_factory=DesignSection)
    noise: NoiseSection = field(default_factory=NoiseSection)
    fit: FitSection = field(default_factory=FitSection)
    conventional: ConventionalSection = field(default_factory=ConventionalSection)
    validation: ValidationSection = field(default_factory=ValidationSection)
    diagnosis: DiagnosisSection = field(default_factory=DiagnosisSection)
    stages: StagesSection = field(default_factory=StagesSection)
    quick: bool = False

    def as_dict(self) -> dict[str, Any]:
        return dataclasses.asdict(self)


#: a small library subset for --quick: pulses, sines and drive cycles that together inform every parameter group
#: (a greedy D-optimal pick over the whole library at the nominal cell); the validation profiles are not among them
QUICK_LIBRARY_IDS: tuple[int, ...] = (1, 19, 37, 109, 379, 397, 415, 487, 505, 541, 667, 721)


def quick(config: CampaignConfig) -> CampaignConfig:
    """The reduced campaign: a small library, fewer profiles per group, noise profiles and repeats, a short fit
    (5 evaluations and 1 polish simulation per stage); the tester rests 300 s instead of 600 s after each
    measured profile, the conventional baseline is the C/3 and 2C discharges plus UDDS, and validation is the 1C
    discharge plus US06 (:mod:`battlab.campaign.assessment`)."""
    lib = config.library if config.library.ids else LibrarySection(QUICK_LIBRARY_IDS)
    return replace(
        config,
        quick=True,
        library=lib,
        design=replace(config.design, profiles_per_group=min(config.design.profiles_per_group, 2)),
        noise=replace(
            config.noise,
            repeats=min(config.noise.repeats, 2),
            profiles_per_direction=min(config.noise.profiles_per_direction, 2),
            max_duration_s=min(config.noise.max_duration_s, 900.0),
        ),
        fit=replace(config.fit, max_evaluations=min(config.fit.max_evaluations, 5), polish=min(config.fit.polish, 1)),
    )


_CHOICES = {("design", "criterion"): ("D", "A", "E"), ("design", "groups"): ("computed", "table9")}


def _coerce(value: Any, default: Any, where: str) -> Any:
    if isinstance(default, bool):
        if not isinstance(value, bool):
            raise InputError(f"{where}: expected true or false, got {value!r}")
        return value
    if isinstance(default, int):
        if isinstance(value, bool) or not isinstance(value, int) or value < 0:
            raise InputError(f"{where}: expected a non-negative integer, got {value!r}")
        return value
    if isinstance(default, float):
        if isinstance(value, bool) or not isinstance(value, (int, float)):
            raise InputError(f"{where}: expected a number, got {value!r}")
        return float(value)
    if isinstance(default, tuple):
        if not isinstance(value, list):
            raise InputError(f"{where}: expected a list, got {value!r}")
        if where.endswith(".c_rates"):
            if not all(isinstance(v, int | float) and not isinstance(v, bool) and v != 0 for v in value):
                raise InputError(f"{where}: expected a list of non-zero C-rates, got {value!r}")
            return tuple(float(v) for v in value)
        if where.endswith("_degC"):
            if not value or not all(isinstance(v, int | float) and not isinstance(v, bool) for v in value):
                raise InputError(f"{where}: expected a list of temperatures in degC, got {value!r}")
            if not all(-40.0 <= v <= 80.0 for v in value):
                raise InputError(f"{where}: temperatures must lie within -40..80 degC, got {value!r}")
            return tuple(float(v) for v in value)
        kind = int if where.endswith(".ids") else str
        if not all(isinstance(v, kind) and not isinstance(v, bool) for v in value):
            raise InputError(f"{where}: expected a list of {kind.__name__}, got {value!r}")
        return tuple(value)
    if not isinstance(value, str):
        raise InputError(f"{where}: expected a string, got {value!r}")
    return value


def from_dict(data: dict[str, Any], source: str, stage_names: tuple[str, ...] = ()) -> CampaignConfig:
    """Settings from a parsed TOML document; ``stage_names`` are the stages ``[stages] skip`` may name."""
    sections = {f.name: f for f in fields(CampaignConfig) if f.name != "quick"}
    out: dict[str, Any] = {}
    for name, body in data.items():
        if name not in sections:
            raise InputError(f"{source}: unknown section [{name}]{did_you_mean(name, list(sections))}")
        if not isinstance(body, dict):
            raise InputError(f"{source}: [{name}] must be a table")
        cls = sections[name].default_factory()  # type: ignore[misc]
        allowed = {f.name: getattr(cls, f.name) for f in fields(cls)}
        values = {}
        for key, value in body.items():
            where = f"{source}: {name}.{key}"
            if key not in allowed:
                raise InputError(
                    f"{where}: unknown key{did_you_mean(key, list(allowed))}; allowed: {', '.join(allowed)}"
                )
            v = _coerce(value, allowed[key], where)
            choices = _CHOICES.get((name, key))
            if choices and v not in choices:
                raise InputError(f"{where}: expected one of {', '.join(choices)}, got {v!r}")
            values[key] = v
        out[name] = replace(cls, **values)
    config = CampaignConfig(**out)
    for s in config.stages.skip:
        if stage_names and s not in stage_names:
            raise InputError(
                f"{source}: stages.skip: unknown stage {s!r}{did_you_mean(s, list(stage_names))}; "
                f"stages are {', '.join(stage_names)}"
            )
    if config.design.profiles_per_group < 1:
        raise InputError(f"{source}: design.profiles_per_group must be at least 1")
    return config


def load(path: str | Path | None, stage_names: tuple[str, ...] = ()) -> CampaignConfig:
    """Read a campaign TOML (or the defaults when ``path`` is None)."""
    if path is None:
        return CampaignConfig()
    p = Path(path)
    try:
        data = tomllib.loads(p.read_text())
    except FileNotFoundError:
        raise InputError(f"{p}: no such campaign config") from None
    except (OSError, UnicodeDecodeError) as exc:
        raise InputError(f"{p}: cannot read ({exc})") from None
    except tomllib.TOMLDecodeError as exc:
        raise InputError(f"{p}: not valid TOML ({exc})") from None
    return from_dict(data, str(p), stage_names)
