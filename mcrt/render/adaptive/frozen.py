"""Adaptive wavefronts replayed without tracing (Dr.Jit's frozen functions).

Every pass of an adaptive render traces its wavefront anew: the integrator's
Python and C++ code builds the Dr.Jit expressions, Dr.Jit generates the
kernels' code and finds them in its kernel cache, a few milliseconds whatever
the wavefront's size. With mcrt's samplers a wavefront is a function of device
arrays only: the active pixels' ids, its lanes, the seed, the epoch (or, for
``sobol``, each pixel's samples so far) and the pixels' moments so far. So
:func:`wavefront` records its kernels (the trace and the reduction,
:func:`~.sums.reduce_wavefront`) with :func:`drjit.freeze` the second time a
(scene, integrator, sampler, batch size, ...) is traced, and replays them after,
for any number of active pixels, in later passes and later renders of the
process: the same kernels on the same inputs, the same bits as tracing
(tests/render/test_adaptive_replay.py).

Traced as before (:func:`.wavefront.trace_wavefront`), the reason said once at
debug level on ``mcrt.render`` (:func:`mcrt.core.replay.note`): ``MCRT_REPLAY=0``,
Mitsuba's samplers (seeded per wavefront with sizes known on the host), an
``on_samples`` callback, mcrt's Python integrators, a sensor that is not one of
the scene's, Mitsuba's ``batch`` sensor (:data:`.wavefront.STATEFUL_SENSORS`: a
recording aborted the process), a user's sampler holding numpy arrays and no
``frozen_inputs()`` (:mod:`mcrt.core.traced_state`), and whatever fails to record
(remembered for the process). The key holds the user's sampler's host values as the film's does.
"""

from __future__ import annotations

from typing import Any

import drjit as dr
import mitsuba as mi
import numpy as np

from ..._gc import collection_held_back
from ...core import replay
from ...core.replay import replayable
from ...core.sampling import sampler_fingerprint, sampler_name, sampler_params
from ...core.trace import film_grid_size, pixel_of_index, trace
from ...core.traced_state import sampler_key
from ...core.traced_state import why_not as sampler_why_not
from ...core.upload import to_device
from .sums import Pending, PixelSums, reduce_wavefront
from .wavefront import STATEFUL_SENSORS, Target, check_passes, rgb_alpha, sample_cells

#: Recordings kept per process (least recently used dropped first): one per
#: (scene, sampler, batch size, ...); each keeps its scene and integrator alive.
LIMIT = 32


class _Now:
    """What the recorded call reads besides its inputs: a plain object, so that
    :func:`drjit.freeze` never traverses the sampler (reseeded by every wavefront)."""

    sampler: Any = None
    sensor = 0
    m = 0
    spp = 0
    s = 0
    progressive = False


_NOW = _Now()
#: Entries: (scene and integrator kept alive, frozen wavefront).
_RECORDINGS = replay.Recordings(LIMIT)  # (failures per kind: for every batch size)


def _body(scene: mi.Scene, integrator: Any, ids: Any, lane: Any, offset: Any, seed: Any,
          moments: list[Any], grid: Any, tables: tuple) -> tuple[list[list[Any]], list[Any]]:
    """One wavefront, as :func:`.wavefront.trace_wavefront` traces it, from
    device arrays only (every width from an input's: replayed for any count of
    active pixels)."""
    now = _NOW
    sensor = scene.sensors()[now.sensor]
    film = sensor.film()
    m = now.m
    pixel_index = dr.gather(mi.UInt32, ids, lane // m)
    if now.progressive:
        offset = dr.gather(mi.UInt32, offset, lane // m)
    now.sampler.seed_lanes(seed, pixel_index, lane % m + offset)
    samples = trace(scene, sensor, now.sampler, integrator, pixel_of_index(film, pixel_index),
                    now.spp)
    values = rgb_alpha(film, samples)
    finite, cell, _ = sample_cells(samples, values, now.s)
    dr.eval(values, finite, cell)
    return reduce_wavefront(moments, grid, ids, m, values, finite, cell, now.s)


def why_not(target: Target) -> str | None:
    """Why the wavefronts of a render cannot be replayed (None: they can)."""
    if replay.switched_off():
        return f"{replay.ENV}=0"
    if not target.ours:
        return f"Mitsuba's {sampler_name(target.sampler)} is seeded per wavefront on the host"
    if target.on_samples is not None:
        return "on_samples receives the samples"
    why = sampler_why_not(target.sampler)
    if why is not None:
        return why
    if not replayable(target.integrator):
        return f"mcrt's {type(target.integrator).__name__} works on the host"
    if not any(x is target.sensor for x in target.scene.sensors()):
        return "the sensor is not one of the scene's"
    if target.sensor.class_name() in STATEFUL_SENSORS:
        # (a recording would release the last wavefront's ids, see STATEFUL_SENSORS)
        return f"Mitsuba's {target.sensor.class_name()} keeps its last call's positions"
    return None


def wavefront(target: Target, ids: np.ndarray, m: int, k: int, seed: int) -> Pending | None:
    """Pass ``k``'s wavefront of ``m`` new samples of each pixel in ``ids``,
    reduced (not committed) as :func:`.wavefront.trace_wavefront` reduces it,
    recorded or replayed; None if it was not (then trace it)."""
    why = why_not(target)
    if why is not None:
        replay.note(f"adaptive wavefronts: {why}")
        return None
    scene, sampler, integrator, acc, spp = (target.scene, target.sampler, target.integrator,
                                            target.acc, target.first)
    index = next(i for i, x in enumerate(scene.sensors()) if x is target.sensor)
    progressive = bool(getattr(sampler, "progressive", False))
    kind = _kind(scene, index, sampler, integrator, spp, acc, progressive)
    if kind in _RECORDINGS.failed:  # one failed recording per process, for every batch size
        return None
    key = (*kind, m)
    entry = _RECORDINGS.get(key, lambda: (scene, integrator, dr.freeze(_body, warn_after=4)),
                            scene=scene)
    if entry is None:  # traced the first time
        return None
    check_passes(k, m, acc.traced[ids] if progressive else None)
    sampler.set_sample_count(m)
    now = _NOW
    now.sampler, now.sensor, now.m, now.spp, now.s = sampler, index, m, spp, acc.s
    now.progressive = progressive
    # Drop the sampler's lane state here: freed inside the recording, the numpy
    # memory an earlier (traced) wavefront's state maps would be released by a
    # host callback, which Dr.Jit cannot record (it aborts the process).
    sampler.seed(0, 1)  # type: ignore[arg-type]  # the stub wants a UInt array
    slots = to_device(mi.UInt32, ids)
    # sobol continues each pixel's sequence; the others draw epoch k at count m.
    offset = (to_device(mi.UInt32, acc.traced[ids]) if progressive
              else dr.opaque(mi.UInt32, k * m))
    try:
        tables: tuple = getattr(sampler, "frozen_inputs", tuple)()
        # No cyclic collection while Dr.Jit records or replays (mcrt.core.replay).
        with collection_held_back():
            sums, out = entry[2](scene, integrator, slots, dr.arange(mi.UInt32, ids.size * m),
                                 offset, dr.opaque(mi.UInt32, seed), acc.moments, acc.prior(),
                                 tables)
            pending = acc.pending(ids, slots, m, sums, out)
    except RuntimeError as error:  # what cannot be recorded is traced, from now on
        _RECORDINGS.fail(key, kind, error, f"adaptive wavefronts of {sampler_name(sampler)}")
        return None
    finally:
        now.sampler = None
    return pending


def clear() -> None:
    """Drop every recording (and the scenes they keep alive) and the failures."""
    _RECORDINGS.clear()


def recordings() -> int:
    """How many times this process's adaptive wavefronts were recorded (traced)."""
    return _RECORDINGS.count()


def _kind(scene: mi.Scene, sensor: int, sampler: mi.Sampler, integrator: Any, spp: int,
          acc: PixelSums, progressive: bool) -> tuple:
    """Everything the traced code decides on the host, but the batch size."""
    name, params = sampler_name(sampler), sampler_params(sampler)
    film = scene.sensors()[sensor].film()
    return (mi.variant(), id(scene), sensor, id(integrator), name,
            tuple(sorted((k, repr(v)) for k, v in params.items())),
            getattr(sampler, "_base_seed", None), sampler_fingerprint(name, params),
            tuple(film_grid_size(film)), tuple(film.crop_offset()), spp, acc.s,
            acc.channels, progressive, *sampler_key(sampler))


__all__ = ["LIMIT", "clear", "recordings", "why_not", "wavefront"]
