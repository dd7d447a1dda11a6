"""The ``adaptive`` integrator plugin: adaptive sampling around any sampling integrator.

``import mcrt`` registers it, so a scene can say::

    <integrator type="adaptive">
        <float name="threshold" value="0.05"/>
        <integrator type="path"/>
    </integrator>

and ``mi.render(scene)`` renders adaptively. The engine is
:func:`mcrt.render.adaptive.render_adaptive`; the full result of the last render
(per-pixel sample counts, variance, standard error, passes) is kept in
``integrator.last_result``.
"""

from __future__ import annotations

import logging

import drjit as dr
import mitsuba as mi
import numpy as np

from ..errors import McrtError
from . import adaptive
from .adaptive import PARAMETERS, PARAMETERS_BY_NAME, AdaptiveSettings, Param, render_adaptive
from .plugins import fill_parameters, register_integrator, wrapper_properties
from .plugins import parameter_row as plugin_row

log = logging.getLogger("mcrt.render")

#: Variant whose ``mi.SamplingIntegrator`` the plugin class derives from.
_classes_variant = mi.variant()


def parameter_row(p: Param) -> str:
    """One row of the plugin's RST parameter table (name, type, text, default)."""
    return plugin_row(p.name, p.kind.__name__,
                      f"{p.help[:1].upper()}{p.help[1:]}. {p.details} (Default: {p.default})")


def _docstring(template: str) -> str:
    """The class docstring: ``template`` with the parameter table filled in."""
    return fill_parameters(template, (parameter_row(p) for p in PARAMETERS))


class AdaptiveIntegrator(mi.SamplingIntegrator):
    __doc__ = _docstring(r"""
    .. _integrator-adaptive:

    Adaptive sampling (:monosp:`adaptive`)
    --------------------------------------

    .. pluginparameters::

     * - (Nested plugin)
       - |integrator|
       - The sampling integrator that computes each sample (``path``,
         ``direct``, ...). (Default: ``path``)
{parameters}

    Pass 0 traces ``min_spp`` samples per pixel; each later pass traces new
    samples only for pixels that fail the error test (and their dilation
    neighbours), through compacted wavefronts, until none fails or the budget
    is spent. Every pass gives a pixel one complete, fresh pattern of the
    scene's sampler (batches grow geometrically), so samples stay stratified
    and never repeat. Per-pixel moments are float64 (Chan's merge); NaN/Inf
    samples are excluded, counted and reported. The scene sampler's type and
    parameters are used, not its ``sample_count``.

    ``integrator.last_result`` holds the last render's
    :class:`~mcrt.render.adaptive.AdaptiveRender` (sample counts, variance,
    standard error, passes). AOVs of the nested integrator are not kept.

    .. tabs::

        .. code-tab:: xml

            <integrator type="adaptive">
                <float name="threshold" value="0.05"/>
                <integrator type="path"/>
            </integrator>

        .. code-tab:: python

            'type': 'adaptive',
            'threshold': 0.05,
            'nested': {'type': 'path'}
    """)

    #: Marker read by :func:`render_adaptive` to unwrap a scene's adaptive integrator.
    is_adaptive = True

    def __init__(self, props: mi.Properties) -> None:
        super().__init__(props)
        inner, values = wrapper_properties(
            "adaptive", props, PARAMETERS_BY_NAME,
            lambda name, value: _typed(PARAMETERS_BY_NAME[name], value))
        if getattr(inner, "is_adaptive", False):
            raise McrtError("adaptive: cannot nest an adaptive integrator in another")
        self.nested = adaptive.check_integrator(inner)
        self.settings = AdaptiveSettings(**values).check()
        self.last_result: adaptive.AdaptiveRender | None = None

    def render(self, scene: mi.Scene, sensor: int | mi.Sensor = 0,  # type: ignore[override]
               seed: int = 0, spp: int = 0, develop: bool = True,
               evaluate: bool = True) -> mi.TensorXf:
        """Render adaptively; ``spp`` (if nonzero) overrides ``max_spp``.

        ``mi.render`` calls this inside a Dr.Jit custom operation, which replaces
        any exception by its own ``RuntimeError('drjit.custom(...): error while
        performing a custom differentiable operation. (see above).')``: an
        :class:`McrtError` is therefore also logged (on ``mcrt.render``, at error
        level; Python prints it on stderr when logging is not set up), so the
        reason is not only in the wrapper's ``__cause__``."""
        try:
            return self._render(scene, sensor, seed, spp, develop)
        except McrtError as error:
            log.error("%s", error)
            raise

    def _render(self, scene: mi.Scene, sensor: int | mi.Sensor, seed: int, spp: int,
                develop: bool) -> mi.TensorXf:
        sensor_obj = scene.sensors()[sensor] if isinstance(sensor, int) else sensor
        settings = self.settings
        if spp and int(spp) < settings.min_spp:
            raise McrtError(f"adaptive: spp={int(spp)} (mi.render's spp sets the budget "
                            f"max_spp) is below min_spp ({settings.min_spp}), the samples of "
                            f"every pixel's first pass; pass spp >= {settings.min_spp} (0: "
                            f"max_spp {settings.max_spp}) or give the integrator a smaller "
                            f"min_spp")
        if spp:
            settings = AdaptiveSettings(**{**settings.__dict__, "max_spp": int(spp)}).check()
        result = render_adaptive(scene, settings=settings, seed=_seed_value(seed),
                                 sensor=sensor_obj, integrator=self.nested)
        self.last_result = result
        film = sensor_obj.film()
        film.prepare([])
        # The film stores linear sRGB[A] and forms its own Y or X Y Z on develop.
        rgb = result.rgb
        if result.channels[-1] == "A":
            rgb = np.concatenate([rgb, result.image[..., -1:]], axis=-1)
        film.put_block(_block(film, rgb))
        if not develop:
            return mi.TensorXf()
        image = film.develop()
        dr.eval(image)
        return image  # type: ignore[return-value]

    def sample(self, scene, sampler, ray, medium=None, active=True):
        """One sample of the nested integrator (adaptivity lives in :meth:`render`)."""
        from ..core.trace import integrator_sample

        return integrator_sample(self.nested, scene, sampler, ray, medium, active)

    def aov_names(self) -> list[str]:
        return []

    def to_string(self) -> str:
        params = ", ".join(f"{k}={v}" for k, v in self.settings.__dict__.items())
        return f"AdaptiveIntegrator[{params}, nested={self.nested}]"


def _typed(p: Param, value):
    """A property's value as the parameter's type (an int property of a float
    parameter is converted; ranges are checked by :meth:`AdaptiveSettings.check`)."""
    if p.kind is int:
        if isinstance(value, bool) or not isinstance(value, int):
            raise McrtError(f"adaptive: '{p.name}' must be an integer, got {value!r}")
        return value
    if isinstance(value, bool) or not isinstance(value, (int, float)):
        raise McrtError(f"adaptive: '{p.name}' must be a number, got {value!r}")
    return float(value)


def _seed_value(seed) -> int:
    if isinstance(seed, int):
        return seed
    array = np.asarray(seed).ravel()
    if array.size != 1:
        raise McrtError("adaptive: expected a single seed value")
    return int(array[0])


def _block(film: mi.Film, image: np.ndarray) -> mi.ImageBlock:
    """An image block holding the reconstructed crop window with unit weights."""
    channels = 4 if mi.has_flag(film.flags(), mi.FilmFlags.Alpha) else 3  # R, G, B[, A]
    if image.shape[2] != channels:
        raise McrtError(f"adaptive: cannot develop {image.shape[2]} channels into a film that "
                        f"stores {channels}")
    h, w, _ = image.shape
    data = np.concatenate([image, np.ones((h, w, 1), np.float32)], axis=-1)
    tensor = mi.TensorXf(np.ascontiguousarray(data, dtype=np.float32))
    return mi.ImageBlock(tensor, film.crop_offset(), film.rfilter(),  # type: ignore[call-overload]
                         border=False, normalize=False)


def register() -> None:
    """Register the ``adaptive`` integrator with the active Mitsuba variant."""
    register_integrator("adaptive", __name__, "AdaptiveIntegrator")


__all__ = ["AdaptiveIntegrator", "parameter_row", "register"]
