"""Extreme radiances and sample counts through real renders, against exact answers.

``scenes/hard/sky.xml`` makes every sample exactly ``float32($sky)``, so each
pixel's exact value is known bit for bit; these tests push the value to the ends
of float32's range. (Smaller and larger sample counts of ordinary values are in
``test_hard_cases.py``; synthetic streams in ``test_numerics.py``.)
"""

from __future__ import annotations

from pathlib import Path

import mitsuba as mi
import numpy as np
import pytest

from mcrt.core.render import render_film, render_stats
from mcrt.core.sampling import make_sampler
from mcrt.render.plan import plan_scene

HARD = Path(__file__).resolve().parents[2] / "scenes" / "hard"


def _sky(value: float, rfilter: str = "box", alpha: bool = False) -> mi.Scene:
    """``sky.xml`` as a 3 x 2 film (a dict scene when the filter or format differs)."""
    if rfilter == "box" and not alpha:
        return plan_scene(HARD / "sky.xml", {"width": "3", "height": "2",
                                             "sky": repr(value)}).scene
    return mi.load_dict({
        "type": "scene", "integrator": {"type": "direct"},
        "sensor": {"type": "orthographic",
                   "to_world": mi.ScalarTransform4f().look_at([0, 1, 0], [0, 0, 0], [0, 0, -1]),
                   "film": {"type": "hdrfilm", "width": 3, "height": 2,
                            "pixel_format": "rgba" if alpha else "rgb",
                            "component_format": "float32", "rfilter": {"type": rfilter}}},
        "sky": {"type": "constant", "radiance": {"type": "rgb", "value": [value] * 3}}})


@pytest.mark.parametrize("rfilter,alpha", [("box", False), ("gaussian", True)])
@pytest.mark.parametrize("value,spp", [(3e38, 16), (1e33, 1 << 19)])
def test_a_bright_finite_pixel_is_not_developed_as_inf(value, spp, rfilter, alpha):
    """Every sample is the finite float32 ``v`` (3e38, or 1e33 at 2^19 spp): the
    film's float64 sums are ``spp x v`` (times the filter's weights), beyond
    float32's 3.4e38. The film divided them by their weight only after rounding
    them to float32, so the pixels came out +Inf, while no sample was non-finite
    and the statistics said ``v``. Exact answer: ``float32(v)`` in every pixel
    (a box film: the float64 mean of equal float32 values is that value; a
    gaussian film: a weighted mean of equal values, rounded to float32, within
    one float32 ulp of it); alpha exactly 0 (no ray hits a surface)."""
    exact = np.float32(value)
    scene = _sky(value, rfilter, alpha)
    film = render_film(scene, make_sampler("independent", spp), seed=1)
    assert film.nonfinite_samples == 0
    assert np.isfinite(film.image).all(), film.rgb
    if rfilter == "box":
        assert (film.rgb == exact).all()
    else:
        np.testing.assert_allclose(film.rgb, exact, rtol=2 ** -23, atol=0)
        assert (film.image[..., 3] == 0).all()  # every ray escapes: no surface, alpha 0
    stats = render_stats(scene, make_sampler("independent", 16), seed=1).stats
    assert (stats.mean == float(exact)).all() and (stats.m2 == 0).all()
