"""Where a ``pointset`` sampler's points come from: a file, or a Python generator.

Both give, for a sample count ``N``, a table of ``T`` sets of ``N`` points in
the unit square, as a float32 array of shape ``(T, N, 2)``, checked here once
(shape, NaN, range) with one-line errors that name the source.

Files: ``.npy`` holding ``(T, N, 2)`` (or ``(N, 2)``: one set); ``.npz`` holding
one such array per point count (any key names); UTK's text format (``.dat``,
``.txt``: one point per line, coordinates separated by spaces, sets separated
by lines starting with ``#``).

Generators: ``fn(count, n, rng)`` returns ``count`` sets of ``n`` points; mcrt
calls it with ``rng = numpy.random.default_rng(seed)`` and caches the table on
disk, keyed by the function's source code, its bound parameters (defaults,
closure values, ``functools.partial`` arguments), ``T``, ``N`` and the seed.

Example::

    >>> import numpy as np
    >>> def jittered(count, n, rng):
    ...     k = int(np.sqrt(n))
    ...     cells = np.stack(np.meshgrid(np.arange(k), np.arange(k)), -1).reshape(-1, 2)
    ...     return (cells + rng.random((count, n, 2))) / k
    >>> GeneratorSource(jittered, sets=8).table(16).shape
    (8, 16, 2)
"""

from __future__ import annotations

import functools
import hashlib
import inspect
import marshal
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np

from ..cache import cache_dir
from ..errors import SamplerError

#: Sets a generator is asked for by default (each pixel and dimension pair draws one).
DEFAULT_SETS = 256
#: Most sets a table may hold (a hash of 16 bits picks the set).
MAX_SETS = 1 << 16
#: Largest point count of one set.
MAX_POINTS = 1 << 20
#: Largest float32 below 1: points are stored as float32, and a point of [0, 1) that would
#: round up to 1 there is stored as this.
ONE_MINUS_EPSILON = float.fromhex("0x1.fffffep-1")
#: Version of the generator cache's file layout (part of every key).
_CACHE_FORMAT = 1


def check_table(points: Any, where: str) -> np.ndarray:
    """``points`` as a float32 ``(T, N, 2)`` array in [0, 1), or a one-line error."""
    try:
        array = np.asarray(points, dtype=np.float64)
    except (TypeError, ValueError) as error:
        raise SamplerError(f"{where}: not an array of numbers ({error})") from None
    if array.ndim == 2 and array.shape[-1:] == (2,):
        array = array[None]
    if array.ndim != 3 or array.shape[2] != 2:
        raise SamplerError(f"{where}: expected an array of shape (sets, points, 2), "
                           f"got {tuple(array.shape)}")
    sets, n = array.shape[:2]
    if sets == 0 or n == 0:
        raise SamplerError(f"{where}: holds no points (shape {tuple(array.shape)})")
    if sets > MAX_SETS or n > MAX_POINTS:
        raise SamplerError(f"{where}: at most {MAX_SETS} sets of {MAX_POINTS} points, "
                           f"got {sets} of {n}")
    bad = np.argwhere(~np.isfinite(array))
    if bad.size:
        t, i, _ = bad[0]
        raise SamplerError(f"{where}: point {i} of set {t} is not a number: "
                           f"{tuple(array[t, i].tolist())}")
    outside = np.argwhere((array < 0) | (array >= 1))
    if outside.size:
        t, i, _ = outside[0]
        raise SamplerError(f"{where}: point {i} of set {t} is {tuple(array[t, i].tolist())}, "
                           f"outside [0, 1)")
    # A value within 2^-25 of 1 rounds up to 1 in float32 (rng.random() gives one in
    # ~3e7, so most large tables hold one): it is stored as the largest float32 below 1.
    single = np.minimum(array, ONE_MINUS_EPSILON).astype(np.float32)
    return np.ascontiguousarray(single)


def _read_utk(path: Path) -> list[np.ndarray]:
    """UTK's text format: sets separated by ``#`` lines, one point per line."""
    sets: list[list[list[float]]] = [[]]
    with path.open(encoding="utf-8", errors="replace") as lines:
        for number, line in enumerate(lines, 1):
            text = line.strip()
            if text.startswith("#"):
                if sets[-1]:
                    sets.append([])
                continue
            if not text:
                continue
            try:
                sets[-1].append([float(v) for v in text.replace(",", " ").split()])
            except ValueError:
                raise SamplerError(f"{path}: line {number} is not a point: {text[:60]!r}") from None
    sets = [s for s in sets if s]
    widths = {len(p) for s in sets for p in s}
    if widths - {2}:
        raise SamplerError(f"{path}: points must have 2 coordinates, found "
                           f"{sorted(widths - {2})[0]}")
    return [np.asarray(s, dtype=np.float64) for s in sets]


def read_point_file(path: str | Path) -> dict[int, np.ndarray]:
    """The tables of a point file by point count (see the module docstring)."""
    path = Path(path)
    where = str(path)
    if not path.is_file():
        raise SamplerError(f"{where}: no such point-set file")
    suffix = path.suffix.lower()
    try:
        if suffix == ".npy":
            arrays = [np.load(path, allow_pickle=False)]
        elif suffix == ".npz":
            with np.load(path, allow_pickle=False) as archive:
                arrays = [archive[key] for key in archive.files]
        elif suffix in (".dat", ".txt", ".pts"):
            parts = _read_utk(path)
            counts = {len(p) for p in parts}
            if len(counts) > 1:
                arrays = [np.stack([p for p in parts if len(p) == c]) for c in sorted(counts)]
            else:
                arrays = [np.stack(parts)] if parts else [np.zeros((0, 0, 2))]
        else:
            raise SamplerError(f"{where}: unknown point-set format {suffix!r} "
                               f"(use .npy, .npz or UTK's .dat text)")
    except (OSError, ValueError, EOFError) as error:
        raise SamplerError(f"{where}: cannot read point sets ({error})") from None
    tables: dict[int, np.ndarray] = {}
    for array in arrays:
        table = check_table(array, where)
        n = table.shape[1]
        if n in tables:
            raise SamplerError(f"{where}: two arrays of {n}-point sets; give one per count")
        tables[n] = table
    if not tables:
        raise SamplerError(f"{where}: holds no point sets")
    return tables


#: Files read by :class:`FileSource`: (path, mtime, size) -> (tables, digest), the most
#: recent :data:`_FILES_KEPT` (a render clones its sampler, which makes it anew).
_FILES: dict[tuple, tuple[dict[int, np.ndarray], str]] = {}
_FILES_KEPT = 8


class FileSource:
    """Point sets read from a file (read once per process and file version)."""

    def __init__(self, filename: str | Path) -> None:
        self.path = Path(filename).expanduser().resolve()
        stat = self.path.stat() if self.path.is_file() else None
        self.key = ("file", str(self.path), stat.st_mtime_ns if stat else 0,
                    stat.st_size if stat else 0)
        read = _FILES.pop(self.key, None)
        if read is None:
            tables = read_point_file(self.path)
            for table in tables.values():
                table.setflags(write=False)  # shared by every sampler of this file
            read = (tables, file_digest(self.path))
        _FILES[self.key] = read
        while len(_FILES) > _FILES_KEPT:
            del _FILES[next(iter(_FILES))]
        self._tables, self.digest = read

    def describe(self) -> str:
        return str(self.path)

    def counts(self) -> tuple[int, ...] | None:
        return tuple(sorted(self._tables))

    def sets(self) -> dict[int, int]:
        """How many sets the file holds of each size."""
        return {n: int(table.shape[0]) for n, table in self._tables.items()}

    def table(self, n: int) -> np.ndarray:
        if n not in self._tables:
            raise count_mismatch(self.describe(), n, self.sets())
        return self._tables[n]


def file_digest(path: str | Path) -> str:
    """Digest of a point file's bytes ("" if it cannot be read)."""
    try:
        return hashlib.sha256(Path(path).read_bytes()).hexdigest()[:20]
    except OSError:
        return ""


def best_count(sets: dict[int, int]) -> int:
    """The set size with the most sets (the smallest of those): the one to use
    when the caller named none."""
    return min(sets, key=lambda n: (-sets[n], n))


def count_mismatch(where: str, n: int, sets: dict[int, int]) -> SamplerError:
    """The error for a sample count the point sets (``sets``: how many of each
    size) do not have; it suggests :func:`best_count`."""
    have = ", ".join(f"{s} set{'s' if s != 1 else ''} of {c}" for c, s in sorted(sets.items()))
    return SamplerError(f"{where}: holds {have} points, not {n}: render with --spp "
                        f"{best_count(sets)} (the count must match a set size)")


def _bound_values(fn: Callable) -> list[Any]:
    """What besides its code decides a function's output: partial arguments,
    defaults and closure values (by repr; arrays by their bytes)."""
    values: list[Any] = []
    while isinstance(fn, functools.partial):
        values += [fn.args, sorted(fn.keywords.items())]
        fn = fn.func
    values += [getattr(fn, "__defaults__", None), getattr(fn, "__kwdefaults__", None)]
    for cell in getattr(fn, "__closure__", None) or ():
        try:
            values.append(cell.cell_contents)
        except ValueError:  # an empty cell
            values.append(None)
    return values


def _code_of(fn: Callable) -> bytes:
    while isinstance(fn, functools.partial):
        fn = fn.func
    try:
        return inspect.getsource(fn).encode()
    except (OSError, TypeError):
        code = getattr(fn, "__code__", None)
        if code is None:
            raise SamplerError(f"points={fn!r}: give a Python function "
                               f"fn(count, n, rng) -> (count, n, 2) array") from None
        return marshal.dumps(code)


def _digest(values: list[Any]) -> str:
    h = hashlib.sha256()
    for value in values:
        if isinstance(value, np.ndarray):
            h.update(value.tobytes())
            h.update(repr((value.dtype, value.shape)).encode())
        else:
            h.update(repr(value).encode())
        h.update(b"\0")
    return h.hexdigest()[:20]


class GeneratorSource:
    """Point sets from ``fn(count, n, rng)``, tabulated per ``N`` and cached on disk."""

    def __init__(self, fn: Callable[..., Any], sets: int = DEFAULT_SETS, seed: int = 0,
                 name: str = "points") -> None:
        if not callable(fn):
            raise SamplerError(f"{name}: points must be a function fn(count, n, rng)")
        if not isinstance(sets, int) or not 1 <= sets <= MAX_SETS:
            raise SamplerError(f"{name}: sets must be an integer in [1, {MAX_SETS}], got {sets!r}")
        self.fn, self.sets, self.seed, self.name = fn, sets, seed, name
        self.digest = _digest([_CACHE_FORMAT, _code_of(fn), *_bound_values(fn), sets, seed])
        self.key = ("generator", name, self.digest)
        self._tables: dict[int, np.ndarray] = {}

    def describe(self) -> str:
        return f"{self.name} (generator {getattr(self.fn, '__name__', 'points')})"

    def counts(self) -> tuple[int, ...] | None:
        return None  # any

    def cache_path(self, n: int) -> Path:
        return cache_dir("pointsets") / f"{self.name}-{self.digest}-{n}.npy"

    def generate(self, n: int) -> np.ndarray:
        """A fresh table for ``n`` points (no cache): the generator's output, checked."""
        rng = np.random.default_rng([self.seed, n])
        try:
            points = self.fn(self.sets, n, rng)
        except SamplerError:
            raise
        except Exception as error:
            raise SamplerError(f"{self.describe()}: failed for n={n}: "
                               f"{type(error).__name__}: {error}") from error
        table = check_table(points, f"{self.describe()}, n={n}")
        if table.shape[:2] != (self.sets, n):
            raise SamplerError(f"{self.describe()}: asked for {self.sets} sets of {n} points, "
                               f"returned {table.shape[0]} of {table.shape[1]}")
        return table

    def _check_repeatable(self, n: int) -> None:
        """Two calls for one set with equal ``rng``s must agree: a generator that
        draws from numpy's global RNG, ``random`` or the clock passed every check
        (its first table is cached, keyed by its code) while Dask workers and a cleared cache made
        other points. (A generator that fails for one set is not judged here.)"""
        try:
            a, b = (np.asarray(self.fn(1, n, np.random.default_rng([self.seed, n])))
                    for _ in range(2))
        except Exception:  # noqa: BLE001  (the full call succeeded)
            return
        if a.shape != b.shape or not np.array_equal(a, b, equal_nan=True):
            raise SamplerError(f"{self.describe()}: two calls with the same rng returned "
                               f"different points; draw every random number from the rng "
                               f"argument (not numpy's global RNG, random or the time), so "
                               f"that the table can be made again")

    def table(self, n: int) -> np.ndarray:
        if n in self._tables:
            return self._tables[n]
        path = self.cache_path(n)
        table: np.ndarray | None = None
        try:
            loaded = np.load(path, allow_pickle=False)
            if loaded.shape == (self.sets, n, 2) and loaded.dtype == np.float32:
                table = loaded
        except (OSError, ValueError, EOFError):
            table = None
        if table is None:
            table = self.generate(n)
            _store(path, table)
        self._check_repeatable(n)  # a cached table too: the cache hid the global RNG
        self._tables[n] = table
        return table


def _store(path: Path, table: np.ndarray) -> None:
    """Write a cache file atomically; a cache that cannot be written is skipped."""
    try:
        path.parent.mkdir(parents=True, exist_ok=True)
        partial = path.with_name(f".{path.name}.partial")
        with partial.open("wb") as handle:
            np.save(handle, table)
        partial.replace(path)
    except OSError:
        pass


def jittered_sets(count: int, n: int, rng: np.random.Generator) -> np.ndarray:
    """``count`` jittered sets of ``n`` points (``k x k`` strata for a square ``n``;
    ``n`` i.i.d. points otherwise): the example generator of the docs and tests."""
    k = int(np.sqrt(n))
    if k * k != n:
        return rng.random((count, n, 2))
    cells = np.stack(np.meshgrid(np.arange(k), np.arange(k)), -1).reshape(-1, 2)
    return (cells + rng.random((count, n, 2))) / k


def example_file(n: int, sets: int | None = None) -> Path:
    """A ``.npy`` file of jittered sets of ``n`` points in mcrt's cache (written once):
    by default 1024 sets (a table's fixed error is ~1/sqrt(8 x 1024) of one set's,
    see docs/extending.md), fewer for large ``n`` (at most 2^20 points, at least 16 sets)."""
    sets = sets or max(16, min(1024, (1 << 20) // n))
    path = cache_dir("pointsets") / f"example-jittered-{sets}x{n}.npy"
    if not path.is_file():
        table = check_table(jittered_sets(sets, n, np.random.default_rng([7, n])), "example")
        _store(path, table)
        if not path.is_file():
            raise SamplerError(f"cannot write the example point sets to {path}")
    return path
