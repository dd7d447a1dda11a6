"""One adaptive wavefront: ``m`` new samples of each of a pass's active pixels,
traced as one compacted wavefront and reduced into pending sums (:mod:`.sums`).

:func:`trace_wavefront` traces it with the engine's pass step (every sampler,
every callback); :mod:`.frozen` replays the same kernels for mcrt's samplers
without tracing, from the helpers here, so both give the same bits.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import drjit as dr
import mitsuba as mi
import numpy as np

from ...core.engine import trace_pass
from ...core.trace import CameraSamples, pixel_of_index
from ...core.upload import to_device
from ...errors import McrtError
from ...samplers.base import is_mcrt_sampler
from .sums import Pending, PixelSums

#: Sensors that keep a variable of their last ``sample_ray_differential`` call
#: (Mitsuba 3.9's ``batch``: its sub-sensor indices, an expression of the
#: positions, so of a wavefront's pixel ids, device memory). Released inside a
#: later recording of a frozen function (the next call of the sensor there), that
#: memory is freed through a host callback, which Dr.Jit cannot record: it
#: aborted the process (``terminate called ... RecordThreadState::enqueue_host_func():
#: this function cannot be recorded!``), uncatchable, in the adaptive render's
#: own replay (:mod:`.frozen` traces their wavefronts) and in a film render's
#: recorded passes after it. :func:`trace_wavefront` therefore calls such a sensor
#: once more on constants, which releases it outside any recording.
STATEFUL_SENSORS = ("BatchSensor",)


@dataclass(frozen=True)
class Target:
    """What every wavefront of one adaptive render traces with and into: the
    scene, its sensor (and film), the sampling integrator, the sampler (cloned
    for the render), the first pass's sample count (ray differentials are scaled
    for it in every pass: one kernel for all passes), the render's sums and the
    optional ``on_samples`` hook."""

    scene: mi.Scene
    sensor: mi.Sensor
    integrator: Any
    sampler: mi.Sampler
    first: int
    acc: PixelSums
    on_samples: Any = None

    @property
    def film(self) -> mi.Film:
        return self.sensor.film()

    @property
    def ours(self) -> bool:
        """mcrt's samplers are seeded per lane from device arrays; Mitsuba's per wavefront."""
        return is_mcrt_sampler(self.sampler)


def rgb_alpha(film: mi.Film, samples: CameraSamples) -> list[Any]:
    """A sample's values as the sums take them: R, G, B [, alpha]."""
    values: list[Any] = [samples.rgb.x, samples.rgb.y, samples.rgb.z]
    if mi.has_flag(film.flags(), mi.FilmFlags.Alpha):
        values.append(dr.select(samples.valid, mi.Float(1.0), mi.Float(0.0)))
    return values


def sample_cells(samples: CameraSamples, values: list[Any], s: int) -> tuple[Any, Any, Any]:
    """``(finite, cell, inside)`` per lane: whether R, G and B are finite, the
    sample's sub-pixel (of ``s x s``) and its position inside the pixel."""
    inside = samples.position - mi.Vector2f(samples.pixel)
    sub = mi.Vector2u(dr.clip(dr.floor(inside * s), 0, s - 1))
    finite = dr.isfinite(values[0]) & dr.isfinite(values[1]) & dr.isfinite(values[2])
    return finite, sub.y * s + sub.x, inside


def check_passes(k: int, m: int, traced: np.ndarray | None = None) -> None:
    """Sample indices are 32-bit: pass ``k`` of batch ``m`` must fit; a progressive
    sampler's batch continues each pixel after its ``traced`` samples, which
    must fit too (an index past 2^32 - 1 would wrap and repeat the first samples)."""
    if (k + 1) * m >= 1 << 32:
        raise McrtError("adaptive: too many passes for 32-bit sample indices; raise growth")
    if traced is not None and traced.size and int(traced.max()) + m >= 1 << 32:
        raise McrtError(f"adaptive: a pixel's {int(traced.max()) + m} samples exceed the "
                        f"32-bit sample indices of a progressive sampler; lower max_spp")


class _Wavefront:
    """The sink of one compacted wavefront (``m`` lanes per pixel of ``ids``):
    its sums are reduced by ``acc`` and staged, merged into ``acc`` by the
    engine at the end of the pass."""

    def __init__(self, acc: PixelSums, staged: list[Pending], ids: np.ndarray,
                 on_samples: Any, k: int) -> None:
        self.acc, self.staged, self.ids, self.on_samples, self.k = acc, staged, ids, on_samples, k
        self.pending: Pending | None = None
        self.bad = 0

    def add(self, samples: CameraSamples, values: list[mi.Float], group: int) -> None:
        finite, cell, inside = sample_cells(samples, values, self.acc.s)
        dr.eval(values, finite, cell, inside if self.on_samples is not None else None)
        self.pending = self.acc.reduce(self.ids, group, values, finite, cell)
        self.bad = self.pending.nonfinite
        if self.on_samples is not None:
            self.on_samples(self.k, np.repeat(self.ids, group),
                            np.array(inside, dtype=np.float64).T,
                            np.array(mi.Color3f(*values[:3]), dtype=np.float64).T)

    def commit(self) -> None:
        if self.pending is not None:
            self.staged.append(self.pending)
            self.pending = None


def trace_wavefront(target: Target, ids: np.ndarray, m: int, k: int, wave_seed: int,
                    staged: list[Pending]) -> int:
    """Trace pass ``k``'s ``m`` new samples of each pixel in ``ids`` (one compacted
    wavefront) with the engine's pass step, its sums appended to ``staged`` (merged
    into ``target.acc`` by the caller at the end of the pass: a pixel is in one
    wavefront per pass, so the sums already hold its earlier passes); returns the
    non-finite samples found."""
    sampler: Any = target.sampler  # mcrt's have seed_lanes; Mitsuba's take a lane count
    acc = target.acc
    lanes = ids.size * m
    progressive = target.ours and getattr(sampler, "progressive", False)
    check_passes(k, m, acc.traced[ids] if progressive else None)
    # Lanes: m consecutive lanes per active pixel, built in the kernel from the ids.
    lane = dr.arange(mi.UInt32, lanes)
    pixel_index = dr.gather(mi.UInt32, to_device(mi.UInt32, ids), lane // m)
    sampler.set_sample_count(m)
    if progressive:
        # One sequence per pixel (sobol): this batch continues it where the pixel's
        # previous batches stopped, so its samples so far are always a prefix.
        start = dr.gather(mi.UInt32, to_device(mi.UInt32, acc.traced[ids]), lane // m)
        sampler.seed_lanes(wave_seed, pixel_index, lane % m + start)
    elif target.ours:
        # Epoch k of the pixel's sequence at sample count m: a fresh pattern.
        sampler.seed_lanes(wave_seed, pixel_index, lane % m + dr.opaque(mi.UInt32, k * m))
    else:
        sampler.set_samples_per_wavefront(m)
        sampler.seed(wave_seed, lanes)
    wavefront = _Wavefront(acc, staged, ids, target.on_samples, k)
    trace_pass(target.scene, target.sensor, target.integrator, sampler,
               pixel_of_index(target.film, pixel_index), target.first, wavefront, m, rgb_alpha)
    release_sensor_state(target.sensor)
    return wavefront.bad


def release_sensor_state(sensor: mi.Sensor) -> None:
    """Let a sensor of :data:`STATEFUL_SENSORS` drop the variables of its last
    call: one call on constants (no device memory) replaces them."""
    if sensor.class_name() in STATEFUL_SENSORS:
        zero: Any = mi.Float(0.0)  # (Mitsuba's stubs type it as Dr.Jit's Float)
        sensor.sample_ray_differential(zero, zero, mi.Point2f(0.5), mi.Point2f(0.5))


__all__ = ["STATEFUL_SENSORS", "Target", "check_passes", "release_sensor_state", "rgb_alpha",
           "sample_cells", "trace_wavefront"]
