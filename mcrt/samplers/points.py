"""The point sets a sampler gives chosen pixels, as numpy arrays.

This is the analysis layer's window on the samplers, and it goes through the
very ``next_1d``/``next_2d`` calls Mitsuba makes during a render: for mcrt's
plugins the lanes are seeded explicitly with (pixel, sample index), so the
points of pixel ``p`` are bit-identical to those pixel ``p`` gets in
``mi.render`` with the same seed and sample count. Mitsuba's built-in samplers
are seeded with their own pixel-major layout over pixels ``0 .. max(pixels)``.
"""

from __future__ import annotations

import numbers
from collections.abc import Sequence
from typing import cast

import drjit as dr
import mitsuba as mi
import numpy as np

from ..errors import SamplerError, whole_number
from .base import is_mcrt_sampler

#: Largest pixel index accepted for Mitsuba's built-in samplers (their layout
#: needs a wavefront covering every pixel up to the largest one requested).
MAX_BUILTIN_PIXEL = 1 << 16


def point_sets(sampler: str | mi.Sampler, pixels: Sequence[int] | int, spp: int,
               dimension: int = 0, ndim: int = 2, seed: int = 0, **params) -> np.ndarray:
    """Points of dimension ``dimension`` for each pixel in ``pixels``.

    ``sampler`` is a plugin name (``params`` go to the plugin) or an instance.
    ``dimension`` counts sampler calls as Mitsuba does (0 = film position, each
    ``next_1d``/``next_2d`` call is one dimension). Returns an array of shape
    ``(len(pixels), spp, ndim)`` (``spp`` after the sampler's rounding), float32.
    A sampler that orders pixels along a film (``zsobol``) and has no ``width``
    takes the pixel indices as one row of ``max(pixels) + 1`` pixels.

    Example::

        >>> pts = point_sets("poisson_disk", pixels=range(4), spp=64)
        >>> pts.shape
        (4, 64, 2)
    """
    if ndim not in (1, 2):
        raise ValueError("ndim must be 1 or 2")
    spp = whole_number(spp, "point_sets: spp")
    if isinstance(pixels, numbers.Integral):  # a count (numpy's integers too)
        pixel_ids = np.arange(whole_number(pixels, "point_sets: pixels (a count)"))
    else:
        pixel_ids = np.asarray(list(cast(Sequence[int], pixels)), dtype=np.int64)
    if pixel_ids.size == 0 or pixel_ids.min() < 0 or pixel_ids.max() >= 2**32:
        raise SamplerError("pixels must be a non-empty list of indices in [0, 2^32)")
    instance: mi.Sampler
    if isinstance(sampler, str):
        instance = mi.load_dict({"type": sampler, "sample_count": int(spp), **params})
    else:
        instance = sampler.clone()
        instance.set_sample_count(int(spp))
    spp = instance.sample_count()

    if is_mcrt_sampler(instance):
        if getattr(instance, "width", None) == 0:  # zsobol without a film: pixels in one row
            instance.set_film_width(int(pixel_ids.max()) + 1)
        pixel = mi.UInt32(np.repeat(pixel_ids, spp).astype(np.uint32))
        sample = mi.UInt32(np.tile(np.arange(spp, dtype=np.uint32), pixel_ids.size))
        instance.seed_lanes(seed, pixel, sample)
        instance.skip_dimensions(dimension)
        rows = np.arange(pixel_ids.size)
        lanes = pixel_ids.size * spp
    else:
        count = int(pixel_ids.max()) + 1
        if count > MAX_BUILTIN_PIXEL:
            raise SamplerError(f"built-in samplers: pixel indices must be < {MAX_BUILTIN_PIXEL}")
        instance.set_samples_per_wavefront(spp)
        instance.seed(seed, count * spp)  # type: ignore[arg-type]  # stub: UInt only
        for _ in range(dimension):
            instance.next_1d()
        rows = pixel_ids
        lanes = count * spp
    values = instance.next_2d() if ndim == 2 else instance.next_1d()
    name = sampler if isinstance(sampler, str) else (getattr(instance, "plugin_name", "")
                                                     or type(instance).__name__)
    array = lane_array(values, lanes, f"{ndim}d", f"{name}: next_{ndim}d (dimension {dimension}) ")
    dr.sync_thread()
    return array.reshape(-1, spp, ndim)[rows]


def lane_array(values, lanes: int, call: str, where: str = "",
               dtype: type = np.float32) -> np.ndarray:
    """The result of a ``next_1d`` (``call`` "1d") or ``next_2d`` ("2d") call on
    ``lanes`` lanes as a ``(lanes, 1 or 2)`` array; a sampler that did not return
    one value (point) per lane is told so in one line (``where`` starts it)."""
    two = call == "2d"
    array: np.ndarray = np.array(values, dtype=dtype)
    if array.shape != ((2, lanes) if two else (lanes,)):
        what = "point" if two else "value"
        got = array.size // 2 if two else array.size
        raise SamplerError(f"{where}returned {got} {what}{'s' if got != 1 else ''} for "
                           f"{lanes} lanes: a sampler returns one {what} per lane")
    return array.T if two else array[:, None]
