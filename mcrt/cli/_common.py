"""Argument types and output checks shared by the subcommands."""

from __future__ import annotations

import argparse
import contextlib
import importlib
import logging
import os
from collections.abc import Iterator, Sequence
from pathlib import Path
from typing import Any

from ..core.atomic import (
    check_free_space,
    ensure_writable_dir,
    refuse_special,
    remove_stale_temporaries,
    special_kind,
)
from ..errors import McrtError

log = logging.getLogger("mcrt")

#: Where outputs go when no ``-o`` is given (never the current directory itself).
OUTPUT_ROOT = Path("out")


def examples(*lines: str) -> str:
    """A subcommand's ``--help`` epilog: its example command lines."""
    return "examples:\n" + "\n".join(f"  {line}" for line in lines)


def positive_int(text: str) -> int:
    """argparse type: an integer >= 1."""
    try:
        value = int(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected a positive integer, got {text!r}") from None
    if value <= 0:
        raise argparse.ArgumentTypeError(f"must be a positive integer, got {value}")
    return value


def non_negative_int(text: str) -> int:
    """argparse type: an integer >= 0 that fits in 32 bits (seeds)."""
    try:
        value = int(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected a non-negative integer, got {text!r}") from None
    if not 0 <= value < 2**32:
        raise argparse.ArgumentTypeError(f"must be in [0, 2^32), got {value}")
    return value


def names_directory(out: str) -> bool:
    """Whether ``-o OUT`` names a directory: it ends in ``/`` or is an existing one."""
    if out.endswith(("/", os.sep)):
        return True
    try:
        return Path(out).is_dir()
    except OSError:  # e.g. a name too long: not a directory; writing it reports why
        return False


def output_stem(out: str | None, default: str) -> Path:
    """``-o OUT`` without a trailing image suffix (``OUT.exr`` and ``OUT.png`` get written).

    No ``-o``: ``out/DEFAULT``. ``OUT`` naming a directory (an existing one, or
    any path ending in ``/``): ``OUT/DEFAULT``.
    """
    if not out:
        path = OUTPUT_ROOT / default
    elif names_directory(out):
        path = Path(out) / default
    else:
        path = Path(out)
    if path.name in ("", ".", ".."):  # cannot happen for the forms above; kept as a guard
        raise McrtError(f"-o {out}: names a directory; give an output path such as "
                        f"{path / 'image'}")
    if path.suffix.lower() in (".exr", ".png"):
        path = path.with_suffix("")
    return path


def check_output_files(*paths: Path) -> None:
    """Fail early if an output path exists but cannot be replaced: a directory,
    a file without write permission, or a FIFO, socket or device (never
    replaced: someone put it there)."""
    for path in paths:
        ensure_writable_dir(path.parent if str(path.parent) else Path("."))
        try:
            if path.exists() and (path.is_dir() or not os.access(path, os.W_OK)):
                raise McrtError(f"cannot overwrite {path}")
        except OSError as error:  # e.g. a file name too long for the file system
            raise McrtError(f"cannot write {path}: {error.strerror}") from None
        kind = special_kind(path)
        if kind is not None:
            raise McrtError(f"cannot overwrite {path}: it is {kind}, not a regular file "
                            f"(remove it or write elsewhere with -o)")


@contextlib.contextmanager
def removed_if_refused(directory: Path) -> Iterator[None]:
    """The checks a command makes before any work: if the block raises an error,
    the folders it created on the way to ``directory`` (``-o out/a/b``: ``out``,
    ``a`` and ``b`` if none existed) are removed again, each only if still
    empty, so a refused command leaves nothing behind. (Not on Ctrl-C: an
    interrupted command writes its partial outputs there.)"""
    missing: list[Path] = []
    path = Path(os.path.abspath(directory))
    try:
        while not os.path.lexists(path) and path != path.parent:
            missing.append(path)
            path = path.parent
    except OSError:  # e.g. a name too long: nothing to remember
        missing = []
    try:
        yield
    except Exception:
        for made in missing:  # deepest first
            try:
                made.rmdir()
            except OSError:
                break  # not created, or not empty: the folders above stay too
        raise


def check_state_files(paths: Sequence[Path], role: str) -> None:
    """Before any work: a one-line error if a file the command reads back and
    rewrites (a checkpoint, a saved state) is a FIFO, socket, device or
    directory; reading a FIFO would wait for ever, and mcrt does not replace
    what someone else put there."""
    for path in paths:
        refuse_special(path, role, "remove it and run the command again")


def check_state_directory(directory: Path, role: str) -> None:
    """As :func:`check_state_files`, for ``directory`` (a study's resume folder)
    and the files in it, if it exists; folders in it are left to the code that
    reads the state (it never opens them as files)."""
    kind = special_kind(directory)
    if kind is None:
        return  # missing, or a regular file: the state's own code reports it
    if kind != "a directory":
        refuse_special(directory, role, "remove it and run the command again")
    try:
        entries = sorted(directory.iterdir())
    except OSError:
        return  # unreadable: the state's own checks report it
    check_state_files([e for e in entries if special_kind(e) != "a directory"], role)


def checkpoint_interval() -> float | None:
    """Seconds between the checkpoints of a running render: ``$MCRT_CHECKPOINT_SECONDS``
    (0: after every pass), by default paced to cost under 2% of the render time."""
    text = os.environ.get("MCRT_CHECKPOINT_SECONDS", "").strip()
    if not text:
        return None
    try:
        value = float(text)
    except ValueError:
        raise McrtError(f"MCRT_CHECKPOINT_SECONDS must be a number of seconds, "
                        f"got {text!r}") from None
    if not value >= 0:
        raise McrtError(f"MCRT_CHECKPOINT_SECONDS must be >= 0, got {text!r}")
    return value


#: Bytes the plots, tables and pages of `pattern`, `integrate` and `demo` need
#: at most besides their images (generous: a few PNG plots, a CSV, a page).
PLOTS_BYTES = 16 << 20


def require_space(directory: Path, needed: int, what: str = "the outputs") -> None:
    """Before any work: remove temporaries of killed writers in ``directory``,
    then refuse to start unless ``needed`` bytes are free there (one line)."""
    remove_stale_temporaries(directory)
    check_free_space(directory, needed, what)


def image_bytes(pixels: int, channels: int = 4) -> int:
    """Upper bound of an image file's size: float32 channels, uncompressed."""
    return pixels * channels * 4


#: Address space one more OpenBLAS thread takes (its 32 MiB work buffer and its stack).
BLAS_THREAD_BYTES = 40 << 20


def import_up_front(modules: Sequence[str], needed: int, what: str) -> None:
    """Import now, before any heavy allocation, the libraries a command loads
    later (``needed``: the address space they take, measured, with room).

    Under ``ulimit -v`` a library loaded late may find no room left: scipy's
    OpenBLAS (which ``colour`` loads) then retries its work buffer forever at
    100% CPU, where SIGTERM is never handled. Here, ``MemoryError`` (``mcrt:
    error: out of memory (...)``) when the limit leaves less than ``needed``
    (plus :data:`BLAS_THREAD_BYTES` for each OpenBLAS thread beyond the first)
    or a library cannot be mapped. A module that is not installed is left to
    the code that uses it to report."""
    import sys

    from ..core.memory import is_allocation_failure, require_address_space

    if all(name in sys.modules for name in modules):
        return
    try:
        threads = max(1, int(os.environ.get("OPENBLAS_NUM_THREADS", "") or os.cpu_count() or 1))
    except ValueError:
        threads = os.cpu_count() or 1
    require_address_space(needed + (threads - 1) * BLAS_THREAD_BYTES, what)
    for name in modules:
        try:
            importlib.import_module(name)
        except ModuleNotFoundError:
            continue
        except Exception as error:
            if is_allocation_failure(error):
                raise MemoryError(f"{name} could not be loaded: {error}") from None
            raise


def speed(seconds: float, rate: float) -> str:
    """``time 1.25 s  3.36 M samples/s``; a render under 0.1 s in ms, under 0.1 M
    samples/s in k samples/s (not ``0.00``)."""
    time = f"{seconds:.2f} s" if seconds >= 0.1 else f"{seconds * 1e3:.3g} ms"
    rate_text = f"{rate / 1e6:.2f} M" if rate >= 1e5 else f"{rate / 1e3:.3g} k"
    return f"time {time}  {rate_text} samples/s"


def note_first_run() -> None:
    """A note before the first render on this machine: Dr.Jit compiles its kernels
    then (cached in ``~/.drjit`` for later runs), which makes it seem slow."""
    cache = Path.home() / ".drjit"
    try:
        empty = not cache.is_dir() or next(os.scandir(cache), None) is None
    except OSError:
        empty = True
    if empty:
        log.info("first run: Dr.Jit compiles the render kernels, which takes a while; they "
                 "are cached in %s, so later runs start faster", cache)


def add_cluster_argument(parser: argparse.ArgumentParser) -> None:
    """``--cluster ADDRESS`` (and ``$MCRT_CLUSTER``): where a job's tasks run."""
    parser.add_argument("--cluster", metavar="ADDRESS",
                        help="run the tasks on a Dask cluster: 'local' or 'local:N' (N worker "
                             "processes on this machine), or a scheduler address such as "
                             "tcp://HOST:8786 (default: $MCRT_CLUSTER, else in this process); "
                             "results are the same bits either way")


@contextlib.contextmanager
def cluster_executor(address: str | None) -> Iterator[Any]:
    """The executor for a cluster ``address`` already chosen (``cluster_address``
    of ``--cluster``, or None after a command decided to stay in this process;
    ``$MCRT_CLUSTER`` is not read again here), connected before any work (a bad
    address is a one-line error), closed afterwards. In-process (no Dask import)
    for None."""
    from ..core.executor import executor_for

    executor = executor_for(address)
    try:
        yield executor
    finally:
        executor.close()


def sampler_choices() -> str:
    """The sampler names for a ``--help`` text (registered ones, plugins' included)."""
    from ..samplers import standalone_names

    return f"{', '.join(standalone_names())}, or one a --plugin registers"


def recorded(args: argparse.Namespace, *words: Any) -> dict[str, str]:
    """What a command's JSON records about how it was made: the ``command`` that
    runs it again (``mcrt --variant V [--plugin FILE]... COMMAND WORDS``, plugin
    files by absolute path, no ``-o``) and the versions of mcrt, Mitsuba and
    Dr.Jit (:mod:`mcrt.core.provenance`)."""
    from ..core.provenance import COMMAND, command_text, software

    plugins = getattr(args, "plugin_files", None) or []
    return {COMMAND: command_text(args.command, *words, plugins=plugins), **software()}


def parse_sampler_params(items: Sequence[str] | None, flag: str = "-P") -> dict[str, Any]:
    """``-P key=value`` items (``flag``: the option as the command names it) to
    sampler plugin parameters: ``true``/``false`` as booleans, numbers as int or
    float, anything else as text. The sample count, seed and plugin type are the
    command's own options (one line naming it)."""
    import re

    from ..core.sampling import RENDER_SETTINGS

    params: dict[str, Any] = {}
    for item in items or []:
        key, sep, value = item.partition("=")
        key, value = key.strip(), value.strip()
        if not sep or not re.fullmatch(r"[A-Za-z_]\w*", key):
            raise McrtError(f"{flag} expects key=value, got {item!r}")
        if key in RENDER_SETTINGS:
            raise McrtError(f"{flag} {key}: use the command's own option ({RENDER_SETTINGS[key]})")
        params[key] = _typed(value)
    return params


def _typed(text: str) -> Any:
    if text.lower() in ("true", "false"):
        return text.lower() == "true"
    for kind in (int, float):
        try:
            return kind(text)
        except ValueError:
            pass
    return text


def param_words(flag: str, items: Sequence[str] | None) -> list[str]:
    """``flag KEY=VALUE`` for each sampler parameter, as a recorded command gives
    them (a point-set file by absolute path: :func:`~mcrt.core.provenance.param_word`)."""
    from ..core.provenance import param_word

    return [w for item in items or [] for w in (flag, param_word(item))]
