"""Shared fixtures: mcrt imported (llvm_ad_rgb active, plugins registered)."""

from __future__ import annotations

import os

os.environ.setdefault("MPLBACKEND", "Agg")
# Small matrix products in the analysis tests run 10-30x slower with OpenBLAS's
# threads competing for 2 cores with Dr.Jit's; one BLAS thread is fastest here.
os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")

import mitsuba as mi  # noqa: E402
import pytest  # noqa: E402

import mcrt  # noqa: E402,F401  (activates the variant and registers the plugins)

OUR_SAMPLERS = ("uniform_grid", "jittered", "poisson_disk")


@pytest.fixture(autouse=True)
def _variant():
    """Every test runs in llvm_ad_rgb with our plugins registered."""
    if mi.variant() != "llvm_ad_rgb":
        mi.set_variant("llvm_ad_rgb")
        mcrt.register()
    yield


def small_cornell(size: int = 32, sampler: str = "independent", spp: int = 16,
                  integrator: dict | None = None, box_filter: bool = False) -> mi.Scene:
    """Mitsuba's Cornell box at a small resolution (fast to render in tests)."""
    scene = mi.cornell_box()
    if box_filter:
        scene["sensor"]["film"]["rfilter"] = {"type": "box"}
    scene["sensor"]["film"]["width"] = size
    scene["sensor"]["film"]["height"] = size
    scene["sensor"]["film"]["component_format"] = "float32"
    scene["sensor"]["sampler"] = {"type": sampler, "sample_count": spp}
    if integrator is not None:
        scene["integrator"] = integrator
    return mi.load_dict(scene)
