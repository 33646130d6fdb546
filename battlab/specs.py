"""What an identified parameter is: name, unit, bounds and its normalisation to θ̄ ∈ [0, 1] (eq. 1).

The 18 dynamic parameters (:mod:`battlab.parameters`) and the parameters of the model extensions (declared by
their causes, :mod:`battlab.causes`) are both :class:`ParameterSpec` values. Bounds apply to identification only:
:meth:`ParameterSpec.normalise` and :meth:`ParameterSpec.denormalise` accept values outside [0, 1].
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from enum import Enum

from protocols.errors import InputError


class Scale(Enum):
    """How a parameter is normalised to θ̄ (eq. 1)."""

    LOG = "log"
    LINEAR = "linear"


@dataclass(frozen=True)
class ParameterSpec:
    """One identified parameter: name, symbol, unit, bounds, nominal and the paper's Table 11 result."""

    name: str
    symbol: str
    unit: str
    lower: float
    upper: float
    nominal: float
    truth: float
    scale: Scale
    description: str

    def normalise(self, value: float) -> float:
        """θ̄ from θ (eq. 1)."""
        if self.scale is Scale.LOG:
            if value <= 0:
                raise InputError(f"{self.name} must be positive for log normalisation, got {value}")
            return (math.log(value) - math.log(self.lower)) / (math.log(self.upper) - math.log(self.lower))
        return (value - self.lower) / (self.upper - self.lower)

    def denormalise(self, theta_bar: float) -> float:
        """θ from θ̄ (inverse of eq. 1)."""
        if self.scale is Scale.LOG:
            return math.exp(math.log(self.lower) + theta_bar * (math.log(self.upper) - math.log(self.lower)))
        return self.lower + theta_bar * (self.upper - self.lower)

    def dvalue_dnormalised(self, value: float) -> float:
        """dθ/dθ̄ at θ: the chain-rule factor from physical to normalised sensitivities."""
        if self.scale is Scale.LOG:
            return value * (math.log(self.upper) - math.log(self.lower))
        return self.upper - self.lower


@dataclass(frozen=True)
class ExtensionParameter(ParameterSpec):
    """A parameter of a model extension: ``off`` is the value at which the extension is the base model exactly
    (its nominal and truth), ``citation`` the model it comes from; ``shapes``: it only shapes the effect (a rate or
    exponent), so it has none while the sizes are at ``off``; ``typical``: a typical size of its change from
    ``off`` in a real cell (magnitude, its unit; None for a shape), against which the smallest change a data set
    would detect is compared. Always normalised linearly (``off`` may be 0)."""

    extension: str = ""
    off: float = 0.0
    citation: str = ""
    shapes: bool = False
    typical: float | None = None

    @property
    def qualified(self) -> str:
        """Its name among the identified parameters: ``KEY.NAME``."""
        return f"{self.extension}.{self.name}"


def extension_parameter(
    key: str,
    name: str,
    unit: str,
    bounds: tuple[float, float],
    off: float,
    what: str,
    citation: str,
    *,
    typical: float | None = None,
    shapes: bool = False,
) -> ExtensionParameter:
    """An extension's parameter of cause ``key`` (linear normalisation over ``bounds``; nominal and truth at
    ``off``)."""
    lo, hi = bounds
    return ExtensionParameter(
        name, name, unit, lo, hi, off, off, Scale.LINEAR, what, key, off, citation, shapes, typical
    )
