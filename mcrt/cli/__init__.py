"""The ``mcrt`` command line: ``mcrt render``, ``mcrt demo``, ...

The global options (``-q``, ``--variant``, ``--plugin``, ``--version``) are
accepted before or after the subcommand. Plugins (``--plugin FILE.py``,
``$MCRT_PLUGINS``, installed packages' entry points, see :mod:`mcrt.plugins`)
are loaded after the variant is selected and before the command runs. User
errors (bad arguments, missing or malformed scenes, unknown samplers, broken
plugins, unwritable outputs) print one line, ``mcrt: error: ...``, and exit with
status 2 before any rendering starts; they never show a traceback.

Each subcommand lives in its own module (``mcrt.cli.<name>_cmd``, with
``add_parser(commands)`` and ``run(args)``). ``mcrt NAME ...`` imports only that
module, so a render does not pay for the study and plotting modules; ``mcrt
--help`` and unknown commands build the parser of every subcommand.
"""

from __future__ import annotations

import argparse
import contextlib
import difflib
import importlib
import logging
import re
import sys
from collections.abc import Iterable, Iterator, Sequence
from typing import Any

from .._exit import leave
from .._gc import collection_held_back
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
    "check": "check_cmd",
}

#: Subcommand -> what it does (``mcrt --help``, the subcommand's own parser, README).
SUMMARIES: dict[str, str] = {
    "render": "render a scene with a chosen sampler, or any mcrt EXR again from its header",
    "demo": "render the shipped scenes with each sampler and compare",
    "pattern": "analyse a sampler's point sets: spectrum, anisotropy, discrepancy",
    "integrate": "Monte-Carlo integration bench: error vs N per sampler",
    "reference": "render a cached, resumable high-spp reference with error bars",
    "compare": "run a sampling study and write an HTML/CSV/JSON report",
    "plan": "show which distribution effects a scene gets and how they are sampled",
    "check": "test a sampler: contract, claimed properties, bias, MSE rate, spectrum",
}

#: Options of ``mcrt`` itself (before the subcommand) that take no value.
_TOP_LEVEL_FLAGS = ("-q", "--quiet")

#: The option choosing Mitsuba's variant (it takes a value).
_VARIANT = "--variant"

#: The option loading a user's sampler plugin (it takes a value; repeatable).
_PLUGIN = "--plugin"

#: Options of ``mcrt`` itself that take a value.
_VALUE_OPTIONS = (_VARIANT, _PLUGIN)

#: What ``mcrt --help`` says mcrt is, and its examples.
DESCRIPTION = "mcrt: a distribution ray tracer for studying sampling, built on Mitsuba 3."
EXAMPLES = ("mcrt demo", "mcrt render scenes/cornell_box.xml --sampler poisson_disk --spp 64",
            "mcrt compare configs/quick.toml -q", "mcrt render --help")


class _HelpFormatter(argparse.HelpFormatter):
    """argparse's formatter, but lines indented by two spaces (examples) are kept
    as they are; the other lines of a description or epilog are wrapped."""

    def _fill_text(self, text: str, width: int, indent: str) -> str:
        lines: list[str] = []
        for paragraph in text.split("\n"):
            if paragraph.startswith("  ") or not paragraph.strip():
                lines.append(indent + paragraph)
            else:
                lines.append(super()._fill_text(paragraph, width, indent))
        return "\n".join(lines)


class _Parser(argparse.ArgumentParser):
    """argparse with one-line errors (argparse's default prints the usage too),
    "did you mean" for a mistyped subcommand, and help that keeps examples."""

    def __init__(self, *args, **kwargs) -> None:
        kwargs.setdefault("formatter_class", _HelpFormatter)
        super().__init__(*args, **kwargs)

    def error(self, message: str):  # noqa: D401 - argparse API
        typo = re.match(r"argument COMMAND: invalid choice: '([^']*)'", message)
        if typo:
            close = difflib.get_close_matches(typo.group(1), COMMANDS, n=1)
            message += f"; did you mean {close[0]!r}?" if close else ""
        self.exit(2, f"{self.prog}: error: {message} (see {self.prog} --help)\n")


def version_text() -> str:
    """``mcrt --version``: mcrt's version and those of Mitsuba, Dr.Jit and Python."""
    import platform

    import drjit
    import mitsuba

    from .. import __version__

    def version(module: object) -> str:
        return str(getattr(module, "__version__", "?"))  # not in the type stubs

    return (f"mcrt {__version__} (Mitsuba {version(mitsuba)}, Dr.Jit {version(drjit)}, "
            f"Python {platform.python_version()})")


def _add_global_options(parser: argparse.ArgumentParser, after_command: bool) -> None:
    """``-q``, ``--variant``, ``--plugin`` and ``--version`` on ``mcrt`` itself and
    (``after_command``) on each subcommand, where they must not replace a value
    given before it (``--plugin`` after the command adds to those before it)."""
    group = parser.add_argument_group("global options") if after_command else parser
    unset: Any = argparse.SUPPRESS  # after the command: no value unless given there
    group.add_argument(*_TOP_LEVEL_FLAGS, action="store_true",
                       default=unset if after_command else False,
                       help="no progress bars and no notes (results and errors still print)")
    group.add_argument(_VARIANT, metavar="NAME", default=unset if after_command else None,
                       help="Mitsuba variant to render with (default llvm_ad_rgb; also "
                            "llvm_ad_spectral, llvm_ad_mono and their _polarized forms, "
                            "cuda_ad_* where a GPU exists)")
    group.add_argument(_PLUGIN, metavar="FILE.py", action="append",
                       dest="plugins_after" if after_command else "plugins",
                       default=unset if after_command else None,
                       help="load a Python file that registers samplers "
                            "(mcrt.register_sampler) or integrands (mcrt.register_integrand), "
                            "before the command runs; repeatable "
                            "(also $MCRT_PLUGINS, paths separated by the OS path separator)")
    group.add_argument("--version", action="version", version=version_text(),
                       help="print the versions of mcrt, Mitsuba and Dr.Jit and exit")


def build_parser(commands: Iterable[str] | None = None,
                 summary: bool = False) -> argparse.ArgumentParser:
    """The ``mcrt`` parser with the given subcommands (default: all of :data:`COMMANDS`).

    Imports the module of each subcommand it adds; with ``summary``, adds every
    subcommand by name and :data:`SUMMARIES` only (enough for ``mcrt --help``,
    ``--version`` and a mistyped command, without importing any of them).
    """
    parser = _Parser(prog="mcrt", description=DESCRIPTION,
                     epilog="examples:\n" + "\n".join(f"  {e}" for e in EXAMPLES))
    _add_global_options(parser, after_command=False)
    subparsers = parser.add_subparsers(dest="command", metavar="COMMAND", parser_class=_Parser)
    subparsers.required = True
    for name in COMMANDS if commands is None else commands:
        if summary:
            subparsers.add_parser(name, help=SUMMARIES[name])
            continue
        module = importlib.import_module(f"{__name__}.{COMMANDS[name]}")
        module.add_parser(subparsers)
        _add_global_options(subparsers.choices[name], after_command=True)
    return parser


def command_of(argv: Sequence[str]) -> str | None:
    """The subcommand ``argv`` runs, if that is clear without parsing: the first
    argument other than ``-q``/``--quiet``, ``--variant NAME`` and ``--plugin
    FILE``, when it names a subcommand.

    None otherwise (``--help``, an abbreviated option, a typo, nothing): then the
    full parser decides, and reports.
    """
    skip = False
    for arg in argv:
        if skip:
            skip = False
        elif arg in _VALUE_OPTIONS:
            skip = True
        elif arg not in _TOP_LEVEL_FLAGS and not arg.startswith(
                tuple(option + "=" for option in _VALUE_OPTIONS)):
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


def _load_plugins(args: argparse.Namespace) -> None:
    """Load the installed packages' samplers, ``$MCRT_PLUGINS`` and every
    ``--plugin`` (before the command, after the variant is chosen). Records in
    ``args.plugin_files`` the files the command line and the environment loaded,
    for the command lines outputs record."""
    from .. import plugins

    plugins.load_entry_points()
    env = plugins.from_environment()
    given = [*(getattr(args, "plugins", None) or []), *getattr(args, "plugins_after", [])]
    files = plugins.load_plugins(given)
    args.plugin_files = list(dict.fromkeys([*env, *files]))


@contextlib.contextmanager
def _configure_logging(quiet: bool) -> Iterator[None]:
    """Notes (mcrt's log records) on stderr as ``mcrt: note: ...``; ``-q`` silences
    them all, and Mitsuba's own warnings too (errors still print). For the
    command only: the ``mcrt`` logger is restored afterwards (``main`` may be
    called from Python)."""
    handler = logging.StreamHandler(sys.stderr)
    handler.setFormatter(logging.Formatter("mcrt: note: %(message)s"))
    logger = logging.getLogger("mcrt")
    saved = logger.handlers[:], logger.level, logger.propagate
    logger.handlers[:] = [handler]
    logger.setLevel(logging.ERROR if quiet else logging.INFO)
    logger.propagate = False
    try:
        yield
    finally:
        logger.handlers[:], level, logger.propagate = saved
        logger.setLevel(level)


@contextlib.contextmanager
def _mitsuba_log(quiet: bool) -> Iterator[None]:
    """With ``-q``, Mitsuba's own warnings are silenced too (for the command only)."""
    if not quiet:
        yield
        return
    import mitsuba as mi

    level = mi.log_level()
    mi.set_log_level(mi.LogLevel.Error)
    try:
        yield
    finally:
        mi.set_log_level(level)


def main(argv: list[str] | None = None) -> int:
    """Entry point of the ``mcrt`` console script (``argv`` None: this process
    runs one command and then ends without tearing the interpreter down, see
    :mod:`mcrt._exit`); ``main(argv)`` runs a command and returns its status."""
    if argv is not None:
        return _run(list(argv), process=False)
    code = _run(sys.argv[1:], process=True)
    leave(code)
    return code


def _run(argv: list[str], process: bool) -> int:
    command = command_of(argv)
    # A parser with just the one subcommand parses its arguments exactly as the
    # full parser would (same prog, usage and messages).
    # Without one (--help, --version, a typo, nothing) the subcommands' names and
    # summaries are all the parser needs.
    try:
        with collection_held_back(freeze=process):  # the command's modules
            parser = build_parser(summary=True) if command is None else build_parser([command])
    except (MemoryError, ImportError, OSError) as error:  # a library that did not fit
        if not _allocation_failure(error):
            raise
        return _out_of_memory()
    args = parser.parse_args(argv)
    from ..core.engine import termination_as_interrupt

    try:
        # SIGTERM/SIGHUP: what Ctrl-C does
        with _configure_logging(args.quiet), termination_as_interrupt(), \
                _mitsuba_log(args.quiet):
            _use_variant(args.variant)
            _load_plugins(args)
            from ..core.provenance import source_digest

            source_digest()  # the code this command runs, hashed before it starts (cached):
            # outputs of a long run do not credit it with an edit made meanwhile
            code = int(args.run(args) or 0)
            sys.stdout.flush()  # a closed pipe shows here, not at exit
            return code
    except BrokenPipeError:  # e.g. `mcrt plan ... | head`: the reader left, nothing to report
        _silence_stdout()
        return 141
    except MemoryError as error:
        return _out_of_memory(_one_line(error) if 0 < len(str(error)) < 300 else "")
    except McrtError as error:
        if _allocation_failure(error):  # e.g. a scene whose plugin library could not be mapped
            return _out_of_memory(_one_line(error))
        print(f"mcrt: error: {_one_line(error)}", file=sys.stderr)
        return 2
    except OSError as error:  # an I/O failure no check foresaw: still one line
        if _allocation_failure(error):
            return _out_of_memory()
        where = f": {error.filename}" if error.filename else ""
        print(f"mcrt: error: {error.strerror or error}{where}", file=sys.stderr)
        return 2
    except (ImportError, RuntimeError) as error:  # a library that did not fit, bad_alloc
        if not _allocation_failure(error):
            raise
        return _out_of_memory()
    except KeyboardInterrupt:
        print("mcrt: interrupted", file=sys.stderr)
        return 130


def _allocation_failure(error: BaseException) -> bool:
    from ..core.memory import is_allocation_failure

    return is_allocation_failure(error)


def _out_of_memory(detail: str = "") -> int:
    """``mcrt: error: out of memory (the limits seen...)``, exit status 2."""
    from .._exit import out_of_memory
    from ..core.memory import out_of_memory_message

    out_of_memory()  # no clean-up handlers at exit: they crash after failed allocations
    print(f"mcrt: error: {out_of_memory_message(detail)}", file=sys.stderr)
    return 2


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
