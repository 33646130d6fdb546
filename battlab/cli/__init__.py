"""The ``battlab`` command. Every user mistake is one line on stderr and exit code 2, never a traceback; so is an
instrument asked for what it does not have (:class:`drivers.errors.NotSupported`)."""

from __future__ import annotations

import sys

import click

from battlab import __version__
from drivers.errors import NotSupported
from protocols.errors import InputError


class _Main(click.Group):
    """A group that turns a user's mistake (bad file, field, value) into one line and a non-zero exit."""

    def main(self, *args: object, **kwargs: object) -> object:
        """Usage errors (a missing argument, a non-number) are one line too, not click's usage block."""
        kwargs["standalone_mode"] = False
        try:
            return super().main(*args, **kwargs)
        except click.exceptions.Abort:
            click.echo("aborted", err=True)
            sys.exit(130)
        except click.UsageError as exc:
            where = f"{exc.ctx.command_path}: " if exc.ctx is not None else ""
            click.echo(f"error: {where}{exc.format_message()}", err=True)
            sys.exit(2)
        except click.ClickException as exc:
            click.echo(f"error: {exc.format_message()}", err=True)
            sys.exit(exc.exit_code)

    def invoke(self, ctx: click.Context) -> object:
        try:
            return super().invoke(ctx)
        except (InputError, NotSupported) as exc:
            click.echo(f"error: {exc}", err=True)
            sys.exit(2)
        except (FileNotFoundError, IsADirectoryError, NotADirectoryError, PermissionError, FileExistsError) as exc:
            click.echo(f"error: {describe_os_error(exc)}", err=True)
            sys.exit(2)


def describe_os_error(exc: OSError) -> str:
    """One line for a file-system error: 'PATH: reason'. Libraries (h5py, matplotlib) raise these without a
    ``filename`` and with the path inside their own message; then that message is the line."""
    if exc.filename is not None:
        where = f"{exc.filename} -> {exc.filename2}" if exc.filename2 is not None else str(exc.filename)
        return f"{where}: {exc.strerror or exc}"
    return " ".join(str(exc).split()) or type(exc).__name__


@click.group(cls=_Main, context_settings={"help_option_names": ["-h", "--help"]})
@click.version_option(__version__, prog_name="battlab")
def main() -> None:
    """battlab: optimal experiments, DFN identification with confidence intervals, and model diagnosis."""


def _register() -> None:
    # each command module registers here (one import line each)
    from battlab.cli.campaign import campaign
    from battlab.cli.design import design, groups, sensitivity
    from battlab.cli.diagnose import diagnose
    from battlab.cli.export import export
    from battlab.cli.fit import fit, validate
    from battlab.cli.library import library
    from battlab.cli.run import run, runs
    from battlab.cli.simulate import simulate
    from battlab.cli.virtual_tester import virtual_tester

    for cmd in (
        simulate,
        library,
        export,
        virtual_tester,
        sensitivity,
        groups,
        design,
        fit,
        validate,
        run,
        runs,
        campaign,
        diagnose,
    ):
        main.add_command(cmd)


_register()
