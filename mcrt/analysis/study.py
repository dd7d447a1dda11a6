"""Studies: what accuracy costs in time, for scenes x samplers x sample counts x seeds.

A study is described by a TOML file (see ``configs/quick.toml``)::

    name = "quick"                      # optional, default: the file's stem
    description = "..."                 # optional
    spp = [4, 16, 64]                   # sample counts (>= 2 distinct)
    seeds = 3                           # K seeds 0..K-1, or a list [0, 7, 9] (>= 2)
    image_spp = 16                      # optional: spp of the report's images
    aliasing_draws = 32                 # optional: sign-flip draws of the aliasing null
    samplers = ["uniform_grid", "jittered",
                {name = "jittered", label = "jitter0.5", params = {jitter = 0.5}}]

    [reference]                         # high-spp image every render is compared with
    spp = 4096
    sampler = "independent"             # optional (default); its standard error is exact
    seed = 0                            # optional
    spp_per_pass = 256                  # optional

    [[scenes]]
    path = "../scenes/checkerboard.xml" # relative to the TOML file
    name = "checkerboard"               # optional, default: the file's stem
    params = {width = 160, height = 120}  # optional $parameters of the scene

:func:`load_config` checks *everything* (keys, numbers, sampler names and
parameters, scene files, films) before any rendering and reports the first
problem as a one-line :class:`~mcrt.errors.McrtError`.

:func:`run_study` renders, for every (scene, sampler, spp) cell, one untimed
warm-up (kernels compile and are cached) and then one render per seed, each
timed by :func:`mcrt.render.passes.render_film`: wall time of tracing all
passes, accumulating and developing the film, between two ``dr.sync_thread()``
(scene loading, sampler construction, copying the image to numpy and the
metrics are *not* included). Per cell it records, over the K seeds, the mean
and spread of: time, MSE and relMSE against the reference, the MSE in excess
of the reference's own noise (:func:`~mcrt.analysis.metrics.mse_excess`),
CIEDE2000, the aliasing score of the error; and from the K images together the
mean per-pixel variance of the pixel estimate (Welford over seeds: the real
variance of the estimator, stratification included), the MSE of the
seed-averaged image (``mse = mse_of_mean + (K - 1) / K * variance`` exactly) and
its bias with a 95% interval. NaN/Inf pixels are counted (``nonfinite``),
logged, left out of the per-pixel moments and count as zero error in the
metrics. Cells whose MSE is below :data:`RESOLVED_FACTOR` x the reference's
noise floor are flagged and left out of fits. Per (scene, sampler) it fits the
log-log slope of the excess MSE against spp and against seconds, and computes
the efficiency ``1 / (excess MSE x seconds)`` of every cell.
"""

from __future__ import annotations

import datetime
import logging
import math
import os
import platform
import time
import tomllib
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from ..errors import McrtError
from .aliasing import MIN_SIZE, Z_THRESHOLD, aliasing_score
from .convergence import efficiency, fit_loglog
from .metrics import (
    REL_MSE_EPSILON,
    bias,
    delta_e_2000,
    error_map,
    mse,
    reference_noise_floor,
    rel_mse,
    variance_map,
)
from .statistics import PixelStats

log = logging.getLogger("mcrt.compare")

#: Sign-flip draws of the aliasing null per render (the standalone default is 64;
#: 32 estimate the null sd to ~13%, plenty for a z threshold of 5, at half the cost).
STUDY_NULL_DRAWS = 32

#: Seed of the untimed warm-up render of each cell (never one of the measured seeds).
WARMUP_SEED = 0xFFFF_FF00

#: The reference must have at least this many times the study's largest spp.
MIN_REFERENCE_FACTOR = 4

#: A cell whose MSE is below this multiple of the reference's noise floor cannot
#: be measured reliably against that reference: it is flagged and left out of fits.
RESOLVED_FACTOR = 2.0

_TOP_KEYS = {"name", "description", "spp", "seeds", "image_spp", "aliasing_draws", "samplers",
             "reference", "scenes"}
_REFERENCE_KEYS = {"spp", "sampler", "seed", "spp_per_pass"}
_SCENE_KEYS = {"path", "name", "params"}
_SAMPLER_KEYS = {"name", "label", "params"}


class ConfigError(McrtError):
    """A study configuration is malformed or names something that does not exist."""


@dataclass(frozen=True)
class SceneSpec:
    name: str
    path: Path
    params: dict[str, str]


@dataclass(frozen=True)
class SamplerSpec:
    name: str                 # plugin name
    label: str                # unique name in this study
    params: dict[str, Any]


@dataclass(frozen=True)
class ReferenceSpec:
    spp: int
    sampler: str = "independent"
    seed: int = 0
    spp_per_pass: int | None = None


@dataclass(frozen=True)
class StudyConfig:
    name: str
    description: str
    scenes: tuple[SceneSpec, ...]
    samplers: tuple[SamplerSpec, ...]
    spp: tuple[int, ...]
    seeds: tuple[int, ...]
    reference: ReferenceSpec
    image_spp: int
    aliasing_draws: int = STUDY_NULL_DRAWS
    path: Path | None = None
    #: effective sample count of every (sampler label, requested spp), filled by validation
    effective_spp: dict[tuple[str, int], int] = field(default_factory=dict)

    @property
    def cells(self) -> int:
        return len(self.scenes) * len(self.samplers) * len(self.spp)

    @property
    def renders(self) -> int:
        """Renders of the study proper: per cell one warm-up and one per seed."""
        return self.cells * (len(self.seeds) + 1)

    def as_dict(self) -> dict:
        return {
            "name": self.name, "description": self.description,
            "config_path": str(self.path) if self.path else None,
            "spp": list(self.spp), "seeds": list(self.seeds), "image_spp": self.image_spp,
            "aliasing_draws": self.aliasing_draws,
            "reference": {"spp": self.reference.spp, "sampler": self.reference.sampler,
                          "seed": self.reference.seed,
                          "spp_per_pass": self.reference.spp_per_pass},
            "scenes": [{"name": s.name, "path": str(s.path), "params": s.params}
                       for s in self.scenes],
            "samplers": [{"name": s.name, "label": s.label, "params": s.params}
                         for s in self.samplers],
        }


# --------------------------------------------------------------------------- config


def _where(context: str, key: str) -> str:
    return f"{context}.{key}" if context else key


def _check_keys(table: dict, allowed: set[str], context: str) -> None:
    unknown = sorted(set(table) - allowed)
    if unknown:
        raise ConfigError(f"{context or 'config'}: unknown key {unknown[0]!r}; "
                          f"expected one of {', '.join(sorted(allowed))}")


def _int(value: Any, where: str, low: int = 1, high: int = 2**31) -> int:
    if isinstance(value, bool) or not isinstance(value, int):
        raise ConfigError(f"{where} must be an integer, got {value!r}")
    if not low <= value < high:
        raise ConfigError(f"{where} must be in [{low}, {high}), got {value}")
    return value


def _str(value: Any, where: str) -> str:
    if not isinstance(value, str) or not value.strip():
        raise ConfigError(f"{where} must be a non-empty string, got {value!r}")
    return value.strip()


def _params(value: Any, where: str, as_str: bool) -> dict:
    if value is None:
        return {}
    if not isinstance(value, dict):
        raise ConfigError(f"{where} must be a table of parameters, got {value!r}")
    out = {}
    for key, item in value.items():
        if isinstance(item, (dict, list)):
            raise ConfigError(f"{where}.{key} must be a number, string or boolean, got {item!r}")
        if as_str:
            item = ("true" if item else "false") if isinstance(item, bool) else str(item)
        out[str(key)] = item
    return out


def parse_config(data: dict, base_dir: Path | None = None, name: str = "study",
                 path: Path | None = None) -> StudyConfig:
    """Check the structure and numbers of a parsed TOML study (no scene loading)."""
    from ..errors import SamplerError
    from ..render.scene import check_sampler_name

    base_dir = base_dir or Path.cwd()
    _check_keys(data, _TOP_KEYS, "")
    for key in ("spp", "seeds", "samplers", "reference", "scenes"):
        if key not in data:
            raise ConfigError(f"missing required key {key!r}")

    spp_list = data["spp"]
    if not isinstance(spp_list, list) or not spp_list:
        raise ConfigError(f"spp must be a non-empty list of sample counts, got {spp_list!r}")
    spp = tuple(sorted({_int(v, "spp[]", 1, 2**20) for v in spp_list}))
    if len(spp) < 2:
        raise ConfigError("spp needs at least two distinct sample counts to fit a slope")

    seeds_value = data["seeds"]
    if isinstance(seeds_value, list):
        seeds = tuple(_int(v, "seeds[]", 0, 2**32) for v in seeds_value)
        if len(set(seeds)) != len(seeds):
            raise ConfigError("seeds must be distinct")
        if WARMUP_SEED in seeds:
            raise ConfigError(f"seed {WARMUP_SEED} is reserved for the warm-up render")
    else:
        seeds = tuple(range(_int(seeds_value, "seeds", 1, 1001)))
    if len(seeds) < 2:
        raise ConfigError("seeds: at least 2 are needed (spread and per-pixel variance)")

    image_spp = data.get("image_spp", spp[len(spp) // 2])
    _int(image_spp, "image_spp", 1, 2**20)
    if image_spp not in spp:
        raise ConfigError(f"image_spp ({image_spp}) must be one of spp {list(spp)}")
    draws = _int(data.get("aliasing_draws", STUDY_NULL_DRAWS), "aliasing_draws", 2, 100001)

    samplers_value = data["samplers"]
    if not isinstance(samplers_value, list) or not samplers_value:
        raise ConfigError("samplers must be a non-empty list of names or tables")
    samplers: list[SamplerSpec] = []
    for i, item in enumerate(samplers_value):
        where = f"samplers[{i}]"
        if isinstance(item, str):
            item = {"name": item}
        if not isinstance(item, dict):
            raise ConfigError(f"{where} must be a sampler name or a table, got {item!r}")
        _check_keys(item, _SAMPLER_KEYS, where)
        if "name" not in item:
            raise ConfigError(f"{where}: missing 'name'")
        sampler = _str(item["name"], f"{where}.name")
        try:
            check_sampler_name(sampler)
        except SamplerError as error:
            raise ConfigError(f"{where}: {error}") from None
        params = _params(item.get("params"), f"{where}.params", as_str=False)
        label = _str(item.get("label", sampler), f"{where}.label")
        if any(c in label for c in ",/\\\n\"<>&"):
            raise ConfigError(f"{where}.label {label!r}: use letters, digits, '.', '-', '_'")
        samplers.append(SamplerSpec(sampler, label, params))
    labels = [s.label for s in samplers]
    duplicate = next((x for x in labels if labels.count(x) > 1), None)
    if duplicate:
        raise ConfigError(f"sampler label {duplicate!r} appears twice; give each a distinct "
                          f"'label'")

    ref = data["reference"]
    if not isinstance(ref, dict):
        raise ConfigError("reference must be a table ([reference])")
    _check_keys(ref, _REFERENCE_KEYS, "reference")
    if "spp" not in ref:
        raise ConfigError("reference: missing 'spp'")
    reference = ReferenceSpec(
        spp=_int(ref["spp"], "reference.spp", 1, 2**31),
        sampler=_str(ref.get("sampler", "independent"), "reference.sampler"),
        seed=_int(ref.get("seed", 0), "reference.seed", 0, 2**32),
        spp_per_pass=(None if ref.get("spp_per_pass") is None
                      else _int(ref["spp_per_pass"], "reference.spp_per_pass", 1, 2**20)))
    try:
        check_sampler_name(reference.sampler)
    except SamplerError as error:
        raise ConfigError(f"reference.sampler: {error}") from None
    if reference.spp < MIN_REFERENCE_FACTOR * max(spp):
        raise ConfigError(f"reference.spp ({reference.spp}) must be at least "
                          f"{MIN_REFERENCE_FACTOR} x the largest spp ({max(spp)})")

    scenes_value = data["scenes"]
    if not isinstance(scenes_value, list) or not scenes_value:
        raise ConfigError("scenes must be a non-empty array of tables ([[scenes]])")
    scenes: list[SceneSpec] = []
    for i, item in enumerate(scenes_value):
        where = f"scenes[{i}]"
        if not isinstance(item, dict):
            raise ConfigError(f"{where} must be a table with a 'path'")
        _check_keys(item, _SCENE_KEYS, where)
        if "path" not in item:
            raise ConfigError(f"{where}: missing 'path'")
        scene_path = Path(_str(item["path"], f"{where}.path")).expanduser()
        if not scene_path.is_absolute():
            scene_path = (base_dir / scene_path).resolve()
        if not scene_path.is_file():
            raise ConfigError(f"{where}: scene file not found: {scene_path}")
        scene_name = _str(item.get("name", scene_path.stem), f"{where}.name")
        scenes.append(SceneSpec(scene_name, scene_path,
                                _params(item.get("params"), f"{where}.params", as_str=True)))
    names = [s.name for s in scenes]
    duplicate = next((x for x in names if names.count(x) > 1), None)
    if duplicate:
        raise ConfigError(f"scene name {duplicate!r} appears twice; give each a distinct 'name'")

    return StudyConfig(
        name=_str(data.get("name", name), "name"),
        description=str(data.get("description", "")).strip(),
        scenes=tuple(scenes), samplers=tuple(samplers), spp=spp, seeds=seeds,
        reference=reference, image_spp=image_spp, aliasing_draws=draws, path=path)


def load_config(path: str | Path, check_scenes: bool = True) -> StudyConfig:
    """Read and validate a study TOML file (see the module doc).

    With ``check_scenes`` every scene is loaded (parameters, plugins, film) and
    every sampler instantiated at every spp (parameters, effective sample count),
    so a study that starts will not fail on its input.
    """
    path = Path(path)
    if not path.is_file():
        raise ConfigError(f"study config not found: {path}")
    try:
        with open(path, "rb") as f:
            data = tomllib.load(f)
    except tomllib.TOMLDecodeError as error:
        raise ConfigError(f"{path}: invalid TOML: {error}") from None
    except OSError as error:
        raise ConfigError(f"cannot read {path}: {error.strerror}") from None
    config = parse_config(data, base_dir=path.resolve().parent, name=path.stem, path=path)
    if check_scenes:
        check_config(config)
    return config


def check_config(config: StudyConfig) -> None:
    """Load every scene and make every sampler, raising a one-line error on the
    first failure; fills ``config.effective_spp``."""
    from ..render.passes import sampling_integrator
    from ..render.plan import plan_scene
    from ..render.scene import make_sampler, quiet_sampler_warnings
    from ..render.trace import film_grid_size

    for spec in config.scenes:
        try:
            scene = plan_scene(spec.path, spec.params).scene
        except McrtError as error:
            raise ConfigError(f"scene {spec.name!r}: {error}") from None
        try:
            sampling_integrator(scene)
        except McrtError as error:
            raise ConfigError(f"scene {spec.name!r}: {error}") from None
        film = scene.sensors()[0].film()
        if not film.rfilter().is_box_filter():
            raise ConfigError(f"scene {spec.name!r}: the study needs a box reconstruction filter "
                              f"(references are box-binned per-pixel means); the film uses "
                              f"{film.rfilter().class_name()}")
        width, height = (int(v) for v in film_grid_size(film))
        if min(width, height) < MIN_SIZE:
            raise ConfigError(f"scene {spec.name!r} renders {width}x{height} pixels; the aliasing "
                              f"measure needs at least {MIN_SIZE}x{MIN_SIZE}")
    with quiet_sampler_warnings():
        for sampler in config.samplers:
            for spp in config.spp:
                try:
                    obj = make_sampler(sampler.name, spp, **sampler.params)
                except McrtError as error:
                    raise ConfigError(f"sampler {sampler.label!r} at {spp} spp: {error}") from None
                config.effective_spp[(sampler.label, spp)] = int(obj.sample_count())
    if config.reference.sampler != "independent":
        log.warning("reference sampler %s: its per-sample standard error overestimates the "
                    "noise of a stratified estimate, so the noise floor subtracted from every "
                    "MSE is too large; 'independent' makes it exact", config.reference.sampler)
    for sampler in config.samplers:
        changed = [f"{s}->{config.effective_spp[(sampler.label, s)]}" for s in config.spp
                   if config.effective_spp[(sampler.label, s)] != s]
        if changed:
            log.info("%s rounds sample counts: %s", sampler.label, ", ".join(changed))


# --------------------------------------------------------------------------- running


@dataclass
class ReferenceInfo:
    """What a scene's reference is and what its noise adds to every MSE."""

    scene: str
    spp: int
    sampler: str
    seconds: float
    noise_floor: float           # mean squared standard error (adds to every MSE)
    rel_noise_floor: float       # the same, weighted like relMSE
    width: int
    height: int
    cached: bool = False         # taken from mcrt's reference cache, not rendered now


@dataclass
class CellImages:
    """Images of one (scene, sampler) at the report's spp (seed = first seed)."""

    render: np.ndarray           # (H, W, 3) linear
    error: np.ndarray            # (H, W) luminance error vs the reference
    std: np.ndarray              # (H, W) per-pixel sd of the estimate across seeds


@dataclass
class StudyResult:
    config: StudyConfig
    references: dict[str, ReferenceInfo]
    cells: list[dict]
    fits: list[dict]
    reference_images: dict[str, np.ndarray]
    images: dict[tuple[str, str], CellImages]
    environment: dict
    seconds: float

    def cell(self, scene: str, sampler: str, spp: int) -> dict:
        for c in self.cells:
            if (c["scene"], c["sampler"], c["spp_requested"]) == (scene, sampler, spp):
                return c
        raise KeyError((scene, sampler, spp))

    def fit(self, scene: str, sampler: str) -> dict:
        for f in self.fits:
            if (f["scene"], f["sampler"]) == (scene, sampler):
                return f
        raise KeyError((scene, sampler))


def environment() -> dict:
    """Versions and machine facts recorded with every study."""
    import drjit as dr
    import mitsuba as mi

    from .. import __version__

    return {"mcrt": __version__, "mitsuba": mi.__version__, "drjit": dr.__version__,
            "variant": mi.variant(), "python": platform.python_version(),
            "platform": platform.platform(), "cpus": os.cpu_count(),
            "started": datetime.datetime.now(datetime.timezone.utc).isoformat(timespec="seconds")}


def _mean_sd(values: list[float]) -> tuple[float, float]:
    a = np.asarray(values, dtype=np.float64)
    return float(a.mean()), float(a.std(ddof=1)) if a.size > 1 else 0.0


class _Progress:
    """A tqdm bar over the study's renders, or nothing."""

    def __init__(self, total: int, enabled: bool):
        self.bar = None
        if enabled:
            from tqdm import tqdm

            self.bar = tqdm(total=total, unit="render", desc="study", dynamic_ncols=True)

    def describe(self, text: str) -> None:
        if self.bar is not None:
            self.bar.set_description(text, refresh=True)

    def note(self, text: str) -> None:
        if self.bar is not None:
            self.bar.write(text)
        else:
            log.info("%s", text)

    def update(self, n: int = 1) -> None:
        if self.bar is not None:
            self.bar.update(n)

    def close(self) -> None:
        if self.bar is not None:
            self.bar.close()


def run_study(config: StudyConfig, progress: bool = False) -> StudyResult:
    """Run every cell of a validated study; see the module doc for what is measured."""
    from ..render.passes import render_film
    from ..render.plan import plan_scene
    from ..render.scene import make_sampler, quiet_sampler_warnings
    from .reference import get_reference

    if not config.effective_spp:
        check_config(config)
    start = time.perf_counter()
    env = environment()
    bar = _Progress(config.renders, progress)
    references: dict[str, ReferenceInfo] = {}
    reference_images: dict[str, np.ndarray] = {}
    cells: list[dict] = []
    images: dict[tuple[str, str], CellImages] = {}
    k = len(config.seeds)
    try:
        for spec in config.scenes:
            bar.describe(f"{spec.name}: reference")
            bar.note(f"[{spec.name}] reference: {config.reference.sampler}, "
                     f"{config.reference.spp} spp")
            def on_pass(index: int, passes: int, name: str = spec.name) -> None:
                bar.describe(f"{name}: reference pass {index + 1}/{passes}")

            ref = get_reference(spec.path, spec.params, spp=config.reference.spp,
                                sampler=config.reference.sampler, seed=config.reference.seed,
                                spp_per_pass=config.reference.spp_per_pass, on_pass=on_pass)
            ref_mean = np.asarray(ref.mean, dtype=np.float64)
            ref_se = np.asarray(ref.standard_error, dtype=np.float64)
            ref_var = ref_se ** 2
            floor = reference_noise_floor(ref_se)
            rel_floor = float(np.mean(ref_var / (ref_mean ** 2 + REL_MSE_EPSILON)))
            height, width = ref_mean.shape[:2]
            references[spec.name] = ReferenceInfo(
                scene=spec.name, spp=int(ref.spp), sampler=config.reference.sampler,
                seconds=float(ref.seconds), noise_floor=floor, rel_noise_floor=rel_floor,
                width=int(width), height=int(height), cached=bool(getattr(ref, "cached", False)))
            reference_images[spec.name] = ref_mean
            planned = plan_scene(spec.path, spec.params)  # as `mcrt render` renders it
            scene = planned.scene

            def render(sampler_obj, seed: int):
                subframes, move = planned.schedule(sampler_obj, None, seed)
                return render_film(scene, sampler_obj, seed=seed, passes=subframes,
                                   on_pass=move)

            for sampler in config.samplers:
                for spp in config.spp:
                    bar.describe(f"{spec.name}: {sampler.label} {spp} spp")
                    with quiet_sampler_warnings():
                        render(make_sampler(sampler.name, spp, **sampler.params),
                               WARMUP_SEED)  # untimed: compiles/caches kernels
                    bar.update()
                    per_seed = []
                    renders = []
                    for seed in config.seeds:
                        with quiet_sampler_warnings():
                            obj = make_sampler(sampler.name, spp, **sampler.params)
                        result = render(obj, seed)
                        rgb = np.asarray(result.rgb, dtype=np.float64)
                        if rgb.shape != ref_mean.shape:
                            raise McrtError(f"scene {spec.name!r}: render shape {rgb.shape} "
                                            f"differs from the reference's {ref_mean.shape}")
                        bad = ~np.isfinite(rgb).all(axis=-1)
                        if bad.any():  # counted and reported; metrics see zero error there
                            log.warning("%s/%s/%d spp seed %d: %d pixels are NaN/Inf",
                                        spec.name, sampler.label, spp, seed, int(bad.sum()))
                            clean = np.where(bad[..., None], ref_mean, rgb)
                        else:
                            clean = rgb
                        score = aliasing_score(error_map(clean, ref_mean),
                                               null_draws=config.aliasing_draws, seed=seed)
                        per_seed.append({
                            "seed": seed, "spp": int(result.spp), "seconds": result.seconds,
                            "mse": mse(clean, ref_mean), "rel_mse": rel_mse(clean, ref_mean),
                            "delta_e": delta_e_2000(clean, ref_mean),
                            "nonfinite": int(bad.sum()), "aliasing": score.as_dict()})
                        renders.append(rgb)
                        bar.update()
                    stats = PixelStats.from_images(renders)
                    cell = _summarise_cell(spec.name, sampler, spp, per_seed, stats, ref_mean,
                                           ref_var, floor, k)
                    cells.append(cell)
                    if spp == config.image_spp:
                        first = np.where(np.isfinite(renders[0]), renders[0], ref_mean)
                        images[(spec.name, sampler.label)] = CellImages(
                            render=renders[0].astype(np.float32),
                            error=error_map(first, ref_mean).astype(np.float32),
                            std=np.sqrt(variance_map(stats.variance)).astype(np.float32))
    finally:
        bar.close()
    fits = [_fit_sampler(config, scene.name, sampler.label, cells)
            for scene in config.scenes for sampler in config.samplers]
    return StudyResult(config=config, references=references, cells=cells, fits=fits,
                       reference_images=reference_images, images=images, environment=env,
                       seconds=time.perf_counter() - start)


def _summarise_cell(scene: str, sampler: SamplerSpec, spp: int, per_seed: list[dict],
                    stats: PixelStats, ref_mean: np.ndarray, ref_var: np.ndarray,
                    floor: float, k: int) -> dict:
    seconds, seconds_sd = _mean_sd([r["seconds"] for r in per_seed])
    mse_mean, mse_sd = _mean_sd([r["mse"] for r in per_seed])
    rel_mean, rel_sd = _mean_sd([r["rel_mse"] for r in per_seed])
    de_mean, de_sd = _mean_sd([r["delta_e"] for r in per_seed])
    excess = mse_mean - floor
    resolved = bool(mse_mean > RESOLVED_FACTOR * floor)
    # The seed-averaged image: its pixels' variance is (between-seed variance) / K.
    b = bias(stats.mean, ref_mean, image_variance=stats.variance / k, reference_variance=ref_var)
    ratio_z = float(np.mean([r["aliasing"]["ratio_z"] for r in per_seed]))
    peak_z = float(np.mean([r["aliasing"]["peak_z"] for r in per_seed]))
    verdict = ("aliased" if ratio_z > Z_THRESHOLD or peak_z > Z_THRESHOLD
               else "blue" if ratio_z < -Z_THRESHOLD else "noise")
    return {
        "scene": scene, "sampler": sampler.label, "plugin": sampler.name,
        "params": dict(sampler.params), "spp_requested": spp,
        "spp": int(per_seed[0]["spp"]), "seeds": [r["seed"] for r in per_seed],
        "seconds": seconds, "seconds_sd": seconds_sd,
        "seconds_min": float(min(r["seconds"] for r in per_seed)),
        "mse": mse_mean, "mse_sd": mse_sd, "mse_floor": floor, "mse_excess": excess,
        "mse_of_mean": mse(stats.mean, ref_mean),
        "resolved": resolved,
        "rel_mse": rel_mean, "rel_mse_sd": rel_sd,
        "efficiency": efficiency(excess, seconds) if resolved else float("nan"),
        "variance": float(variance_map(stats.variance).mean()),
        "bias": b.value, "bias_low": b.low, "bias_high": b.high,
        "delta_e": de_mean, "delta_e_sd": de_sd,
        "aliasing_ratio": float(np.mean([r["aliasing"]["ratio"] for r in per_seed])),
        "aliasing_ratio_z": ratio_z,
        "aliasing_peak": float(np.mean([r["aliasing"]["peak"] for r in per_seed])),
        "aliasing_peak_z": peak_z, "aliasing": verdict,
        "nonfinite": int(sum(r["nonfinite"] for r in per_seed)),
        "per_seed": per_seed,
    }


def _fit_sampler(config: StudyConfig, scene: str, sampler: str, cells: list[dict]) -> dict:
    """Log-log slopes of the excess MSE vs spp and vs seconds over the resolved
    cells' per-seed values."""
    mine = [c for c in cells if c["scene"] == scene and c["sampler"] == sampler]
    used = [c for c in mine if c["resolved"]]
    x_spp, x_sec, y = [], [], []
    for c in used:
        for r in c["per_seed"]:
            x_spp.append(c["spp"])
            x_sec.append(r["seconds"])
            y.append(r["mse"] - c["mse_floor"])
    out: dict = {"scene": scene, "sampler": sampler, "points": len(y),
                 "cells_used": len(used), "cells": len(mine)}
    for key, x in (("spp", x_spp), ("seconds", x_sec)):
        try:
            fit = fit_loglog(x, y)
        except ValueError:
            out.update({f"slope_{key}": float("nan"), f"slope_{key}_se": float("nan"),
                        f"intercept_{key}": float("nan"), f"r2_{key}": float("nan")})
            continue
        out.update({f"slope_{key}": fit.slope, f"slope_{key}_se": fit.slope_se,
                    f"intercept_{key}": fit.intercept, f"r2_{key}": fit.r2})
    effs = [c["efficiency"] for c in mine if math.isfinite(c["efficiency"])]
    out["efficiency_max"] = max(effs) if effs else float("nan")
    return out


__all__ = ["CellImages", "ConfigError", "ReferenceInfo", "ReferenceSpec", "SamplerSpec",
           "SceneSpec", "StudyConfig", "StudyResult", "check_config", "load_config",
           "parse_config", "run_study"]
