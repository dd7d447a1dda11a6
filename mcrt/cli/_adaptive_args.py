"""``mcrt render --adaptive``: the adaptive options, derived from the parameter
declarations (:data:`mcrt.render.adaptive.PARAMETERS`)."""

from __future__ import annotations

import argparse
from dataclasses import asdict
from typing import Any

import mitsuba as mi

from ..errors import McrtError
from ..render.adaptive import PARAMETERS, AdaptiveSettings, Param

#: The parameter that ``--spp`` sets when its own flag is not given.
SPP_PARAMETER = "max_spp"


def cli_parameters() -> tuple[Param, ...]:
    """The adaptive parameters that have a command-line flag."""
    return tuple(p for p in PARAMETERS if p.cli)


def help_text(p: Param) -> str:
    """A flag's help: the parameter's description and its default."""
    if p.name == SPP_PARAMETER:
        return f"{p.help} (default: --spp if given, else {p.default})"
    return f"{p.help} (default {p.default})"


def add_cli_arguments(parser: argparse.ArgumentParser) -> None:
    """Add ``--adaptive`` and its parameters to an argparse (sub)parser."""
    group = parser.add_argument_group(
        "adaptive sampling", "with --adaptive, OUT.exr gets the layers rgb, variance, stderr, "
        "stderr_y, spp and nonfinite, and OUT_spp.png is a heat map of the sample counts")
    group.add_argument("--adaptive", action="store_true",
                       help="adaptive sampling (automatic if the scene's integrator is "
                            "'adaptive')")
    for p in cli_parameters():
        group.add_argument(p.flag, dest=f"adaptive_{p.name}", type=p.kind, default=None,
                           metavar="N" if p.kind is int else "X", help=help_text(p))


def cli_settings(args: argparse.Namespace, scene: mi.Scene,
                 plan=None) -> AdaptiveSettings | None:
    """Settings for ``mcrt render`` (None: a fixed-spp render), checked up front.

    Defaults come from the scene's ``adaptive`` integrator if it has one. ``plan``
    (the scene's render plan, :mod:`mcrt.render.plan`) is checked for effects the
    adaptive renderer does not support: motion blur needs sub-frames that move
    the geometry between passes of *all* pixels.
    """
    given = {p.name: getattr(args, f"adaptive_{p.name}", None) for p in cli_parameters()}
    given = {k: v for k, v in given.items() if v is not None}
    integrator: Any = scene.integrator()  # an `adaptive` one has .settings
    scene_adaptive = getattr(integrator, "is_adaptive", False)
    if not (getattr(args, "adaptive", False) or scene_adaptive):
        if given:
            flags = ", ".join(p.flag for p in cli_parameters() if p.name in given)
            raise McrtError(f"{flags}: only with --adaptive")
        return None
    if plan is not None and plan.on("motion"):
        raise McrtError("--adaptive does not render motion blur (it needs sub-frames of the "
                        "whole image); add --effect motion=off or drop --adaptive")
    from ..render.adaptive import check_integrator  # (the engine: loaded for --adaptive only)

    check_integrator(integrator.nested if scene_adaptive else integrator)
    base = integrator.settings if scene_adaptive else AdaptiveSettings()
    if SPP_PARAMETER not in given and getattr(args, "spp", None):
        given[SPP_PARAMETER] = args.spp
    return AdaptiveSettings(**{**asdict(base), **given}).check()


__all__ = ["SPP_PARAMETER", "add_cli_arguments", "cli_parameters", "cli_settings", "help_text"]
