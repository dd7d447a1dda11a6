"""Start-up checks: a usable libLLVM and an active vectorised Mitsuba variant.

Dr.Jit's LLVM backend loads the system ``libLLVM`` at run time. Versions 14-16
(the defaults on Debian 12 and Ubuntu 22.04) load fine and then abort the whole
process on the first kernel with ``LLVM ERROR: Cannot select ... fminimum``.
We ask Dr.Jit which version it loaded *before* any kernel is compiled and turn
a missing or too-old library into a clear, actionable message.
"""

from __future__ import annotations

import os
import sys
from collections.abc import Callable
from types import TracebackType

from .errors import SetupError

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


def initialise() -> str:
    """:func:`ensure_variant` for ``import mcrt``.

    An uncaught :class:`SetupError` (say, ``import mcrt`` on a machine with only
    libLLVM 15, or the ``mcrt`` command there) is printed as one line with the
    install hint instead of a traceback; code that catches it is unaffected.
    """
    try:
        return ensure_variant()
    except SetupError:
        if not isinstance(sys.excepthook, _OneLineSetupErrors):
            sys.excepthook = _OneLineSetupErrors(sys.excepthook)
        raise
