"""Trace one wavefront of camera samples: the per-lane core of every renderer.

This is Mitsuba's ``SamplingIntegrator::render_sample`` in Python, so that mcrt
can choose which lanes to trace (all pixels, passes, compacted adaptive
wavefronts) and what to do with each sample's value (develop a film, or keep
exact per-pixel statistics). Mitsuba's own camera-sample order is kept:
pixel position (2D), then the lens (2D) only if the sensor has an aperture,
then time (1D) only if the shutter is open for a non-zero time, then the
wavelengths (1D) in spectral variants. The radiance is turned into the linear
RGB an ``ImageBlock`` stores, as ``ImageBlock::put`` does: spectra through the
CIE curves, a monochrome value copied into the three channels.
"""

from __future__ import annotations

import re
from dataclasses import dataclass
from typing import Any

import drjit as dr
import mitsuba as mi

from ..errors import SceneError


@dataclass
class CameraSamples:
    """Per-lane results of :func:`trace`, still lazy Dr.Jit expressions."""

    #: Integer pixel of each lane (film coordinates, crop offset included).
    pixel: mi.Vector2i
    #: Continuous film position where the sample lands (for the film's filter).
    position: mi.Vector2f
    #: Sensor-weighted radiance of the sample (linear sRGB, whatever the variant).
    rgb: mi.Color3f
    #: Whether the integrator produced a valid sample (alpha).
    valid: mi.Bool
    #: Extra channels from AOV integrators, in ``integrator.aov_names()`` order.
    aovs: list[Any]
    #: Wavelengths of the ray (needed by ``ImageBlock.put``).
    wavelengths: Any


def film_grid_size(film: mi.Film) -> mi.ScalarVector2u:
    """Number of pixels Mitsuba samples: the crop window plus the filter
    border when the film samples it."""
    size = mi.ScalarVector2u(film.crop_size())
    if film.sample_border():
        size += 2 * film.rfilter().border_size()
    return size


def pixel_of_index(film: mi.Film, index: mi.UInt32) -> mi.Vector2i:
    """Film pixel of a linear pixel index over :func:`film_grid_size`."""
    width = int(film_grid_size(film)[0])
    y = index // width
    pos = mi.Vector2i(mi.Int32(index - y * width), mi.Int32(y))
    if film.sample_border():
        pos -= film.rfilter().border_size()
    return pos + mi.Vector2i(film.crop_offset())


def to_rgb(value: Any, wavelengths: Any, active: Any = True) -> mi.Color3f:
    """The linear RGB an ``ImageBlock`` stores for a radiance ``value`` (of a
    polarized variant: its Mueller matrix's intensity, as Mitsuba's films take)."""
    if mi.is_polarized:
        value = mi.unpolarized_spectrum(value)
    if mi.is_spectral:
        return mi.spectrum_to_srgb(value, wavelengths, active)
    if mi.is_monochromatic:
        return mi.Color3f(value[0])
    return mi.Color3f(value)


def is_differentiable(integrator: mi.Integrator) -> bool:
    """Whether ``integrator`` is one of Mitsuba's Python differentiable
    integrators (``prb``, ``prb_basic``, ``direct_projective``, ``prbvolpath``,
    ...), whose ``sample()`` takes an AD mode and extra state."""
    # Their Python base class can be loaded under two module names; its C++ base is one.
    return isinstance(integrator, mi.CppADIntegrator)


def integrator_sample(integrator: mi.SamplingIntegrator, scene: mi.Scene, sampler: mi.Sampler,
                      ray: mi.RayDifferential3f, medium: Any = None,
                      active: Any = True) -> tuple[Any, Any, list[Any]]:
    """``(spectrum, valid, aovs)`` of one sample of ``integrator`` along ``ray``.

    Mitsuba's differentiable integrators are driven the way their own
    ``render()`` drives them: primal mode, no adjoint, no incoming state,
    derivatives suspended, and no sensor medium (they do not support one).
    A Mitsuba plugin that cannot evaluate what the scene asks of it (a
    spectral-only emitter in an RGB variant, a bump map over a texture without
    gradients, ...) fails here; that is a :class:`~mcrt.errors.SceneError`,
    since ``mi.render`` fails the same way.
    """
    try:
        if is_differentiable(integrator):
            differentiable: Any = integrator  # a Python class: its sample() is not the stub's
            with dr.suspend_grad():
                result: Any = differentiable.sample(
                    mode=dr.ADMode.Primal, scene=scene, sampler=sampler, ray=ray,
                    depth=mi.UInt32(0), δL=None, δaovs=None, state_in=None,
                    active=mi.Bool(active))
            return result[0], result[1], list(result[2])
        spec, valid, aovs = integrator.sample(scene, sampler, ray, medium, active)
    except RuntimeError as error:
        raise _plugin_error(error) from error
    return spec, valid, list(aovs)


#: How Mitsuba's C++ plugins word an error: ``[ClassName] message``.
_PLUGIN_ERROR = re.compile(r"^\[(\w+)\] (.+)", re.S)


def _plugin_error(error: RuntimeError) -> Exception:
    """``error`` as a :class:`SceneError` when, at its root (Dr.Jit wraps the
    errors raised inside its loops and calls), a Mitsuba plugin refused to
    evaluate something; else ``error`` itself (a bug, with its traceback)."""
    root: BaseException = error
    while root.__cause__ is not None:
        root = root.__cause__
    found = _PLUGIN_ERROR.match(str(root).strip()) if isinstance(root, RuntimeError) else None
    if found is None:
        return error
    message = " ".join(found.group(2).split())
    hint = ""
    if "non-spectral" in message:
        hint = "; render it with a spectral variant, e.g. --variant llvm_ad_spectral"
    return SceneError(f"Mitsuba cannot render this scene ({found.group(1)}: {message}; "
                      f"mi.render fails the same way){hint}")


def trace(scene: mi.Scene, sensor: mi.Sensor, sampler: mi.Sampler,
          integrator: mi.SamplingIntegrator, pixel: mi.Vector2i, spp: int,
          active: Any = True) -> CameraSamples:
    """Draw one camera sample per lane at integer ``pixel`` and integrate it.

    ``sampler`` must already be seeded for ``dr.width(pixel)`` lanes. ``spp`` is
    the pixel's total sample count (it scales ray differentials, as in Mitsuba).
    """
    film = sensor.film()
    crop_size = mi.ScalarVector2f(film.crop_size())
    scale = 1.0 / crop_size
    offset = -mi.ScalarVector2f(film.crop_offset()) * scale

    jitter: Any = sampler.next_2d(active)
    position: Any = mi.Vector2f(pixel) + jitter
    adjusted = dr.fma(position, scale, offset)

    aperture = mi.Point2f(0.5)
    if sensor.needs_aperture_sample():
        aperture = sampler.next_2d(active)

    # Mitsuba's stubs type these arrays as Dr.Jit's, not as mi.Float: Any for both.
    time: Any = mi.Float(sensor.shutter_open())
    if sensor.shutter_open_time() > 0:
        time += sampler.next_1d(active) * sensor.shutter_open_time()

    wavelength: Any = mi.Float(0.0)
    if mi.is_spectral:
        wavelength = sampler.next_1d(active)

    ray, ray_weight = sensor.sample_ray_differential(time, wavelength, adjusted, aperture, active)
    if ray.has_differentials:
        scale_factor: Any = dr.rsqrt(float(spp))
        ray.scale_differential(scale_factor)

    spec, valid, aovs = integrator_sample(integrator, scene, sampler, ray, sensor.get_medium(),
                                          active)
    return CameraSamples(pixel=pixel, position=position,
                         rgb=to_rgb(ray_weight * spec, ray.wavelengths, active),
                         valid=mi.Bool(valid),
                         aovs=list(aovs), wavelengths=ray.wavelengths)
