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

Interruption and resume: with a :class:`StudyState` (``mcrt compare`` keeps one
in ``<report dir>/.mcrt-resume/``) every finished cell is saved atomically as
soon as it is done, keyed by :func:`study_key` (the configuration's content,
the scenes' content and the software versions). A Ctrl-C raises
:class:`StudyInterrupted`, a ``KeyboardInterrupt`` carrying the partial
:class:`StudyResult` of the finished cells; the next run with the same key
takes the saved cells instead of rendering them again (cells, not seeds, are
the unit of resume: the seeds of an interrupted cell are rendered again).
"""

from __future__ import annotations

import datetime
import hashlib
import json
import logging
import math
import os
import platform
import shutil
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
from ..core.stats import PixelStats

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
#: Longest scene name (UTF-8 bytes): images_<name>.png must fit a 255-byte file name.
MAX_NAME_BYTES = 200
#: Characters refused in scene names and sampler labels (they name files and CSV cells).
_BAD_NAME_CHARS = ",/\\\n\r\t\0\"<>&:*?|"


class ConfigError(McrtError):
    """A study configuration is malformed or names something that does not exist.

    The message is kept on one line even when it quotes a value with line breaks.
    """

    def __init__(self, message: str):
        super().__init__(" ".join(str(message).splitlines()))


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


def _sampler_name(value: Any, where: str, label: str) -> str:
    """A known sampler name (ours or Mitsuba's); ``label`` prefixes the error."""
    from ..errors import SamplerError
    from ..render.scene import check_sampler_name

    name = _str(value, where)
    try:
        check_sampler_name(name)
    except SamplerError as error:
        raise ConfigError(f"{label}: {error}") from None
    return name


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
        sampler = _sampler_name(item["name"], f"{where}.name", where)
        params = _params(item.get("params"), f"{where}.params", as_str=False)
        reserved = sorted(set(params) & {"type", "sample_count", "seed"})
        if reserved:
            raise ConfigError(f"{where}.params.{reserved[0]}: set by the study (spp and seeds "
                              f"are the study's own keys), not a sampler parameter")
        label = _str(item.get("label", sampler), f"{where}.label")
        if any(c in label for c in _BAD_NAME_CHARS):
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
        sampler=_sampler_name(ref.get("sampler", "independent"), "reference.sampler",
                              "reference.sampler"),
        seed=_int(ref.get("seed", 0), "reference.seed", 0, 2**32),
        spp_per_pass=(None if ref.get("spp_per_pass") is None
                      else _int(ref["spp_per_pass"], "reference.spp_per_pass", 1, 2**20)))
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
        raw_path = _str(item["path"], f"{where}.path")
        try:
            scene_path = Path(raw_path).expanduser()  # "~nobody/x": RuntimeError
            if not scene_path.is_absolute():
                scene_path = (base_dir / scene_path).resolve()  # a NUL: ValueError
            found = scene_path.is_file()  # a name too long: OSError
        except (RuntimeError, ValueError, OSError) as error:
            reason = error.strerror if isinstance(error, OSError) else error
            raise ConfigError(f"{where}.path {raw_path!r}: {reason}") from None
        if not found:
            raise ConfigError(f"{where}: scene file not found: {scene_path}")
        scene_name = _str(item.get("name", scene_path.stem), f"{where}.name")
        if any(c in scene_name for c in _BAD_NAME_CHARS) or scene_name in (".", ".."):
            raise ConfigError(f"{where}.name {scene_name!r} names report files: use letters, "
                              f"digits, '.', '-', '_'")
        if len(scene_name.encode()) > MAX_NAME_BYTES:
            raise ConfigError(f"{where}.name is {len(scene_name.encode())} bytes long; it names "
                              f"report files (images_<name>.png): at most {MAX_NAME_BYTES}")
        scenes.append(SceneSpec(scene_name, scene_path,
                                _params(item.get("params"), f"{where}.params", as_str=True)))
    names = [s.name for s in scenes]
    duplicate = next((x for x in names if names.count(x) > 1), None)
    if duplicate:
        raise ConfigError(f"scene name {duplicate!r} appears twice; give each a distinct 'name'")

    study_name = _str(data.get("name", name), "name")
    if any(c in study_name for c in "/\\\0\n") or study_name in (".", ".."):
        raise ConfigError(f"name {study_name!r} names the default report directory: use "
                          f"letters, digits, '.', '-', '_'")
    return StudyConfig(
        name=study_name,
        description=_description(data.get("description", "")),
        scenes=tuple(scenes), samplers=tuple(samplers), spp=spp, seeds=seeds,
        reference=reference, image_spp=image_spp, aliasing_draws=draws, path=path)


def _one_line(error: BaseException) -> str:
    return " ".join(str(error).split())


def _description(value: Any) -> str:
    if not isinstance(value, str):
        raise ConfigError(f"description must be a string, got {value!r}")
    return value.strip()


def load_config(path: str | Path, check_scenes: bool = True) -> StudyConfig:
    """Read and validate a study TOML file (see the module doc).

    With ``check_scenes`` every scene is loaded (parameters, plugins, film) and
    every sampler instantiated at every spp (parameters, effective sample count),
    so a study that starts will not fail on its input.
    """
    path = Path(path)
    try:
        if path.is_dir():
            raise ConfigError(f"study config {path} is a directory, not a TOML file")
        if not path.is_file():
            raise ConfigError(f"study config not found: {path}")
        with open(path, "rb") as f:
            data = tomllib.load(f)
    except tomllib.TOMLDecodeError as error:
        raise ConfigError(f"{path}: invalid TOML: {_one_line(error)}") from None
    except UnicodeDecodeError:
        raise ConfigError(f"{path}: invalid TOML: not UTF-8 text") from None
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
    """What a study measured; ``partial`` when it was interrupted (see ``progress``)."""

    config: StudyConfig
    references: dict[str, ReferenceInfo]
    cells: list[dict]
    fits: list[dict]
    reference_images: dict[str, np.ndarray]
    images: dict[tuple[str, str], CellImages]
    environment: dict
    seconds: float
    #: the cell being rendered when the study was interrupted, with its seeds done
    #: (``{"scene", "sampler", "spp", "seeds_done", "seeds_total"}``), else None
    interrupted: dict | None = None
    #: cells taken from an earlier run's saved state instead of being rendered
    resumed_cells: int = 0
    #: how to resume a partial study (set by the command line)
    resume_command: str | None = None

    @property
    def partial(self) -> bool:
        """True when some cells of the configuration were not measured."""
        return len(self.cells) < self.config.cells

    @property
    def scenes(self) -> list[str]:
        """Scenes with a reference (all of them unless the study was interrupted)."""
        return [s.name for s in self.config.scenes if s.name in self.references]

    def pending(self) -> list[tuple[str, str, int]]:
        """(scene, sampler label, spp) of every cell not measured, in study order."""
        done = {(c["scene"], c["sampler"], c["spp_requested"]) for c in self.cells}
        return [key for key in cell_keys(self.config) if key not in done]

    def progress(self) -> dict:
        """Cells done / total, the interrupted cell, the pending cells (JSON-ready)."""
        return {"partial": self.partial, "cells_done": len(self.cells),
                "cells_total": self.config.cells, "cells_resumed": self.resumed_cells,
                "seeds_per_cell": len(self.config.seeds), "interrupted": self.interrupted,
                "pending": [{"scene": a, "sampler": b, "spp": c} for a, b, c in self.pending()],
                "resume": self.resume_command if self.partial else None}

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


class StudyInterrupted(KeyboardInterrupt):
    """Ctrl-C during :func:`run_study`; ``result`` holds the finished cells."""

    def __init__(self, result: StudyResult):
        super().__init__("study interrupted")
        self.result = result


def cell_keys(config: StudyConfig) -> list[tuple[str, str, int]]:
    """(scene, sampler label, spp) of every cell, in the order a study runs them."""
    return [(scene.name, sampler.label, spp) for scene in config.scenes
            for sampler in config.samplers for spp in config.spp]


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


# --------------------------------------------------------------------------- resume state

#: Directory of the resume state inside a report directory.
STATE_DIR = ".mcrt-resume"

#: Version of the state's layout; a state of another format is ignored.
STATE_FORMAT = 1


def study_key(config: StudyConfig) -> str:
    """SHA-256 (hex, 32 digits) of everything a study's numbers depend on.

    The parsed configuration (not its bytes: comments, the study's name and
    description do not change a measurement), the content of every scene file
    (with the files it includes, :func:`~mcrt.analysis.reference.scene_digest`)
    and the versions of mcrt, Mitsuba and Dr.Jit. A saved state with another
    key belongs to another study and is never resumed.
    """
    import drjit as dr
    import mitsuba as mi

    from .. import __version__
    from .reference import scene_digest

    study = config.as_dict()
    for key in ("name", "description", "config_path"):
        study.pop(key, None)
    payload = {"format": STATE_FORMAT, "study": study,
               "scenes": [scene_digest(s.path, s.params) for s in config.scenes],
               "versions": [__version__, mi.__version__, dr.__version__, mi.variant()]}
    text = json.dumps(payload, sort_keys=True, separators=(",", ":"), default=str)
    return hashlib.sha256(text.encode()).hexdigest()[:32]


def _plain(value: Any) -> Any:
    """JSON-ready copy keeping NaN/Inf (Python's json writes and reads them back)."""
    if isinstance(value, dict):
        return {str(k): _plain(v) for k, v in value.items()}
    if isinstance(value, (list, tuple)):
        return [_plain(v) for v in value]
    if isinstance(value, (bool, np.bool_)):
        return bool(value)
    if isinstance(value, (int, np.integer)):
        return int(value)
    if isinstance(value, (float, np.floating)):
        return float(value)
    if isinstance(value, Path):
        return str(value)
    return value


def reference_fingerprint(mean: np.ndarray, standard_error: np.ndarray) -> str:
    """SHA-256 of a reference's float64 mean and standard error: the cells
    measured against one reference are only resumed against the same bits."""
    digest = hashlib.sha256()
    for array in (mean, standard_error):
        a = np.ascontiguousarray(array, dtype=np.float64)
        digest.update(repr(a.shape).encode() + a.tobytes())
    return digest.hexdigest()[:32]


class StudyState:
    """Finished cells of a study, saved after every cell so that a run can resume.

    Lives in ``<report dir>/.mcrt-resume/``: ``state.json`` (the key, the
    reference fingerprints and every finished cell with its per-seed values)
    and one ``.npz`` per (scene, sampler) with the report's images. Every file
    is written atomically and the images before the ``state.json`` that
    refers to them, so a kill at any moment leaves a consistent state.
    """

    def __init__(self, directory: str | os.PathLike, key: str):
        self.directory = Path(directory)
        self.key = key
        self.cells: dict[tuple[str, str, int], dict] = {}
        self.references: dict[str, str] = {}
        self.seconds = 0.0
        self.runs = 0
        self.writable = True

    @property
    def path(self) -> Path:
        return self.directory / "state.json"

    @classmethod
    def open(cls, report_dir: str | os.PathLike, config: StudyConfig,
             restart: bool = False) -> StudyState:
        """The saved state of ``config`` in ``report_dir``, or an empty one.

        A state that is unreadable, of another format or of another study
        (another :func:`study_key`) is ignored with a note (and replaced by the
        first cell this run saves); ``restart`` deletes any saved state. Nothing
        is written here: the directory is created by the first :meth:`add`.
        """
        state = cls(Path(report_dir) / STATE_DIR, study_key(config))
        if restart:
            state.clear()
        if not state.path.exists():
            return state
        try:
            data = json.loads(state.path.read_text(encoding="utf-8"))
            if not isinstance(data, dict) or data.get("format") != STATE_FORMAT:
                raise ValueError("unknown format")
            if data.get("key") != state.key:
                log.info("%s belongs to another configuration (or other scene files or "
                         "versions); starting afresh", state.path)
                return state
            keys = set(cell_keys(config))
            for cell in data["cells"]:
                key = (cell["scene"], cell["sampler"], int(cell["spp_requested"]))
                if key in keys:
                    state.cells[key] = cell
            state.references = {str(k): str(v) for k, v in data["references"].items()}
            state.seconds = float(data.get("seconds", 0.0))
            state.runs = int(data.get("runs", 0))
        except (OSError, ValueError, KeyError, TypeError, AttributeError) as error:
            log.warning("ignoring unreadable resume state %s (%s)", state.path, error)
            state.cells.clear()
            state.references.clear()
        return state

    def _image_path(self, scene: str, label: str) -> Path:
        name = hashlib.sha256(f"{scene}\0{label}".encode()).hexdigest()[:16]
        return self.directory / f"images_{name}.npz"

    def images(self, scene: str, label: str) -> CellImages | None:
        """The saved images of (scene, sampler), or None if missing or unreadable."""
        try:
            with np.load(self._image_path(scene, label), allow_pickle=False) as data:
                return CellImages(render=data["render"], error=data["error"], std=data["std"])
        except (OSError, ValueError, KeyError):
            return None

    def check_reference(self, scene: str, fingerprint: str) -> None:
        """Forget the cells of ``scene`` if its reference changed since they were measured."""
        old = self.references.get(scene)
        if old is not None and old != fingerprint:
            stale = [key for key in self.cells if key[0] == scene]
            if stale:
                log.info("the reference of %s changed: %d saved cells are measured again",
                         scene, len(stale))
            for key in stale:
                del self.cells[key]
        self.references[scene] = fingerprint

    def add(self, cell: dict, images: CellImages | None, seconds: float) -> None:
        """Record a finished cell (and its images) and save; a write failure
        (disk full, ...) is logged once and turns saving off, the study goes on."""
        key = (cell["scene"], cell["sampler"], cell["spp_requested"])
        self.cells[key] = _plain(cell)
        if not self.writable:
            return
        from ..core.atomic import atomic_path

        try:
            self.directory.mkdir(parents=True, exist_ok=True)
            if images is not None:
                with atomic_path(self._image_path(cell["scene"], cell["sampler"])) as tmp, \
                        open(tmp, "wb") as f:
                    np.savez(f, render=images.render, error=images.error, std=images.std)
            self.save(seconds)
        except (McrtError, OSError) as error:
            log.warning("cannot save the resume state (%s); the study goes on, but an "
                        "interruption will lose the cells not saved", error)
            self.writable = False

    def save(self, seconds: float) -> None:
        """Write ``state.json`` atomically (``seconds``: study time so far, all runs)."""
        from .. import __version__
        from ..core.atomic import atomic_path

        data = {"format": STATE_FORMAT, "key": self.key, "mcrt": __version__,
                "runs": self.runs + 1, "seconds": seconds, "references": self.references,
                "cells": list(self.cells.values())}
        text = json.dumps(data, indent=0)  # NaN stays NaN: json reads it back
        with atomic_path(self.path) as tmp, open(tmp, "w", encoding="utf-8") as f:
            f.write(text + "\n")

    def clear(self) -> None:
        """Delete the saved state (``--restart``)."""
        shutil.rmtree(self.directory, ignore_errors=True)


# --------------------------------------------------------------------------- running


def run_study(config: StudyConfig, progress: bool = False,
              state: StudyState | None = None) -> StudyResult:
    """Run every cell of a validated study; see the module doc for what is measured.

    With ``state``, cells saved there are taken instead of rendered and every
    cell finished now is added to it. Ctrl-C raises :class:`StudyInterrupted`
    with the result of the cells finished so far.
    """
    from ..render.passes import render_film
    from ..render.plan import plan_scene
    from ..render.scene import make_sampler, quiet_sampler_warnings
    from .reference import get_reference

    if not config.effective_spp:
        check_config(config)
    start = time.perf_counter()
    before = state.seconds if state is not None else 0.0
    env = environment()
    if state is not None and state.cells:
        env["resumed"] = True
    bar = _Progress(config.renders, progress)
    references: dict[str, ReferenceInfo] = {}
    reference_images: dict[str, np.ndarray] = {}
    cells: list[dict] = []
    images: dict[tuple[str, str], CellImages] = {}
    k = len(config.seeds)
    current: dict | None = None
    resumed = 0

    def result(interrupted: dict | None = None) -> StudyResult:
        fits = [_fit_sampler(config, scene, sampler.label, cells)
                for scene in references for sampler in config.samplers]
        return StudyResult(config=config, references=references, cells=cells, fits=fits,
                           reference_images=reference_images, images=images, environment=env,
                           seconds=before + time.perf_counter() - start,
                           interrupted=interrupted, resumed_cells=resumed)

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
            if state is not None:
                state.check_reference(spec.name, reference_fingerprint(ref_mean, ref_se))
            planned = None

            def render(sampler_obj, seed: int):
                subframes, move = planned.schedule(sampler_obj, None, seed)
                return render_film(planned.scene, sampler_obj, seed=seed, passes=subframes,
                                   on_pass=move)

            for sampler in config.samplers:
                for spp in config.spp:
                    saved = state.cells.get((spec.name, sampler.label, spp)) if state else None
                    saved_images = (state.images(spec.name, sampler.label)
                                    if saved is not None and spp == config.image_spp else None)
                    if saved is not None and (spp != config.image_spp or saved_images):
                        cells.append(saved)
                        if saved_images is not None:
                            images[(spec.name, sampler.label)] = saved_images
                        resumed += 1
                        bar.update(k + 1)
                        continue
                    if planned is None:
                        planned = plan_scene(spec.path, spec.params)  # as `mcrt render` does
                    bar.describe(f"{spec.name}: {sampler.label} {spp} spp")
                    per_seed = []
                    current = {"scene": spec.name, "sampler": sampler.label, "spp": spp,
                               "seeds_done": 0, "seeds_total": k}
                    with quiet_sampler_warnings():
                        render(make_sampler(sampler.name, spp, **sampler.params),
                               WARMUP_SEED)  # untimed: compiles/caches kernels
                    bar.update()
                    renders = []
                    for seed in config.seeds:
                        with quiet_sampler_warnings():
                            obj = make_sampler(sampler.name, spp, **sampler.params)
                        result_ = render(obj, seed)
                        rgb = np.asarray(result_.rgb, dtype=np.float64)
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
                            "seed": seed, "spp": int(result_.spp), "seconds": result_.seconds,
                            "mse": mse(clean, ref_mean), "rel_mse": rel_mse(clean, ref_mean),
                            "delta_e": delta_e_2000(clean, ref_mean),
                            "nonfinite": int(bad.sum()), "aliasing": score.as_dict()})
                        renders.append(rgb)
                        current["seeds_done"] = len(per_seed)
                        bar.update()
                    stats = PixelStats.from_images(renders)
                    cell = _plain(_summarise_cell(spec.name, sampler, spp, per_seed, stats,
                                                  ref_mean, ref_var, floor, k))
                    cell_images = None
                    if spp == config.image_spp:
                        first = np.where(np.isfinite(renders[0]), renders[0], ref_mean)
                        cell_images = CellImages(
                            render=renders[0].astype(np.float32),
                            error=error_map(first, ref_mean).astype(np.float32),
                            std=np.sqrt(variance_map(stats.variance)).astype(np.float32))
                        images[(spec.name, sampler.label)] = cell_images
                    cells.append(cell)
                    current = None
                    if state is not None:
                        state.add(cell, cell_images, before + time.perf_counter() - start)
    except _interrupts():
        raise StudyInterrupted(result(current)) from None
    finally:
        bar.close()
    return result()


def _interrupts() -> tuple[type[BaseException], ...]:
    """What a Ctrl-C raises out of a render: ``KeyboardInterrupt``, or the render
    module's own ``RenderInterrupted`` (which carries the render's partial
    passes, of no use to a study: a cell needs all of its seeds' full renders)."""
    from ..render import passes

    own = getattr(passes, "RenderInterrupted", None)
    if isinstance(own, type) and issubclass(own, BaseException) \
            and not issubclass(own, KeyboardInterrupt):
        return (KeyboardInterrupt, own)
    return (KeyboardInterrupt,)


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
    cells' per-seed values (NaN unless at least two sample counts are resolved:
    the timing scatter of one cell's seeds is not a slope)."""
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
            if len({c["spp"] for c in used}) < 2:  # one cell's seed scatter is no slope
                raise ValueError("fewer than two resolved sample counts")
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


__all__ = ["STATE_DIR", "CellImages", "ConfigError", "ReferenceInfo", "ReferenceSpec",
           "SamplerSpec", "SceneSpec", "StudyConfig", "StudyInterrupted", "StudyResult",
           "StudyState", "cell_keys", "check_config", "load_config", "parse_config",
           "reference_fingerprint", "run_study", "study_key"]
