"""``mcrt render --from FILE.exr``: render again what an EXR file records, and
say whether the pixels came out the same, bit for bit.

Every EXR mcrt writes records the ``command`` that renders it
(:mod:`mcrt.core.provenance`): ``mcrt render`` and ``mcrt render --adaptive``
files, ``mcrt reference`` files (rendered again without the reference cache) and
a study's images (a seed's render; the mean over the study's seeds, each seed
rendered by the command and folded in seed order as the study folds them). The
variant and the user's plugins come from the command too. Exit status 0 when
the new file's pixels equal the old file's bit for bit, 1 when they differ (the
note says by how much), 2 when the file cannot be rendered again.
"""

from __future__ import annotations

import argparse
import contextlib
import io
import json
import logging
import tempfile
from pathlib import Path

import numpy as np

from ..core.provenance import (
    COMMAND,
    command_words,
    scene_facts,
    software,
    software_changes,
)
from ..errors import McrtError
from ..io import read_exr, write_exr
from ._common import check_output_files, output_stem

log = logging.getLogger("mcrt.render")

#: The options that set what a render renders, by ``argparse`` destination.
_SETTINGS = {"scene": "SCENE.xml", "sampler": "--sampler", "sampler_params": "-P",
             "spp": "--spp", "seed": "--seed", "defines": "-D", "effect": "--effect",
             "multisample": "--multisample", "adaptive": "--adaptive"}


def run_from(args: argparse.Namespace) -> int:
    source = Path(args.from_exr)
    _refuse_settings(args, source)
    layers, header = read_exr(source)
    words = command_words(header, source)
    if header.get("partial"):
        raise McrtError(f"{source} is a partial render (interrupted): its own command "
                        f"finishes it: {header[COMMAND]}")
    stem = output_stem(args.output, f"{source.stem}_again") if args.output \
        else source.with_name(f"{source.stem}_again")
    if stem.with_suffix(".exr").resolve() == source.resolve():
        raise McrtError(f"-o {args.output}: that is {source} itself; write elsewhere")
    _note_scene_changes(words, header, source)
    changes = software_changes(header)
    if changes:
        log.warning("%s was written by other software: %s; the pixels may differ for that "
                    "reason", source, "; ".join(changes))
    extra = ["--cluster", args.cluster] if getattr(args, "cluster", None) else []
    log.info("rendering again: %s", header[COMMAND])
    image: np.ndarray | None
    if header.get("mcrt_kind") == "study_mean":
        out, image = _mean_over_seeds(words, header, stem, extra)
    else:
        if header.get("mcrt_kind") in ("reference", "study_reference"):
            extra.append("--no-cache")  # rendered again, not found in the cache
        code = _mcrt([*words, *extra, "-o", str(stem)], args.quiet)
        if code:
            return code
        out = stem.with_suffix(".exr")
        image = _film_image(read_exr(out)[0])
    return _compare(out, image, source, _film_image(layers), bool(changes))


#: The film's own channels when they are not R, G, B [A] (the ``rgb`` layer): the
#: unprefixed channels of an XYZ, XYZA or luminance-alpha film, in this order.
_FILM_CHANNELS = ("X", "Y", "Z", "A")


def _film_image(layers: dict[str, np.ndarray]) -> np.ndarray | None:
    """The film's image among :func:`~mcrt.io.read_exr`'s layers: the ``rgb`` layer
    (R G B [A], or a luminance film's Y), else the film's unprefixed channels
    stacked (X Y Z [A], Y A); None when the file has neither."""
    if "rgb" in layers:
        return layers["rgb"]
    names = [c for c in _FILM_CHANNELS if c in layers]
    return np.stack([layers[c] for c in names], axis=-1) if names else None


def _refuse_settings(args: argparse.Namespace, source: Path) -> None:
    """``--from`` takes every setting from the file: refuse any given beside it."""
    from ._adaptive_args import cli_parameters

    given = [flag for dest, flag in _SETTINGS.items() if getattr(args, dest, None)]
    given += [p.flag for p in cli_parameters()
              if getattr(args, f"adaptive_{p.name}", None) is not None]
    if given:
        raise McrtError(f"--from {source} takes every setting from the file; drop "
                        f"{', '.join(dict.fromkeys(given))} (only -o, -q and --cluster go "
                        f"with it)")


def _mcrt(words: list[str], quiet: bool) -> int:
    from . import main

    return main([*(["-q"] if quiet else []), *words])


def _note_scene_changes(words: list[str], header: dict, source: Path) -> None:
    """A note when the scene's files are not what they were when ``source`` was
    written (the pixels will then differ, and the note says why)."""
    command = next(i for i, w in enumerate(words) if w in ("render", "reference"))
    scene = words[command + 1]
    params = dict(w.split("=", 1) for i, w in enumerate(words) if i and words[i - 1] == "-D")
    recorded = header.get("scene_digest")
    now = scene_facts(scene, params).get("scene_digest")
    if recorded and now != recorded:
        log.warning("%s's files are not what they were when %s was written (scene digest "
                    "%s..., now %s): the pixels will differ", scene, source, recorded[:12],
                    (now or "unreadable")[:12])


def _mean_over_seeds(words: list[str], header: dict, stem: Path, extra: list[str]
                     ) -> tuple[Path, np.ndarray]:
    """A study's mean image again: each of its seeds rendered by the recorded
    command, folded in seed order as the study folds them."""
    from ..analysis.study.summary import cell_renders
    from ..core.stats import PixelStats

    seeds = [int(s) for s in json.loads(str(header.get("seeds", "[]")))]
    if not seeds:
        raise McrtError("the file records no seeds to render")
    out = stem.with_suffix(".exr")
    check_output_files(out)
    renders = []
    with tempfile.TemporaryDirectory(prefix="mcrt-from-") as folder, \
            contextlib.redirect_stdout(io.StringIO()):  # each seed's "wrote ..." is a temporary
        for i, seed in enumerate(seeds):
            log.info("seed %d (%d of %d)", seed, i + 1, len(seeds))
            seed_stem = Path(folder) / f"seed{seed}"
            code = _mcrt([*words, "--seed", str(seed), *extra, "-o", str(seed_stem)], True)
            if code:
                raise McrtError(f"the render of seed {seed} failed (exit status {code})")
            renders.append(np.asarray(read_exr(seed_stem.with_suffix(".exr"))[0]["rgb"],
                                      np.float32)[..., :3])
    views = cell_renders(renders, PixelStats.from_images(renders))
    out.parent.mkdir(parents=True, exist_ok=True)
    write_exr(out, {"rgb": views.mean, "variance": views.variance}, {**header, **software()})
    print(f"wrote {out} (the mean over {len(seeds)} seeds)")
    return out, views.mean


def _compare(out: Path, image: np.ndarray | None, source: Path, original: np.ndarray | None,
             other_software: bool = False) -> int:
    """Say whether ``image`` (written to ``out``) equals ``source``'s pixels bit for bit."""
    if original is None or image is None:
        raise McrtError(f"{source if original is None else out} has no film image (R G B, "
                        f"X Y Z or Y) to compare")
    new = np.asarray(image, np.float32)
    old = np.asarray(original, np.float32)
    channels = min(new.shape[-1], old.shape[-1]) if new.ndim == 3 else None
    if channels is not None:
        new, old = new[..., :channels], old[..., :channels]
    if new.shape == old.shape and np.array_equal(new.view(np.uint32), old.view(np.uint32)):
        print(f"{out}: the same pixels as {source}, bit for bit")
        return 0
    if new.shape != old.shape:
        print(f"{out}: {new.shape[1]}x{new.shape[0]} pixels, {source} has "
              f"{old.shape[1]}x{old.shape[0]}")
        return 1
    differ = np.any(new.view(np.uint32) != old.view(np.uint32), axis=-1)
    gap = np.abs(np.nan_to_num(new.astype(np.float64) - old))
    print(f"{out}: {int(differ.sum())} of {differ.size} pixels differ from {source} "
          f"(largest difference {float(gap.max()):.3g})"
          + (" -- it was written by other software (noted above)" if other_software else ""))
    return 1


__all__ = ["run_from"]
