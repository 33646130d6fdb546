"""A campaign stage as one declared unit: what it needs, the settings it reads, whether it uses the tester, the files
it writes and its section of the report.

A unit receives only the settings it declares: it runs with a view of the campaign whose configuration refuses
any other section (:class:`ScopedConfig`), and its rerun key (:func:`battlab.campaign.stages.stage_key`) holds
exactly those settings, so a stage that reads a setting it did not declare fails at once instead of silently
reusing stale results; the files it returns must be among the roles it declares.
"""

from __future__ import annotations

import fnmatch
from collections.abc import Callable, Mapping
from dataclasses import dataclass, fields, replace
from typing import Any

from battlab.campaign.config import CampaignConfig
from battlab.campaign.stages import Stage, StageContext, StageOutput

#: the configuration's sections a unit may declare; ``quick`` is the reduced variant's flag
SECTIONS: tuple[str, ...] = tuple(f.name for f in fields(CampaignConfig))


class UndeclaredSetting(RuntimeError):
    """A stage read a setting it did not declare (a programming error, not a user's)."""


class ScopedConfig:
    """A campaign configuration that answers only the sections ``allowed`` (read by stage ``stage``)."""

    def __init__(self, config: CampaignConfig, allowed: tuple[str, ...], stage: str) -> None:
        self._config, self._allowed, self._stage = config, frozenset(allowed), stage

    def __getattr__(self, name: str) -> Any:
        if name.startswith("_"):
            raise AttributeError(name)
        if name in SECTIONS and name not in self._allowed:
            raise UndeclaredSetting(
                f"campaign stage {self._stage!r} reads [{name}] without declaring it (its rerun key would miss it)"
            )
        return getattr(self._config, name)


@dataclass(frozen=True)
class Unit:
    """One campaign stage (see the module docstring). ``run(camp)`` makes the stage's function of its context;
    ``reads``: configuration sections (:data:`SECTIONS`); ``outputs``: file roles (``fnmatch`` patterns, e.g.
    ``log_*``); ``report(view)``: its report sections (:mod:`battlab.campaign.report`), None for none;
    ``after_all``: it needs every stage before it (``"tester"``: every earlier stage that uses the tester)."""

    name: str
    title: str
    run: Callable[[Any], Callable[[StageContext], StageOutput]]
    needs: tuple[str, ...] = ()
    reads: tuple[str, ...] = ()
    uses_tester: bool = False
    outputs: tuple[str, ...] = ()
    report: Callable[[Any], Any] | None = None
    after_all: str | None = None

    def __post_init__(self) -> None:
        bad = [s for s in self.reads if s not in SECTIONS]
        if bad:
            raise ValueError(f"campaign unit {self.name!r}: unknown settings sections {bad}")

    def settings(self, config: CampaignConfig) -> dict[str, Any]:
        """The settings it reads: its rerun key's part of the configuration."""
        cfg = config.as_dict()
        return {s: cfg[s] for s in self.reads}

    def stage(self, camp: Any, needs: tuple[str, ...]) -> Stage:
        """The runnable stage: the unit's function on a view of ``camp`` scoped to its settings, its returned files
        checked against its declared roles."""
        scoped = replace(camp, config=ScopedConfig(camp.config, self.reads, self.name))
        fn = self.run(scoped)

        def run(ctx: StageContext) -> StageOutput:
            out = fn(ctx)
            extra = [r for r in out.files if not any(fnmatch.fnmatchcase(r, p) for p in self.outputs)]
            if extra:
                raise UndeclaredSetting(f"campaign stage {self.name!r} wrote undeclared file roles {extra}")
            return out

        return Stage(self.name, run, needs, self.settings(camp.config), self.title)


def resolve_needs(unit: Unit, before: list[Stage], skipped: set[str], units: Mapping[str, Unit]) -> tuple[str, ...]:
    """The stages ``unit`` needs among those before it (``after_all``: every one, or every one using the tester)."""
    if unit.after_all == "all":
        return tuple(s.name for s in before)
    if unit.after_all == "tester":
        return tuple(s.name for s in before if units[s.name].uses_tester)
    return unit.needs


__all__ = ["SECTIONS", "ScopedConfig", "UndeclaredSetting", "Unit", "resolve_needs"]
