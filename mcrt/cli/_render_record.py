"""What ``mcrt render`` records about a render, and the check that keeps a default
output name from silently replacing a different render.

The header of a render's EXR holds every setting that changes its pixels (the
sampler and its parameters, seed, samples per pixel, ``-D`` parameters, effect
overrides, ``--multisample``, the adaptive settings, the film's filter, the
plan, the variant and the user's plugins), the scene's content digest, the
versions of mcrt, Mitsuba and Dr.Jit, and the ``command`` that renders it
again (:mod:`mcrt.core.provenance`; ``mcrt render --from FILE.exr``).
"""

from __future__ import annotations

import argparse
import json
import logging
import shlex
from dataclasses import asdict
from pathlib import Path
from typing import Any

from ..core.provenance import (
    COMMAND,
    absolute,
    command_text,
    define_word,
    param_word,
    scene_facts,
    software,
)
from ..core.sampling import sampler_fingerprint, sampler_name
from ..core.sampling import sampler_params as sampler_params_of
from ..errors import McrtError

log = logging.getLogger("mcrt.render")

#: Header keys of the settings that change a render's pixels (compared before
#: a default output name replaces a file).
SETTINGS = ("variant", "plugins", "scene", "defines", "sampler", "sampler_params", "spp_requested",
            "seed", "effect_overrides", "multisample", "adaptive")


def render_words(args: argparse.Namespace, spp: int) -> list[str]:
    """The render's arguments after ``render``, every one that changes its pixels
    (the scene by absolute path; no ``-o``)."""
    from ..core.scene_files import working_directory_files
    from ..render.scene import parse_defines
    from ._adaptive_args import cli_parameters

    words = [absolute(args.scene)]
    if args.sampler:  # else the scene's own sampler, with its own parameters
        words += ["--sampler", args.sampler]
        words += [w for p in getattr(args, "sampler_params", None) or []
                  for w in ("-P", param_word(p))]
    words += ["--spp", str(spp), "--seed", str(args.seed)]
    local = working_directory_files(args.scene, parse_defines(args.defines))
    words += [w for d in args.defines or [] for w in ("-D", define_word(d, local))]
    words += [w for e in args.effect or [] for w in ("--effect", e)]
    words += ["--multisample"] if getattr(args, "multisample", False) else []
    if getattr(args, "adaptive", False):
        words.append("--adaptive")
        for p in cli_parameters():
            value = getattr(args, f"adaptive_{p.name}", None)
            if value is not None and p.flag != "--spp":
                words += [p.flag, str(value)]
    return words


def job_text(args: argparse.Namespace, spp: int, stem: Path) -> str:
    """The render as the command line its checkpoints record (with its ``-o``)."""
    return f"{render_command(args, spp)} {shlex.join(['-o', str(stem)])}"


def render_command(args: argparse.Namespace, spp: int) -> str:
    """The ``mcrt`` command line that renders the same pixels."""
    return command_text("render", *render_words(args, spp),
                        plugins=getattr(args, "plugin_files", None) or [])


def render_metadata(args: argparse.Namespace, params: dict[str, str], sampler, spp: int,
                    scene, plan, adaptive=None) -> dict[str, Any]:
    """What a render's EXR header records: everything needed to reproduce it."""
    params_of = sampler_params_of(sampler)
    meta: dict[str, Any] = {
        **software(), "mcrt_kind": "render_adaptive" if adaptive else "render",
        COMMAND: render_command(args, spp), "scene": str(args.scene),
        **scene_facts(args.scene, params),
        "defines": " ".join(f"{k}={v}" for k, v in params.items()),
        "sampler": sampler_name(sampler), "sampler_params": json.dumps(params_of, sort_keys=True),
        "spp_requested": spp, "seed": args.seed,
        "effect_overrides": ",".join(args.effect or []), "effects": ",".join(plan.effects_on),
        "multisample": int(bool(getattr(args, "multisample", False))),
        "filter": str(scene.sensors()[0].film().rfilter()),
        "adaptive": json.dumps(asdict(adaptive), sort_keys=True) if adaptive else "",
        "plugins": json.dumps([absolute(p) for p in getattr(args, "plugin_files", None) or []]),
    }
    code = sampler_fingerprint(meta["sampler"], params_of)
    if code:
        meta["sampler_code"] = code
    return meta


def check_replaces_same(exr_path: Path, metadata: dict[str, Any], named: bool) -> None:
    """Before a render replaces ``exr_path``: a default name (``named`` False)
    never replaces a different render (an error says what differs); a name given
    with ``-o`` does, with a note. The same render (an earlier or interrupted run
    of the same command) is replaced silently."""
    from ..io import read_exr_header

    if not exr_path.is_file():
        return
    try:
        old = read_exr_header(exr_path)
    except (McrtError, OSError):
        old = None
    if old is not None and old.get(COMMAND) == metadata[COMMAND]:
        return
    if old is None or "mcrt_version" not in old:
        what = "a file mcrt did not write"
    elif COMMAND not in old:
        if not named:  # written by an older mcrt that recorded no command: replaced, said so
            log.info("replacing %s, written by mcrt %s", exr_path, old.get("mcrt_version"))
        return
    else:
        what = f"another render ({differences(old, metadata)})"
    if named:
        log.info("replacing %s, %s", exr_path, what)
        return
    raise McrtError(f"{exr_path} holds {what}: not replaced; name this render's output with "
                    f"-o (or remove the file)")


def differences(old: dict[str, Any], new: dict[str, Any]) -> str:
    """The settings two render headers disagree on, in words."""
    found = [f"{key} {_shown(old.get(key))} there, {_shown(new.get(key))} here"
             for key in SETTINGS if str(old.get(key, "")) != str(new.get(key, ""))]
    if old.get("mcrt_kind") != new.get("mcrt_kind"):
        found.insert(0, f"{old.get('mcrt_kind', 'unknown kind')} there, "
                        f"{new.get('mcrt_kind')} here")
    return "; ".join(found) or "a different command"


def _shown(value: Any) -> str:
    text = str(value) if value not in (None, "") else "none"
    return text if len(text) <= 60 else text[:57] + "..."


__all__ = ["SETTINGS", "check_replaces_same", "differences", "job_text", "render_command",
           "render_metadata", "render_words"]
