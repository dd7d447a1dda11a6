"""The ``multisample`` integrator plugin: multisampling around any sampling integrator.

``import mcrt`` registers it, so a scene can say::

    <integrator type="multisample">
        <integrator type="direct"/>
    </integrator>

and ``mi.render(scene)`` (or ``mcrt render``) traces the sampler's N positions
per pixel for visibility and shades once per surface per pixel (see
:mod:`mcrt.render.multisample`). The integrator counts what it shaded:
``integrator.counts`` (:class:`ShadingCounts`), reset by ``reset_counts()``.

It traces with device arrays only (``replayable``), so mcrt's film renders
record it once and replay it (:mod:`mcrt.core.replay`). A replay runs none of
its Python code: each wavefront queues its counts as device arrays, a frozen
render returns them (``take_replay_outputs``) and hands them back after each
replay (``put_replay_outputs``), and ``counts`` reads the queue when it is read.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

import drjit as dr
import mitsuba as mi
import numpy as np

from ..core.trace import integrator_sample
from ..errors import McrtError
from . import multisample as ms
from .plugins import fill_parameters, register_integrator, wrapper_properties
from .plugins import parameter_row as plugin_row

#: Wavefronts whose counts wait on the device before they are read back.
QUEUED = 16

#: Variant whose ``mi.SamplingIntegrator`` the plugin class derives from.
_classes_variant = mi.variant()



@dataclass(frozen=True)
class Param:
    """One string parameter of the plugin: name, default, choices, description."""

    name: str
    default: str
    choices: tuple[str, ...]
    help: str


#: The plugin's parameters (read by ``__init__``, listed in the docstring table).
PARAMETERS = (
    Param("representative", "centre", ms.REPRESENTATIVES,
          "which sample of a group is shaded: ``centre``, the group's sample whose ray is "
          "closest to the mean ray of the pixel (the covered sample nearest the centre of "
          "the pixel's pattern, as MSAA shades at the pixel centre), or ``first``, the "
          "group's first sample in sample order"),
    Param("group_by", "primitive", ms.GROUPINGS,
          "what makes two samples of a pixel one group: the same shape, instance and "
          "``primitive`` (triangle), or the same ``shape`` and instance (a smooth mesh is "
          "one group)"),
)
PARAMETERS_BY_NAME = {p.name: p for p in PARAMETERS}

def parameter_row(p: Param) -> str:
    """One row of the plugin's RST parameter table."""
    return plugin_row(p.name, "string",
                      f"{p.help[:1].upper()}{p.help[1:]}. (Default: ``{p.default}``)")


def _docstring(template: str) -> str:
    return fill_parameters(template, (parameter_row(p) for p in PARAMETERS))


@dataclass
class ShadingCounts:
    """What the integrator traced and shaded since the last ``reset_counts()``."""

    samples: int = 0  # visibility samples (lanes)
    evaluations: int = 0  # shading evaluations (group representatives)
    #: Shading evaluations per pixel of the sampled grid, (height, width), summed
    #: over wavefronts; None until a wavefront ran (or when the grid changed).
    per_pixel: np.ndarray | None = None
    wavefronts: int = 0
    samples_per_pixel: list[int] = field(default_factory=list)  # N of each wavefront

    @property
    def per_sample(self) -> float:
        """Shading evaluations per visibility sample (1 for supersampling)."""
        return self.evaluations / self.samples if self.samples else 0.0


class MultisampleIntegrator(mi.SamplingIntegrator):
    __doc__ = _docstring(r"""
    .. _integrator-multisample:

    Multisampling (:monosp:`multisample`)
    -------------------------------------

    .. pluginparameters::

     * - (Nested plugin)
       - |integrator|
       - The sampling integrator that shades a group (``direct``, ``path``,
         ...). (Default: ``path``)
{parameters}

    Every sample of a pixel traces its primary ray for visibility; samples
    whose rays hit the same surface (shape, instance, primitive; or all misses)
    form a group, and only one sample per group, its representative, is shaded
    by the nested integrator, in a compacted wavefront. Every sample then
    carries its group's shaded value, so the film's reconstruction filter and
    mcrt's statistics work unchanged: with a box filter a pixel is the
    coverage-weighted sum of its groups' colours. Shading noise, texture detail
    and shading discontinuities inside one surface (shadow edges) are sampled
    once per group, not N times: textures alias unless they are prefiltered.

    The wavefront must be pixel-major with the same number of samples for every
    pixel (``mi.render`` and ``mcrt render`` are); ``mcrt render`` groups the
    samples of one pass, so a pixel's N samples share shading only when a pass
    holds all of them (``integrator.counts.samples_per_pixel`` says what each
    wavefront had). Not supported: spectral variants, nesting in ``adaptive``.

    .. tabs::

        .. code-tab:: xml

            <integrator type="multisample">
                <integrator type="direct"/>
            </integrator>

        .. code-tab:: python

            'type': 'multisample',
            'nested': {'type': 'direct'}
    """)

    def __init__(self, props: mi.Properties) -> None:
        super().__init__(props)
        inner, values = wrapper_properties(
            "multisample", props, PARAMETERS_BY_NAME,
            lambda name, value: _choice(PARAMETERS_BY_NAME[name], value))
        if getattr(inner, "is_adaptive", False) or isinstance(inner, MultisampleIntegrator):
            raise McrtError("multisample: cannot nest an adaptive or multisample integrator")
        if mi.is_spectral:
            raise McrtError("multisample: spectral variants are not supported (a group's "
                            "samples have different wavelengths)")
        self.nested = inner
        self.representative = values.get("representative", PARAMETERS_BY_NAME[
            "representative"].default)
        self.group_by = values.get("group_by", PARAMETERS_BY_NAME["group_by"].default)
        self._state = _State()

    #: Traces with device arrays only: film renders replay it (:mod:`mcrt.core.replay`).
    replayable = True

    @property
    def counts(self) -> ShadingCounts:
        """What was traced and shaded since the last ``reset_counts()`` (read
        from the device now: wavefronts only queue their counts)."""
        state = self._state
        for per_pixel, shape in zip(state.pending[::2], state.pending[1::2], strict=True):
            _add(state.counts, np.array(per_pixel, dtype=np.int64),
                 *(int(v) for v in np.array(shape)))
        state.pending.clear()
        return state.counts

    def reset_counts(self) -> None:
        """Start counting samples and shading evaluations from zero."""
        self._state.counts = ShadingCounts()
        self._state.pending.clear()
        self._state.traced.clear()

    def take_replay_outputs(self) -> list[Any]:
        """The counts of the wavefronts traced in a frozen function since the
        last take (device arrays, the frozen function's outputs), removed."""
        taken, self._state.traced = self._state.traced, []
        return taken

    def put_replay_outputs(self, values: list[Any]) -> None:
        """Counts a frozen function recorded or replayed (:meth:`take_replay_outputs`)."""
        self._state.pending.extend(values)
        self._bound_queue()

    def _bound_queue(self) -> None:
        """Read the queue once it holds :data:`QUEUED` wavefronts: a long render
        keeps at most that many grids of counts on the device."""
        if len(self._state.pending) >= 2 * QUEUED:
            _ = self.counts

    def sample(self, scene, sampler, ray, medium=None, active=True):
        """Visibility for every lane, shading for one representative per group."""
        lanes = _ray_width(ray)
        if lanes == 1 and sampler.wavefront_size() > 1:
            # One ray for every sample (a radiance meter's): no surfaces to tell
            # apart, every lane shaded by the nested integrator's own samples.
            layout = ms.wavefront_layout(scene, sampler.wavefront_size())
            shaded_per_pixel = dr.full(mi.UInt32, layout.group, layout.pixels)
        else:
            layout = ms.wavefront_layout(scene, lanes)
            shaded_per_pixel = dr.ones(mi.UInt32, layout.pixels) if layout.group == 1 else None
        if shaded_per_pixel is not None:  # nothing to share
            spec, valid, aovs = integrator_sample(self.nested, scene, sampler, ray, medium,
                                                  active)
            self._count(layout, shaded_per_pixel)
            return spec, valid, aovs
        dr.eval(ray)  # once: keys, distances and the compaction all read it
        keys = ms.surface_keys(scene, ray, self.group_by, active)
        distance = (ms.centre_distance(ray, layout.group)
                    if self.representative == "centre" else None)
        dr.eval(keys, distance)
        rep = ms.representatives(keys, distance, layout.group, active)
        seed = ms.shading_seed(sampler, active)
        shaded = ms.shade_groups(scene, self.nested, self._state.shading, seed, ray, rep,
                                 layout.group, medium)
        self._count(layout, shaded.per_pixel)
        return shaded.spectrum, shaded.valid, shaded.aovs

    def _count(self, layout: ms.Wavefront, per_pixel: mi.UInt32) -> None:
        """Queue a wavefront's counts: representatives per pixel and its shape
        (lanes, samples per pixel, grid), both device arrays, so a frozen render
        returns them (the shape as a kernel's output: a replay makes it too)."""
        index, shape = dr.arange(mi.UInt32, 4), mi.UInt32(0)
        for i, value in enumerate((layout.lanes, layout.group, *layout.grid)):
            shape = dr.select(index == i, value, shape)
        dr.eval(per_pixel, shape)
        state = self._state
        if dr.flag(dr.JitFlag.FreezingScope):
            state.traced += [per_pixel, shape]
        else:  # (a recording that failed left its arrays: an unfrozen render follows it)
            state.traced.clear()
            state.pending += [per_pixel, shape]
            self._bound_queue()

    def aov_names(self) -> list[str]:
        return list(self.nested.aov_names())

    def to_string(self) -> str:
        return (f"MultisampleIntegrator[representative={self.representative}, "
                f"group_by={self.group_by}, nested={self.nested}]")


class _State:
    """The integrator's changing state, in a plain object: Dr.Jit traverses an
    integrator's attributes (lists, dataclasses, samplers, not plain objects)
    as inputs of a frozen render, so counts kept there would make every render
    record again."""

    def __init__(self) -> None:
        self.counts = ShadingCounts()  # the wavefronts read back so far
        self.pending: list[Any] = []  # per wavefront queued: per_pixel, shape (device arrays)
        self.traced: list[Any] = []  # the same, traced in a frozen function, not yet taken
        #: Cloned and seeded per wavefront for the representatives' shading dimensions.
        #: (Loaded serially: this runs on a worker of the scene's parallel instantiation.)
        self.shading = mi.load_dict({"type": "independent", "sample_count": 1},
                                    parallel=False)


def _ray_width(ray: mi.Ray3f) -> int:
    return max(dr.width(ray.o), dr.width(ray.d))


def shares_shading(sensor: mi.Sensor) -> bool:
    """Whether multisampling shares shading among a pixel's samples on ``sensor``:
    not when it traces one ray for every sample (a radiance meter's), where
    :meth:`MultisampleIntegrator.sample` shades every lane."""
    from .plan.camera import auto_float

    ray, _ = sensor.sample_ray(auto_float(0.0), auto_float(0.5),
                               mi.Point2f([0.25, 0.75], [0.25, 0.75]),
                               mi.Point2f(0.5, 0.5))
    return _ray_width(ray) > 1


def _add(counts: ShadingCounts, per_pixel: np.ndarray, lanes: int, group: int, width: int,
         height: int) -> None:
    """Add one wavefront's counts (read from the device) to ``counts``."""
    grid = per_pixel.reshape(height, width)
    if counts.per_pixel is None and counts.wavefronts == 0:
        counts.per_pixel = grid
    elif counts.per_pixel is not None and counts.per_pixel.shape == grid.shape:
        counts.per_pixel = counts.per_pixel + grid
    else:
        counts.per_pixel = None
    counts.samples += lanes
    counts.evaluations += int(per_pixel.sum())
    counts.wavefronts += 1
    counts.samples_per_pixel.append(group)


def _choice(p: Param, value: Any) -> str:
    if not isinstance(value, str) or value not in p.choices:
        raise McrtError(f"multisample: '{p.name}' must be one of {', '.join(p.choices)}, "
                        f"got {value!r}")
    return value


def register() -> None:
    """Register the ``multisample`` integrator with the active Mitsuba variant."""
    register_integrator("multisample", __name__, "MultisampleIntegrator")


__all__ = ["PARAMETERS", "MultisampleIntegrator", "ShadingCounts", "register", "shares_shading"]
