"""Start-up checks: a usable libLLVM and an active vectorised Mitsuba variant.

Dr.Jit's LLVM backend loads the system ``libLLVM`` at run time. Versions 14-16
(the defaults on Debian 12 and Ubuntu 22.04) load fine and then abort the whole
process on the first kernel with ``LLVM ERROR: Cannot select ... fminimum``.
We ask Dr.Jit which version it loaded *before* any kernel is compiled and turn
a missing or too-old library into a clear, actionable message.

The ``mcrt`` command (the console script, ``python -m mcrt``) also prepares the
process here, when this module is imported, before numpy, scipy or Mitsuba are:

* one thread for the BLAS and OpenMP pools (:data:`BLAS_THREAD_VARIABLES`, each
  only where the user has not set it). OpenBLAS gives every pool thread a
  32 MiB work buffer, and under an address-space limit (``ulimit -v``) it
  retries a failed buffer forever (scipy's copy, at import: 100% CPU, SIGTERM
  never handled) or aborts the process (numpy's, at the first matrix
  operation). mcrt's matrices are 4x4 at most, so the threads bought nothing.
* under ``ulimit -v``: numpy's OpenBLAS takes its work buffer now, while the
  address space is free (:func:`claim_blas_buffer`), so that the first matrix
  operation cannot abort the process later; Mitsuba is imported only with
  :data:`MITSUBA_START_BYTES` of address space left (a half-loaded Mitsuba or
  libLLVM aborted or crashed). A limit too low for either, or a library that
  still cannot be mapped, ends in one line, ``mcrt: error: out of memory
  (...)``, exit status 2.
"""

from __future__ import annotations

import os
import resource
import sys
from collections.abc import Callable, MutableMapping, Sequence
from types import TracebackType

from .errors import SetupError

#: Thread-pool sizes of BLAS and OpenMP runtimes that the ``mcrt`` command sets
#: to 1 unless the user has set them (OpenBLAS, OpenMP, MKL, BLIS, Accelerate,
#: numexpr).
BLAS_THREAD_VARIABLES = ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS", "MKL_NUM_THREADS",
                         "BLIS_NUM_THREADS", "VECLIB_MAXIMUM_THREADS", "NUMEXPR_NUM_THREADS")


def running_as_command(argv: Sequence[str] | None = None,
                       orig_argv: Sequence[str] | None = None) -> bool:
    """Whether this process is the ``mcrt`` command: the console script
    (``sys.argv[0]`` is ``.../mcrt``) or ``python -m mcrt`` (which shows in
    ``sys.orig_argv``; ``sys.argv[0]`` is ``-m`` while the package imports)."""
    argv = sys.argv if argv is None else argv
    orig_argv = getattr(sys, "orig_argv", []) if orig_argv is None else orig_argv
    name = os.path.basename(argv[0]) if argv else ""
    if name in ("mcrt", "mcrt.exe", "mcrt-script.py"):
        return True
    names = ("mcrt", "mcrt.__main__", "mcrt.cli")
    args, i = list(orig_argv[1:]), 0
    while i < len(args):  # the interpreter's options, up to -m MODULE, -c CODE or a script
        arg = args[i]
        if arg == "-m":
            return i + 1 < len(args) and args[i + 1] in names
        if arg.startswith("-m"):
            return arg[2:] in names
        if arg in ("-X", "-W"):  # options with a separate value
            i += 2
            continue
        if arg in ("-c", "-") or not arg.startswith("-"):
            return False
        i += 1
    return False


def limit_blas_threads(environ: MutableMapping[str, str] | None = None) -> list[str]:
    """Set every :data:`BLAS_THREAD_VARIABLES` the user has not set (or set
    empty) to ``1``; returns the names set. Effective only before the libraries
    are loaded (numpy, scipy), and for the processes this one starts."""
    environ = os.environ if environ is None else environ
    chosen = [name for name in BLAS_THREAD_VARIABLES if not environ.get(name, "").strip()]
    for name in chosen:
        environ[name] = "1"
    return chosen


#: Address space numpy's import and OpenBLAS's work buffer take (measured: 84 MiB
#: of libraries, then the 32 MiB buffer), with room to spare.
BLAS_START_BYTES = 160 << 20


#: Address space importing Mitsuba (with Dr.Jit, libLLVM and the llvm_ad_rgb
#: variant) takes (measured: 332 MiB, 318 with 1 MiB thread stacks), with room.
MITSUBA_START_BYTES = 384 << 20


def _address_space_limited() -> bool:
    return resource.getrlimit(resource.RLIMIT_AS)[0] != resource.RLIM_INFINITY


def claim_blas_buffer() -> None:
    """Under an address-space limit: import numpy and run one tiny LAPACK call,
    so that OpenBLAS allocates its work buffer now (it keeps it) rather than at
    the first matrix operation of a command, where a failed allocation aborts
    the process; and load hashlib's OpenSSL (which, when it cannot be mapped
    later, logs a traceback for every hash instead of raising). ``MemoryError``
    when the limit leaves no room for them."""
    if not _address_space_limited():
        return
    from .core.memory import is_allocation_failure, require_address_space

    require_address_space(BLAS_START_BYTES, "numpy and its BLAS work buffer")
    try:
        import hashlib  # noqa: F401  (OpenSSL: loaded late, hashlib logs a traceback per hash)

        import numpy as np

        np.linalg.inv(np.eye(2))
    except (ImportError, OSError) as error:
        if is_allocation_failure(error):
            raise MemoryError(f"numpy could not be loaded: {error}") from None
        raise


def _out_of_memory_at_start(what: str) -> SetupError:
    from .core.memory import describe

    return SetupError(f"out of memory ({describe()}) while loading {what}; raise the limit")


def prepare_command() -> None:
    """What the ``mcrt`` command does first, before numpy, scipy and Mitsuba are
    imported: :func:`limit_blas_threads` and :func:`claim_blas_buffer`. A limit
    too low to start ends the process with one line and exit status 2."""
    limit_blas_threads()
    try:
        claim_blas_buffer()
    except MemoryError:
        _exit_with(_out_of_memory_at_start("numpy"))

#: Oldest libLLVM major version known to compile Mitsuba 3.9 kernels.
MIN_LLVM_MAJOR = 17

#: Variant selected when the user has not activated one.
DEFAULT_VARIANT = "llvm_ad_rgb"

_INSTALL_HINT = (
    "install a libLLVM >= {min} (Debian 12 / Ubuntu 24.04: `apt install libllvm19`; "
    "`bash scripts/setup.sh` does it for you) or point DRJIT_LIBLLVM_PATH at a "
    "libLLVM.so of version >= {min}"
)


def llvm_status() -> tuple[bool, str]:
    """Return ``(usable, description)`` for the libLLVM Dr.Jit has loaded.

    Never compiles a kernel, so it is safe to call with a broken libLLVM.
    """
    import drjit as dr

    hint = _INSTALL_HINT.format(min=MIN_LLVM_MAJOR)
    override = os.environ.get("DRJIT_LIBLLVM_PATH")
    if not dr.has_backend(dr.JitBackend.LLVM):
        if _address_space_limited():
            from .core.memory import LLVM_LOAD_BYTES, address_space_left

            left = address_space_left()
            if left is not None and left < LLVM_LOAD_BYTES:  # libLLVM did not fit, not missing
                raise MemoryError("libLLVM could not be mapped")
        where = f"DRJIT_LIBLLVM_PATH={override!r} could not be loaded" if override \
            else "no libLLVM shared library was found"
        return False, f"Dr.Jit's LLVM backend is unavailable: {where}; {hint}"
    major, minor, patch = dr.detail.llvm_version()
    version = f"{major}.{minor}.{patch}"
    if major < MIN_LLVM_MAJOR:
        source = f" (from DRJIT_LIBLLVM_PATH={override!r})" if override else ""
        return False, (f"Dr.Jit loaded libLLVM {version}{source}, which crashes on "
                       f"Mitsuba's kernels; {hint}")
    return True, f"libLLVM {version}"


def ensure_variant() -> str:
    """Activate :data:`DEFAULT_VARIANT` if no variant is active; check LLVM if used.

    Returns the active variant name. Raises :class:`SetupError` with an install
    hint when the LLVM backend is needed but unusable.
    """
    import mitsuba as mi

    variant = mi.variant()
    wanted = variant or DEFAULT_VARIANT
    check_vectorised(wanted)
    if wanted.startswith("llvm_"):
        usable, message = llvm_status()
        if not usable:
            raise SetupError(message)
    if variant is None:
        mi.set_variant(DEFAULT_VARIANT)
        variant = DEFAULT_VARIANT
    return variant


def check_vectorised(variant: str) -> None:
    """mcrt traces wavefronts with Dr.Jit: refuse a scalar variant in one line."""
    if variant.startswith("scalar_"):
        raise SetupError(f"mcrt renders with Mitsuba's vectorised variants (llvm_* or cuda_*, "
                         f"e.g. llvm_ad_rgb); {variant!r} is a scalar variant")


def select_variant(name: str) -> str:
    """Activate variant ``name`` (the CLI's ``--variant``) with one-line errors for
    unknown, scalar, unusable (no libLLVM) or unavailable (no GPU) variants."""
    import mitsuba as mi

    if name not in mi.variants():
        raise SetupError(f"unknown variant {name!r}; this Mitsuba has: "
                         f"{', '.join(v for v in mi.variants() if not v.startswith('scalar_'))}")
    check_vectorised(name)
    if name.startswith("llvm_"):
        usable, message = llvm_status()
        if not usable:
            raise SetupError(message)
    if name.startswith("cuda_"):
        import drjit as dr

        if not dr.has_backend(dr.JitBackend.CUDA):
            raise SetupError(f"variant {name!r} needs an NVIDIA GPU with its driver (CUDA); "
                             f"none was found: use an llvm_* variant")
    try:
        mi.set_variant(name)
    except Exception as error:  # e.g. a cuda_* variant on a machine without a GPU
        first = str(error).strip().splitlines()[0] if str(error).strip() else type(error).__name__
        raise SetupError(f"cannot use variant {name!r}: {first}") from None
    return name


class _OneLineSetupErrors:
    """``sys.excepthook`` printing a :class:`SetupError` as one line; other
    exceptions go to the previous hook."""

    def __init__(self, previous: Callable[[type[BaseException], BaseException,
                                           TracebackType | None], object]) -> None:
        self.previous = previous

    def __call__(self, exc_type: type[BaseException], exc: BaseException,
                 tb: TracebackType | None) -> None:
        if issubclass(exc_type, SetupError):
            sys.stderr.write(f"mcrt: error: {exc}\n")
        else:
            self.previous(exc_type, exc, tb)


def _exit_with(error: SetupError) -> None:
    """The ``mcrt`` command, before its ``main`` runs: one line, exit status 2.

    Ends the process at once (``os._exit``): an interpreter shutting down with
    Mitsuba or Dr.Jit half loaded can crash in their destructors."""
    try:
        sys.stderr.write(f"mcrt: error: {error}\n")
        sys.stderr.flush()
    finally:
        os._exit(2)


def initialise() -> str:
    """:func:`ensure_variant` for ``import mcrt``.

    An uncaught :class:`SetupError` (say, ``import mcrt`` on a machine with only
    libLLVM 15, or the ``mcrt`` command there) is printed as one line with the
    install hint instead of a traceback; code that catches it is unaffected.
    Mitsuba, Dr.Jit or libLLVM that cannot be mapped under an address-space
    limit is such an error (``out of memory (...)``). The ``mcrt`` command ends
    with exit status 2 after the line.
    """
    try:
        try:
            if COMMAND and _address_space_limited() and "mitsuba" not in sys.modules:
                from .core.memory import require_address_space

                # A library that half loads can abort the process or leave it
                # broken (C++ initialisers, Dr.Jit's LLVM start-up): not tried.
                require_address_space(MITSUBA_START_BYTES, "Mitsuba, Dr.Jit and libLLVM")
            return ensure_variant()
        except SetupError:
            raise
        except Exception as error:  # under ulimit -v: whatever a half-loaded library raises
            from .core.memory import is_allocation_failure

            if is_allocation_failure(error):
                raise _out_of_memory_at_start("Mitsuba and libLLVM") from None
            raise
    except SetupError as error:
        if COMMAND:
            _exit_with(error)
        if not isinstance(sys.excepthook, _OneLineSetupErrors):
            sys.excepthook = _OneLineSetupErrors(sys.excepthook)
        raise


#: Whether this process is the ``mcrt`` command (:func:`running_as_command`).
COMMAND = running_as_command()
if COMMAND:
    prepare_command()
