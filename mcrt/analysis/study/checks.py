"""The checks a study runs before rendering: every scene loads as the run will
load it, every sampler is made at every spp (one-line :class:`ConfigError`s)."""

from __future__ import annotations

import logging

import mitsuba as mi

from ...errors import McrtError
from ..aliasing import MIN_SIZE, measurable
from .config import ConfigError, SceneSpec, StudyConfig

log = logging.getLogger("mcrt.compare")


def check_config(config: StudyConfig) -> None:
    """Load every scene and make every sampler, raising a one-line error on the
    first failure; fills ``config.effective_spp`` and ``config.film_pixels``."""
    for spec in config.scenes:
        config.film_pixels[spec.name] = _check_scene(spec)
    _check_samplers(config)
    _check_reference(config)
    if config.reference.sampler != "independent":
        log.warning("reference sampler %s: its per-sample standard error overestimates the "
                    "noise of a stratified estimate, so the noise floor subtracted from every "
                    "MSE is too large; 'independent' makes it exact", config.reference.sampler)
    for sampler in config.samplers:
        changed = [f"{s}->{config.effective_spp[(sampler.label, s)]}" for s in config.spp
                   if config.effective_spp[(sampler.label, s)] != s]
        if changed:
            log.info("%s rounds sample counts: %s", sampler.label, ", ".join(changed))


def _check_scene(spec: SceneSpec) -> int:
    """The scene loads, mcrt can drive its integrator, its film suits the study;
    the pixels of its film's grid. Planned as the run will plan it, and kept for
    it (:func:`~mcrt.render.loaded.planned_scene`)."""
    from ...core.render import film_base_channels
    from ...core.trace import film_grid_size
    from ...render.loaded import planned_scene

    try:  # refuses integrators mcrt cannot drive
        scene = planned_scene(spec.path, spec.params).scene
    except McrtError as error:
        raise ConfigError(f"scene {spec.name!r}: {error}") from None
    film = scene.sensors()[0].film()  # any filter: references develop with the film's own
    channels = film_base_channels(film)
    if channels[:1] == ["Y"] and mi.is_monochromatic:  # pixel_format rgb would change nothing
        raise ConfigError(f"scene {spec.name!r}: the {mi.variant()} variant develops luminance "
                          f"only; the study measures colour errors against an RGB reference: "
                          f"run it in an RGB or spectral variant (e.g. llvm_ad_rgb)")
    if channels[:1] == ["Y"]:
        raise ConfigError(f"scene {spec.name!r}: the film stores luminance only (channels "
                          f"{' '.join(channels)}); the study measures colour errors against "
                          f"an RGB reference: give the film pixel_format rgb")
    width, height = (int(v) for v in film.crop_size())  # the image the study measures
    if not measurable((height, width)):
        log.info("scene %r renders %dx%d pixels: its cells get no aliasing score (n/a; the "
                 "measure needs %dx%d), the errors are measured as usual", spec.name, width,
                 height, MIN_SIZE, MIN_SIZE)
    grid = film_grid_size(film)
    return int(grid[0]) * int(grid[1])


def _check_samplers(config: StudyConfig) -> None:
    """Every sampler at every spp; records its effective sample count."""
    from ...core.sampling import make_sampler, quiet_sampler_warnings

    with quiet_sampler_warnings():
        for sampler in config.samplers:
            for spp in config.spp:
                try:
                    obj = make_sampler(sampler.name, spp, **sampler.params)
                except McrtError as error:
                    raise ConfigError(f"sampler {sampler.label!r} at {spp} spp: {error}") from None
                config.effective_spp[(sampler.label, spp)] = int(obj.sample_count())


def _check_reference(config: StudyConfig) -> None:
    """The reference's sampler, with its parameters, renders every scene's passes."""
    from ..pass_plan import plan_passes

    ref = config.reference
    planner = logging.getLogger("mcrt.reference")  # (its notes come when it is made)
    level = planner.level
    planner.setLevel(logging.ERROR)
    try:
        for spec in config.scenes:
            plan_passes(ref.sampler, ref.spp, config.film_pixels[spec.name], ref.spp_per_pass,
                        ref.params)
    except McrtError as error:
        raise ConfigError(f"reference of scene {spec.name!r}: {error}") from None
    finally:
        planner.setLevel(level)
