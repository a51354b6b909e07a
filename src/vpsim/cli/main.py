"""The ``vpsim`` command line. Bad input: one line on stderr, exit status 2, no traceback.

Each command lives in its own module of this package and registers itself on :data:`cli`; this module only
wires them and turns :class:`~vpsim.errors.VpsimError` into a one-line message.
"""

from __future__ import annotations

import importlib
import importlib.util
import sys

import click

from ..errors import VpsimError

# command modules, imported lazily by main() so `vpsim --help` stays fast
COMMAND_MODULES = (
    "simulate",
    "maps",
    "params",
    "paper",
    "engine",
    "scaling",
    "bench",
    "sweep",
    "vehicle",
    "fleet",
)


@click.group(context_settings={"help_option_names": ["-h", "--help"]})
@click.version_option(package_name="vpsim")
def cli():
    """Drive-cycle simulation of vehicle propulsion systems: one physical model, three methods."""


def _load_commands() -> None:
    for name in COMMAND_MODULES:
        if importlib.util.find_spec(f"{__package__}.{name}") is not None:
            importlib.import_module(f"{__package__}.{name}")


def main(argv=None) -> int:
    _load_commands()
    try:
        cli.main(args=argv, prog_name="vpsim", standalone_mode=False)
    except VpsimError as exc:
        click.echo(f"vpsim: error: {exc}", err=True)
        return 2
    except click.exceptions.Abort:
        click.echo("vpsim: aborted", err=True)
        return 130
    except click.ClickException as exc:
        exc.show()
        return 2
    except (OSError, MemoryError) as exc:  # unwritable --out, disk full: say so in one line
        click.echo(f"vpsim: error: {exc}", err=True)
        return 2
    return 0


if __name__ == "__main__":  # pragma: no cover
    sys.exit(main())
