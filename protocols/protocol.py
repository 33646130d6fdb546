"""Test protocols: a sequence of steps with end conditions and safety limits, read and written as TOML/JSON.

Steps (positive current = charge, SI units):

* :class:`Rest` - zero current;
* :class:`ConstantCurrent` - a fixed current [A];
* :class:`ConstantVoltage` - a fixed voltage [V], optionally with a current limit [A];
* :class:`CCCV` - constant current until ``voltage`` [V], then constant voltage there (charge if current > 0);
* :class:`ProfileStep` - a sampled current profile (:class:`protocols.Profile`), zero-order hold.

End conditions (:class:`EndCondition`, the first one met ends the step)::

    "time >= 3600"        step time [s]
    "voltage <= 2.5"      terminal voltage [V] (>= or <=)
    "current <= 0.054"    |I| [A] (the CV taper; >= or <=)
    "capacity >= 0.5"     |charge moved in the step| [Ah]

Safety limits (:class:`SafetyLimits`) abort the whole test: they are the tester's abort band, by default the
cell's window 2.5-4.2 V widened by 50 mV (so CV holds at the window edge do not trip them), |I| <= 5C and
T <= 50 degC (stored in K).

File format (TOML or JSON, same structure)::

    name = "C/20 OCV"
    capacity_ah = 2.7                 # 1C = 2.7 A; lets steps give `c_rate` instead of `current`
    [limits]
    voltage_min = 2.45                # V
    voltage_max = 4.25                # V
    current_max = 13.5                # A (magnitude)
    temperature_max = 323.15          # K
    [[steps]]
    kind = "cccv"                     # rest | cc | cv | cccv | profile
    current = 1.35                    # A, positive = charge (or c_rate = 0.5)
    voltage = 4.2
    until = ["current <= 0.054", "time >= 14400"]
    [[steps]]
    kind = "profile"
    library_id = 339                  # or: file = "p.csv" (relative to this file) or inline:
    # profile = { t = [...], current = [...], soc0 = 0.8 }

A typo (unknown field, wrong type, unknown kind) is an :class:`InputError` naming the file, the step (1-based)
and the field.
"""

from __future__ import annotations

import json
import math
import tomllib
from collections.abc import Callable, Mapping
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from protocols.constants import RATED_CAPACITY_AH
from protocols.directions import Direction
from protocols.errors import InputError
from protocols.profile import Profile
from protocols.steps import (
    CCCV,
    Comparison,
    ConstantCurrent,
    ConstantVoltage,
    EndCondition,
    ProfileStep,
    Quantity,
    Rest,
    SafetyLimits,
    Step,
    StepKind,
    after,
    capacity_reached,
    current_below,
    did_you_mean,
    number,
    step_duration,
    voltage_above,
    voltage_below,
)

__all__ = [
    "CCCV",
    "Comparison",
    "ConstantCurrent",
    "ConstantVoltage",
    "EndCondition",
    "ProfileStep",
    "Protocol",
    "Quantity",
    "Rest",
    "SafetyLimits",
    "Step",
    "StepKind",
    "after",
    "capacity_reached",
    "current_below",
    "step_duration",
    "voltage_above",
    "voltage_below",
]


_STEP_TYPES: dict[StepKind, type] = {
    StepKind.REST: Rest,
    StepKind.CC: ConstantCurrent,
    StepKind.CV: ConstantVoltage,
    StepKind.CCCV: CCCV,
    StepKind.PROFILE: ProfileStep,
}
_FIELDS: dict[StepKind, tuple[str, ...]] = {
    StepKind.REST: ("kind", "until", "label"),
    StepKind.CC: ("kind", "current", "c_rate", "until", "label"),
    StepKind.CV: ("kind", "voltage", "direction", "until", "label"),
    StepKind.CCCV: ("kind", "current", "c_rate", "voltage", "until", "label"),
    StepKind.PROFILE: ("kind", "profile", "file", "library_id", "label"),
}
_TOP_FIELDS = ("name", "description", "capacity_ah", "limits", "steps", "library")
_PROFILE_FIELDS = ("t", "current", "id", "kind", "soc0", "params")


@dataclass(frozen=True)
class Protocol:
    """A named sequence of steps with safety limits; ``capacity_ah`` is the cell's rated capacity."""

    name: str
    steps: tuple[Step, ...]
    limits: SafetyLimits = field(default_factory=SafetyLimits)
    capacity_ah: float = RATED_CAPACITY_AH
    description: str = ""

    def __post_init__(self) -> None:
        object.__setattr__(self, "steps", tuple(self.steps))
        if not self.steps:
            raise InputError(f"protocol {self.name!r}: has no steps")
        for k, s in enumerate(self.steps, start=1):
            if not isinstance(s, tuple(_STEP_TYPES.values())):
                raise InputError(f"protocol {self.name!r}: step {k} is not a step ({type(s).__name__})")
        if not self.capacity_ah > 0:
            raise InputError(f"protocol {self.name!r}: capacity_ah must be positive, got {self.capacity_ah}")

    # --- construction helpers -------------------------------------------------------------------------

    @classmethod
    def from_profile(cls, profile: Profile, *, limits: SafetyLimits | None = None, name: str | None = None) -> Protocol:
        """A protocol of one profile step."""
        label = f"profile {profile.id}" if profile.id is not None else "profile"
        return cls(name or label, (ProfileStep(profile, label),), limits or SafetyLimits())

    def check(self) -> Protocol:
        """Raise :class:`InputError` if a step asks for more than the safety limits allow."""
        lim = self.limits
        for k, s in enumerate(self.steps, start=1):
            where = f"protocol {self.name!r}, step {k} ({s.kind.value})"
            if isinstance(s, ConstantCurrent | CCCV) and abs(s.current) > lim.current_max * (1 + 1e-12):
                raise InputError(
                    f"{where}: current {s.current:g} A exceeds the limit {lim.current_max:g} A (limits.current_max)"
                )
            if isinstance(s, ProfileStep) and s.profile.max_abs_current > lim.current_max * (1 + 1e-12):
                raise InputError(
                    f"{where}: profile {s.profile.id if s.profile.id is not None else '(unnamed)'} reaches "
                    f"{s.profile.max_abs_current:.4g} A, beyond the "
                    f"limit {lim.current_max:g} A (limits.current_max); scale the profile down"
                )
            if isinstance(s, ConstantVoltage | CCCV) and not lim.voltage_min <= s.voltage <= lim.voltage_max:
                raise InputError(
                    f"{where}: voltage {s.voltage:g} V is outside the limits "
                    f"[{lim.voltage_min:g}, {lim.voltage_max:g}] V"
                )
        return self

    @property
    def profile_duration_s(self) -> float:
        """Total duration of the profile steps [s]."""
        return sum(s.profile.duration for s in self.steps if isinstance(s, ProfileStep))

    # --- dict / TOML / JSON ---------------------------------------------------------------------------

    def to_dict(self, *, profile_files: Callable[[int, Profile], str] | None = None) -> dict[str, Any]:
        """Plain-data form (TOML/JSON-ready). ``profile_files(k, profile)`` may return a file to reference."""
        lim = self.limits
        out: dict[str, Any] = {"name": self.name}
        if self.description:
            out["description"] = self.description
        out["capacity_ah"] = self.capacity_ah
        out["limits"] = {
            "voltage_min": lim.voltage_min,
            "voltage_max": lim.voltage_max,
            "current_max": lim.current_max,
            "temperature_max": lim.temperature_max,
        }
        out["steps"] = [_step_to_dict(k, s, profile_files) for k, s in enumerate(self.steps, start=1)]
        return out

    @classmethod
    def from_dict(
        cls,
        data: Mapping[str, Any],
        *,
        source: str = "protocol",
        base_dir: Path | None = None,
        library: Any = None,
    ) -> Protocol:
        """Read the plain-data form; errors name ``source``, the step and the field."""
        if not isinstance(data, Mapping):
            raise InputError(f"{source}: expected a table of protocol fields, got {type(data).__name__}")
        for key in data:
            if key not in _TOP_FIELDS:
                hint = did_you_mean(key, _TOP_FIELDS)
                raise InputError(f"{source}: unknown field {key!r}{hint}; allowed: {', '.join(_TOP_FIELDS)}")
        name = data.get("name", Path(source).stem)
        if not isinstance(name, str):
            raise InputError(f"{source}: field 'name' must be a string, got {name!r}")
        cap = data.get("capacity_ah", RATED_CAPACITY_AH)
        try:
            cap = number(cap, "capacity_ah")
            limits = _limits_from(data.get("limits", {}), source)
        except InputError as exc:
            raise InputError(f"{source}: {exc}") from None
        raw_steps = data.get("steps")
        if not isinstance(raw_steps, list) or not raw_steps:
            raise InputError(f"{source}: needs a non-empty list 'steps' ([[steps]] tables in TOML)")
        lib_ref = data.get("library")
        resolver = _LibraryResolver(library, lib_ref, base_dir, source)
        steps = [
            _step_from_dict(k, raw, cap, source=source, base_dir=base_dir, resolver=resolver)
            for k, raw in enumerate(raw_steps, start=1)
        ]
        desc = data.get("description", "")
        try:
            return cls(name, tuple(steps), limits, cap, str(desc))
        except InputError as exc:
            raise InputError(f"{source}: {exc}") from None

    def to_toml(self, path: str | Path, *, inline_profiles: bool = True) -> Path:
        """Write TOML; with ``inline_profiles=False`` profiles go to CSV files beside it."""
        import tomli_w

        path = Path(path)
        data = self.to_dict(profile_files=None if inline_profiles else _sidecar_writer(path))
        path.write_text(tomli_w.dumps(_drop_none(data)))
        return path

    def to_json(self, path: str | Path, *, inline_profiles: bool = True) -> Path:
        """Write JSON (same structure as TOML)."""
        path = Path(path)
        data = self.to_dict(profile_files=None if inline_profiles else _sidecar_writer(path))
        path.write_text(json.dumps(data, indent=1))
        return path

    def save(self, path: str | Path, *, inline_profiles: bool = True) -> Path:
        """Write TOML or JSON according to the suffix."""
        path = Path(path)
        if path.suffix.lower() == ".json":
            return self.to_json(path, inline_profiles=inline_profiles)
        if path.suffix.lower() == ".toml":
            return self.to_toml(path, inline_profiles=inline_profiles)
        raise InputError(f"{path}: protocol files end in .toml or .json")

    @classmethod
    def load(cls, path: str | Path, *, library: Any = None) -> Protocol:
        """Read a TOML or JSON protocol file (``library``: a Library or path for ``library_id`` steps)."""
        path = Path(path)
        data = read_table_file(path, "protocol")
        return cls.from_dict(data, source=str(path), base_dir=path.parent, library=library)


def read_table_file(path: Path, what: str) -> Any:
    """The data of a TOML or JSON file; a missing file, another suffix or bad syntax is an :class:`InputError`
    naming ``path`` and ``what`` it should be (e.g. "protocol", "plan")."""
    if not path.is_file():
        raise InputError(f"{path}: no such {what} file")
    try:
        text = path.read_text(encoding="utf-8")
    except UnicodeDecodeError:
        raise InputError(f"{path}: not a text file (binary content); expected a {what} .toml or .json") from None
    suffix = path.suffix.lower()
    try:
        if suffix == ".json":
            return json.loads(text)
        if suffix == ".toml":
            return tomllib.loads(text)
    except (json.JSONDecodeError, tomllib.TOMLDecodeError) as exc:
        raise InputError(f"{path}: not valid {suffix[1:].upper()}: {exc}") from None
    raise InputError(f"{path}: {what} files end in .toml or .json")


def _drop_none(obj: Any) -> Any:
    if isinstance(obj, dict):
        return {k: _drop_none(v) for k, v in obj.items() if v is not None}
    if isinstance(obj, list):
        return [_drop_none(v) for v in obj]
    return obj


def _sidecar_writer(path: Path) -> Callable[[int, Profile], str]:
    folder = path.with_name(path.stem + ".profiles")

    def write(k: int, profile: Profile) -> str:
        folder.mkdir(exist_ok=True)
        target = folder / f"step{k:03d}.csv"
        profile.to_csv(target)
        return str(target.relative_to(path.parent))

    return write


def _limits_from(raw: Any, source: str) -> SafetyLimits:
    if not isinstance(raw, Mapping):
        raise InputError(f"'limits' must be a table, got {raw!r}")
    names = ("voltage_min", "voltage_max", "current_max", "temperature_max")
    for key in raw:
        if key not in names:
            raise InputError(f"limits: unknown field {key!r}{did_you_mean(key, names)}; allowed: {', '.join(names)}")
    return SafetyLimits(**{k: raw[k] for k in names if k in raw})


def _profile_to_dict(p: Profile) -> dict[str, Any]:
    out: dict[str, Any] = {}
    if p.id is not None:
        out["id"] = p.id
    if p.kind is not None:
        out["kind"] = p.kind
    if p.soc0 is not None:
        out["soc0"] = float(p.soc0)
    if p.params:
        out["params"] = _drop_none(json.loads(json.dumps(dict(p.params))))
    out["t"] = [float(x) for x in p.t]
    out["current"] = [float(x) for x in p.current]
    return out


def _step_to_dict(k: int, s: Step, profile_files: Callable[[int, Profile], str] | None) -> dict[str, Any]:
    d: dict[str, Any] = {"kind": s.kind.value}
    if isinstance(s, ConstantCurrent | CCCV):
        d["current"] = s.current
    if isinstance(s, ConstantVoltage | CCCV):
        d["voltage"] = s.voltage
    if isinstance(s, ConstantVoltage):
        d["direction"] = s.direction.value
    if isinstance(s, ProfileStep):
        if profile_files is not None:
            d["file"] = profile_files(k, s.profile)
            meta = {"id": s.profile.id, "kind": s.profile.kind, "soc0": s.profile.soc0}
            d["profile"] = {key: v for key, v in meta.items() if v is not None}
        else:
            d["profile"] = _profile_to_dict(s.profile)
    if s.ends:
        d["until"] = [str(e) for e in s.ends]
    if s.label:
        d["label"] = s.label
    return d


class _LibraryResolver:
    """Finds library profiles for ``library_id`` steps: the given Library/path, the file's
    ``library`` key, or a fresh deterministic build."""

    def __init__(self, library: Any, ref: Any, base_dir: Path | None, source: str) -> None:
        self._given, self._ref, self._base, self._source = library, ref, base_dir, source
        self._lib: Any = None

    def get(self, pid: Any, where: str) -> Profile:
        from protocols.library import Library

        if self._lib is None:
            if isinstance(self._given, Library):
                self._lib = self._given
            elif self._given is not None or self._ref is not None:
                ref = Path(self._given if self._given is not None else self._ref)
                if not ref.is_absolute() and self._base is not None and self._given is None:
                    ref = self._base / ref
                self._lib = Library.load(ref)
            else:
                self._lib = Library.build()
        try:
            return self._lib[pid]
        except InputError as exc:
            raise InputError(f"{where}: field 'library_id': {exc}") from None


def _step_from_dict(
    k: int, raw: Any, capacity_ah: float, *, source: str, base_dir: Path | None, resolver: _LibraryResolver
) -> Step:
    where = f"{source}: step {k}"
    if not isinstance(raw, Mapping):
        raise InputError(f"{where}: expected a table of step fields, got {raw!r}")
    kind_raw = raw.get("kind")
    kinds = [s.value for s in StepKind]
    if kind_raw is None:
        raise InputError(f"{where}: missing field 'kind' (one of {', '.join(kinds)})")
    try:
        kind = StepKind(kind_raw)
    except ValueError:
        raise InputError(
            f"{where}: field 'kind': unknown step kind {kind_raw!r}{did_you_mean(str(kind_raw), kinds)}; "
            f"expected one of {', '.join(kinds)}"
        ) from None
    allowed = _FIELDS[kind]
    for key in raw:
        if key not in allowed:
            hint = did_you_mean(key, allowed)
            raise InputError(f"{where} ({kind.value}): unknown field {key!r}{hint}; allowed: {', '.join(allowed)}")

    def num(name: str, unit: str) -> float:
        if name not in raw:
            raise InputError(f"{where} ({kind.value}): missing field {name!r} [{unit}]")
        v = raw[name]
        if isinstance(v, bool) or not isinstance(v, int | float) or not math.isfinite(v):
            raise InputError(f"{where} ({kind.value}): field {name!r} must be a number [{unit}], got {v!r}")
        return float(v)

    def current() -> float:
        if "current" in raw and "c_rate" in raw:
            raise InputError(f"{where} ({kind.value}): give 'current' or 'c_rate', not both")
        if "c_rate" in raw:
            return num("c_rate", "1/h") * capacity_ah
        return num("current", "A")

    until = raw.get("until", [])
    if isinstance(until, str):
        until = [until]
    if not isinstance(until, list):
        raise InputError(f"{where} ({kind.value}): field 'until' must be a list of strings, got {until!r}")
    label = raw.get("label", "")
    if not isinstance(label, str):
        raise InputError(f"{where} ({kind.value}): field 'label' must be a string, got {label!r}")
    try:
        if kind is StepKind.REST:
            return Rest(tuple(until), label)
        if kind is StepKind.CC:
            return ConstantCurrent(current(), tuple(until), label)
        if kind is StepKind.CV:
            direction = raw.get("direction", Direction.CHARGE.value)
            return ConstantVoltage(num("voltage", "V"), tuple(until), direction, label)
        if kind is StepKind.CCCV:
            return CCCV(current(), num("voltage", "V"), tuple(until), label)
        profile = _profile_from(raw, where, base_dir, resolver)
        return ProfileStep(profile, label)
    except InputError as exc:
        msg = str(exc)
        raise InputError(msg if msg.startswith(source) else f"{where} ({kind.value}): {msg}") from None


def _profile_from(raw: Mapping[str, Any], where: str, base_dir: Path | None, resolver: _LibraryResolver) -> Profile:
    sources = [key for key in ("file", "library_id") if key in raw]
    inline = raw.get("profile")
    if inline is not None and not isinstance(inline, Mapping):
        raise InputError(f"field 'profile' must be a table, got {inline!r}")
    inline = dict(inline or {})
    for key in inline:
        if key not in _PROFILE_FIELDS:
            raise InputError(
                f"field 'profile': unknown field {key!r}{did_you_mean(key, _PROFILE_FIELDS)}; "
                f"allowed: {', '.join(_PROFILE_FIELDS)}"
            )
    has_data = "t" in inline or "current" in inline
    if len(sources) + has_data != 1:
        raise InputError("give exactly one of 'file', 'library_id' or inline profile.t/profile.current")
    meta = {key: inline[key] for key in ("id", "kind", "soc0", "params") if key in inline}
    if "file" in raw:
        f = Path(raw["file"])
        if not f.is_absolute() and base_dir is not None:
            f = base_dir / f
        return Profile.from_csv(f, **meta)
    if "library_id" in raw:
        p = resolver.get(raw["library_id"], where)
        return p.with_meta(**meta) if meta else p
    for key in ("t", "current"):
        if not isinstance(inline.get(key), list):
            raise InputError(f"field 'profile.{key}' must be a list of numbers")
    try:
        return Profile(np.asarray(inline["t"], dtype=float), np.asarray(inline["current"], dtype=float), **meta)
    except (TypeError, ValueError):
        raise InputError("fields 'profile.t' and 'profile.current' must hold numbers only") from None
