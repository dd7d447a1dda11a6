"""The pass engine: the one loop every mcrt render runs.

A render of ``spp`` samples per pixel is traced in passes of ``group`` samples
of every pixel (``group`` divides ``spp``). Each pass: run the ``on_pass`` hook
(motion blur moves geometry there), trace one pixel-major wavefront
(:func:`~mcrt.core.trace.trace`), hand the samples to an accumulator, advance
the sampler, and commit the pass with Ctrl-C held back, so an interrupt never
leaves half a pass in the sums. The passes of one render form *one* pattern per
pixel: mcrt's counter-based samplers continue their sequences exactly across
passes, Mitsuba's stratified samplers continue through ``advance()``, and its
``independent`` is seeded afresh by every pass (:func:`reseeds_each_pass`).

Accumulators (:mod:`mcrt.core.accumulators`) keep their sums on the device in
float64 and combine each pass elementwise (no atomics), so a render is
bit-identical across runs and thread counts. Their state is a dict of numpy
arrays: that is what a checkpoint stores and what resuming restores.

The pass size is a pure function of the film (size; a box filter folds
passes of up to 4 samples per pixel in as it traces them), the sample count,
the kind of sampler and the backend (:func:`pass_shape`), never of the
machine's thread count or free memory (unless that is short:
:func:`fitted_shape`), so results do not depend on where they were computed.
"""

from __future__ import annotations

import contextlib
import logging
import signal
import threading
import time
from collections.abc import Callable, Iterator
from dataclasses import dataclass
from typing import Any, Protocol

import drjit as dr
import mitsuba as mi
import numpy as np

from ..errors import McrtError
from ..samplers.base import is_mcrt_sampler
from ..samplers.kit import hash_keys, hash_keys_int, split_sample
from .memory import BYTES_PER_LANE, KERNEL_BYTES, lane_budget
from .progress import Progress
from .sampling import bind_film_width, raise_if_interrupted, sampler_name
from .trace import CameraSamples, film_grid_size, pixel_of_index, trace

log = logging.getLogger("mcrt.engine")

#: Largest wavefront (pixels x samples per pass) traced in one kernel. Passes of
#: one sample per pixel are never split further, so a film larger than this
#: still renders (one pixel per lane).
MAX_LANES_PER_PASS = 1 << 20

#: Signals handled like Ctrl-C while passes run: the finished passes are kept.
INTERRUPT_SIGNALS = (signal.SIGINT, signal.SIGTERM, signal.SIGHUP)


@dataclass(frozen=True)
class PassShape:
    """How a render of ``spp`` samples per pixel over ``pixels`` is split."""

    pixels: int
    spp: int
    group: int  # samples per pixel per pass

    @property
    def passes(self) -> int:
        return self.spp // self.group

    @property
    def lanes(self) -> int:
        return self.pixels * self.group


def pass_shape(pixels: int, spp: int, max_lanes: int | None = None,
               passes: int | None = None, fold: int = 1,
               fold_lanes: int | None = None) -> PassShape:
    """Largest ``group`` dividing ``spp`` with ``pixels * group <= max_lanes``
    (at least 1), or ``spp // passes`` when the number of passes is forced.

    ``fold`` > 1: the accumulator folds passes of up to ``fold`` samples per
    pixel (a power of two) into its sums as it traces them, storing nothing per
    lane, so such a group may take up to ``fold_lanes`` lanes (default ``fold``
    times the limit): a larger film then renders in fewer, larger passes."""
    if spp < 1:
        raise McrtError(f"a render needs at least 1 sample per pixel, got {spp}")
    if passes is not None:
        if passes <= 0 or spp % passes:
            raise McrtError(f"cannot split {spp} samples per pixel into {passes} equal passes")
        return PassShape(pixels, spp, spp // passes)
    limit = max_lanes or MAX_LANES_PER_PASS
    group = max((g for g in range(1, spp + 1) if spp % g == 0 and pixels * g <= limit),
                default=1)
    folded = fold_lanes if fold_lanes is not None else fold * limit
    while fold > group and (spp % fold or pixels * fold > folded):
        fold //= 2
    return PassShape(pixels, spp, max(group, fold))


def fitted_shape(pixels: int, spp: int, max_lanes: int | None = None,
                 passes: int | None = None, bytes_per_lane: int = BYTES_PER_LANE,
                 fixed_bytes: int = 0, fold: int = 1,
                 fold_lanes: int | None = None, available: int | None = None) -> PassShape:
    """:func:`pass_shape`, with passes made smaller only when the default ones
    would not fit the memory available (cgroup, ``ulimit -v``, the host, a Dask
    worker's limit: see :mod:`mcrt.core.memory`; ``available``: the memory where
    the passes run, when that is not this process), with a note: such a render may
    differ in the last bits from one made with the default passes. Never below one
    sample per pixel per pass."""
    shape = pass_shape(pixels, spp, max_lanes, passes, fold, fold_lanes)
    if max_lanes is not None or passes is not None:
        return shape
    budget = lane_budget(bytes_per_lane, fixed_bytes + KERNEL_BYTES, available)
    if budget is None or shape.lanes <= budget:
        return shape
    smaller = pass_shape(pixels, spp, max(pixels, budget), fold=fold, fold_lanes=budget)
    if smaller.passes != shape.passes:
        log.info("passes of %d samples per pixel (not %d) to fit the memory available%s; "
                 "the image may differ in the last bits from one made with more memory",
                 smaller.group, shape.group, "" if available is None else " on the Dask workers")
    return smaller


class PassSink(Protocol):
    """What one traced pass is fed into (see :func:`trace_pass`)."""

    def add(self, samples: CameraSamples, values: list[Any], group: int) -> None:
        """Compute (and evaluate) the sums with this pass's ``values`` added;
        keep them pending until :meth:`commit`."""

    def commit(self) -> None:
        """Make the pending sums current (called with interrupts held back)."""


class Accumulator(PassSink, Protocol):
    """A sink that accumulates a whole render and can be checkpointed."""

    def state(self) -> dict[str, np.ndarray]:
        """The sums as numpy arrays (for checkpoints and results)."""

    def restore(self, state: dict[str, np.ndarray]) -> None:
        """Continue from :meth:`state` of an earlier, identical render."""


def sampling_integrator(scene: mi.Scene) -> mi.SamplingIntegrator:
    """The scene's integrator, checked to be one the engine can drive."""
    integrator = scene.integrator()
    if not isinstance(integrator, mi.SamplingIntegrator):
        adjoint = isinstance(integrator, mi.AdjointIntegrator)
        raise McrtError(f"mcrt renders with sampling integrators (path, direct, ...); this scene "
                        f"uses {integrator.class_name()}"
                        + (" (an adjoint integrator: it traces from the lights and splats onto "
                           "the film)" if adjoint else "")
                        + "; render it with mi.render, or give it a sampling integrator")
    if integrator.class_name() == "StokesIntegrator":
        # Checked in Mitsuba 3.9.1: the binding of its sample() ends the process
        # with a segmentation fault, so it must never be called.
        raise McrtError("the stokes integrator cannot be driven one sample at a time from "
                        "Python (in Mitsuba 3.9 its sample() crashes); render it with "
                        "mi.render, or give mcrt the integrator it wraps")
    return integrator


def supported_film(film: mi.Film) -> mi.Film:
    """``film``, checked to be one mcrt develops: an ``hdrfilm`` (a ``specfilm``'s
    channels are its own spectral sensitivities, which mcrt's RGB, luminance and
    XYZ accumulation does not form)."""
    if film.class_name() != "HDRFilm":
        raise McrtError(f"mcrt renders hdrfilm films (RGB, luminance or XYZ channels); this "
                        f"scene's film is a {film.class_name()}: give it an hdrfilm, or "
                        f"render it with mi.render")
    check_rfilter(film)
    return film


def check_rfilter(film: mi.Film, where: str = "") -> None:
    """Refuse a reconstruction filter of no width (a ``gaussian`` of ``stddev`` 0
    or below, a ``tent`` of ``radius`` 0, a ``lanczos`` of 0 ``lobes``): Mitsuba
    takes it, then weighs no sample, so its image is black or NaN, and a negative
    width hangs ``mi.render``."""
    radius = float(film.rfilter().radius())
    if radius > 0 and radius < float("inf"):
        return
    described = " ".join(str(film.rfilter()).split())
    raise McrtError(f"{where}the film's reconstruction filter has radius {radius:g} "
                    f"({described}): it gives no sample a weight (mi.render makes such an "
                    f"image black or NaN, and hangs on a negative radius); give it a "
                    f"positive width (gaussian stddev, tent radius, lanczos lobes)")


def film_values(film: mi.Film, samples: CameraSamples) -> list[Any]:
    """The channels an ``ImageBlock`` of ``film`` receives for each sample:
    R, G, B, [A,] the weight 1, then the integrator's AOVs."""
    values: list[Any] = [samples.rgb.x, samples.rgb.y, samples.rgb.z]
    if mi.has_flag(film.flags(), mi.FilmFlags.Alpha):
        values.append(dr.select(samples.valid, mi.Float(1.0), mi.Float(0.0)))
    values.append(mi.Float(1.0))
    return values + list(samples.aovs)


def reseeds_each_pass(sampler: mi.Sampler) -> bool:
    """Whether each pass seeds ``sampler`` afresh with :func:`resume_seed` of its
    index instead of advancing it: Mitsuba's ``independent``, whose samples are
    independent whatever the seed, so a pass never stores its per-lane random
    state (16 bytes a lane) for the next, and a resumed or distributed pass is
    exactly the pass an uninterrupted render traces."""
    return not is_mcrt_sampler(sampler) and sampler_name(sampler) == "independent"


def keeps_lane_state(sampler: mi.Sampler) -> bool:
    """Whether ``sampler`` stores random state per lane between passes
    (Mitsuba's stratified samplers): their passes stay within
    :data:`MAX_LANES_PER_PASS` lanes even when the accumulator stores nothing."""
    return not is_mcrt_sampler(sampler) and not reseeds_each_pass(sampler)


def resume_seed(sampler: mi.Sampler, seed: Any, passes_done: Any) -> Any:
    """The seed that continues a render after ``passes_done`` passes.

    mcrt's samplers are counter-based and continue their exact sequence; the
    random state of Mitsuba's lives in C++, so they continue with a seed
    derived from ``(seed, passes done)``: resumed passes never repeat earlier ones.
    ``seed`` and ``passes_done`` may be device values (a replayed render's inputs).
    """
    if is_mcrt_sampler(sampler) or (isinstance(passes_done, int) and passes_done == 0):
        return seed
    if isinstance(seed, int) and isinstance(passes_done, int):
        return hash_keys_int(seed, passes_done, 0x2E5)
    derived = hash_keys(mi.UInt32(seed), passes_done, 0x2E5)
    return derived if isinstance(passes_done, int) else \
        dr.select(mi.UInt32(passes_done) == 0, mi.UInt32(seed), derived)


def position_sampler(sampler: mi.Sampler, seed: Any, index: Any, shape: PassShape) -> None:
    """Seed ``sampler`` for a wavefront of ``shape`` at the start of pass
    ``index`` of a render seeded with ``seed``: where :func:`run_passes` has it
    then (exactly for mcrt's samplers and ``independent``; Mitsuba's stratified
    samplers continue with :func:`resume_seed`)."""
    sampler.set_samples_per_wavefront(shape.group)  # (a hint the next seed() takes)
    sampler.seed(resume_seed(sampler, seed, index), shape.lanes)
    if is_mcrt_sampler(sampler):
        sampler.start_pass(index)  # counter-based: the exact next samples


class PassReplayer(Protocol):
    """Runs a pass without tracing it (:class:`mcrt.core.pass_replay.PassReplay`)."""

    def run(self, accumulator: Accumulator, index: int) -> bool:
        """Add pass ``index`` into ``accumulator`` (committed); False: trace it."""
        ...


@contextlib.contextmanager
def deferred_interrupts() -> Iterator[None]:
    """Hold back Ctrl-C and termination signals until the block is done, then
    raise ``KeyboardInterrupt``. A no-op outside the main thread."""
    if threading.current_thread() is not threading.main_thread():
        yield
        return
    caught: list[int] = []
    previous = {s: signal.signal(s, lambda signum, frame: caught.append(signum))
                for s in INTERRUPT_SIGNALS}
    try:
        yield
    finally:
        for s, handler in previous.items():
            signal.signal(s, handler)
    if caught:
        raise KeyboardInterrupt


@contextlib.contextmanager
def termination_as_interrupt() -> Iterator[None]:
    """Inside the block, SIGTERM and SIGHUP raise ``KeyboardInterrupt`` like
    Ctrl-C does, so a killed render keeps its finished passes; one that arrived
    while Dr.Jit traced Python code (which wraps it in a ``RuntimeError``) is
    raised as the interrupt it was (:func:`~.sampling.raise_if_interrupted`)."""
    if threading.current_thread() is not threading.main_thread():
        yield
        return

    def interrupt(signum, frame):
        raise KeyboardInterrupt

    previous = {s: signal.signal(s, interrupt) for s in (signal.SIGTERM, signal.SIGHUP)}
    try:
        yield
    except RuntimeError as error:
        raise_if_interrupted(error)
        raise
    finally:
        for s, handler in previous.items():
            signal.signal(s, handler)


@dataclass
class PassRun:
    """Where a run of passes stands: passes done and render seconds so far."""

    shape: PassShape
    done: int = 0
    seconds: float = 0.0


def run_passes(scene: mi.Scene, sampler: mi.Sampler, accumulator: Accumulator,
               run: PassRun, seed: int, sensor: int = 0,
               on_pass: Callable[[int, int], None] | None = None,
               progress: Progress | None = None,
               values: Callable[[mi.Film, CameraSamples], list[Any]] = film_values,
               stop: int | None = None, replayer: PassReplayer | None = None) -> None:
    """Trace passes ``run.done .. run.shape.passes - 1`` (or ``stop - 1``) of
    ``scene`` into ``accumulator``; ``run`` is updated after every committed pass.

    ``sampler`` must have the sample count ``run.shape.spp``. Ctrl-C (and
    SIGTERM/SIGHUP) raise ``KeyboardInterrupt`` between passes, with ``run``
    and the accumulator holding every finished pass. ``replayer`` runs the
    passes it can without tracing them (the same bits).
    """
    shape = run.shape
    sensor_obj = scene.sensors()[sensor]
    integrator = sampling_integrator(scene)
    film = sensor_obj.film()
    bind_film_width(sampler, grid_pixels(film)[0])  # zsobol orders pixels along the film
    position_sampler(sampler, seed, run.done, shape)
    reseed = reseeds_each_pass(sampler)
    pixel_index, _ = split_sample(dr.arange(mi.UInt32, shape.lanes), shape.group)
    pixel = pixel_of_index(film, pixel_index)
    first, end = run.done, shape.passes if stop is None else stop
    dr.sync_thread()
    with termination_as_interrupt():
        for index in range(first, end):
            start = time.perf_counter()
            if on_pass is not None:
                on_pass(index, shape.passes)

            def committed(index: int = index, start: float = start) -> None:
                run.done = index + 1
                run.seconds += time.perf_counter() - start

            if replayer is not None:
                with deferred_interrupts():  # the sums and the passes done change together
                    replayed = replayer.run(accumulator, index)
                    if replayed:
                        committed()
                if replayed:
                    if progress is not None:
                        progress.update(1)
                    continue
                replayer = None  # traced from here: the sampler as the loop has it
                position_sampler(sampler, seed, index, shape)
            elif reseed and index > first:
                pass_seed: Any = resume_seed(sampler, seed, index)  # the stub wants a UInt
                sampler.seed(pass_seed, shape.lanes)

            trace_pass(scene, sensor_obj, integrator, sampler, pixel, shape.spp, accumulator,
                       shape.group, values, committed,
                       advance=not reseed and index + 1 < end)
            if progress is not None:
                progress.update(1)


def trace_pass(scene: mi.Scene, sensor: mi.Sensor, integrator: mi.SamplingIntegrator,
               sampler: mi.Sampler, pixel: mi.Vector2i, spp: int, accumulator: PassSink,
               group: int,
               values: Callable[[mi.Film, CameraSamples], list[Any]] = film_values,
               committed: Callable[[], None] | None = None, advance: bool = True) -> None:
    """The step every render repeats: trace one wavefront (``sampler`` seeded for
    it, ``group`` consecutive lanes per pixel), advance the sampler, let the
    accumulator fold the samples in (one kernel with the sampler's next state),
    and commit with interrupts held back (``committed`` runs in that block).

    ``advance=False`` (a render's last pass) leaves the sampler where it is, so
    its next state is never computed nor stored (Mitsuba's samplers keep 16
    bytes of random state per lane)."""
    samples = trace(scene, sensor, sampler, integrator, pixel, spp)
    if advance:
        sampler.advance()
        sampler.schedule_state()
    accumulator.add(samples, values(sensor.film(), samples), group)
    with deferred_interrupts():  # an accumulator may update its sums in place here
        accumulator.commit()
        dr.sync_thread()
        if committed is not None:
            committed()


def grid_pixels(film: mi.Film) -> tuple[int, int]:
    """``(width, height)`` of the pixel grid a render samples."""
    grid = film_grid_size(film)
    return int(grid[0]), int(grid[1])
