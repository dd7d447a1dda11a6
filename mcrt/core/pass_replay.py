"""Film passes replayed one at a time (Dr.Jit's frozen functions).

:mod:`mcrt.core.replay` records a *whole* render and replays it with a new
seed, for renders that nothing watches or changes between passes. Many renders
are not like that: ``mcrt render`` shows a progress bar and saves checkpoints,
a resumed render starts in the middle, motion blur moves the scene before each
sub-frame, a render of many passes is too long to record whole, and a cluster
task renders one pass of a render. Most of their passes differ only in device
values (the pass index, the seed, the sums so far), so
:class:`PassReplay` records *one pass* with :func:`drjit.freeze` (the sampler
positioned at pass ``index``, the trace, the film's fold into a copy of the
sums) and replays it for every later pass of this render and of later renders
with the same (scene, sampler, pass shape), with the same bits as tracing
(tests/core/test_pass_replay.py). Between passes the caller runs its hooks as
before: a checkpoint, a progress note.

Traced instead (the reason said once at debug level on ``mcrt.render``):

* ``MCRT_REPLAY=0``;
* films of more than :data:`MAX_SUMS` sums (the copy costs more than tracing);
* a sub-frame hook (``on_pass``) that does not say ``replayable = True``: a
  replayed kernel reads the arrays that shapes' methods use (through Dr.Jit's
  virtual calls) at the addresses they had when it was recorded, so a scene
  update between passes must leave them where they are. Motion blur's
  :class:`~mcrt.render.motion.SubframeHook` writes moving meshes in place and
  says why not where it cannot (an emitting mesh, a GPU); when it replaced the
  vertex arrays instead, replays of scenes/effects/motion.xml read the
  recording's address, right only in the sub-frames whose new array happened
  to land there (every third);
* Mitsuba's samplers that keep random state per lane between passes
  (``stratified``, ``multijitter``, ...: only ``independent`` is seeded afresh
  by each pass);
* a user's sampler holding numpy arrays and no ``frozen_inputs()``
  (:func:`mcrt.core.traced_state.why_not`), or one whose Python state a trace
  changes (a call counter: seeding does not set it back), seen as it records;
* integrators that work on the host; other accumulators than the film's
  (statistics renders, references); and whatever fails to record (remembered
  for the process).
"""

from __future__ import annotations

from typing import Any

import drjit as dr
import mitsuba as mi

from .._gc import collection_held_back
from ..samplers.base import is_mcrt_sampler
from ..samplers.kit import split_sample
from . import replay
from .accumulators import FilmAccumulator
from .engine import (
    Accumulator,
    PassShape,
    film_values,
    grid_pixels,
    position_sampler,
    reseeds_each_pass,
    sampling_integrator,
)
from .sampling import bind_film_width, sampler_name
from .trace import pixel_of_index, trace
from .traced_state import sampler_key
from .traced_state import why_not as sampler_why_not

#: Most float64 sums a film may have for its passes to be replayed: a replayed
#: pass adds into a copy of them, which at 512x512 RGBA (2^20 values, 16 passes
#: of 2^20 lanes) cost more than tracing saved (a render 0.9% slower; 64x64:
#: 0.4 ms per pass replayed against 1.9-2.2 ms traced, benchmarks/film_pass_cost.py).
MAX_SUMS = 1 << 19

#: Recordings kept per process (least recently used dropped first): one per
#: (scene, sampler, pass shape, ...); each keeps its scene alive.
LIMIT = 16


class _Now:
    """What the recorded call reads besides its inputs: a plain object, so that
    :func:`drjit.freeze` never traverses the sampler (reseeded by every pass)."""

    sampler: Any = None
    shape: PassShape | None = None
    sensor = 0
    channels = 0


_NOW = _Now()
#: This process's recorded passes (:func:`mcrt.core.replay.clear` clears them).
RECORDINGS = replay.Recordings(LIMIT)


def _body(scene: mi.Scene, seed: Any, index: Any, sums: list[Any], nonfinite: Any,
          tables: tuple) -> tuple[list[Any], Any, list[Any]]:
    """Pass ``index`` of a render seeded with ``seed``, folded into copies of
    ``sums`` and ``nonfinite``: what :func:`~mcrt.core.engine.run_passes` traces."""
    now = _NOW
    shape = now.shape
    assert shape is not None
    sensor = scene.sensors()[now.sensor]
    film = sensor.film()
    integrator = sampling_integrator(scene)
    sampler = now.sampler
    bind_film_width(sampler, grid_pixels(film)[0])  # zsobol orders pixels along the film
    position_sampler(sampler, seed, index, shape)
    pixel_index, _ = split_sample(dr.arange(mi.UInt32, shape.lanes), shape.group)
    samples = trace(scene, sensor, sampler, integrator, pixel_of_index(film, pixel_index),
                    shape.spp)
    accumulator = FilmAccumulator(film, now.channels)
    # Copies, not the inputs in place: a recording that fails after the pass was
    # added must leave the sums as they were (the pass is then traced).
    accumulator.sums, accumulator.nonfinite = [dr.copy(s) for s in sums], dr.copy(nonfinite)
    accumulator.add(samples, film_values(film, samples), shape.group)
    accumulator.commit()
    return accumulator.sums, accumulator.nonfinite, replay.take_outputs(integrator)


def why_not(scene: mi.Scene, sampler: mi.Sampler, subframes: object = None,
            sums: int = 0) -> str | None:
    """Why the passes of a film render of ``scene`` with ``sampler`` cannot be
    replayed one at a time (None: they can); ``subframes``: the render's
    sub-frame hook, if any; ``sums``: float64 values in the film's sums."""
    if replay.switched_off():
        return f"{replay.ENV}=0"
    if sums > MAX_SUMS:
        return f"a film of more than {MAX_SUMS} sums (copying them costs more than tracing)"
    if subframes is not None:
        replayable = getattr(subframes, "replayable", False)
        if replayable is not True:
            why = replayable if isinstance(replayable, str) else "a sub-frame hook"
            return f"the scene moves between passes ({why})"
    if not (is_mcrt_sampler(sampler) or reseeds_each_pass(sampler)):
        return f"Mitsuba's {sampler_name(sampler)} keeps random state per lane"
    holds = sampler_why_not(sampler)
    if holds is not None:
        return holds
    integrator = sampling_integrator(scene)
    if not replay.replayable(integrator):
        return f"mcrt's {type(integrator).__name__} works on the host"
    return None


class PassReplay:
    """The passes of one film render, replayed (:class:`~mcrt.core.engine.PassReplayer`).

    ``eager``: record at the first pass (worth it when several passes follow);
    otherwise the first render of a kind traces, as :class:`~mcrt.core.replay.Recordings`
    does, and the next one records."""

    def __init__(self, scene: mi.Scene, sampler: mi.Sampler, shape: PassShape, seed: int,
                 sensor: int, channels: int, eager: bool) -> None:
        self.scene, self.sampler, self.shape, self.seed = scene, sampler, shape, seed
        self.sensor, self.channels, self.eager = sensor, channels, eager
        self.kind = replay.render_key(scene, sampler, (shape.lanes, shape.group, shape.spp),
                                      sensor, channels)

    def run(self, accumulator: Accumulator, index: int) -> bool:
        """Add pass ``index`` into ``accumulator`` (a film's); False: trace it."""
        if not isinstance(accumulator, FilmAccumulator) or self.kind in RECORDINGS.failed:
            return False
        entry = RECORDINGS.get(self.kind, lambda: (self.scene, dr.freeze(_body, warn_after=8)),
                                self.scene, eager=self.eager)
        if entry is None:
            return False
        now = _NOW
        now.sampler, now.shape, now.sensor, now.channels = (self.sampler, self.shape,
                                                            self.sensor, self.channels)
        # Drop the sampler's lane state out here: freed inside the recording, memory
        # that numpy arrays map would be released by a host callback, which Dr.Jit
        # cannot record (it aborts the process).
        self.sampler.seed(0, 1)  # type: ignore[arg-type]  # the stub wants a UInt array
        before = sampler_key(self.sampler)
        try:
            tables: tuple = getattr(self.sampler, "frozen_inputs", tuple)()
            # No cyclic collection while Dr.Jit records or replays (mcrt.core.replay).
            with collection_held_back():
                sums, nonfinite, outputs = entry[1](
                    self.scene, dr.opaque(mi.UInt32, self.seed), dr.opaque(mi.UInt32, index),
                    accumulator.sums, accumulator.nonfinite, tables)
                dr.eval(sums, nonfinite, outputs)
            dr.sync_thread()
        except RuntimeError as error:  # what cannot be recorded is traced, from now on
            RECORDINGS.fail(self.kind, self.kind, error, f"passes of {sampler_name(self.sampler)}")
            return False
        finally:
            now.sampler = None
        accumulator.sums, accumulator.nonfinite = list(sums), nonfinite
        replay.put_outputs(sampling_integrator(self.scene), outputs)
        self.sampler.seed(0, 1)  # type: ignore[arg-type]
        if sampler_key(self.sampler) != before:  # this pass was traced (recorded) and is
            # right; a replay of it would repeat the values it read, where a trace moves on
            RECORDINGS.fail(self.kind, self.kind, RuntimeError(
                "it changes its Python attributes while traced (a counter?), which a replay "
                "would not"), f"passes of {sampler_name(self.sampler)}")
        return True


__all__ = ["LIMIT", "MAX_SUMS", "RECORDINGS", "PassReplay", "why_not"]
