"""The model's option set: the thermal option and the model extensions that are on.

Each extension is declared with its cause (:mod:`battlab.causes`: the submodel's states, equations and hooks, its
parameters); :data:`CATALOG` maps the catalog keys to their extension classes. :class:`ModelOptions` is part of the
compiled stepper's cache key (the generated source differs per option set).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import TYPE_CHECKING

from battlab import causes, parameters
from battlab.causes.extension import Extension
from protocols.errors import InputError

if TYPE_CHECKING:
    from battlab.cell import Cell

#: catalog key → extension class, in catalog order (the order of θ̄ after the 18)
CATALOG: dict[str, type[Extension]] = {c.key: c.extension for c in causes.extended() if c.extension is not None}


@dataclass(frozen=True)
class ModelOptions:
    """The option set of one compiled model: the thermal option and the extensions that are on (catalog order).

    Immutable and hashable: a cache key. Contradictory options (an extension given twice, two extensions owning one
    model slot, a thermal extension in an isothermal model) are one :class:`InputError`."""

    isothermal: bool = False
    extensions: tuple[Extension, ...] = ()

    def __post_init__(self) -> None:
        keys = [e.key for e in self.extensions]
        if len(set(keys)) != len(keys):
            raise InputError(f"model options: an extension is given twice ({keys})")
        order = list(CATALOG)
        object.__setattr__(self, "extensions", tuple(sorted(self.extensions, key=lambda e: order.index(e.key))))
        clash = causes.slot_conflicts([e.key for e in self.extensions])
        if clash:
            a, b, slot = clash[0]
            raise InputError(f"model extensions {a!r} and {b!r} both change the model's {slot}: switch one off")
        if self.isothermal:
            bad = [e.key for e in self.extensions if e.requires_thermal]
            if bad:
                raise InputError(
                    f"extension {bad[0]!r} acts through the temperature: it cannot be on in an isothermal simulation"
                )

    @classmethod
    def of(cls, cell: Cell, isothermal: bool = False) -> ModelOptions:
        """The options a cell's extensions ask for."""
        return cls(bool(isothermal), tuple(CATALOG[k]() for k in cell.extensions))

    @property
    def parameter_names(self) -> tuple[str, ...]:
        """θ̄'s names: the 18, then every extension's ``KEY.NAME``."""
        return parameters.NAMES + tuple(p.qualified for e in self.extensions for p in e.parameters)


__all__ = ["CATALOG", "Extension", "ModelOptions"]
