"""Common machinery of mcrt's sampler plugins: seeding, lane layout, passes.

Every mcrt sampler is a *counter-based* sampler: the value of dimension ``d`` of
sample ``j`` of pixel ``p`` is a pure function ``f(seed, p, j, d)``. The sampler
state is therefore three size-1 integers (a seed key, the dimension index and
the pass index) plus the lane layout, which makes ``clone()`` exact, reseeding
free of recompilation, and lets the analysis layer ask for the points of any
pixel through the very code Mitsuba calls (:meth:`McrtSampler.seed_lanes`).

Sample index ``j`` runs past the sample count ``N`` when a pixel gets more
passes than one (``advance()``): index ``j`` belongs to *epoch* ``j // N``, and
each epoch is a complete, freshly permuted and jittered pattern of ``N`` points.

The classes derive from the ``mi.Sampler`` of the variant that was active when
this module was imported; ``mcrt.register()`` re-imports the sampler modules
after a variant switch (Mitsuba does the same for its own Python plugins).
"""

from __future__ import annotations

from typing import TYPE_CHECKING, ClassVar, TypeGuard, cast

import drjit as dr
import mitsuba as mi

from ..errors import SamplerError
from . import _layout
from ._hash import hash_extend, hash_keys, hash_keys_int
from ._stratified import split_sample
from ._types import Mask, SeedValue

if TYPE_CHECKING:
    import drjit.auto.ad

#: ``seed()``'s default wavefront size: "keep the previous one" (Mitsuba's -1).
_KEEP_WAVEFRONT = 0xFFFFFFFF

#: Sample indices are 32-bit: index ``2^32 + j`` would be sample ``j`` again.
SAMPLE_INDEX_LIMIT = 1 << 32


def _literal_or_evaluated(value) -> bool:
    return value.state in (dr.VarState.Literal, dr.VarState.Evaluated)


class McrtSampler(mi.Sampler):
    """Base of the mcrt sampler plugins (see the module docstring).

    Subclasses set :attr:`plugin_name`, read their parameters in
    :meth:`_configure`, round sample counts in :meth:`_effective_count` and
    implement :meth:`_sample_1d` / :meth:`_sample_2d` as pure functions of
    ``(dimension key, sample index)``.
    """

    plugin_name: ClassVar[str] = ""
    #: Whether sample ``j`` of a pixel is the same point whatever the sample count
    #: (one sequence per pixel): renderers that trace a pixel in batches then continue
    #: the sequence where the last batch stopped (adaptive sampling).
    progressive: ClassVar[bool] = False
    #: Properties of the points this sampler promises (keys of
    #: :data:`mcrt.samplers.registry.CLAIMS`); ``mcrt check`` verifies them.
    claims: ClassVar[frozenset[str]] = frozenset()
    #: One line on what the sampler does (tables of samplers, ``mcrt check``).
    summary: ClassVar[str] = ""
    #: The C++ class whose base implementations ``_run_base`` calls.
    _cpp_base: ClassVar[type] = mi.Sampler

    # -- construction -------------------------------------------------------
    def __init__(self, props: mi.Properties) -> None:
        super().__init__(props)
        self._base_calls: set[str] = set()
        base_seed = props.get("seed", 0)
        if not isinstance(base_seed, int) or base_seed < 0:
            raise SamplerError(f"{self.plugin_name}: 'seed' must be a non-negative integer, "
                               f"got {base_seed!r}")
        self._base_seed = base_seed
        self._configure(props)
        self._key = mi.UInt32(0)
        self._dim = mi.UInt32(0)
        self._pass = mi.UInt32(0)
        self._pass_count: int | mi.UInt32 = 0
        self._layout: _layout.Layout | None = None
        self._lanes: tuple[mi.UInt32, mi.UInt32] | None = None
        self._lane_stride = 0
        self._lane_span = 1  # first sample indices lie below this (1: unknown)
        self._past_limit = ""  # why the current pass cannot be drawn ("" if it can)
        _layout.clear_samples_per_wavefront(self)
        self.set_sample_count(self.sample_count())

    def _configure(self, props: mi.Properties) -> None:
        """Read plugin-specific parameters (override)."""

    @staticmethod
    def example_params(spp: int) -> dict:
        """Parameters the plugin needs outside a render, for ``spp`` samples
        (override; e.g. ``zsobol``'s film width). Used by ``mcrt check`` and tests."""
        return {}

    def _parameters(self) -> dict:
        """Plugin-specific parameters, as given to ``mi.load_dict`` (override)."""
        return {}

    def _effective_count(self, spp: int) -> int:
        """The sample count actually used for a requested ``spp`` (override)."""
        return spp

    def _too_many(self, limit: int, spp: int, why: str) -> SamplerError:
        """The error for a sample count beyond the pattern's ``limit`` (``why``: what
        bounds it). The count is the whole render's: splitting it into passes does
        not help, independent renders with different seeds do."""
        return SamplerError(f"{self.plugin_name}: at most {limit} samples per pixel ({why}), "
                            f"got {spp}; for more, average renders with different seeds, "
                            f"or use sobol")

    def _sample_count_changed(self, spp: int) -> None:
        """Hook called after the sample count changed (override)."""

    # -- nanobind re-entry guard ---------------------------------------------
    def _run_base(self, name: str, *args) -> bool:
        """Run the C++ base implementation of ``name`` exactly once.

        Called from Python, an override that calls its C++ base is re-entered
        once by nanobind's trampoline; called from C++, it is not. Returns False
        in the re-entered call, which must then return at once.
        """
        base = getattr(self._cpp_base, name)
        if name in self._base_calls:
            base(self, *args)
            return False
        self._base_calls.add(name)
        try:
            base(self, *args)
        finally:
            self._base_calls.discard(name)
        return True

    # -- Mitsuba's sampler interface ---------------------------------------
    def set_sample_count(self, spp: int) -> None:
        if spp <= 0:
            raise SamplerError(f"{self.plugin_name}: sample count must be positive, got {spp}")
        count = self._effective_count(int(spp))
        if not self._run_base("set_sample_count", count):
            return
        self._sample_count_changed(count)

    def seed(self, seed: SeedValue, wavefront_size: int = _KEEP_WAVEFRONT) -> None:
        if not self._run_base("seed", seed, wavefront_size):
            return
        wavefront = self.wavefront_size()  # the C++ base applied Mitsuba's rules
        group_hint = _layout.take_samples_per_wavefront(self)
        self._layout = _layout.resolve_layout(wavefront, self.sample_count(), group_hint,
                                              _layout.probe_available())
        self._key = self._seed_key(seed)
        pixel, in_group = split_sample(dr.arange(mi.UInt32, wavefront), self._layout.group)
        self._lane_span = self._layout.group
        self._set_lanes(pixel, in_group, self._layout.group)

    def advance(self) -> None:
        """Move every lane to its next sample (next pass); dimensions restart at 0."""
        self._restart(self._pass_count + 1)

    def start_pass(self, index: int | mi.UInt32) -> None:
        """Put every lane at pass ``index`` of its sequence, dimension 0: what
        ``index`` calls of :meth:`advance` after seeding do. ``index`` may be a
        device value (the input of a replayed pass, :mod:`mcrt.core.pass_replay`)."""
        self._restart(index)

    def schedule_state(self) -> None:
        dr.schedule(self._key, self._dim, self._pass)

    def next_1d(self, active: Mask = True) -> drjit.auto.ad.Float:
        key, sample = self._next_dimension()
        # mi.Float, which Mitsuba's stub calls drjit.auto.ad.Float here (see ._types).
        return cast("drjit.auto.ad.Float", self._sample_1d(key, sample, active))

    def next_2d(self, active: Mask = True) -> mi.Point2f:
        key, sample = self._next_dimension()
        return self._sample_2d(key, sample, active)

    def fork(self) -> McrtSampler:
        """A fresh, unseeded sampler with the same parameters."""
        props = mi.Properties()
        props["sample_count"] = self.sample_count()
        props["seed"] = self._base_seed
        for name, value in self._parameters().items():
            props[name] = value
        return type(self)(props)

    def clone(self) -> McrtSampler:
        """An identical copy: it draws the same values as this sampler from now on.
        Every instance attribute is copied (shallowly), the lane state and also
        what a user set after construction (``sampler.scale = 0.5``) or a trace
        changed: renders work on a clone, so what they do to it stays there."""
        other = self.fork()
        if self._layout is not None:
            other._run_base("seed", 0, self.wavefront_size())
        for name, value in self.__dict__.items():
            if name != "_base_calls":  # (the re-entry guard of each object)
                setattr(other, name, value)
        return other

    def to_string(self) -> str:
        params = "".join(f", {k}={v}" for k, v in self._parameters().items())
        return (f"{type(self).__name__}[sample_count={self.sample_count()}, "
                f"seed={self._base_seed}{params}]")

    def __repr__(self) -> str:
        return self.to_string()

    # -- mcrt extensions -----------------------------------------------------
    def seed_lanes(self, seed: int, pixel: mi.UInt32, sample: mi.UInt32,
                   stride: int | None = None) -> None:
        """Seed with an explicit (pixel, sample index) per lane.

        Used by the analysis layer (points of chosen pixels) and by renderers that
        trace compacted wavefronts. ``advance()`` then adds ``stride`` (default:
        the sample count) to every lane's sample index.
        """
        pixel, sample = mi.UInt32(pixel), mi.UInt32(sample)
        if dr.width(pixel) != dr.width(sample):
            raise SamplerError("seed_lanes(): pixel and sample arrays differ in length")
        self._run_base("seed", seed, dr.width(pixel))
        _layout.take_samples_per_wavefront(self)
        self._layout = _layout.Layout(dr.width(pixel), 1)
        self._key = self._seed_key(seed)
        self._lane_span = 1  # the lanes' first samples are device values: checked at 0
        self._set_lanes(pixel, sample, self.sample_count() if stride is None else int(stride))

    def frozen_inputs(self) -> tuple:
        """Device arrays the sampler reads besides its lane state (a table of
        point sets, say): a replayed render (:mod:`mcrt.core.replay`) takes them
        as inputs. None by default."""
        return ()

    def set_film_width(self, width: object) -> None:
        """The width of the pixel grid about to be rendered: ignored by samplers
        whose pixels are independent (``zsobol`` orders pixels along the film)."""

    def skip_dimensions(self, count: int) -> None:
        """Advance the dimension index by ``count`` without drawing samples."""
        self._dim = self._dim + count

    @property
    def layout(self) -> _layout.Layout | None:
        """The lane layout chosen at the last ``seed()`` (None before seeding)."""
        return self._layout

    # -- internals -------------------------------------------------------------
    def _restart(self, pass_count: int | mi.UInt32) -> None:
        self._pass_count = pass_count
        self._past_limit = ""
        if isinstance(pass_count, int):
            end = pass_count * self._lane_stride + self._lane_span
            if end > SAMPLE_INDEX_LIMIT:
                self._past_limit = (
                    f"{self.plugin_name}: pass {pass_count} of {self._lane_stride} samples per "
                    f"pixel reaches sample index {end - 1}, past the 32-bit indices' last "
                    f"({SAMPLE_INDEX_LIMIT - 1}): it would repeat the pixel's first samples; "
                    f"for more samples, average renders with different seeds")
        self._pass = dr.opaque(mi.UInt32, pass_count) if isinstance(pass_count, int) else \
            mi.UInt32(pass_count)
        self._dim = dr.opaque(mi.UInt32, 0)

    def _seed_key(self, seed: SeedValue) -> mi.UInt32:
        """Opaque per-render key; never modifies the caller's ``seed`` variable."""
        if isinstance(seed, int):
            return dr.opaque(mi.UInt32, hash_keys_int(self._base_seed, seed))
        seed = mi.UInt32(seed)
        if dr.width(seed) != 1:
            raise SamplerError("seed() expects a single seed value")
        if _literal_or_evaluated(seed) and not dr.flag(dr.JitFlag.FreezingScope):
            return dr.opaque(mi.UInt32, hash_keys_int(self._base_seed, int(seed[0])))
        key = hash_keys(mi.UInt32(self._base_seed), seed)  # a new variable
        dr.make_opaque(key)
        return key

    def _set_lanes(self, pixel: mi.UInt32, first_sample: mi.UInt32, stride: int) -> None:
        """Lane state after seeding: the per-lane (seed, pixel) hash and sample
        index of pass 0; pass ``k`` uses sample ``first_sample + k * stride``.

        Both stay lazy expressions (no memory): inside Mitsuba's path loop they
        are loop-invariant, so the pixel part of every dimension's hash is
        computed once per path instead of once per dimension.
        """
        self._lanes = (hash_keys(self._key, pixel), mi.UInt32(first_sample))
        self._lane_stride = stride
        self._restart(0)

    def _next_dimension(self) -> tuple[mi.UInt32, mi.UInt32]:
        """Key of (seed, pixel, dimension) and sample index per lane; consumes
        the dimension. The key equals ``hash_keys(seed key, pixel, dimension)``."""
        pixel_key, first_sample = self._drawable_lanes()
        dim = self._dim
        self._dim = dim + 1
        return hash_extend(pixel_key, dim), first_sample + self._pass * self._lane_stride

    def _drawable_lanes(self) -> tuple[mi.UInt32, mi.UInt32]:
        """The lane state, if the lanes' sample indices of this pass exist: seeded,
        and not wrapped past 2^32 (an ``advance()`` after the last pass, as
        Mitsuba makes, is fine as long as nothing is drawn there); else raise."""
        if self._lanes is None:
            raise SamplerError(f"{self.plugin_name}: seed() must be called before sampling")
        if self._past_limit:
            raise SamplerError(self._past_limit)
        return self._lanes

    def _sample_1d(self, key: mi.UInt32, sample: mi.UInt32, active: Mask) -> mi.Float:
        raise NotImplementedError

    def _sample_2d(self, key: mi.UInt32, sample: mi.UInt32, active: Mask) -> mi.Point2f:
        raise NotImplementedError


def is_mcrt_sampler(sampler: mi.Sampler) -> TypeGuard[McrtSampler]:
    """Whether ``sampler`` is one of mcrt's (counter-based, ``seed_lanes``) samplers.

    Checked by module rather than by class: after a variant switch the plugin
    classes are re-created, and objects of either generation qualify.
    """
    return any(cls.__module__ == __name__ and cls.__name__ == "McrtSampler"
               for cls in type(sampler).__mro__)
