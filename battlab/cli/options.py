"""Options shared by several commands, spelled the same everywhere."""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from typing import Any

import click

#: the cell physics of a virtual tester: ``dfn`` battlab's DFN-thermal model, ``standin`` the drivers'
#: equivalent-circuit cell (fast, for tests); ``auto`` (where a default must be picked): ``dfn`` when battlab's
#: physics factory is importable, else ``standin``
PHYSICS = ("dfn", "standin")
#: other spellings accepted (not listed in --help)
PHYSICS_ALIASES = {"stand-in": "standin", "stand_in": "standin", "ecm": "standin", "model": "dfn"}


class AliasChoice(click.Choice):
    """A choice that also takes hidden alternative spellings, mapped to the listed value."""

    def __init__(self, choices: Sequence[str], aliases: Mapping[str, str], case_sensitive: bool = False) -> None:
        super().__init__(list(choices), case_sensitive=case_sensitive)
        self.aliases = {k.lower(): v for k, v in aliases.items()}

    def convert(self, value: Any, param: click.Parameter | None, ctx: click.Context | None) -> Any:
        if isinstance(value, str) and value.strip().lower() in self.aliases:
            value = self.aliases[value.strip().lower()]
        return super().convert(value, param, ctx)


def physics_option(*, auto: bool, default: str) -> Any:
    """``--physics``: ``dfn|standin``, with ``auto`` listed where the command picks by what is installed; ``auto``
    is accepted everywhere (where battlab's model is always there it means ``dfn``)."""
    listed = ("auto", *PHYSICS) if auto else PHYSICS
    aliases = dict(PHYSICS_ALIASES) if auto else {**PHYSICS_ALIASES, "auto": "dfn"}
    what = "dfn: battlab's DFN-thermal model; standin: the drivers' equivalent-circuit cell (fast, for tests)"
    if auto:
        what = f"auto: dfn if battlab's physics is available, else standin; {what}"
    return click.option(
        "--physics",
        type=AliasChoice(listed, aliases),
        default=default,
        show_default=True,
        help=f"Cell physics of the virtual tester. {what}.",
    )


__all__ = ["PHYSICS", "AliasChoice", "physics_option"]
