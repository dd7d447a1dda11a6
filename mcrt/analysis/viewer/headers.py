"""What a study's EXR files record in their headers, and the reference's layers.

Every EXR of a study's report (:mod:`.files`) says how it was made, so that a
file taken out of its report can be reproduced and compared:

==================  ==========================================================
``mcrt_kind``       ``study_mean``, ``study_seed`` or ``study_reference``
``study``           the study's name
``scene``           the scene's name in the study
``scene_path``      the scene's XML file
``scene_digest``    SHA-256 of its content (:func:`~mcrt.core.scene_files.scene_digest`:
                    the XML, the files it includes and names)
``scene_params``    the scene's ``$key`` parameters (JSON; the ``-D`` of ``mcrt render``)
``filter``          the film's reconstruction filter (Mitsuba's description)
``plan``            the render plan (JSON: effects, camera, integrator, ...;
                    :class:`~mcrt.render.plan.RenderPlan` without the scene's own
                    sampler and sample count) and ``effects``, the effects on
``sampler``         the sampler's label in the study; ``sampler_plugin`` and
                    ``sampler_params`` (JSON) what it is; ``sampler_code`` the
                    digest of a user's sampler code, if it is one
``spp``             samples per pixel requested; ``spp_effective`` rendered
``seeds``           the study's seeds (JSON list); ``seed_count``; ``seed`` on a
                    first seed's render
``variant``         Mitsuba's variant; ``mcrt_version``, ``mcrt_source``,
                    ``mitsuba_version``, ``drjit_version`` as the study ran
``command``         ``mcrt render`` of one seed's render (``--seed`` added on
                    a seed's file), the reference's ``mcrt reference``: what
                    ``mcrt render --from FILE.exr`` runs
==================  ==========================================================

The reference's file has the sampler, seed and spp of the reference and, when
the reference is in mcrt's reference cache (where the study put it), its
standard-error, variance and sample-count layers (``stderr``, ``variance``,
``count``, ``effective_count`` for a filtered reference, ``nonfinite``) and
the header of ``mcrt reference`` (passes, pass plan, samples, cache key); else
``reference_stats`` says why not. Scene facts that cannot be had (a scene no
longer there, a scene that does not load) are left out, with ``scene_problem``
saying why: a report is written whatever its scenes have become.
"""

from __future__ import annotations

import json
import logging
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from ...core.provenance import (
    COMMAND,
    absolute,
    command_text,
    define_words,
    param_word,
    plugin_files,
)

if TYPE_CHECKING:
    from ..reference import Reference
    from ..study import SamplerSpec, SceneSpec, StudyResult

log = logging.getLogger("mcrt.report")

Header = dict[str, str | int | float]

#: Fields of the render plan that describe the scene's own sampler, not the render's.
_PLAN_OMITTED = ("sampler", "spp", "subframes", "subframe_times")


@dataclass
class SceneRecord:
    """What the headers of one scene's files share, and its reference if cached."""

    scene: str
    header: Header
    reference: Reference | None = None
    #: why the reference's statistics are not in its file ("" when they are)
    reference_note: str = ""
    #: sample count -> sub-frames of a render (motion blur; 1 without)
    subframes: Any = None
    notes: list[str] = field(default_factory=list)


def _json(value: Any) -> str:
    return json.dumps(value, sort_keys=True, separators=(",", ":"), default=str)


def study_header(result: StudyResult) -> Header:
    """What every file of the study shares: the study, its seeds, the software."""
    env = result.environment
    seeds = list(result.config.seeds)
    return {"study": result.config.name, "seeds": _json(seeds), "seed_count": len(seeds),
            "variant": str(env.get("variant", "")), "mcrt_version": str(env.get("mcrt", "")),
            **({"mcrt_source": str(env["mcrt_source"])} if env.get("mcrt_source") else {}),
            "mitsuba_version": str(env.get("mitsuba", "")),
            "drjit_version": str(env.get("drjit", ""))}


def _cached_reference(result: StudyResult, spec: SceneSpec) -> Reference | None:
    """The study's reference of ``spec`` from mcrt's reference cache, without
    rendering: None if it is not there (or is not the study's, bit for bit)."""
    # _setup plans the scene and derives the cache key as get_reference does; the
    # report must not render, so the finished state is looked up, never made.
    from ..reference import ReferenceRequest, _setup
    from ..reference_cache import load_state

    config = result.config.reference
    setup = _setup(ReferenceRequest(spec.path, spec.params, config.spp, config.sampler,
                                    config.seed, config.spp_per_pass, config.params))
    found = load_state(setup.finished, setup.key, setup.plan, setup.shape, complete=True,
                       filtered=setup.filtered)
    if found is None:
        return None
    ref = setup.result(found[0], found[2], cached=True)
    mine = np.asarray(result.reference_images[spec.name], np.float64)
    return ref if np.array_equal(np.asarray(ref.mean, np.float64), mine) else None


def describe_scene(result: StudyResult, spec: SceneSpec) -> SceneRecord:
    """The scene's facts for the headers (scene file, digest, filter, plan) and
    its cached reference; what cannot be had is left out and said why."""
    from ...core.scene_files import scene_digest
    from ...render.loaded import planned_scene

    header: Header = {"scene": spec.name, "scene_path": str(spec.path),
                      "scene_params": _json(dict(spec.params))}
    record = SceneRecord(spec.name, header)
    # Whatever fails here, the report is written all the same, saying what is missing.
    try:
        header["scene_digest"] = scene_digest(spec.path, spec.params)
    except Exception as error:
        record.notes.append(f"no digest: {error}")
    try:
        record.reference = _cached_reference(result, spec)
        if record.reference is None:
            record.reference_note = "not in the reference cache"
    except Exception as error:
        record.reference_note = f"the reference cache could not be read: {error}"
    try:
        planned = planned_scene(spec.path, dict(spec.params))
        header["filter"] = str(planned.scene.sensors()[0].film().rfilter())
        plan = planned.plan.to_dict()
        header["plan"] = _json({k: v for k, v in plan.items() if k not in _PLAN_OMITTED})
        header["effects"] = ",".join(planned.plan.effects_on)
        record.subframes = planned.subframes_for
    except Exception as error:
        record.notes.append(f"not planned: {' '.join(str(error).split())}")
    if record.notes:
        header["scene_problem"] = "; ".join(record.notes)
        log.warning("%s: the report's EXR headers lack some scene facts (%s)", spec.name,
                    header["scene_problem"])
    return record


def cell_header(result: StudyResult, record: SceneRecord, label: str, spp: int) -> Header:
    """A cell's part of its files' headers (with :func:`study_header`'s)."""
    from ...core.sampling import sampler_fingerprint

    sampler = next(s for s in result.config.samplers if s.label == label)
    effective = int(result.cell(record.scene, label, spp)["spp"])
    header: Header = {**record.header, "sampler": label, "sampler_plugin": sampler.name,
                      "sampler_params": _json(dict(sampler.params)), "spp": int(spp),
                      "spp_effective": effective}
    code = sampler_fingerprint(sampler.name)
    if code:
        header["sampler_code"] = code
    header[COMMAND] = seed_command(result, record, sampler, spp)
    if record.subframes is not None:
        header["subframes"] = int(record.subframes(effective))
    return header


def seed_command(result: StudyResult, record: SceneRecord, sampler: SamplerSpec, spp: int
                 ) -> str:
    """The ``mcrt render`` command of one seed's render of a cell, without
    ``--seed`` (a seed's file adds it; a mean file's seeds are ``seeds``)."""
    scene = next(s for s in result.config.scenes if s.name == record.scene)
    words = [absolute(scene.path),
             *define_words(scene.path, dict(scene.params)),
             "--sampler", sampler.name,
             *[w for k, v in sampler.params.items()
               for w in ("-P", param_word(f"{k}={_cli_value(v)}"))],
             "--spp", spp]
    plugins: list[str | Path] = [*result.config.plugins, *plugin_files(sampler.name)]
    return command_text("render", *words, plugins=plugins,
                        variant=str(result.environment.get("variant", "")))


def _cli_value(value: Any) -> str:
    """A sampler parameter as ``-P key=value`` writes it (booleans as true/false)."""
    return str(value).lower() if isinstance(value, bool) else str(value)


def reference_file(result: StudyResult, record: SceneRecord
                   ) -> tuple[dict[str, np.ndarray], Header]:
    """The reference's layers and its part of the header (with :func:`study_header`'s)."""
    from ..reference_exr import reference_layers, reference_metadata

    config = result.config.reference
    info = result.references[record.scene]
    header: Header = {**record.header, "sampler": info.sampler, "seed": int(config.seed),
                      "spp": int(config.spp), "spp_effective": int(info.spp)}
    ref = record.reference
    if ref is None:
        header["reference_stats"] = f"unavailable: {record.reference_note}"
        return {"rgb": np.asarray(result.reference_images[record.scene], np.float32)}, header
    meta = reference_metadata(ref, str(record.header["scene_path"]),
                              json.loads(str(record.header["scene_params"])))
    for key in ("scene", "params", "mcrt_kind", "mcrt_version", "spp", "requested_spp"):
        meta.pop(key, None)  # said above, as every file of the study says it
    layers = reference_layers(ref)
    header.update(meta)
    header["estimator"] = "filtered" if "effective_count" in layers else "box"
    return layers, header


__all__ = ["Header", "SceneRecord", "cell_header", "describe_scene", "reference_file",
           "study_header"]
