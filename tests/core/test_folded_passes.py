"""Passes folded into a box-filtered film while they are traced.

A box-filtered film adds passes of up to ``FOLD`` samples per pixel into its
float64 sums inside the tracing kernel (Dr.Jit's non-atomic scatter-add, which
sums a SIMD packet's lanes per pixel first), instead of storing the pass and
summing each pixel's samples in a second kernel. These tests pin what that may
not change: the image of the stored path, bit for bit; the same bits for any
thread count; and the pass shapes that decide which path a render takes.
"""

from __future__ import annotations

import drjit as dr
import numpy as np
import pytest

from mcrt.core.accumulators import FOLD, FilmAccumulator
from mcrt.core.engine import MAX_LANES_PER_PASS, keeps_lane_state, pass_shape, reseeds_each_pass
from mcrt.core.render import render_film
from mcrt.core.sampling import make_sampler
from tests.conftest import small_cornell


def test_pass_shapes_fold_up_to_four_samples_per_pixel_on_large_films():
    """Stored passes keep to MAX_LANES_PER_PASS lanes; a folded pass takes the
    largest power of two <= FOLD dividing spp, within FOLD x that limit."""
    big = MAX_LANES_PER_PASS  # one lane per pixel fills a stored pass
    assert FOLD == 4
    assert pass_shape(big, 16).group == 1
    assert pass_shape(big, 16, fold=FOLD).group == 4
    assert pass_shape(big, 6, fold=FOLD).group == 2  # 4 does not divide 6
    assert pass_shape(big, 9, fold=FOLD).group == 1
    assert pass_shape(big, 16, fold=FOLD, fold_lanes=big).group == 1  # sampler state
    assert pass_shape(4 * big, 16, fold=FOLD).group == 1  # 4 spp would be 16x the limit
    assert pass_shape(2 * big, 16, fold=FOLD).group == 2
    # Small films: the stored rule's larger groups (fewer passes) win.
    assert pass_shape(64 * 64, 16, fold=FOLD).group == 16
    assert pass_shape(64 * 64, 16, passes=4, fold=FOLD).group == 4  # forced count


def test_only_mitsubas_stratified_samplers_keep_state_between_passes():
    assert reseeds_each_pass(make_sampler("independent", 4))
    assert not keeps_lane_state(make_sampler("independent", 4))
    assert keeps_lane_state(make_sampler("multijitter", 4))
    assert not keeps_lane_state(make_sampler("jittered", 4))
    assert not reseeds_each_pass(make_sampler("sobol", 4))


@pytest.mark.slow
@pytest.mark.parametrize("name", ["jittered", "independent", "multijitter"])
def test_folded_passes_give_the_stored_paths_bits(name, monkeypatch):
    """16 spp in 4 passes of 4: folded while tracing (the default for a box
    filter) and stored then summed per pixel (fold disabled) give the same
    image and non-finite counts, bit for bit. A lost in-packet add (several
    lanes of one pixel writing at once) would lose samples and show here."""
    scene = small_cornell(24, box_filter=True)
    folded = render_film(scene, make_sampler(name, 16), seed=7, passes=4)
    assert FilmAccumulator(scene.sensors()[0].film(), 5).fold == FOLD
    monkeypatch.setattr(FilmAccumulator, "fold", property(lambda self: 0))
    stored = render_film(scene, make_sampler(name, 16), seed=7, passes=4)
    assert folded.passes == stored.passes == 4
    assert np.array_equal(folded.nonfinite, stored.nonfinite)
    assert folded.image.tobytes() == stored.image.tobytes()
    assert folded.rgb.mean() > 0.05  # a real render, not two empty films


def test_folded_passes_are_the_same_bits_for_any_thread_count():
    """80 x 80 pixels x 4 spp: 25,600 lanes, split into blocks of different
    sizes for 1, 2 and 3 threads (whole SIMD packets each)."""
    scene = small_cornell(80, box_filter=True)
    images = []
    for threads in (1, 2, 3):
        dr.set_thread_count(threads)
        try:
            film = render_film(scene, make_sampler("sobol", 8), seed=2, passes=2)
        finally:
            dr.set_thread_count(2)
        images.append(film.image.tobytes())
    assert images[0] == images[1] == images[2]
