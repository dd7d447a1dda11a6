"""Colour has one home (mcrt.core.colour): Mitsuba's matrix, and the luminance
weights every layer uses, the report viewer's JavaScript included."""

from __future__ import annotations

import re
from importlib import resources

import mitsuba as mi
import numpy as np

from mcrt.analysis import metrics
from mcrt.analysis.viewer import SCRIPTS, viewer_assets
from mcrt.analysis.viewer import data as viewer_data
from mcrt.core.colour import LUMINANCE_WEIGHTS, SRGB_TO_XYZ, XYZ_TO_SRGB
from mcrt.core.render import in_film_format, srgb_to_xyz_matrix
from mcrt.render.adaptive import criterion


def test_the_matrix_is_mitsubas():
    unit = mi.Color3f(mi.Float(1, 0, 0), mi.Float(0, 1, 0), mi.Float(0, 0, 1))
    mitsuba = np.array(mi.srgb_to_xyz(unit), dtype=np.float64)  # [row, column]
    np.testing.assert_array_equal(SRGB_TO_XYZ, mitsuba)
    np.testing.assert_array_equal(srgb_to_xyz_matrix(), mitsuba)
    np.testing.assert_allclose(XYZ_TO_SRGB @ SRGB_TO_XYZ, np.eye(3), atol=1e-12)


def test_luminance_weights_are_the_y_row():
    assert tuple(SRGB_TO_XYZ[1]) == LUMINANCE_WEIGHTS
    # Mitsuba's luminance, and Rec. 709's published four digits.
    lum = mi.luminance(mi.Color3f(mi.Float(1, 0, 0), mi.Float(0, 1, 0), mi.Float(0, 0, 1)))
    np.testing.assert_array_equal(np.array(lum, dtype=np.float64), LUMINANCE_WEIGHTS)
    np.testing.assert_allclose(LUMINANCE_WEIGHTS, (0.2126, 0.7152, 0.0722), atol=1e-4)
    assert abs(sum(LUMINANCE_WEIGHTS) - 1.0) < 1e-7


def test_every_layer_uses_the_same_weights():
    assert metrics.LUMINANCE_WEIGHTS is LUMINANCE_WEIGHTS
    assert tuple(criterion.LUMINANCE) == LUMINANCE_WEIGHTS
    assert viewer_data.LUM == LUMINANCE_WEIGHTS
    rgb = np.array([[[0.3, 0.6, 0.1]]])
    y = metrics.luminance(rgb)
    film = mi.load_dict({"type": "hdrfilm", "width": 1, "height": 1, "pixel_format": "luminance"})
    for other in (criterion._luminance(rgb), viewer_data._luminance(rgb),
                  in_film_format(film, rgb, alpha=False)[0][..., 0]):
        np.testing.assert_allclose(other, y, rtol=1e-15)


def test_the_viewer_gets_the_weights_from_python():
    """The page defines ``LUM`` from mcrt.core.colour; no script has its own."""
    _, script = viewer_assets()
    found = re.findall(r"var LUM = \[([^\]]*)\];", script)
    assert len(found) == 1
    assert tuple(float(w) for w in found[0].split(",")) == LUMINANCE_WEIGHTS
    here = resources.files("mcrt.analysis.viewer")
    for name in SCRIPTS:
        text = (here / name).read_text(encoding="utf-8")
        assert not re.search(r"\bvar LUM\b|0\.2126", text), name
