"""Point sets as a sampler: a user's file or generator, rendered like our tables.

:func:`draw_from_tables` is the one way a set is drawn from a table of sets
(``poisson_disk`` uses it too): per (seed, pixel, dimension pair, epoch) a hash
picks a set, a permutation of its sample order (which decorrelates dimension
pairs) and a randomisation of the set (:data:`RANDOMIZATIONS`).
"""

from __future__ import annotations

from collections.abc import Callable
from contextvars import ContextVar
from typing import TYPE_CHECKING, ClassVar, cast

import drjit as dr
import mitsuba as mi

from ..errors import SamplerError
from ._hash import hash_extend, permute
from ._stratified import epoch_key, split_sample, stratified_1d
from ._types import Mask
from .base import McrtSampler

# .point_sources (numpy) is imported on first use, as poisson_disk's tables are.
if TYPE_CHECKING:
    from .point_sources import FileSource

#: Randomisations of a drawn set, and what each keeps of the set's properties.
RANDOMIZATIONS: dict[str, str] = {
    "none": "the set as given; unbiased only if each point of the table is uniform "
            "over its sets (random sets); pixels that draw the same set get the same points",
    "symmetry": "one of the 8 symmetries of the square (swap and mirror the axes; the "
                "default): keeps k x k strata, (0,m,2)-nets, distances and the spectrum (up "
                "to a 90-degree turn); unbiased only for random sets",
    "shift": "a toroidal (Cranley-Patterson) shift: keeps toroidal distances and the "
             "power spectrum; makes every point uniform, so any set renders unbiased; "
             "moves strata and nets off the grid",
    "xor": "a random digital shift (xor of the 24-bit binary fractions): keeps "
           "elementary intervals, so (0,m,2)-nets stay nets; makes every point uniform",
    "symmetry_shift": "a symmetry, then a toroidal shift (as poisson_disk): keeps "
                      "toroidal distances and the spectrum up to a turn; unbiased for any set",
}
#: How 1D dimensions are drawn.
ONE_D: dict[str, str] = {
    "stratified": "N jittered strata (as jittered), whatever the sets",
    "projection": "the x coordinate of a randomised set (the sets' own 1D projection)",
}
#: Randomisations that leave the sets' own randomness as the only one: each point
#: is uniform only if the table's sets are random, so they need many sets.
UNSHIFTED = ("none", "symmetry")
#: Fewest sets a table may have under an unshifted randomisation.
MIN_SETS_UNSHIFTED = 16
#: The default randomisation (it keeps strata and nets; a jittered file renders
#: with jittered's variance, where a toroidal shift adds ~30% on the Cornell box).
DEFAULT_RANDOMIZE = "symmetry"

#: Largest float32 below 1.
ONE_MINUS_EPSILON = float.fromhex("0x1.fffffep-1")
_INV_2_16 = 1.0 / (1 << 16)
_INV_2_24 = 1.0 / (1 << 24)

#: Device copies of tables by (variant, source key, point count): flat x, y, set count.
_DEVICE: dict[tuple, tuple[mi.Float, mi.Float, int]] = {}


def device_table(key: tuple, table_of) -> tuple[mi.Float, mi.Float, int]:
    """Flat Dr.Jit copies (x, y) of a ``(T, N, 2)`` table and ``T``; ``table_of()``
    gives the numpy table the first time (per variant).

    Kept out of the sampler's ``__dict__`` on purpose: Dr.Jit turns every array
    stored there into loop state, and a table is not per-lane state.
    """
    full_key = (mi.variant(), *key)
    if full_key not in _DEVICE:
        table = table_of()
        _DEVICE[full_key] = (mi.Float(table[:, :, 0].ravel()), mi.Float(table[:, :, 1].ravel()),
                             int(table.shape[0]))
    return _DEVICE[full_key]


#: The file source of the sampler being forked (see :meth:`PointSetSampler.fork`).
_FORKING: ContextVar[FileSource | None] = ContextVar("mcrt_pointset_forking", default=None)


def _resolved(filename: str) -> str:
    """Where Mitsuba's file resolver finds ``filename``: in a scene, relative to
    the scene's folder first, as every other file the scene names (and as its
    content digest and travelling bundle assume), then the working directory;
    ``filename`` as given when it finds nothing (read relative to the working
    directory, and reported there)."""
    resolver = cast(Callable[[], mi.FileResolver], mi.file_resolver)()  # not in the stubs
    return str(resolver.resolve(filename))


def _wrap(v: mi.Float) -> mi.Float:
    """``v mod 1`` for ``v`` in [0, 2]: exact (Sterbenz) and always below 1."""
    return dr.minimum(dr.select(v >= 1.0, v - 1.0, v), ONE_MINUS_EPSILON)


def _xor_shift(v: mi.Float, bits: mi.UInt32) -> mi.Float:
    fixed = mi.UInt32(v * float(1 << 24)) ^ (bits & 0xFFFFFF)
    return mi.Float(fixed) * _INV_2_24


def draw_from_tables(dim_key: mi.UInt32, sample: mi.UInt32, n: int,
                     table: tuple[mi.Float, mi.Float, int], randomize: str,
                     active: Mask = True) -> mi.Point2f:
    """Point ``sample`` of the set that (seed, pixel, dimension, epoch) draws."""
    table_x, table_y, n_tables = table
    epoch, rank = split_sample(sample, n)
    set_key = epoch_key(dim_key, epoch)
    index = permute(rank, n, set_key, active)
    # The set key is a well-mixed hash already: its bits pick the set and the
    # symmetry directly; one more mix gives the shift.
    chosen = ((set_key >> 8) & 0xFFFF) % n_tables
    point = chosen * n + index
    x = dr.gather(mi.Float, table_x, point, active)
    y = dr.gather(mi.Float, table_y, point, active)
    if randomize in ("symmetry", "symmetry_shift"):
        symmetry = set_key >> 29  # 3 bits: swap axes, mirror x, mirror y
        x, y = dr.select((symmetry & 1) != 0, y, x), dr.select((symmetry & 1) != 0, x, y)
        x = dr.select((symmetry & 2) != 0, 1.0 - x, x)
        y = dr.select((symmetry & 4) != 0, 1.0 - y, y)
        if randomize == "symmetry":  # 1 - 0 is 1: keep the points below 1
            x, y = dr.minimum(x, ONE_MINUS_EPSILON), dr.minimum(y, ONE_MINUS_EPSILON)
    if randomize in ("shift", "symmetry_shift"):
        shift = hash_extend(set_key, 0x9D15C)  # 16 bits per axis: a shift on a 2^-16 grid
        x = _wrap(x + mi.Float(shift >> 16) * _INV_2_16)
        y = _wrap(y + mi.Float(shift & 0xFFFF) * _INV_2_16)
    elif randomize == "xor":
        bits = hash_extend(set_key, 0x5A17)
        x, y = _xor_shift(x, bits), _xor_shift(y, hash_extend(bits, 1))
    return mi.Point2f(x, y)


class PointSetSampler(McrtSampler):
    r"""
    .. _sampler-pointset:

    Point-set sampler (:monosp:`pointset`)
    --------------------------------------

    .. pluginparameters::

     * - filename
       - |string|
       - The point sets: ``.npy`` of shape (T, N, 2), ``.npz`` with one such
         array per point count, or UTK's text format (sets separated by ``#``
         lines). Points must lie in [0, 1). (Required, unless the sampler was
         registered with a generator)
     * - sample_count
       - |int|
       - Samples per pixel: must equal a set size N of the file. (Default: 4,
         or the file's smallest set size if it holds no 4-point sets)
     * - randomize
       - |string|
       - ``none``, ``symmetry``, ``shift``, ``xor`` or ``symmetry_shift`` (see
         :data:`RANDOMIZATIONS`). (Default: ``symmetry``; it needs at least 16
         random sets, as ``none`` does)
     * - dims1d
       - |string|
       - 1D dimensions: ``stratified`` or ``projection``. (Default: ``stratified``)
     * - seed
       - |int|
       - Seed offset. (Default: 0)

    Every 2D dimension pair (film position, lens, light, BSDF, ...) of every
    pixel draws one of the T sets, chosen by a hash of (seed, pixel, dimension,
    epoch), with its sample order permuted by the same key (so dimension pairs
    are decorrelated) and the chosen randomisation applied. Passes beyond the
    first draw fresh sets (epochs), as ``poisson_disk`` does.

    .. tabs::

        .. code-tab:: python

            'type': 'pointset',
            'filename': 'sets.npy',
            'sample_count': 64
    """

    plugin_name = "pointset"
    summary = "a user's point sets from a file, randomised per pixel and dimension"
    #: A generator's point source (set on the classes of ``register_sampler``);
    #: None: the ``filename`` property names the source.
    source: ClassVar[object | None] = None
    #: The randomisation used when the scene does not choose one.
    default_randomize: ClassVar[str] = DEFAULT_RANDOMIZE

    def _configure(self, props: mi.Properties) -> None:
        from .point_sources import FileSource

        self.randomize = str(props.get("randomize", self.default_randomize))
        if self.randomize not in RANDOMIZATIONS:
            raise SamplerError(f"{self.plugin_name}: 'randomize' must be one of "
                               f"{', '.join(RANDOMIZATIONS)}, got {self.randomize!r}")
        self.dims1d = str(props.get("dims1d", "stratified"))
        if self.dims1d not in ONE_D:
            raise SamplerError(f"{self.plugin_name}: 'dims1d' must be one of "
                               f"{', '.join(ONE_D)}, got {self.dims1d!r}")
        if self.source is not None:
            if "filename" in props:
                raise SamplerError(f"{self.plugin_name}: its points come from a generator; "
                                   f"it takes no 'filename'")
            self._source = self.source
            self.filename = ""
        else:
            if "filename" not in props:
                raise SamplerError(f"{self.plugin_name}: give the point sets' file, e.g. "
                                   f"<string name=\"filename\" value=\"sets.npy\"/>")
            path = _resolved(str(props["filename"]))
            kept = _FORKING.get()  # a fork or clone keeps the tables its original read
            self._source = kept if kept is not None and kept.describe() == path \
                else FileSource(path)
            self.filename = self._source.describe()  # by absolute path, as found
        # Without a sample_count the C++ default (4) stands in; a file that has no
        # 4-point sets then serves its smallest (see _effective_count).
        self._count_defaulted = "sample_count" not in props

    def fork(self) -> McrtSampler:
        """A fresh sampler with the same parameters and the same point tables: not
        read again (the file may have changed or gone since, e.g. a cluster
        bundle's copy; a render works on a clone of its sampler)."""
        token = _FORKING.set(cast("FileSource", self._source) if self.filename else None)
        try:
            return super().fork()
        finally:
            _FORKING.reset(token)

    def _parameters(self) -> dict:
        params = {"randomize": self.randomize, "dims1d": self.dims1d}
        return {"filename": self.filename, **params} if self.filename else params

    def sample_counts(self) -> tuple[int, ...] | None:
        """The sample counts this sampler serves, ascending: the set sizes of its
        file; None for a generator (any count)."""
        return self._source.counts()  # type: ignore[attr-defined]

    def _effective_count(self, spp: int) -> int:
        counts = self.sample_counts()
        defaulted, self._count_defaulted = self._count_defaulted, False
        if counts is not None and spp not in counts:
            from .point_sources import best_count, count_mismatch  # (a file: it has counts)

            sets = self._source.sets()  # type: ignore[attr-defined]
            if defaulted:  # constructed without a sample_count
                return best_count(sets)
            raise count_mismatch(f"{self.plugin_name} ({self._source.describe()})",  # type: ignore[attr-defined]
                                 spp, sets)
        return spp

    def _sample_count_changed(self, spp: int) -> None:
        _, _, sets = self._table()  # tabulate / read now, not in the middle of a render
        if self.randomize in UNSHIFTED and sets < MIN_SETS_UNSHIFTED:
            raise SamplerError(
                f"{self.plugin_name} ({self._source.describe()}): only {sets} set(s) of "  # type: ignore[attr-defined]
                f"{spp} points with randomize={self.randomize!r}: the sets are the only "
                f"randomness, too little to be unbiased; give at least {MIN_SETS_UNSHIFTED} "
                f"random sets, or randomize='shift' or 'xor' (one deterministic set)")

    def frozen_inputs(self) -> tuple:
        return self._table()[:2]

    def _table(self) -> tuple[mi.Float, mi.Float, int]:
        n = self.sample_count()
        source = self._source
        return device_table((*source.key, n), lambda: source.table(n))  # type: ignore[attr-defined]

    def _sample_1d(self, key: mi.UInt32, sample: mi.UInt32, active: Mask) -> mi.Float:
        if self.dims1d == "projection":
            return mi.Float(self._sample_2d(key, sample, active).x)
        return stratified_1d(key, sample, self.sample_count(), 1.0, active)

    def _sample_2d(self, key: mi.UInt32, sample: mi.UInt32, active: Mask) -> mi.Point2f:
        return draw_from_tables(key, sample, self.sample_count(), self._table(),
                                self.randomize, active)

    @staticmethod
    def example_params(spp: int) -> dict:
        """A file of jittered sets for ``spp`` (square) points, for the contract
        tests and ``mcrt check pointset``."""
        from .point_sources import example_file

        return {"filename": str(example_file(spp))}


PLUGINS = (PointSetSampler,)
