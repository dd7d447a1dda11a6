"""The ``mcrt`` command line: ``mcrt render``, ``mcrt demo``, ...

User errors (bad arguments, missing or malformed scenes, unknown samplers,
unwritable outputs) print one line, ``mcrt: error: ...``, and exit with status 2
before any rendering starts; they never show a traceback.
"""

from __future__ import annotations

import argparse
import logging
import sys

from ..errors import McrtError
from . import compare_cmd, demo_cmd, integrate_cmd, pattern_cmd, plan_cmd, reference_cmd, render_cmd


class _Parser(argparse.ArgumentParser):
    """argparse with one-line errors (argparse's default prints the usage too)."""

    def error(self, message: str):  # noqa: D401 - argparse API
        self.exit(2, f"{self.prog}: error: {message} (see {self.prog} --help)\n")


def build_parser() -> argparse.ArgumentParser:
    parser = _Parser(prog="mcrt", description=__doc__.splitlines()[0])
    parser.add_argument("-q", "--quiet", action="store_true", help="no progress bars or notes")
    commands = parser.add_subparsers(dest="command", metavar="COMMAND", parser_class=_Parser)
    commands.required = True
    for module in (render_cmd, demo_cmd, pattern_cmd, integrate_cmd, reference_cmd, compare_cmd,
                   plan_cmd):
        module.add_parser(commands)
    return parser


def _configure_logging(quiet: bool) -> None:
    handler = logging.StreamHandler(sys.stderr)
    handler.setFormatter(logging.Formatter("mcrt: note: %(message)s"))
    logger = logging.getLogger("mcrt")
    logger.handlers[:] = [handler]
    logger.setLevel(logging.WARNING if quiet else logging.INFO)
    logger.propagate = False


def main(argv: list[str] | None = None) -> int:
    """Entry point of the ``mcrt`` console script."""
    args = build_parser().parse_args(argv)
    _configure_logging(args.quiet)
    try:
        return int(args.run(args) or 0)
    except McrtError as error:
        print(f"mcrt: error: {_one_line(error)}", file=sys.stderr)
        return 2
    except OSError as error:  # an I/O failure no check foresaw: still one line
        where = f": {error.filename}" if error.filename else ""
        print(f"mcrt: error: {error.strerror or error}{where}", file=sys.stderr)
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
