"""Replayed film renders: traced once, then replayed with a new seed (Dr.Jit's frozen functions).

A film render of a scene traces the integrator (Python and C++ building Dr.Jit
expressions), looks its kernels up in the kernel cache and launches them. For the
small images of a study, tracing is most of the time. :func:`render` records a
whole render (every pass, the film's development) with :func:`drjit.freeze` the
second time a (scene, sampler, pass shape) is rendered (a render made once is
traced as usual: recording it would cost a little and gain nothing), and later
renders of it with another seed replay the recorded kernels without tracing: the
same kernels on the same inputs, so the same bits as rendering unfrozen (tested
for every sampler, filters, AOVs, variants, several passes and a whole study in
tests/core/test_replay.py).

A recording is keyed by everything the traced code decides on the host: the
scene object (kept alive by its entry, so its id is never reused), the sensor,
the sampler's plugin, class, parameters, base seed and sample count (Mitsuba's
samplers by what a clone of them draws, as some hide their base seed), the user's
sampler code and the Python values it reads (:mod:`mcrt.core.traced_state`), the
pass shape, the film's channels and the variant. The seed is the one input that
changes. What cannot be replayed renders unfrozen, and the first
render of each kind says why (a note on ``mcrt.render``):

* renders that report or change something between passes: checkpoints, resumed
  renders, motion-blur sub-frames (the scene moves between passes), progress
  bars over several passes, passes run as tasks elsewhere; and renders of more
  than :data:`MAX_PASSES` passes (long enough for tracing not to matter);
* integrators written in Python by mcrt (``multisample`` counts its shading
  evaluations on the host);
* a user's sampler holding numpy arrays and no ``frozen_inputs()``
  (:func:`mcrt.core.traced_state.why_not`);
* whatever fails to record (e.g. a sampler that reads arrays on the host while
  tracing): it is remembered and never tried again in the process.

``MCRT_REPLAY=0`` (or ``off``, ``false``, ``no``) renders everything unfrozen (for
comparisons and A/B benchmarks); ``1``, ``on``, ``true``, ``yes`` or unset: replay
where it can; any other value is a one-line error (:func:`~mcrt.core.environ.env_switch`).
"""

from __future__ import annotations

import logging
import time
from collections import OrderedDict
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from dataclasses import dataclass
from typing import Any

import drjit as dr
import mitsuba as mi

from .._gc import collection_held_back
from .accumulators import FilmAccumulator
from .engine import PassRun, PassShape, run_passes, sampling_integrator
from .environ import env_switch
from .sampling import describe, sampler_fingerprint, sampler_name, sampler_params
from .traced_state import sampler_key
from .traced_state import why_not as sampler_why_not

log = logging.getLogger("mcrt.render")

#: The environment variable that switches replay off (``0``, see :func:`switched_off`).
ENV = "MCRT_REPLAY"

#: Most passes a replayed render has: a render of more passes is long enough that
#: tracing is a small part of it, and its recording would keep every pass's launches.
MAX_PASSES = 16

#: Recordings kept per process (least recently used dropped first); each holds its
#: kernels and keeps its scene alive.
LIMIT = 16


@dataclass
class Replayed:
    """A replayed render's outputs, still on the device, and its wall time."""

    image: Any  # the developed film (TensorXf)
    nonfinite: Any  # UInt32 per grid pixel
    sums: list[Any]  # Float64 per channel: the accumulator's state
    seconds: float


class _Recording:
    """What the call that records uses: the caller's sampler and the pass shape.
    A plain object, so :func:`drjit.freeze` keys it by identity (one, for the
    process) and never traverses the sampler, whose state changes as it renders."""

    sampler: Any = None
    shape: PassShape | None = None
    sensor: int = 0
    channels: int = 0


class Recordings:
    """Frozen functions keyed by everything their traced code decides on the host.

    :meth:`get` answers None the first time it sees a key (trace that render:
    recording one made once would cost and gain nothing) and the entry made by
    ``make()`` from the second time on (it records, and later calls replay), for
    as long as the scene has the arrays it was recorded with (:class:`SceneArrays`); at
    most ``limit`` entries are kept, the least recently used dropped first; what
    failed to record is remembered (:meth:`fail`, :attr:`failed`) and traced from
    then on. Film renders (here), their passes one at a time
    (:mod:`mcrt.core.pass_replay`) and adaptive wavefronts
    (:mod:`mcrt.render.adaptive.frozen`) each keep one; :func:`clear` clears all."""

    def __init__(self, limit: int) -> None:
        self.limit = limit
        #: key -> (the scene's array indices, the arrays, their SceneArrays, the entry)
        self.entries: OrderedDict[tuple, tuple[tuple, list[Any], Any, Any]] = OrderedDict()
        self.seen: OrderedDict[tuple, None] = OrderedDict()  # (key, state) traced once
        self.failed: dict[tuple, str] = {}  # kinds that failed to record, and why
        self.made = 0  # entries made (recordings started) since the last clear
        _EVERY.append(self)

    def get(self, key: tuple, make: Callable[[], Any], scene: mi.Scene,
            eager: bool = False) -> Any | None:
        """The entry of ``key`` (None: trace this call). An entry recorded while
        ``scene`` had other :class:`SceneArrays` is dropped and this call traced;
        an entry holds the arrays it was recorded with, so that a new array never
        takes their (reused) variable index."""
        held = self.entries.get(key)
        traversal = held[2] if held is not None else SceneArrays(scene)
        arrays = traversal.now()
        state = tuple(dr.detail.collect_indices(arrays))
        if held is not None and held[0] != state:
            del self.entries[key]
            held = None
        if held is None:
            if not (eager or _WARMING) and (key, state) not in self.seen:
                self.seen[(key, state)] = None
                while len(self.seen) > 4 * self.limit:
                    self.seen.popitem(last=False)
                return None
            held = self.entries[key] = (state, arrays, traversal, make())
            self.made += 1
            while len(self.entries) > self.limit:
                self.entries.popitem(last=False)
        self.entries.move_to_end(key)
        return held[3]

    def fail(self, key: tuple, kind: tuple, error: BaseException, what: str) -> None:
        """The recording of ``key`` failed: drop it, remember ``kind`` (traced from
        now on) and say why once (``what``: the renders concerned)."""
        self.entries.pop(key, None)
        self.failed[kind] = reason(error)
        note(f"{what}: {self.failed[kind]}")

    def clear(self) -> None:
        self.made = 0
        self.entries.clear()
        self.seen.clear()
        self.failed.clear()

    def count(self) -> int:
        """How many times the kept frozen functions were recorded (each entry's last item)."""
        return sum(int(getattr(held[3][-1], "n_recordings", 0)) for held in self.entries.values())


_NOW = _Recording()
_EVERY: list[Recordings] = []
_RECORDINGS = Recordings(LIMIT)  # entries: (scene kept alive, frozen render)
_NOTED: set[str] = set()
_WARMING = False  # see warming_up()


@contextmanager
def warming_up() -> Iterator[None]:
    """Renders in this block warm their kind up: recorded at once instead of
    traced, so that every render of the kind after the block replays. For an
    untimed warm-up before timed renders (a study cell's, the timing
    protocol's): without it the first timed render of each kind recorded."""
    global _WARMING
    before, _WARMING = _WARMING, True
    try:
        yield
    finally:
        _WARMING = before


def _body(scene: mi.Scene, seed: Any, tables: tuple) -> tuple[Any, Any, list[Any], list[Any]]:
    """The render a frozen function records: every pass, then the film developed
    (``tables``: the sampler's own device arrays, inputs like the scene's)."""
    now = _NOW
    film = scene.sensors()[now.sensor].film()
    accumulator = FilmAccumulator(film, now.channels)
    assert now.shape is not None
    run_passes(scene, now.sampler, accumulator, PassRun(now.shape), seed, sensor=now.sensor)
    return (accumulator.develop(), accumulator.nonfinite, accumulator.sums,
            take_outputs(sampling_integrator(scene)))


class SceneArrays:
    """A scene's parameters (``mi.traverse``) that are Dr.Jit arrays of other
    than one value: vertex buffers, textures, volumes; :meth:`now` reads them.

    A recording is replayed only while they are the arrays it was recorded with
    (written over in place, as motion blur moves meshes, is fine): after a
    parameter was set to a new array through ``mi.traverse``, replays of a moved
    mesh were sometimes (on a cold kernel cache) right only where the new array
    landed at the old one's address (tests/core/test_replay.py). Single values
    are replayed as they are now. A recording keeps its scene's traversal (the
    parameters read the scene's current values: 3 us a call where traversing
    takes 0.1-0.2 ms); nothing else keeps one, as a scene kept alive stays in
    Dr.Jit's registry, where its plugins are traced with every other scene's."""

    def __init__(self, scene: mi.Scene) -> None:
        self.params = mi.traverse(scene)
        self.keys = []
        for key in self.params.keys():
            if self.params.properties[key][0] is None:
                continue  # Mitsuba 3.9.1's hair BSDF lists an unset sigma_a as None,
                # which reading the parameter fails on (TypeError in its hashing)
            value = self.params[key]
            if dr.is_jit_v(value) and dr.width(value) != 1:
                self.keys.append(key)

    def now(self) -> list[Any]:
        return [self.params[key] for key in self.keys]


def switched_off() -> bool:
    """Whether ``MCRT_REPLAY`` (``0``, ``off``, ``false``, ``no``) switches every
    replay off; a value that is not a switch is a one-line :class:`McrtError`."""
    return not env_switch(ENV, True)


def replayable(integrator: Any) -> bool:
    """Whether ``integrator`` traces with device arrays only: Mitsuba's (C++)
    integrators and any that says so with ``replayable = True`` (mcrt's Python
    integrators are not, unless they do)."""
    return not type(integrator).__module__.startswith("mcrt.") or \
        bool(getattr(integrator, "replayable", False))


def take_outputs(integrator: Any) -> list[Any]:
    """What a replayable integrator computed on the device while it was traced
    (shading counts, say), taken from it: a recording returns them, so that a
    replay makes them again (:meth:`take_replay_outputs`; none by default)."""
    take = getattr(integrator, "take_replay_outputs", None)
    return list(take()) if take is not None else []


def put_outputs(integrator: Any, values: list[Any]) -> None:
    """Hand a recording's or replay's :func:`take_outputs` back to the integrator."""
    if values:
        integrator.put_replay_outputs(values)


def why_not(scene: mi.Scene, shape: PassShape, progress: bool, **kept: Any) -> str | None:
    """Why a render cannot be replayed (None: it can). ``kept``: the render's
    checkpoint, resume, sub-frame and task arguments (any not None refuses)."""
    if switched_off():
        return f"{ENV}=0"
    given = [name for name, value in kept.items() if value is not None]
    if given:
        return f"the render has {', '.join(given)}"
    if progress and shape.passes > 1:
        return "a progress bar follows its passes"
    if shape.passes > MAX_PASSES:
        return f"more than {MAX_PASSES} passes"
    integrator = sampling_integrator(scene)
    if not replayable(integrator):
        return f"mcrt's {type(integrator).__name__} works on the host"
    return None


def render(scene: mi.Scene, sampler: mi.Sampler, shape: PassShape, seed: int, sensor: int,
           channels: int) -> Replayed | None:
    """The render of ``scene`` with ``sampler`` (sample count set, film prepared)
    in passes of ``shape``, recorded or replayed; None if it cannot be (then
    render it unfrozen)."""
    why = sampler_why_not(sampler)
    if why is not None:
        note(why)
        return None
    key = render_key(scene, sampler, shape, sensor, channels)
    if key in _RECORDINGS.failed:
        return None
    entry = _RECORDINGS.get(key, lambda: (scene, dr.freeze(_body, warn_after=4)), scene)
    if entry is None:  # a render made once (of this scene's arrays) is traced
        return None
    _NOW.sampler, _NOW.shape, _NOW.sensor, _NOW.channels = sampler, shape, sensor, channels
    start = time.perf_counter()
    try:
        tables: tuple = getattr(sampler, "frozen_inputs", tuple)()
        # No cyclic collection while Dr.Jit records or replays: a collection there frees
        # unrelated garbage holding Dr.Jit variables in the middle of the recording,
        # which aborted the process (seen once in CI, a Mitsuba sampler's render).
        with collection_held_back():
            image, nonfinite, sums, outputs = entry[1](scene, dr.opaque(mi.UInt32, seed), tables)
            dr.eval(image, nonfinite, sums, outputs)
        dr.sync_thread()
        put_outputs(sampling_integrator(scene), outputs)
    except RuntimeError as error:  # what cannot be recorded renders unfrozen, from now on
        _RECORDINGS.fail(key, key, error, f"{sampler_name(sampler)} cannot be replayed")
        return None
    finally:
        _NOW.sampler = None
    return Replayed(image, nonfinite, list(sums), time.perf_counter() - start)


def note(why: str) -> None:
    """Say once per process (at debug level) why renders of a kind run unfrozen."""
    if why not in _NOTED:
        _NOTED.add(why)
        log.debug("rendering without replay: %s", why)


def clear() -> None:
    """Drop every recording (and the scenes they keep alive), and forget the
    failures and notes."""
    for recordings in _EVERY:
        recordings.clear()
    _NOTED.clear()


def recordings() -> int:
    """How many times the frozen renders of this process were recorded (traced)."""
    return _RECORDINGS.count()


def render_key(scene: mi.Scene, sampler: mi.Sampler, shape: Any, sensor: int,
               channels: int) -> tuple:
    """Everything a film render's traced code decides on the host (``shape``:
    the pass shape, or what of it the recording depends on)."""
    name = sampler_name(sampler)
    identity = getattr(sampler, "_base_seed", None)
    if identity is None:  # Mitsuba's: what a clone of it draws (some hide their base seed)
        probe, fixed = sampler.clone(), 0x5EED
        probe.seed(fixed, 4)  # type: ignore[arg-type]  # the stub wants a UInt array
        identity = tuple(float(v) for v in probe.next_1d()) + (describe(sampler),)
    params = tuple(sorted((k, repr(v)) for k, v in sampler_params(sampler).items()))
    return (mi.variant(), id(scene), sensor, name, params, identity, sampler.sample_count(),
            sampler_fingerprint(name, sampler_params(sampler)), shape, channels,
            *sampler_key(sampler))


def reason(error: BaseException) -> str:
    """Why a recording failed, on one line: the root cause's message."""
    while error.__cause__ is not None:
        error = error.__cause__
    return " ".join(str(error).split())[:300]


__all__ = ["ENV", "LIMIT", "MAX_PASSES", "Recordings", "Replayed", "clear", "note", "put_outputs",
           "SceneArrays", "reason", "recordings", "render", "render_key", "replayable",
           "switched_off", "take_outputs", "warming_up", "why_not"]
