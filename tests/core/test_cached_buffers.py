"""Film renders give Dr.Jit's cached buffers back only for large films.

Returning them before and after developing lowers a large film's peak; below
:data:`~mcrt.core.accumulators.RELEASE_PIXELS` the cached buffers are a pass's,
larger than the film's, and returning them only makes the next render of the
process map and fault them in again (an adaptive render of edges.xml took
1.3-1.5 s instead of 1.0 after two film renders)."""

from __future__ import annotations

import drjit as dr
import pytest

from mcrt.core import accumulators
from mcrt.core.render import render_film
from mcrt.render.scene import load_scene
from tests.conftest import CHECKERBOARD


@pytest.fixture
def flushes(monkeypatch):
    """How many times Dr.Jit's malloc cache was flushed (the real flush runs)."""
    calls = []
    real = dr.flush_malloc_cache

    def counted() -> None:
        calls.append(1)
        real()

    monkeypatch.setattr(dr, "flush_malloc_cache", counted)
    return calls


def _render(width: int, height: int) -> None:
    scene = load_scene(CHECKERBOARD, {"width": str(width), "height": str(height), "spp": "1"})
    render_film(scene, "independent", spp=1, seed=3)


def test_a_small_film_keeps_the_cached_buffers(flushes):
    _render(320, 240)
    assert not flushes


def test_a_large_film_gives_them_back_before_and_after_developing(flushes):
    side = int(accumulators.RELEASE_PIXELS ** 0.5)
    _render(side, side)
    assert len(flushes) >= 2


def test_the_threshold_counts_the_film_pixels(flushes):
    accumulators.release_cached_memory(accumulators.RELEASE_PIXELS - 1)
    assert not flushes
    accumulators.release_cached_memory(accumulators.RELEASE_PIXELS)
    accumulators.release_cached_memory()  # (no film: a worker short of memory)
    assert len(flushes) == 2
