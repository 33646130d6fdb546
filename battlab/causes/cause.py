"""The declaration of one catalog cause: a physical mechanism that can make a cell's measured voltage (or
temperature) differ from its model, declared once in its own module (:mod:`battlab.causes`).

A cause owns the base parameters that express it (a refit of them is its fix when they explain a residual) and,
when the base model cannot express it, a model extension: a submodel with its own states, equations and
parameters (unit, "off" value at which the model is the base model exactly, bounds, typical size, citation), with
exact sensitivities like the 18. It declares which experiments inform it, the model slots its extension occupies
(two extensions that own one slot cannot both be on unless they compose), and how it is validated. Every other
table (the parameter registry, the fit's informing rules, the diagnosis's directions and typical sizes, BPX keys,
command-line choices) is derived from these declarations.
"""

from __future__ import annotations

from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, field
from types import MappingProxyType
from typing import Any

from battlab.causes.extension import Extension, register_parameters
from battlab.specs import ExtensionParameter

#: why a data set cannot inform a parameter (its name without the key) or test a cause; None: it can
Reason = str | None


@dataclass(frozen=True)
class Evidence:
    """What informs a cause: the input library's profile kind (``pulse``, ``sine``, ``drive``) and the experiment
    that identifies it and separates it from what it is confused with on data that cannot tell."""

    kind: str
    experiment: str


@dataclass(frozen=True)
class Cause:
    """One catalog cause (see the module docstring).

    ``base``: the cell values (among the 18 identified parameters, or other cell keys) that express the mechanism;
    ``extension`` and ``parameters``: its submodel and the submodel's parameters (``KEY.NAME`` among the identified
    ones), or none when the base model expresses it fully; ``slots``: the parts of the model its extension changes
    (``composes_with``: causes that may own a slot with it, their changes adding up); ``uninformed(name,
    experiments, i_rest)``: why these experiments cannot inform its parameter ``name`` (i_rest [A]: the current
    below which the cell rests); ``untestable(experiments, i_rest)``: why a diagnosis on them cannot test the cause
    at any size; ``differentiable_at_off``: its voltage is differentiable at "off" (a score test is possible);
    ``example``: values that switch it on at a realistic size (tests, benchmarks); ``validated_by``: the reference
    it is checked against and where; ``separates``: per other cause that mimics it, the experiment that tells
    them apart; ``slow_cycle``: its parameters (names without the key) that change what the slow (C/20) OCV cycle
    measures, refitted with the equilibrium when the cause is fitted from a campaign's data (a current sensor's
    offset moves the charge count the equilibrium stands on)."""

    key: str
    title: str
    mechanism: str
    informed_by: Evidence
    base: tuple[str, ...] = ()
    extension: type[Extension] | None = None
    parameters: tuple[ExtensionParameter, ...] = ()
    slots: frozenset[str] = frozenset()
    composes_with: frozenset[str] = frozenset()
    uninformed: Callable[[str, Sequence[Any], float], Reason] | None = None
    untestable: Callable[[Sequence[Any], float], Reason] | None = None
    differentiable_at_off: bool = True
    example: Mapping[str, float] = field(default_factory=lambda: MappingProxyType({}))
    validated_by: str = ""
    separates: Mapping[str, str] = field(default_factory=lambda: MappingProxyType({}))
    slow_cycle: tuple[str, ...] = ()

    def __post_init__(self) -> None:
        object.__setattr__(self, "example", MappingProxyType(dict(self.example)))
        object.__setattr__(self, "separates", MappingProxyType(dict(self.separates)))
        object.__setattr__(self, "slots", frozenset(self.slots))
        object.__setattr__(self, "composes_with", frozenset(self.composes_with))
        if (self.extension is None) != (not self.parameters):
            raise ValueError(f"cause {self.key!r}: an extension and its parameters come together")
        if self.extension is not None and self.extension.key != self.key:
            raise ValueError(f"cause {self.key!r}: its extension's key is {self.extension.key!r}")
        bad = [p.name for p in self.parameters if p.extension != self.key]
        if bad:
            raise ValueError(f"cause {self.key!r}: parameters {bad} are declared for another cause")
        names = {p.name for p in self.parameters}
        if set(self.slow_cycle) - names:
            raise ValueError(f"cause {self.key!r}: slow_cycle names {sorted(set(self.slow_cycle) - names)}, not its")
        if set(self.example) - names:
            raise ValueError(f"cause {self.key!r}: example values for unknown parameters {set(self.example) - names}")
        if self.extension is not None and not self.slots:
            raise ValueError(f"cause {self.key!r}: an extension must say which model slots it occupies")
        if self.extension is not None:
            register_parameters(self.key, self.parameters)

    @property
    def qualified_names(self) -> tuple[str, ...]:
        """Its extension's parameters as identified parameters: ``KEY.NAME``."""
        return tuple(p.qualified for p in self.parameters)

    @property
    def typical(self) -> dict[str, float]:
        """Typical sizes of its extension parameters' change from "off" (name → magnitude), where declared."""
        return {p.name: float(p.typical) for p in self.parameters if p.typical is not None}

    def not_informed(self, names: Sequence[str], experiments: Sequence[Any], i_rest: float) -> dict[str, str]:
        """Of ``names`` (``KEY.NAME``), this cause's parameters that ``experiments`` cannot inform, with why."""
        if self.uninformed is None:
            return {}
        out = {}
        for n in names:
            key, _, name = n.partition(".")
            if key == self.key and (why := self.uninformed(name, experiments, i_rest)):
                out[n] = why
        return out

    def why_untestable(self, experiments: Sequence[Any], i_rest: float) -> Reason:
        """Why a diagnosis on ``experiments`` cannot test this cause whatever its size, or None."""
        if self.extension is None:
            return None
        why = self.untestable(experiments, i_rest) if self.untestable is not None else None
        if why is None and not self.differentiable_at_off:
            return "not score-tested: its voltage is not differentiable at its off value"
        return why
