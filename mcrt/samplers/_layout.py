"""Which pixel and which sample each wavefront lane belongs to.

Mitsuba renders a wavefront of ``W*H*g`` lanes, pixel-major: lane ``i`` is pixel
``i // g``, sample ``i % g`` of the current pass, where ``g`` (samples per pixel
per pass) is given to the sampler by ``set_samples_per_wavefront(g)``. Usually
``g`` equals the sample count, but Mitsuba splits a render into passes with a
smaller ``g`` when ``W*H*spp`` exceeds 2^32 or when the integrator sets the
(deprecated) ``samples_per_pass``; it then calls ``advance()`` between passes.

A Python sampler never sees that call: nanobind's trampoline does not forward
``set_samples_per_wavefront``, so Mitsuba's C++ base class stores ``g`` in a
field that has no Python accessor. Guessing ``g`` from the wavefront size is
ambiguous exactly in the split case and would silently assign strata across
pixel boundaries. We therefore read the field from the C++ object.

The field's offset is *located and verified at run time* on a probe object
(write distinctive values through the public C++ setters, find them, change
them, find them again); nothing about the layout is hard-coded. If the probe
fails (another Mitsuba build), :func:`resolve_layout` falls back to inference and
refuses the one ambiguous case (wavefronts of 2^30 lanes or more, see below)
with a clear message instead of producing wrong strata.

After ``seed()`` consumes the value we reset the field to 0, which means "not
set since the last seed": a later direct ``seed(s, w)`` call (as in Mitsuba's own
sampler tests, or ``mi.render``'s final ``seed(0, 1)``) then uses the documented
default layout instead of a stale value.
"""

from __future__ import annotations

import ctypes
from dataclasses import dataclass
from functools import cache

import mitsuba as mi

from ..errors import SamplerError

#: Mitsuba splits a render only when W*H*spp > 2^32 - 1; the split pass then has
#: at least (2^32 - 1) / 4 lanes (k = ceil(W*H*spp / L) passes of floor(spp / k)
#: samples). Smaller wavefronts are never split passes.
SPLIT_MIN_LANES = (0xFFFFFFFF + 3) // 4

_SCAN_WORDS = 40  # the fields sit well inside the first 160 bytes of the object


def _probe_instance() -> mi.Sampler:
    """A minimal Python sampler of the active variant, used only to locate fields."""

    class _ProbeSampler(mi.Sampler):
        def fork(self):  # pragma: no cover - never called
            return self

        def clone(self):  # pragma: no cover - never called
            return self

        def next_1d(self, active=True):  # pragma: no cover - never called
            return mi.Float(0.5)

        def next_2d(self, active=True):  # pragma: no cover - never called
            return mi.Point2f(0.5)

    return _ProbeSampler(mi.Properties())


def _words(obj: mi.Sampler) -> ctypes.Array:
    return (ctypes.c_uint32 * _SCAN_WORDS).from_address(obj.ptr)


@cache
def _spw_word_index(variant: str) -> int | None:
    """Index (in uint32 words) of ``m_samples_per_wavefront``, or None if not found.

    Mitsuba declares ``m_sample_count, m_samples_per_wavefront, m_wavefront_size``
    consecutively; we look for three distinctive values set through the C++
    setters and confirm with a second, different triple.
    """
    try:
        probe = _probe_instance()
        found = None
        for count, spw, wavefront in ((720720, 5040, 987_654_321), (9699690, 2310, 123_456_789)):
            mi.Sampler.set_sample_count(probe, count)
            mi.Sampler.set_samples_per_wavefront(probe, spw)
            mi.Sampler.seed(probe, 0, wavefront)  # type: ignore[arg-type]  # stub: UInt only
            words = list(_words(probe))
            hits = [i for i in range(1, _SCAN_WORDS - 1)
                    if words[i - 1] == count and words[i] == spw and words[i + 1] == wavefront]
            if len(hits) != 1 or (found is not None and hits[0] != found):
                return None
            found = hits[0]
        if found is None:  # pragma: no cover - the loop above always runs
            return None
        # Writing the field must be seen by the C++ side and vice versa.
        _words(probe)[found] = 7
        if list(_words(probe))[found] != 7 or probe.sample_count() != 9699690 \
                or probe.wavefront_size() != 123_456_789:
            return None
        return found
    except Exception:  # any surprise: fall back to inference
        return None


def take_samples_per_wavefront(sampler: mi.Sampler) -> int | None:
    """Return ``g`` set since the last call (by Mitsuba or a user), and clear it.

    Returns None when nothing was set, or when the field cannot be located.
    """
    index = _spw_word_index(mi.variant())
    if index is None:
        return None
    words = _words(sampler)
    value = int(words[index])
    words[index] = 0
    return value or None


def clear_samples_per_wavefront(sampler: mi.Sampler) -> None:
    """Mark the field as "not set" (done at construction: C++ initialises it to 1)."""
    index = _spw_word_index(mi.variant())
    if index is not None:
        _words(sampler)[index] = 0


def probe_available() -> bool:
    """Whether the C++ ``samples_per_wavefront`` field could be located."""
    return _spw_word_index(mi.variant()) is not None


@dataclass(frozen=True)
class Layout:
    """Lane-to-(pixel, sample) mapping of one seeded wavefront.

    ``group`` lanes form one pixel's samples of a pass (``g``); ``wavefront``
    is the number of lanes.
    """

    wavefront: int
    group: int

    @property
    def pixels(self) -> int:
        return self.wavefront // self.group


def resolve_layout(wavefront: int, sample_count: int, samples_per_wavefront: int | None,
                   probed: bool) -> Layout:
    """Decide the lane layout for ``seed(seed, wavefront)``.

    * ``samples_per_wavefront`` given: Mitsuba's own rule, ``g`` = that value.
    * otherwise, a wavefront that is a multiple of the sample count is pixel-major
      with ``g = sample_count`` (what ``mi.render`` does in one pass);
    * otherwise every lane is its own sequence (``g = 1``), advanced by ``advance()``.

    Without the probe, a wavefront of ``SPLIT_MIN_LANES`` or more might be one
    pass of a render Mitsuba split up, with an unknown ``g``: refuse.
    """
    if wavefront <= 0:
        raise SamplerError(f"wavefront size must be positive, got {wavefront}")
    if samples_per_wavefront:
        group = samples_per_wavefront
        if wavefront % group:
            raise SamplerError(
                f"wavefront size {wavefront} is not a multiple of samples_per_wavefront {group}")
        return Layout(wavefront, group)
    if not probed and wavefront >= SPLIT_MIN_LANES:
        raise SamplerError(
            f"a wavefront of {wavefront} lanes may be one pass of a render that Mitsuba "
            "split into passes, and this Mitsuba build does not tell a Python sampler the "
            "samples per pass; render fewer samples per call (e.g. `mcrt render`, which "
            "renders in passes) or call set_samples_per_wavefront() before seed()")
    group = sample_count if wavefront % sample_count == 0 else 1
    return Layout(wavefront, group)
