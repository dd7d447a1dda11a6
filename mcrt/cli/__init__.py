"""The ``mcrt`` command line: ``mcrt render``, ``mcrt demo``, ...

User errors (bad arguments, missing or malformed scenes, unknown samplers,
unwritable outputs) print one line, ``mcrt: error: ...``, and exit with status 2
before any rendering starts; they never show a traceback.

Each subcommand lives in its own module (``mcrt.cli.<name>_cmd``, with
``add_parser(commands)`` and ``run(args)``). ``mcrt NAME ...`` imports only that
module, so a render does not pay for the study and plotting modules; ``mcrt
--help`` and unknown commands build the parser of every subcommand.
"""

from __future__ import annotations

import argparse
import importlib
import logging
import sys
from collections.abc import Iterable, Sequence

from ..errors import McrtError

#: Subcommand -> its module in this package, in the order ``mcrt --help`` lists them.
COMMANDS: dict[str, str] = {
    "render": "render_cmd",
    "demo": "demo_cmd",
    "pattern": "pattern_cmd",
    "integrate": "integrate_cmd",
    "reference": "reference_cmd",
    "compare": "compare_cmd",
    "plan": "plan_cmd",
}

#: Options of ``mcrt`` itself (before the subcommand) that take no value.
_TOP_LEVEL_FLAGS = ("-q", "--quiet")

#: The option choosing Mitsuba's variant (it takes a value).
_VARIANT = "--variant"


class _Parser(argparse.ArgumentParser):
    """argparse with one-line errors (argparse's default prints the usage too)."""

    def error(self, message: str):  # noqa: D401 - argparse API
        self.exit(2, f"{self.prog}: error: {message} (see {self.prog} --help)\n")


def build_parser(commands: Iterable[str] | None = None) -> argparse.ArgumentParser:
    """The ``mcrt`` parser with the given subcommands (default: all of :data:`COMMANDS`).

    Imports the module of each subcommand it adds.
    """
    parser = _Parser(prog="mcrt", description=(__doc__ or "mcrt").splitlines()[0])
    parser.add_argument(*_TOP_LEVEL_FLAGS, action="store_true", help="no progress bars or notes")
    parser.add_argument(_VARIANT, metavar="NAME", default=None,
                        help="Mitsuba variant to render with (default llvm_ad_rgb; also "
                             "llvm_ad_spectral, llvm_ad_mono, cuda_ad_* where a GPU exists)")
    subparsers = parser.add_subparsers(dest="command", metavar="COMMAND", parser_class=_Parser)
    subparsers.required = True
    for name in COMMANDS if commands is None else commands:
        module = importlib.import_module(f"{__name__}.{COMMANDS[name]}")
        module.add_parser(subparsers)
    return parser


def command_of(argv: Sequence[str]) -> str | None:
    """The subcommand ``argv`` runs, if that is clear without parsing: the first
    argument other than ``-q``/``--quiet``, when it names a subcommand.

    None otherwise (``--help``, an abbreviated option, a typo, nothing): then the
    full parser decides, and reports.
    """
    skip = False
    for arg in argv:
        if skip:
            skip = False
        elif arg == _VARIANT:
            skip = True
        elif arg not in _TOP_LEVEL_FLAGS and not arg.startswith(_VARIANT + "="):
            return arg if arg in COMMANDS else None
    return None


def _use_variant(name: str | None) -> None:
    """Switch Mitsuba to ``--variant NAME`` and register mcrt's plugins for it."""
    if name is None:
        return
    import mitsuba as mi

    from .. import register
    from .._platform import select_variant

    if mi.variant() != name:
        select_variant(name)
        register()


def _configure_logging(quiet: bool) -> None:
    handler = logging.StreamHandler(sys.stderr)
    handler.setFormatter(logging.Formatter("mcrt: note: %(message)s"))
    logger = logging.getLogger("mcrt")
    logger.handlers[:] = [handler]
    logger.setLevel(logging.WARNING if quiet else logging.INFO)
    logger.propagate = False


def main(argv: list[str] | None = None) -> int:
    """Entry point of the ``mcrt`` console script."""
    argv = sys.argv[1:] if argv is None else list(argv)
    command = command_of(argv)
    # A parser with just the one subcommand parses its arguments exactly as the
    # full parser would (same prog, usage and messages).
    args = build_parser(None if command is None else [command]).parse_args(argv)
    _configure_logging(args.quiet)
    from ..core.engine import termination_as_interrupt

    try:
        with termination_as_interrupt():  # SIGTERM/SIGHUP: what Ctrl-C does
            _use_variant(args.variant)
            return int(args.run(args) or 0)
    except McrtError as error:
        print(f"mcrt: error: {_one_line(error)}", file=sys.stderr)
        return 2
    except OSError as error:  # an I/O failure no check foresaw: still one line
        where = f": {error.filename}" if error.filename else ""
        print(f"mcrt: error: {error.strerror or error}{where}", file=sys.stderr)
        return 2
    except MemoryError:
        from ..core.memory import describe

        print(f"mcrt: error: out of memory ({describe()}); use a smaller image or raise the "
              f"limit", file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        print("mcrt: interrupted", file=sys.stderr)
        return 130
    except BrokenPipeError:  # e.g. `mcrt ... | head`: the reader left, nothing to report
        _silence_stdout()
        return 141


def _one_line(error: Exception) -> str:
    """The message on one line (paths may contain newlines)."""
    return " ".join(str(error).split("\n"))


def _silence_stdout() -> None:
    """Point stdout at /dev/null so Python's exit-time flush cannot fail again."""
    import os

    devnull = os.open(os.devnull, os.O_WRONLY)
    os.dup2(devnull, sys.stdout.fileno())


if __name__ == "__main__":  # pragma: no cover
    sys.exit(main())
