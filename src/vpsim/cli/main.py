"""The ``vpsim`` command line. Bad input: one line on stderr, exit status 2, no traceback.

Each command lives in its own module of this package and registers itself on :data:`cli`; this module only
wires them and turns every exception into one line on stderr:

* :class:`~vpsim.errors.VpsimError` (bad input, infeasible request), a usage error of the command line, an
  operating-system error (unwritable ``--out``, disk full): ``vpsim: error: ...``, exit status 2;
* Ctrl-C: ``vpsim: interrupted``, exit status 130;
* a Python warning (a numerical one from the model, say): ``vpsim: warning: ...`` on one line;
* anything else is a bug of vpsim: ``vpsim: internal error: <type>: <message> (please report; ...)``, exit
  status 3. With the environment variable ``VPSIM_DEBUG=1`` the traceback is printed as well.
"""

from __future__ import annotations

import importlib
import importlib.util
import os
import sys
import warnings
from pathlib import Path

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
    "machine",
    "charge",
)

EXIT_ERROR = 2  # bad input: the user can act on the message
EXIT_INTERNAL = 3  # a bug of vpsim: the message asks for a report
EXIT_INTERRUPTED = 130
MAX_MESSAGE_CHARS = 1000  # an error line is cut here (a message may quote a huge field of a file)


@click.group(context_settings={"help_option_names": ["-h", "--help"]})
@click.version_option(package_name="vpsim")
def cli():
    """Drive-cycle simulation of vehicle propulsion systems: one physical model, three methods."""


def vehicle_option(default: str = "hofman2011", help: str = "Preset name or a TOML parameter file."):
    """The option that names the car: ``--vehicle`` or, as the documents call the built-in cars presets,
    ``--preset``."""
    return click.option("--vehicle", "--preset", "vehicle", default=default, show_default=True, help=help)


def _load_commands() -> None:
    for name in COMMAND_MODULES:
        if importlib.util.find_spec(f"{__package__}.{name}") is not None:
            importlib.import_module(f"{__package__}.{name}")


def one_line(text: object) -> str:
    """``text`` as a single line of bounded length (newlines folded, long text cut with an ellipsis)."""
    s = " ".join(str(text).split())
    if len(s) > MAX_MESSAGE_CHARS:
        s = s[: MAX_MESSAGE_CHARS - 3] + "..."
    return s


def _say(prefix: str, text: object) -> None:
    click.echo(f"vpsim: {prefix}: {one_line(text)}", err=True)


def _debug() -> bool:
    return os.environ.get("VPSIM_DEBUG", "").strip() not in ("", "0")


def main(argv=None) -> int:
    """Run the command line with ``argv`` (default ``sys.argv[1:]``); return the exit status."""
    with warnings.catch_warnings():
        warnings.showwarning = _show_warning  # a Python warning is one line too, not a source excerpt
        try:
            _load_commands()
            return _run(argv)
        except KeyboardInterrupt:
            click.echo("vpsim: interrupted", err=True)
            return EXIT_INTERRUPTED


def _show_warning(message, category, filename, lineno, file=None, line=None) -> None:
    where = Path(filename).name if filename else "?"
    _say("warning", f"{category.__name__}: {message} ({where}:{lineno})")


def _run(argv) -> int:
    try:
        status = cli.main(args=argv, prog_name="vpsim", standalone_mode=False)
    except VpsimError as exc:
        _say("error", exc)
        return EXIT_ERROR
    except click.exceptions.NoArgsIsHelpError as exc:  # plain `vpsim` or `vpsim engine`: the help
        click.echo(exc.ctx.get_help() if exc.ctx is not None else str(exc))
        return 0
    except click.exceptions.Abort:
        click.echo("vpsim: aborted", err=True)
        return EXIT_INTERRUPTED
    except click.exceptions.UsageError as exc:
        cmd = exc.ctx.command_path if exc.ctx is not None else "vpsim"
        _say("error", f"{exc.format_message()} (see '{cmd} --help')")
        return EXIT_ERROR
    except click.ClickException as exc:  # click.FileError and the like
        _say("error", exc.format_message())
        return EXIT_ERROR
    except RecursionError as exc:  # before OSError/MemoryError: a bug, not the user's input
        return _internal(exc)
    except MemoryError:
        _say("error", "out of memory")
        return EXIT_ERROR
    except OSError as exc:  # unwritable --out, disk full, a directory given as a file: one line
        _say("error", _os_message(exc))
        return EXIT_ERROR
    except Exception as exc:  # noqa: BLE001 - the last resort: never a traceback for a user
        return _internal(exc)
    return status if isinstance(status, int) else 0


def _os_message(exc: OSError) -> str:
    if exc.filename is not None and exc.strerror:
        where = f"{exc.filename}: " if exc.filename2 is None else f"{exc.filename} -> {exc.filename2}: "
        return f"{where}{exc.strerror}"
    return str(exc) or type(exc).__name__


def _internal(exc: BaseException) -> int:
    if _debug():
        import traceback

        traceback.print_exception(exc, file=sys.stderr)
    _say(
        "internal error",
        f"{type(exc).__name__}: {one_line(exc)[:300]} "
        "(please report; rerun with VPSIM_DEBUG=1 for the traceback)",
    )
    return EXIT_INTERNAL


if __name__ == "__main__":  # pragma: no cover
    sys.exit(main())
