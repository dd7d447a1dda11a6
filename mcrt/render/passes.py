"""Render a scene in passes, with progress, into the scene's film.

Each pass traces ``g`` samples of every pixel (``g`` divides the sample count),
and the sampler is ``advance()``-d between passes, so the passes of one render
together form *one* stratified pattern per pixel (``jittered`` at 1024 spp in
four passes of 256 fills all 1024 strata), exactly as Mitsuba's own multi-pass
renders do. The image is developed by the film (reconstruction filter and all),
so a one-pass render equals ``mi.render`` with the same sampler and seed.
"""

from __future__ import annotations

import time
from dataclasses import dataclass, field

import drjit as dr
import mitsuba as mi
import numpy as np

from ..errors import McrtError
from ..samplers._stratified import split_sample
from .trace import film_grid_size, pixel_of_index, trace

#: Default cap on lanes per pass: big enough that typical renders run in one
#: kernel, small enough to bound memory and give a progress bar granularity.
MAX_LANES_PER_PASS = 1 << 24


def samples_per_pass(pixels: int, spp: int, max_lanes: int = MAX_LANES_PER_PASS) -> int:
    """Largest divisor ``g`` of ``spp`` with ``pixels * g <= max_lanes`` (at least 1)."""
    best = 1
    for g in range(1, spp + 1):
        if spp % g == 0 and pixels * g <= max_lanes:
            best = g
    return best


@dataclass
class FilmRender:
    """A developed image and how it was made."""

    image: np.ndarray  # (height, width, channels), float32
    channels: list[str]
    spp: int
    passes: int
    seconds: float  # wall time of the passes, synchronised (kernel compilation included)
    pixels: int
    extra: dict = field(default_factory=dict)

    @property
    def samples(self) -> int:
        return self.pixels * self.spp

    @property
    def samples_per_second(self) -> float:
        return self.samples / self.seconds if self.seconds > 0 else float("inf")

    @property
    def rgb(self) -> np.ndarray:
        return self.image[..., :3]


def sampling_integrator(scene: mi.Scene) -> mi.SamplingIntegrator:
    """The scene's integrator, checked to be one mcrt can drive."""
    integrator = scene.integrator()
    if not isinstance(integrator, mi.SamplingIntegrator):
        raise McrtError(f"mcrt renders with sampling integrators (path, direct, ...); this scene "
                        f"uses {type(integrator).__name__}")
    return integrator


def channel_names(film: mi.Film, count: int) -> list[str]:
    """Names of the developed film's channels (R, G, B[, A], then AOVs)."""
    try:
        names = [f.name for f in film.bitmap().struct_()]
    except Exception:  # films without a bitmap view: generic names
        names = []
    if len(names) != count:
        names = (["R", "G", "B", "A"] + [f"C{i}" for i in range(4, count)])[:count]
    return names


def render_film(scene: mi.Scene, sampler: mi.Sampler | None = None, spp: int | None = None,
                seed: int = 0, sensor: int = 0, progress: bool = False,
                max_lanes: int = MAX_LANES_PER_PASS) -> FilmRender:
    """Render ``scene`` with ``sampler`` (default: the sensor's) at ``spp``.

    Returns the developed film as a numpy array together with the effective
    sample count (samplers may round it), number of passes and wall time.
    """
    sensor_obj = scene.sensors()[sensor]
    integrator = sampling_integrator(scene)
    film = sensor_obj.film()
    sampler = sampler if sampler is not None else sensor_obj.sampler()
    if spp is not None:
        sampler.set_sample_count(spp)
    spp = sampler.sample_count()

    grid = film_grid_size(film)
    pixels = int(grid[0]) * int(grid[1])
    group = samples_per_pass(pixels, spp, max_lanes)
    n_passes = spp // group
    lanes = pixels * group

    film.prepare(integrator.aov_names())
    block = film.create_block()
    block.set_offset(film.crop_offset())
    block.set_coalesce(block.coalesce() and group >= 4)
    has_alpha = mi.has_flag(film.flags(), mi.FilmFlags.Alpha)
    box_filter = film.rfilter().is_box_filter()

    sampler.set_samples_per_wavefront(group)
    sampler.seed(seed, lanes)
    pixel_index, _ = split_sample(dr.arange(mi.UInt32, lanes), group)
    pixel = pixel_of_index(film, pixel_index)

    bar = _progress_bar(n_passes, lanes, enabled=progress and n_passes > 1)
    dr.sync_thread()
    start = time.perf_counter()
    for _ in range(n_passes):
        s = trace(scene, sensor_obj, sampler, integrator, pixel, spp)
        values = [s.rgb.x, s.rgb.y, s.rgb.z]
        values += [dr.select(s.valid, 1.0, 0.0), mi.Float(1.0)] if has_alpha else [mi.Float(1.0)]
        values += s.aovs
        block.put(mi.Vector2f(pixel) if box_filter else s.position, values)
        sampler.advance()
        sampler.schedule_state()
        dr.eval(block.tensor())
        bar.update(1)
    film.put_block(block)
    image = film.develop()
    dr.sync_thread()
    seconds = time.perf_counter() - start
    bar.close()

    array = np.array(image, dtype=np.float32)
    return FilmRender(image=array, channels=channel_names(film, array.shape[-1]), spp=spp,
                      passes=n_passes, seconds=seconds, pixels=pixels)


class _NoBar:
    def update(self, n: int) -> None:
        pass

    def close(self) -> None:
        pass


def _progress_bar(passes: int, lanes: int, enabled: bool):
    if not enabled:
        return _NoBar()
    from tqdm import tqdm

    return tqdm(total=passes, unit="pass", desc="render", leave=False, dynamic_ncols=True,
                postfix={"samples/pass": lanes})
