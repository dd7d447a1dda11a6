"""Interleaved storage for fast gathers (mcrt.core.packed), and the filtered
film that stores its passes that way."""

from __future__ import annotations

from pathlib import Path

import drjit as dr
import mitsuba as mi
import numpy as np
import pytest

from mcrt.core.packed import MAX_GROUP, Packed, group_sizes
from mcrt.core.render import render_film, render_stats
from mcrt.core.sampling import make_sampler
from tests.conftest import ROOT


@pytest.mark.parametrize("columns", range(1, 20))
def test_group_sizes_are_powers_of_two_that_add_up(columns):
    sizes = group_sizes(columns)
    assert sum(sizes) == columns
    assert all(s & (s - 1) == 0 and 1 <= s <= MAX_GROUP for s in sizes)
    assert sizes == sorted(sizes, reverse=True)
    assert len(set(s for s in sizes if s < MAX_GROUP)) == len([s for s in sizes if s < MAX_GROUP])


def test_group_sizes_examples():
    assert group_sizes(5) == [4, 1]
    assert group_sizes(6) == [4, 2]
    assert group_sizes(11) == [8, 2, 1]
    assert group_sizes(16) == [8, 8]


@pytest.mark.parametrize("count", [1, 2, 3, 5, 7, 8, 11])
def test_gather_returns_every_column_at_every_lane(count):
    """Column c of lane i holds 100 c + i: any mix-up of columns, lanes or
    groups shows; inactive lanes read 0."""
    lanes = 37
    columns = [mi.Float(np.arange(lanes) + 100.0 * c) for c in range(count)]
    packed = Packed.of(columns)
    dr.eval(packed.arrays)
    assert sum(dr.width(a) for a in packed.arrays) == count * lanes  # no padding
    lane = mi.UInt32([36, 0, 5, 17])
    active = mi.Bool([True, True, False, True])
    got = np.array([np.array(v) for v in packed.gather(lane, active)])
    want = np.array([[36, 0, 0, 17]]) + 100.0 * np.arange(count)[:, None] * \
        np.array([[1, 1, 0, 1]])
    np.testing.assert_array_equal(got, want)


def _degenerate_with(filter_name: str, tmp_path: Path) -> mi.Scene:
    """scenes/hard/degenerate.xml (NaN and Inf samples) with another filter."""
    hard = ROOT / "scenes" / "hard"
    text = (hard / "degenerate.xml").read_text()
    assert '<rfilter type="box"/>' in text
    scene_file = tmp_path / "degenerate.xml"
    scene_file.write_text(text.replace('<rfilter type="box"/>',
                                       f'<rfilter type="{filter_name}"/>'))
    (tmp_path / "meshes").symlink_to(hard / "meshes")
    return mi.load_file(str(scene_file), width="24", height="12")


@pytest.mark.slow
@pytest.mark.parametrize("filter_name", ["gaussian", "tent"])
def test_filtered_film_leaves_non_finite_samples_out(filter_name, tmp_path):
    """A filtered film of a scene with NaN/Inf samples (stored with their x
    position NaN: no weight) equals, to float32 rounding, the independent
    filtered statistics of the same samples, and counts the same samples
    as non-finite per pixel as the box-binned moments do."""
    scene = _degenerate_with(filter_name, tmp_path)
    film = render_film(scene, make_sampler("independent", 16), seed=3, passes=2)
    stats = render_stats(scene, make_sampler("independent", 16), seed=3, passes=2,
                         filtered=True).stats
    moments = render_stats(scene, make_sampler("independent", 16), seed=3, passes=2).stats
    assert film.nonfinite.sum() > 0, "the scene must make non-finite samples"
    np.testing.assert_array_equal(film.nonfinite, moments.nonfinite)
    assert np.isfinite(film.image).all()
    np.testing.assert_allclose(film.rgb, stats.mean, rtol=2e-6, atol=1e-7)
