"""The catalog of causes: the physical mechanisms that make a cell's measurements differ from its model, each
declared once in its own module of this package (:class:`battlab.causes.cause.Cause`: the base parameters it
owns, its model extension and the extension's parameters, what informs it, the model slots it occupies, how it is
validated). Every other table is derived from :data:`CAUSES`: the parameter registry
(:data:`battlab.parameters.EXTENSIONS`), the model's extension classes (:data:`battlab.model.extensions.CATALOG`),
the fit's informing rules, the diagnosis's directions and typical sizes, the command line's choices.

To add a cause: write its module (a ``CAUSE``), then add its name to :data:`MODULES`. The order of :data:`MODULES`
is the order of the extensions' parameters in θ̄ after the 18 (append new causes at the end).
"""

from __future__ import annotations

from importlib import import_module

from battlab.causes.cause import Cause, Evidence
from protocols.errors import InputError
from protocols.steps import did_you_mean

#: the registered causes' modules, one per line, in catalog order
MODULES: tuple[str, ...] = (
    "contact_resistance",
    "current_sensor",
    "thermal",
    "equilibrium",
    "hysteresis",
    "double_layer",
    "capacity_fade",
    "electrolyte",
    "solid_diffusion",
    "kinetics",
)

#: the catalog, in :data:`MODULES` order
CAUSES: tuple[Cause, ...] = tuple(import_module(f"{__name__}.{m}").CAUSE for m in MODULES)
#: catalog key → cause
BY_KEY: dict[str, Cause] = {c.key: c for c in CAUSES}
KEYS: tuple[str, ...] = tuple(BY_KEY)


def cause(key: str) -> Cause:
    """The cause with catalog key ``key``; an unknown key is an :class:`InputError` that lists the catalog."""
    try:
        return BY_KEY[key]
    except KeyError:
        raise InputError(f"unknown cause {key!r}{did_you_mean(key, KEYS)}; expected one of {', '.join(KEYS)}") from None


def extended() -> tuple[Cause, ...]:
    """The causes that bring a model extension, in catalog order."""
    return tuple(c for c in CAUSES if c.extension is not None)


def slot_conflicts(keys: list[str] | tuple[str, ...]) -> list[tuple[str, str, str]]:
    """(cause, cause, slot) for each pair of ``keys`` whose extensions own one model slot without composing: they
    cannot both be on."""
    out = []
    for i, a in enumerate(keys):
        for b in keys[i + 1 :]:
            ca, cb = cause(a), cause(b)
            if b not in ca.composes_with and a not in cb.composes_with:
                out += [(a, b, s) for s in sorted(ca.slots & cb.slots)]
    return out


def owner(name: str) -> Cause | None:
    """The cause that owns a cell value (a base parameter, e.g. ``D_s_n``) or an extension parameter
    (``KEY.NAME``); None for a value no cause claims (geometry, constants)."""
    key, dot, _ = name.partition(".")
    if dot:
        return BY_KEY.get(key)
    return next((c for c in CAUSES if name in c.base), None)


__all__ = ["BY_KEY", "CAUSES", "KEYS", "MODULES", "Cause", "Evidence", "cause", "extended", "owner", "slot_conflicts"]
