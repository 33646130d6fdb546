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


def extension_option() -> Any:
    """``--extension KEY[:NAME=VALUE,...]`` (repeatable): switch a catalog model extension on."""
    from battlab.parameters import EXTENSIONS

    return click.option(
        "--extension",
        "extensions",
        multiple=True,
        metavar="KEY[:NAME=VALUE,...]",
        help="Switch a model extension on, its parameters [SI] at VALUE (the rest at their 'off' values); "
        f"repeatable. KEY: {', '.join(EXTENSIONS)}. E.g. contact_resistance:R_c=0.0015.",
    )


def apply_extensions(cell: Any, specs: Sequence[str], isothermal: bool = False) -> Any:
    """``cell`` with the ``--extension`` specs switched on; a bad spec or a contradiction with ``isothermal`` is
    one :class:`InputError` naming the option."""
    from battlab.model.extensions import ModelOptions
    from protocols.errors import InputError

    for spec in specs:
        key, _, rest = spec.partition(":")
        values: dict[str, float] = {}
        for item in filter(None, (s.strip() for s in rest.split(","))):
            name, eq, text = item.partition("=")
            try:
                values[name.strip()] = float(text)
            except ValueError:
                raise InputError(
                    f"--extension {spec!r}: expected KEY[:NAME=VALUE,...] with numbers, e.g. "
                    "contact_resistance:R_c=0.0015"
                ) from None
            if not eq:
                raise InputError(f"--extension {spec!r}: {item!r} is not NAME=VALUE")
        try:
            cell = cell.with_extension(key.strip(), **values)
        except InputError as exc:
            raise InputError(f"--extension {spec!r}: {exc}") from None
    try:
        ModelOptions.of(cell, isothermal)
    except InputError as exc:
        raise InputError(f"--extension with --isothermal: {exc}") from None
    return cell


def ocp_option() -> Any:
    """``--ocp E=FILE`` (repeatable): an electrode's open-circuit potential from a half-cell CSV."""
    return click.option(
        "--ocp",
        "ocps",
        multiple=True,
        metavar="E=FILE",
        help="Replace electrode E's open-circuit potential (E: n or p) by a half-cell curve: a CSV of stoichiometry "
        "and potential vs Li/Li+ [V]; repeatable. E.g. p=nca_half_cell.csv.",
    )


def apply_ocps(cell: Any, specs: Sequence[str]) -> Any:
    """``cell`` with the ``--ocp`` curves; a bad spec or file is one :class:`InputError` naming the option."""
    from battlab.io.ocp import with_half_cell_ocp
    from protocols.errors import InputError

    for spec in specs:
        electrode, eq, path = spec.partition("=")
        if not eq or electrode.strip() not in ("n", "p") or not path.strip():
            raise InputError(f"--ocp {spec!r}: expected E=FILE with E n or p, e.g. p=nca_half_cell.csv")
        try:
            cell = with_half_cell_ocp(cell, electrode.strip(), path.strip())
        except InputError as exc:
            raise InputError(f"--ocp {spec!r}: {exc}") from None
    return cell


def dataclass_options(fields: Sequence[Any]) -> Any:
    """Click options made from dataclass fields whose metadata holds their help (``help``; optional ``flag``,
    ``metavar``, ``choices``, ``type`` "path", ``cli_default``): one declaration of each setting, in the options
    value the workflow takes. A boolean field is a flag; the option's default is the field's."""

    def decorate(fn: Any) -> Any:
        for f in reversed(list(fields)):
            meta = f.metadata
            flags = meta.get("flag") or (f"--{f.name.replace('_', '-')}",)
            default = meta.get("cli_default", f.default)
            kw: dict[str, Any] = {"help": meta["help"], "default": default}
            if meta.get("metavar"):
                kw["metavar"] = meta["metavar"]
            if isinstance(f.default, bool):
                kw["is_flag"] = True
            elif meta.get("choices"):
                kw["type"] = click.Choice(list(meta["choices"]))
                kw["show_default"] = True
            elif meta.get("type") == "path":
                kw["type"] = click.Path(dir_okay=False)
            elif isinstance(f.default, int | float) and f.default is not None:
                kw["type"] = type(f.default)
                kw["show_default"] = True
            elif f.type in ("float | None", "float"):
                kw["type"] = float
            fn = click.option(*flags, f.name, **kw)(fn)
        return fn

    return decorate


__all__ = [
    "PHYSICS",
    "dataclass_options",
    "AliasChoice",
    "apply_extensions",
    "apply_ocps",
    "extension_option",
    "ocp_option",
    "physics_option",
]
