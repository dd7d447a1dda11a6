"""Samplers made from a user's point sets: a generator function or a file.

Each becomes a subclass of the active variant's ``PointSetSampler`` with its
point source fixed; after a variant switch the registry's rebuild hook makes
the class again from the re-imported ``pointset`` module.
"""

from __future__ import annotations

import importlib
from collections.abc import Callable
from pathlib import Path

from ..errors import SamplerError
from . import registry


def points_class(name: str, *, points: Callable | None = None, file: str | Path | None = None,
                 sets: int | None = None, seed: int = 0, randomize: str = "symmetry",
                 claims: frozenset[str] = frozenset(), origin: str = "") -> str:
    """Register sampler ``name`` serving ``points`` (a generator) or ``file``."""
    from . import point_sources, pointset

    if randomize not in pointset.RANDOMIZATIONS:
        raise SamplerError(f"{name}: randomize must be one of "
                           f"{', '.join(pointset.RANDOMIZATIONS)}, got {randomize!r}")
    source: object
    if isinstance(seed, bool) or not isinstance(seed, int) or not 0 <= seed < 1 << 32:
        raise SamplerError(f"{name}: seed must be an integer in [0, 2^32), got {seed!r}")
    if points is not None:
        source = point_sources.GeneratorSource(
            points, point_sources.DEFAULT_SETS if sets is None else sets, seed, name)
        what = f"points from {getattr(points, '__name__', 'a generator')}()"
    else:
        if sets is not None:
            raise SamplerError(f"{name}: sets= is for generators; a file holds its own sets")
        source = point_sources.FileSource(_beside_plugin(file))  # type: ignore[arg-type]
        what = f"point sets of {Path(str(file)).name}"
    summary = f"{what}, {randomize}"
    # A plugin file's registration keeps naming the file after a variant switch.
    origin = origin or registry.default_origin("register_sampler")

    def make() -> type:
        module = importlib.import_module(f"{__package__}.pointset")
        return type(f"PointSet_{name}", (module.PointSetSampler,),
                    {"plugin_name": name, "source": source, "default_randomize": randomize,
                     "claims": claims, "summary": summary, "__doc__": summary,
                     "example_params": staticmethod(lambda spp: {})})

    fingerprint = source.digest

    def rebuild() -> None:
        registry.register_class(make(), name, origin=origin, rebuild=rebuild, kind="points",
                                fingerprint=fingerprint)

    rebuild()
    return name


def _beside_plugin(file: str | Path) -> str | Path:
    """A point-set file as a plugin file names it: a relative path is relative
    to the plugin's folder (as a study configuration's paths are to its file), so
    that the command an output records (the plugin by absolute path) reads the
    same file from any working directory; outside a plugin file, ``file`` as it
    is (relative to the working directory)."""
    plugin = Path(registry.default_origin())
    name = Path(str(file)).expanduser()
    if name.is_absolute() or plugin.suffix != ".py" or not plugin.is_file():
        return file
    return plugin.resolve().parent / name
