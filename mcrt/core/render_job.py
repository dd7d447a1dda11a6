"""A render as a resumable job: its key, where its checkpoint lives, what it must fit.

``mcrt render`` and any Python caller of :func:`~mcrt.core.render.render_film`
or :func:`~mcrt.render.adaptive.render_adaptive` resume the same way:

>>> key = render_key("scene.xml", {}, {}, "sobol", 64, seed=0, passes=None)  # doctest: +SKIP
>>> store = CheckpointStore(checkpoint_paths(Path("out/img.exr"), key), key)  # doctest: +SKIP
>>> film = render_film(scene, sampler, checkpoints=Checkpointing(
...     store.load(), store.save_periodic))  # doctest: +SKIP
>>> store.discard()  # once the outputs are written  # doctest: +SKIP

The key is the content of the scene (:func:`~mcrt.core.scene_files.scene_digest`)
and every setting, so a checkpoint is only ever resumed by the render that made it;
the checkpoint sits next to the output (``.OUT.exr.mcrt-resume.npz``), else in
mcrt's cache (``resume/KEY.npz``) where the output's folder cannot take it.
"""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

from ..cache import cache_dir
from .job import content_key
from .memory import film_bytes, require_memory
from .sampling import sampler_fingerprint
from .scene_files import scene_digest


def render_key(scene: str | Path, params: dict[str, str], overrides: dict[str, bool],
               sampler: str, spp: int, seed: int, passes: int | None, **settings: Any) -> str:
    """Identity of a render for resuming: the scene's content and every setting
    (and a user's sampler code, see :func:`~mcrt.core.sampling.sampler_fingerprint`)."""
    given = settings.get("sampler_params")  # a dict, or the EXR header's JSON text
    code = sampler_fingerprint(sampler, json.loads(given) if isinstance(given, str) else given)
    return content_key({"kind": "render", "scene": scene_digest(scene, params),
                        "params": sorted(params.items()), "effects": sorted(overrides.items()),
                        "sampler": sampler, "spp": spp, "seed": seed, "passes": passes,
                        "settings": settings, **({"sampler_code": code} if code else {})})


def checkpoint_paths(exr_path: Path, key: str) -> tuple[Path, Path]:
    """Where a render's checkpoint is kept: next to its output, else in the cache."""
    return (exr_path.with_name(f".{exr_path.name}.mcrt-resume.npz"),
            cache_dir("resume") / f"{key}.npz")


def require_render_memory(width: int, height: int, subpixels: int | None = None) -> None:
    """A one-line error before rendering if even the smallest pass of a
    ``width`` x ``height`` render cannot fit the memory available;
    ``subpixels``: an adaptive render's sub-pixel grid (None: a film render)."""
    pixels = width * height
    # adaptive: moments, counts, sub-pixel sums (4 channels) and their snapshot copies
    fixed = film_bytes(pixels) if subpixels is None else pixels * (72 + subpixels ** 2 * 40) * 3
    require_memory(pixels, fixed, f"a {width}x{height} render")


__all__ = ["checkpoint_paths", "render_key", "require_render_memory"]
