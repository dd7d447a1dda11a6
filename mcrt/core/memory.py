"""How much memory a render may use, and how many lanes a pass can have.

The memory available to this process is the smallest of:

* the address-space limit (``ulimit -v``, ``RLIMIT_AS``) less the address space
  already mapped (``VmSize``: that is what the limit counts);
* the cgroup's limit less its current use (cgroup v2 ``memory.max`` /
  ``memory.current``, or v1 ``memory.limit_in_bytes`` / ``memory.usage_in_bytes``),
  with the memory the kernel can reclaim from the cgroup's page cache added;
* the host's ``MemAvailable``;
* limits that nothing in the kernel enforces, added by :func:`add_limit`: a Dask
  worker's memory limit, which its nanny enforces by terminating the process
  (:mod:`mcrt.core.worker_memory`).

A pass's peak is modelled as ``fixed_bytes + lanes * bytes_per_lane``:
``fixed_bytes`` for what does not depend on the pass size (the accumulator's
float64 sums, the developed image), ``bytes_per_lane`` for the wavefront
(Dr.Jit's per-lane state, the traced values and the pending sums).
:data:`BYTES_PER_LANE` and :func:`film_bytes` are measured upper bounds for
mcrt's passes (llvm variants: a 512x512 Cornell box at 0.26 to 4.2 million lanes
adds about 30 bytes per lane to a film render's peak, and a reference's pass
about 95 bytes per lane and 330 per pixel; the model's total is 1.2-2x the
measured peak).
"""

from __future__ import annotations

import ctypes
import ctypes.util
import errno
import os
import resource
import time
from collections.abc import Callable
from pathlib import Path

from ..errors import McrtError

#: Peak bytes a traced lane of a film render adds (measured ~30; safety 1.6).
BYTES_PER_LANE = 48

#: Peak bytes a traced lane of a statistics render (references) adds: the
#: per-lane float64 values of the moments (measured ~95 at 512x512, 1-9 spp).
STATS_BYTES_PER_LANE = 128

#: What compiling and launching a pass's kernel takes besides its data (LLVM).
KERNEL_BYTES = 32 << 20

#: Share of the available memory a render plans to use (the rest: the
#: allocator's slack, Python objects, the output writers).
USABLE_SHARE = 0.8


def _read_int(path: Path) -> int | None:
    try:
        text = path.read_text().split()[0]
    except (OSError, IndexError, MemoryError):
        return None
    return int(text) if text.isdigit() else None


def resident_bytes() -> int | None:
    """This process's resident memory (``VmRSS``): what a Dask nanny limits. Read
    from ``/proc/self/statm`` (6 us; ``/proc/self/status``: 29 us): a worker's
    every render asks."""
    try:
        fd = os.open("/proc/self/statm", os.O_RDONLY)
        try:
            pages = int(os.read(fd, 256).split()[1])
        finally:
            os.close(fd)
        return pages * os.sysconf("SC_PAGE_SIZE")
    except (OSError, ValueError, IndexError):
        return _status_bytes("VmRSS")


def _status_bytes(field: str) -> int | None:
    """A ``kB`` field of ``/proc/self/status`` in bytes (``VmSize``, ``VmRSS``)."""
    try:
        for line in Path("/proc/self/status").read_text().splitlines():
            if line.startswith(field + ":"):
                return int(line.split()[1]) * 1024
    except (OSError, ValueError, IndexError, MemoryError):
        pass
    return None


def _address_space_left() -> int | None:
    soft, _ = resource.getrlimit(resource.RLIMIT_AS)
    if soft == resource.RLIM_INFINITY:
        return None
    return max(0, soft - (_status_bytes("VmSize") or 0))


def address_space_left() -> int | None:
    """Bytes of address space ``ulimit -v`` still allows (None: no limit)."""
    return _address_space_left()


#: Address space that loading libLLVM takes (measured: ~130 MiB for libLLVM 19):
#: a backend that failed to load with less than this left did not fit.
LLVM_LOAD_BYTES = 256 << 20

#: With less address space than this left, a failed thread start (``EAGAIN``:
#: no room for its stack) is a failed allocation too.
THREAD_START_BYTES = 64 << 20

#: What the messages of failed allocations say: the loader's for a library that
#: does not fit (``failed to map segment``), ``ENOMEM``, C++'s ``bad_alloc``.
_ALLOCATION_FAILURES = ("failed to map segment", "cannot allocate memory", "bad_alloc",
                        "memory allocation failed")


def is_allocation_failure(error: BaseException) -> bool:
    """Whether ``error`` is an allocation that failed, or was caused by one (its
    ``__cause__``, or its ``__context__`` unless raised ``from None``):
    ``MemoryError``, ``ENOMEM``, a shared library that could not be mapped
    (``ImportError: ... failed to map segment from shared object``), C++'s
    ``std::bad_alloc`` as Mitsuba reports it, or a thread that could not start
    (``EAGAIN``, Python's ``can't start new thread``) with the address space
    (``ulimit -v``) nearly used up."""
    seen: BaseException | None = error
    for _ in range(8):  # the chain of causes (a failed import inside another's)
        if seen is None:
            return False
        if _failed_allocation(seen):
            return True
        seen = seen.__cause__ or (None if seen.__suppress_context__ else seen.__context__)
    return False


def _failed_allocation(error: BaseException) -> bool:
    if isinstance(error, MemoryError) or getattr(error, "errno", None) == errno.ENOMEM:
        return True
    try:
        text = str(error).lower()
    except MemoryError:
        return True
    if any(sign in text for sign in _ALLOCATION_FAILURES):
        return True
    if not isinstance(error, McrtError) and "out of memory" in text:  # ours say it in words
        return True
    if "resource temporarily unavailable" in text or "can't start new thread" in text or \
            getattr(error, "errno", None) == errno.EAGAIN:
        left = _address_space_left()
        return left is not None and left < THREAD_START_BYTES
    return False


def require_address_space(needed: int, what: str) -> None:
    """``MemoryError`` unless ``ulimit -v`` leaves ``needed`` bytes of address
    space, before loading or allocating ``what`` where a failure could not be
    caught (OpenBLAS retries a failed buffer forever or aborts; Dr.Jit crashes)."""
    left = _address_space_left()
    if left is not None and left < needed:
        raise MemoryError(f"{what} needs about {_mib(needed)} of address space, "
                          f"{_mib(left)} are left under ulimit -v")


def _cgroup_dir() -> Path | None:
    """This process's cgroup directory (v2 unified, or v1's memory controller)."""
    try:
        lines = Path("/proc/self/cgroup").read_text().splitlines()
    except OSError:
        return None
    for line in lines:
        parts = line.split(":", 2)
        if len(parts) != 3:
            continue
        if parts[0] == "0" and parts[1] == "":
            return CGROUP_ROOT / parts[2].lstrip("/")
        if "memory" in parts[1].split(","):
            return CGROUP_ROOT / "memory" / parts[2].lstrip("/")
    return None


#: Where cgroup file systems are mounted.
CGROUP_ROOT = Path("/sys/fs/cgroup")
#: Seconds for which the cgroup levels that limit memory (and their limits) are
#: reused: finding them reads ~18 files (0.14 ms, a sixth of a replayed
#: study-sized render); the usage of the limited levels is read at every call.
LIMITS_TTL = 5.0
_limits: tuple[float, list[tuple[Path, int]]] | None = None


def _limited_levels() -> list[tuple[Path, int]]:
    """The cgroup levels with a memory limit and their limits, this one and its
    parents (a parent's limit binds as well: containers often limit a parent)."""
    global _limits
    now = time.monotonic()
    if _limits is not None and now - _limits[0] < LIMITS_TTL:
        return _limits[1]
    directory = _cgroup_dir()
    levels: list[tuple[Path, int]] = []
    for level in [] if directory is None else [directory, *directory.parents]:
        if not level.is_relative_to(CGROUP_ROOT):
            break
        limit = _read_int(level / "memory.max") or _read_int(level / "memory.limit_in_bytes")
        if limit is not None and limit < 1 << 60:
            levels.append((level, limit))
    _limits = (now, levels)
    return levels


def _cgroup_left() -> int | None:
    left = None
    for level, limit in _limited_levels():
        used = _read_int(level / "memory.current") or _read_int(level / "memory.usage_in_bytes")
        if used is None:
            continue
        reclaimable = 0
        try:
            for line in (level / "memory.stat").read_text().splitlines():
                name, _, value = line.partition(" ")
                if name in ("inactive_file", "total_inactive_file"):
                    reclaimable = int(value)
        except (OSError, ValueError):
            pass
        here = max(0, limit - used + reclaimable)
        left = here if left is None else min(left, here)
    return left


def _host_available() -> int | None:
    try:
        for line in Path("/proc/meminfo").read_text().splitlines():
            if line.startswith("MemAvailable:"):
                return int(line.split()[1]) * 1024
    except (OSError, ValueError, IndexError):
        pass
    return None


#: The limits of :func:`add_limit`, by name: each returns the bytes it still allows.
_LIMITS: dict[str, Callable[[], int | None]] = {}


def add_limit(name: str, left: Callable[[], int | None]) -> None:
    """Count a limit that neither the kernel nor ``ulimit`` enforces in
    :func:`available_bytes`: ``left()`` returns the bytes it still allows (None:
    none now); ``name`` says it in messages ("the Dask worker's memory limit").
    Replaces a limit of the same name."""
    _LIMITS[name] = left


def _other_limits() -> list[tuple[str, int]]:
    """(name, bytes left) of the limits of :func:`add_limit` that say one now."""
    found = []
    for name, left in list(_LIMITS.items()):
        value = left()
        if value is not None:
            found.append((name, value))
    return found


def available_bytes() -> int | None:
    """Bytes this process can still allocate (the tightest of ``ulimit -v``, the
    cgroup limit, the host's available memory and :func:`add_limit`'s limits);
    None if none is known."""
    known = [v for v in (_address_space_left(), _cgroup_left(), _host_available())
             if v is not None] + [left for _, left in _other_limits()]
    return min(known) if known else None


def lane_budget(bytes_per_lane: int = BYTES_PER_LANE, fixed_bytes: int = 0,
                available: int | None = None) -> int | None:
    """The most lanes one pass can trace within the memory available
    (``available``, default :func:`available_bytes`): ``(USABLE_SHARE * available
    - fixed_bytes) // bytes_per_lane``, at least 0; None when no limit is known."""
    if available is None:
        available = available_bytes()
    if available is None:
        return None
    usable = int(available * USABLE_SHARE) - int(fixed_bytes)
    return max(0, usable // max(1, int(bytes_per_lane)))


def film_bytes(pixels: int, channels: int = 5) -> int:
    """Memory of a render's per-pixel state besides the wavefront: float64 sums,
    the developed float32 image and its numpy copy (a 2048x2048 render at 1 spp
    peaks at ~360 MiB above the process's start; this model says 512 MiB)."""
    return pixels * channels * (8 + 4 + 4)


def moments_bytes(pixels: int) -> int:
    """Memory of a reference's per-pixel state: the moments (count, mean, M2,
    nonfinite: 64 bytes) of the running total, of the pass on the device and in
    numpy, of their merge and of the saved state (measured: ~330 bytes per pixel
    at 256x256 to 1024x1024)."""
    return pixels * 64 * 6


def _mib(value: int) -> str:
    return f"{value / 2**20:.0f} MiB"


def require_memory(pixels: int, fixed_bytes: int, what: str,
                   bytes_per_lane: int = BYTES_PER_LANE, available: int | None = None,
                   where: str = "") -> int | None:
    """Before rendering: the lane budget (as :func:`lane_budget`, with
    :data:`KERNEL_BYTES` added to ``fixed_bytes``), or a one-line
    :class:`McrtError` if even the smallest pass (one sample of every pixel)
    cannot fit. ``available``: the memory where the passes run, if not here
    (``where`` says where: " on a Dask worker")."""
    if available is None:
        available, where = available_bytes(), ""
    fixed_bytes += KERNEL_BYTES
    budget = lane_budget(bytes_per_lane, fixed_bytes, available)
    if budget is not None and budget < pixels:
        assert available is not None
        needed = (fixed_bytes + pixels * bytes_per_lane) / USABLE_SHARE
        if not where:
            limits = []
            if _address_space_left() is not None:
                limits.append("ulimit -v")
            if _cgroup_left() is not None:
                limits.append("the cgroup's memory limit")
            limits += [name for name, _ in _other_limits()]
            where = f" (under {' and '.join(limits)})" if limits else ""
        raise McrtError(f"not enough memory for {what}: even its smallest pass (1 sample per "
                        f"pixel) needs about {_mib(int(needed))}, {_mib(available)} are "
                        f"available{where}; use a smaller image or raise the limit")
    return budget


def out_of_memory_message(detail: str = "") -> str:
    """The one line (after ``mcrt: error:``) of a command that ran out of memory:
    the limits seen (:func:`describe`) and, if given, what failed."""
    where = f": {detail}" if detail else ""
    return f"out of memory ({describe()}){where}; use a smaller image or raise the limit"


def describe() -> str:
    """The memory limits seen, for notes, bug reports and the out-of-memory
    message (which is printed with the memory nearly used up: never raises)."""
    try:
        parts = [f"{name} {_mib(value)}" for name, value in
                 (("ulimit -v left", _address_space_left()), ("cgroup left", _cgroup_left()),
                  ("host available", _host_available()),
                  *((f"{name} left", left) for name, left in _other_limits()))
                 if value is not None]
        return ", ".join(parts) or "no limit known"
    except Exception:  # MemoryError included: the message must still be printed
        return "the limits could not be read"


#: glibc's ``mallopt`` parameters (malloc.h) and the values :func:`reuse_freed_memory` sets.
_M_TRIM_THRESHOLD, _M_MMAP_THRESHOLD = -1, -3
MMAP_THRESHOLD = 32 << 20
TRIM_THRESHOLD = 64 << 20


def reuse_freed_memory() -> bool:
    """Let this process reuse the memory numpy frees, where Dask's nanny turned that
    off: it starts workers with ``MALLOC_TRIM_THRESHOLD_=65536``, which also fixes
    glibc's mmap threshold at 128 KiB, so every array above it is mapped afresh
    and page-faulted on each use. A study's tasks score their renders in numpy
    (FFTs, CIEDE2000): on a ``local:1`` worker a task cost 28.7 ms more than in
    the client's process, 11-12.5 ms with this (benchmarks/cluster_scaling.py;
    :class:`mcrt.core.cluster.WorkerSetup` calls it). Sets the thresholds to
    glibc's own dynamic ceiling; False where it did nothing."""
    if "MALLOC_TRIM_THRESHOLD_" not in os.environ:
        return False
    try:
        libc = ctypes.CDLL(ctypes.util.find_library("c") or "libc.so.6")
        return bool(libc.mallopt(_M_MMAP_THRESHOLD, MMAP_THRESHOLD)
                    and libc.mallopt(_M_TRIM_THRESHOLD, TRIM_THRESHOLD))
    except (OSError, AttributeError):  # not glibc
        return False


__all__ = ["BYTES_PER_LANE", "KERNEL_BYTES", "LLVM_LOAD_BYTES", "STATS_BYTES_PER_LANE",
           "THREAD_START_BYTES", "add_limit", "address_space_left", "available_bytes",
           "describe", "film_bytes", "is_allocation_failure", "lane_budget", "moments_bytes",
           "out_of_memory_message", "require_address_space", "require_memory",
           "resident_bytes", "reuse_freed_memory"]
