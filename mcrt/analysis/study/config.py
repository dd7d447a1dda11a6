"""A study's configuration: its schema, the TOML parser and the checks run before rendering.

:func:`parse_config` checks the structure and numbers of a parsed TOML
document, :func:`load_config` reads the file and (by default) runs
:func:`~mcrt.analysis.study.checks.check_config`, which loads every scene and
makes every sampler. Every
problem is reported as a one-line :class:`ConfigError`.
"""

from __future__ import annotations

import logging
import tomllib
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from ...core.provenance import FILE_PARAMS
from ...errors import McrtError
from ...plugins import file_digest

log = logging.getLogger("mcrt.compare")

#: Sign-flip draws of the aliasing null per render (the standalone default is 64;
#: 32 estimate the null sd to ~13%, plenty for a z threshold of 5, at half the cost).
STUDY_NULL_DRAWS = 32

#: Seed of the untimed warm-up render of each cell (never one of the measured seeds).
WARMUP_SEED = 0xFFFF_FF00

#: The reference must have at least this many times the study's largest spp.
MIN_REFERENCE_FACTOR = 4

#: Longest scene name (UTF-8 bytes): images_<name>.png must fit a 255-byte file name.
MAX_NAME_BYTES = 200

_TOP_KEYS = {"name", "description", "spp", "seeds", "image_spp", "aliasing_draws", "samplers",
             "reference", "scenes", "filters", "baseline", "time_rounds", "plugins"}

#: Timed renders per cell when the configuration does not say (at least one per seed):
#: five rounds keep the 95% interval of a cell's time within a few percent on a quiet
#: machine (BENCHMARKS.md, timing stability).
DEFAULT_TIME_ROUNDS = 5
#: Mitsuba's reconstruction filters, the values of a study's ``filters`` axis.
FILTERS = ("box", "tent", "gaussian", "mitchell", "catmullrom", "lanczos")
#: Joins a scene's name and a filter into the scene name of a ``filters`` study's cells.
FILTER_SEPARATOR = "~"
_REQUIRED_KEYS = ("spp", "seeds", "samplers", "reference", "scenes")
_REFERENCE_KEYS = {"spp", "sampler", "seed", "spp_per_pass", "params"}
_SCENE_KEYS = {"path", "name", "params"}
_SAMPLER_KEYS = {"name", "label", "params"}
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
    #: the film's filter set by the study's ``filters`` axis ("": the scene's own)
    rfilter: str = ""


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
    params: dict[str, Any] = field(default_factory=dict)  # the sampler's plugin parameters

    def sampler_text(self) -> str:
        """``pointset (filename=/x/sets.npy)``: the sampler and its parameters."""
        given = ", ".join(f"{k}={v}" for k, v in sorted(self.params.items()))
        return f"{self.sampler} ({given})" if given else self.sampler


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
    #: the ``filters`` axis (empty: every scene renders with its own filter)
    filters: tuple[str, ...] = ()
    #: the sampler label efficiencies are compared with (ratios and their intervals)
    baseline: str = ""
    #: timed renders per cell (0: :data:`DEFAULT_TIME_ROUNDS`); never fewer than the seeds
    time_rounds: int = 0
    #: effective sample count of every (sampler label, requested spp), filled by validation
    effective_spp: dict[tuple[str, int], int] = field(default_factory=dict)
    #: pixels of every scene's film grid (by scene name), filled by validation
    film_pixels: dict[str, int] = field(default_factory=dict)
    #: the user's sampler plugins (``plugins = [...]``, resolved), loaded by :func:`parse_config`
    plugins: tuple[Path, ...] = ()

    @property
    def cells(self) -> int:
        return len(self.scenes) * len(self.samplers) * len(self.spp)

    @property
    def rounds(self) -> int:
        """Timed renders per cell: one per seed (scored), then timing-only renders."""
        return max(self.time_rounds or DEFAULT_TIME_ROUNDS, len(self.seeds))

    @property
    def renders(self) -> int:
        """Renders of the study proper: per cell one warm-up and one per round."""
        return self.cells * (self.rounds + 1)

    def as_dict(self) -> dict[str, Any]:
        return {
            "name": self.name, "description": self.description,
            "config_path": str(self.path.resolve()) if self.path else None,  # any folder
            "spp": list(self.spp), "seeds": list(self.seeds), "image_spp": self.image_spp,
            "aliasing_draws": self.aliasing_draws, "baseline": self.baseline,
            "time_rounds": self.rounds,
            "reference": {"spp": self.reference.spp, "sampler": self.reference.sampler,
                          "seed": self.reference.seed,
                          "spp_per_pass": self.reference.spp_per_pass,
                          **({"params": self.reference.params} if self.reference.params
                             else {})},
            "scenes": [{"name": s.name, "path": str(s.path), "params": s.params,
                        "filter": s.rfilter} for s in self.scenes],
            "filters": list(self.filters),
            "samplers": [{"name": s.name, "label": s.label, "params": s.params}
                         for s in self.samplers],
            # Only when given (older studies keep their keys); a plugin's content is
            # part of its samplers, so its digest is recorded (and keys the saved state).
            **({"plugins": [{"path": str(p), "sha256": file_digest(p)} for p in self.plugins]}
               if self.plugins else {}),
        }


def cell_keys(config: StudyConfig) -> list[tuple[str, str, int]]:
    """(scene, sampler label, spp) of every cell, in the order a study runs them."""
    return [(scene.name, sampler.label, spp) for scene in config.scenes
            for sampler in config.samplers for spp in config.spp]


# --------------------------------------------------------------------------- value checks


def _check_keys(table: dict[str, Any], allowed: set[str], context: str) -> None:
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
    from ...core.sampling import check_sampler_name
    from ...errors import SamplerError

    name = _str(value, where)
    try:
        check_sampler_name(name)
    except SamplerError as error:
        raise ConfigError(f"{label}: {error}") from None
    return name


def _params(value: Any, where: str, as_str: bool) -> dict[str, Any]:
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


def _unique(names: list[str], what: str, key: str) -> None:
    duplicate = next((x for x in names if names.count(x) > 1), None)
    if duplicate:
        raise ConfigError(f"{what} {duplicate!r} appears twice; give each a distinct {key!r}")


def _description(value: Any) -> str:
    if not isinstance(value, str):
        raise ConfigError(f"description must be a string, got {value!r}")
    return value.strip()


# --------------------------------------------------------------------------- parsing


def parse_config(data: dict[str, Any], base_dir: Path | None = None, name: str = "study",
                 path: Path | None = None) -> StudyConfig:
    """Check the structure and numbers of a parsed TOML study (no scene loading)."""
    base_dir = base_dir or Path.cwd()
    _check_keys(data, _TOP_KEYS, "")
    for key in _REQUIRED_KEYS:
        if key not in data:
            raise ConfigError(f"missing required key {key!r}")
    spp = _parse_spp(data["spp"])
    seeds = _parse_seeds(data["seeds"])
    image_spp = data.get("image_spp", spp[len(spp) // 2])
    _int(image_spp, "image_spp", 1, 2**20)
    if image_spp not in spp:
        raise ConfigError(f"image_spp ({image_spp}) must be one of spp {list(spp)}")
    draws = _int(data.get("aliasing_draws", STUDY_NULL_DRAWS), "aliasing_draws", 2, 100001)
    plugins = _load_plugins(data.get("plugins"), base_dir)  # before any sampler name is checked
    samplers = _parse_samplers(data["samplers"], base_dir)
    reference = _parse_reference(data["reference"], max(spp), base_dir)
    filters = _parse_filters(data.get("filters"))
    scenes = _with_filters(_parse_scenes(data["scenes"], base_dir), filters)
    rounds = _int(data.get("time_rounds", max(DEFAULT_TIME_ROUNDS, len(seeds))), "time_rounds",
                  2, 1001)
    if rounds < len(seeds):
        raise ConfigError(f"time_rounds ({rounds}) must be at least the number of seeds "
                          f"({len(seeds)}): every seed's render is timed")
    return StudyConfig(
        name=_study_name(data.get("name", name)),
        description=_description(data.get("description", "")),
        scenes=scenes, samplers=samplers, spp=spp, seeds=seeds,
        reference=reference, image_spp=image_spp, aliasing_draws=draws, path=path,
        filters=filters, baseline=_baseline(data.get("baseline"), samplers),
        time_rounds=rounds, plugins=plugins)


def _baseline(value: Any, samplers: tuple[SamplerSpec, ...]) -> str:
    """The sampler label efficiencies are compared with: the configuration's, else
    ``independent`` (the plain Monte-Carlo estimator) when studied, else the first."""
    labels = [s.label for s in samplers]
    if value is None:
        return "independent" if "independent" in labels else labels[0]
    label = _str(value, "baseline")
    if label not in labels:
        raise ConfigError(f"baseline {label!r} is not one of the study's samplers "
                          f"({', '.join(labels)})")
    return label


def _load_plugins(value: Any, base_dir: Path) -> tuple[Path, ...]:
    """``plugins = ["my_sampler.py", ...]`` (relative to the configuration's folder):
    each file must exist; each is loaded now (see :mod:`mcrt.plugins`)."""
    if value is None:
        return ()
    if not isinstance(value, list) or not all(isinstance(v, str) and v.strip() for v in value):
        raise ConfigError(f"plugins must be a list of plugin files (strings), got {value!r}")
    from ...plugins import load_plugin

    paths = []
    for i, raw in enumerate(value):
        try:
            path = Path(raw.strip()).expanduser()
            path = (path if path.is_absolute() else base_dir / path).resolve()
            found = path.is_file()
        except (RuntimeError, ValueError, OSError) as error:
            raise ConfigError(f"plugins[{i}] {raw!r}: {error}") from None
        if not found:
            raise ConfigError(f"plugins[{i}]: plugin file not found: {path}")
        try:
            load_plugin(path)
        except McrtError as error:
            raise ConfigError(f"plugins[{i}]: {error}") from None
        paths.append(path)
    return tuple(dict.fromkeys(paths))


def _parse_spp(value: Any) -> tuple[int, ...]:
    if not isinstance(value, list) or not value:
        raise ConfigError(f"spp must be a non-empty list of sample counts, got {value!r}")
    spp = tuple(sorted({_int(v, "spp[]", 1, 2**20) for v in value}))
    if len(spp) < 2:
        raise ConfigError("spp needs at least two distinct sample counts to fit a slope")
    return spp


def _parse_seeds(value: Any) -> tuple[int, ...]:
    if isinstance(value, list):
        seeds = tuple(_int(v, "seeds[]", 0, 2**32) for v in value)
        if len(set(seeds)) != len(seeds):
            raise ConfigError("seeds must be distinct")
        if WARMUP_SEED in seeds:
            raise ConfigError(f"seed {WARMUP_SEED} is reserved for the warm-up render")
    else:
        seeds = tuple(range(_int(value, "seeds", 1, 1001)))
    if len(seeds) < 2:
        raise ConfigError("seeds: at least 2 are needed (spread and per-pixel variance)")
    return seeds


def _parse_samplers(value: Any, base_dir: Path) -> tuple[SamplerSpec, ...]:
    if not isinstance(value, list) or not value:
        raise ConfigError("samplers must be a non-empty list of names or tables")
    samplers = tuple(_parse_sampler(item, f"samplers[{i}]", base_dir)
                     for i, item in enumerate(value))
    _unique([s.label for s in samplers], "sampler label", "label")
    return samplers


def _parse_sampler(item: Any, where: str, base_dir: Path) -> SamplerSpec:
    if isinstance(item, str):
        item = {"name": item}
    if not isinstance(item, dict):
        raise ConfigError(f"{where} must be a sampler name or a table, got {item!r}")
    _check_keys(item, _SAMPLER_KEYS, where)
    if "name" not in item:
        raise ConfigError(f"{where}: missing 'name'")
    sampler = _sampler_name(item["name"], f"{where}.name", where)
    params = _sampler_params(item.get("params"), f"{where}.params", base_dir)
    label = _str(item.get("label", sampler), f"{where}.label")
    if any(c in label for c in _BAD_NAME_CHARS):
        raise ConfigError(f"{where}.label {label!r}: use letters, digits, '.', '-', '_'")
    return SamplerSpec(sampler, label, params)


def _sampler_params(value: Any, where: str, base_dir: Path) -> dict[str, Any]:
    """A sampler's ``params`` table: a point-set file relative to the configuration's
    folder (as scenes and plugins are); the spp and seeds are the study's own keys."""
    from ...core.sampling import RENDER_SETTINGS  # (mitsuba: imported when first needed)

    params = _params(value, where, as_str=False)
    reserved = sorted(set(params) & set(RENDER_SETTINGS))
    if reserved:
        raise ConfigError(f"{where}.{reserved[0]}: set by the study (spp and seeds are the "
                          f"study's own keys), not a sampler parameter")
    for key in FILE_PARAMS:
        if isinstance(params.get(key), str) and params[key]:
            params[key] = str((base_dir / params[key]).resolve())
    return params


def _parse_reference(ref: Any, max_spp: int, base_dir: Path) -> ReferenceSpec:
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
                      else _int(ref["spp_per_pass"], "reference.spp_per_pass", 1, 2**20)),
        params=_sampler_params(ref.get("params"), "reference.params", base_dir))
    if reference.spp < MIN_REFERENCE_FACTOR * max_spp:
        raise ConfigError(f"reference.spp ({reference.spp}) must be at least "
                          f"{MIN_REFERENCE_FACTOR} x the largest spp ({max_spp})")
    return reference


def _parse_scenes(value: Any, base_dir: Path) -> tuple[SceneSpec, ...]:
    if not isinstance(value, list) or not value:
        raise ConfigError("scenes must be a non-empty array of tables ([[scenes]])")
    scenes = tuple(_parse_scene(item, f"scenes[{i}]", base_dir) for i, item in enumerate(value))
    _unique([s.name for s in scenes], "scene name", "name")
    return scenes


def _parse_scene(item: Any, where: str, base_dir: Path) -> SceneSpec:
    if not isinstance(item, dict):
        raise ConfigError(f"{where} must be a table with a 'path'")
    _check_keys(item, _SCENE_KEYS, where)
    if "path" not in item:
        raise ConfigError(f"{where}: missing 'path'")
    scene_path = _scene_path(_str(item["path"], f"{where}.path"), where, base_dir)
    scene_name = _str(item.get("name", scene_path.stem), f"{where}.name")
    if any(c in scene_name for c in _BAD_NAME_CHARS) or scene_name in (".", ".."):
        raise ConfigError(f"{where}.name {scene_name!r} names report files: use letters, "
                          f"digits, '.', '-', '_'")
    if len(scene_name.encode()) > MAX_NAME_BYTES:
        raise ConfigError(f"{where}.name is {len(scene_name.encode())} bytes long; it names "
                          f"report files (images_<name>.png): at most {MAX_NAME_BYTES}")
    return SceneSpec(scene_name, scene_path,
                     _params(item.get("params"), f"{where}.params", as_str=True))


def _parse_filters(value: Any) -> tuple[str, ...]:
    if value is None:
        return ()
    if not isinstance(value, list) or not value:
        raise ConfigError(f"filters must be a non-empty list of filter names, got {value!r}")
    filters = tuple(_str(v, "filters[]") for v in value)
    unknown = next((f for f in filters if f not in FILTERS), None)
    if unknown is not None:
        raise ConfigError(f"filters: unknown filter {unknown!r}; expected {', '.join(FILTERS)}")
    _unique(list(filters), "filter", "filters")
    return filters


def _with_filters(scenes: tuple[SceneSpec, ...], filters: tuple[str, ...]
                  ) -> tuple[SceneSpec, ...]:
    """Every scene once per filter (``name~filter``), its film's filter replaced
    (:data:`mcrt.render.scene.RFILTER_PARAM`: references are made with it too)."""
    if not filters:
        return scenes
    from ...render.scene import RFILTER_PARAM

    return tuple(SceneSpec(f"{s.name}{FILTER_SEPARATOR}{f}", s.path,
                           {**s.params, RFILTER_PARAM: f}, rfilter=f)
                 for s in scenes for f in filters)


def _scene_path(raw_path: str, where: str, base_dir: Path) -> Path:
    """The scene file ``raw_path`` (relative to ``base_dir``), which must exist."""
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
    return scene_path


def _study_name(value: Any) -> str:
    study_name = _str(value, "name")
    if any(c in study_name for c in "/\\\0\n") or study_name in (".", ".."):
        raise ConfigError(f"name {study_name!r} names the default report directory: use "
                          f"letters, digits, '.', '-', '_'")
    return study_name


# --------------------------------------------------------------------------- loading


def load_config(path: str | Path, check_scenes: bool = True) -> StudyConfig:
    """Read and validate a study TOML file (see :mod:`mcrt.analysis.study`).

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
        raise ConfigError(f"{path}: invalid TOML: {' '.join(str(error).split())}") from None
    except UnicodeDecodeError:
        raise ConfigError(f"{path}: invalid TOML: not UTF-8 text") from None
    except OSError as error:
        raise ConfigError(f"cannot read {path}: {error.strerror}") from None
    config = parse_config(data, base_dir=path.resolve().parent, name=path.stem, path=path)
    if check_scenes:
        from .checks import check_config

        check_config(config)
    return config
