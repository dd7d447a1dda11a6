"""Reconstruction filters: the study's ``filters`` axis and the edge measurements.

The edge test compares measured blur and ringing with what the filter's formula
implies: the expected edge-spread function of a separable kernel ``k(x) k(y)``
across an edge at 5 degrees is the normalised integral of the kernel over a
half-plane, computed here on a 0.005-pixel grid. Margins: the measured profile
averages ~8 pixels per 1/16-pixel bin over 4 seeds; the pixel noise near the
edge at 16 jittered spp is below 0.02 of the step (sd), so a bin mean has sd
< 0.005 and the 10-90% crossings move by < 0.01 px: 0.04 px and 1% of the step
are > 4 sd, yet far smaller than the differences between filters.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from mcrt.analysis.edge import edge_metrics, rise_width
from mcrt.analysis.study.config import FILTERS, ConfigError, parse_config
from mcrt.core.render import render_film
from mcrt.render.scene import RFILTER_PARAM, load_scene

ROOT = Path(__file__).resolve().parents[2]
EDGE = ROOT / "scenes" / "filters" / "slanted_edge.xml"


def _cubic(x, b, c):
    x = np.abs(x)
    near = ((12 - 9 * b - 6 * c) * x**3 + (-18 + 12 * b + 6 * c) * x**2 + (6 - 2 * b)) / 6
    far = ((-b - 6 * c) * x**3 + (6 * b + 30 * c) * x**2 + (-12 * b - 48 * c) * x
           + (8 * b + 24 * c)) / 6
    return np.where(x < 1, near, np.where(x < 2, far, 0.0))


#: Mitsuba's filters with their default parameters: (radius, kernel).
KERNELS = {
    "box": (0.5, lambda x: (np.abs(x) < 0.5) * 1.0),
    "tent": (1.0, lambda x: np.maximum(0.0, 1.0 - np.abs(x))),
    "gaussian": (2.0, lambda x: np.maximum(0.0, np.exp(-x**2 / 0.5) - np.exp(-4.0 / 0.5))),
    "mitchell": (2.0, lambda x: _cubic(x, 1 / 3, 1 / 3)),
    "catmullrom": (2.0, lambda x: _cubic(x, 0.0, 0.5)),
    "lanczos": (3.0, lambda x: np.sinc(x) * np.sinc(x / 3) * (np.abs(x) < 3)),
}


def expected_edge(name: str, angle: float = 5.0) -> tuple[float, float]:
    """(10-90% width, overshoot %) of the exact edge-spread function."""
    radius, k = KERNELS[name]
    h = 0.005
    u = np.arange(-radius + h / 2, radius, h)
    uu, vv = np.meshgrid(u, u)
    weight = (k(uu) * k(vv)).ravel()
    t = np.radians(angle)
    order = np.argsort((uu * np.cos(t) + vv * np.sin(t)).ravel())
    esf = np.cumsum(weight[order]) / weight.sum()
    x = (uu * np.cos(t) + vv * np.sin(t)).ravel()[order]
    return rise_width(x, esf), max(esf.max() - 1.0, 0.0) * 100


@pytest.mark.slow
@pytest.mark.parametrize("name", FILTERS)
def test_edge_blur_and_ringing_match_the_filter(name):
    scene = load_scene(EDGE, {RFILTER_PARAM: name, "width": "96", "height": "96"})
    images = [render_film(scene, seed=s).rgb[..., 0].astype(np.float64) for s in range(4)]
    m = edge_metrics(images, 0.2, 0.8)
    width, overshoot = expected_edge(name)
    assert abs(m.width - width) < 0.04, (m.width, width)
    assert abs(m.overshoot - overshoot) < 1.0 and abs(m.undershoot - overshoot) < 1.0
    assert m.noise > 0


def test_expected_edges_order_the_filters():
    # The trade-off the study shows: the non-negative filters do not ring and
    # blur more the wider they are; the negative lobes ring more the sharper.
    widths = {n: expected_edge(n)[0] for n in FILTERS}
    rings = {n: expected_edge(n)[1] for n in FILTERS}
    assert abs(widths["box"] - 0.8) < 0.01  # a box-filtered step: a 1-pixel ramp
    assert widths["box"] < widths["tent"] < widths["gaussian"]
    assert max(rings["box"], rings["tent"], rings["gaussian"]) < 1e-6
    assert 0 < rings["mitchell"] < rings["catmullrom"] < rings["lanczos"]


def _study(filters) -> dict:
    data = {"spp": [1, 2], "seeds": 2, "samplers": ["independent"],
            "reference": {"spp": 8}, "scenes": [{"path": str(EDGE), "name": "edge",
                                                 "params": {"width": 32, "height": 32}}]}
    if filters is not None:
        data["filters"] = filters
    return data


def test_config_expands_every_scene_once_per_filter():
    config = parse_config(_study(["box", "lanczos"]))
    assert [s.name for s in config.scenes] == ["edge~box", "edge~lanczos"]
    assert [s.rfilter for s in config.scenes] == ["box", "lanczos"]
    assert config.scenes[1].params == {"width": "32", "height": "32", RFILTER_PARAM: "lanczos"}
    assert config.cells == 4 and config.filters == ("box", "lanczos")
    assert config.as_dict()["filters"] == ["box", "lanczos"]
    plain = parse_config(_study(None))
    assert [s.name for s in plain.scenes] == ["edge"] and plain.scenes[0].rfilter == ""
    for bad, message in ((["sinc"], "unknown filter"), (["box", "box"], "twice"),
                         ([], "non-empty"), ("box", "non-empty")):
        with pytest.raises(ConfigError, match=message):
            parse_config(_study(bad))


def test_the_filter_parameter_replaces_or_adds_the_film_filter(tmp_path):
    scene = load_scene(EDGE, {RFILTER_PARAM: "mitchell"})
    assert "Mitchell" in str(scene.sensors()[0].film().rfilter())
    bare = tmp_path / "bare.xml"  # a film without an <rfilter>: Mitsuba's default gaussian
    bare.write_text('<scene version="3.0.0"><sensor type="perspective"><film type="hdrfilm">'
                    '<integer name="width" value="8"/><integer name="height" value="8"/>'
                    '</film></sensor></scene>')
    assert "Gaussian" in str(load_scene(bare).sensors()[0].film().rfilter())
    assert "Tent" in str(load_scene(bare, {RFILTER_PARAM: "tent"}).sensors()[0].film().rfilter())


@pytest.mark.slow
def test_a_study_varies_the_filter(tmp_path, monkeypatch):
    from mcrt.analysis.study import run_study

    monkeypatch.setenv("MCRT_CACHE_DIR", str(tmp_path / "cache"))
    result = run_study(parse_config(_study(["box", "gaussian"])))
    cells = {(c["scene"], c["spp_requested"]): c for c in result.cells}
    assert sorted(cells) == [("edge~box", 1), ("edge~box", 2), ("edge~gaussian", 1),
                             ("edge~gaussian", 2)]
    assert {c["filter"] for c in result.cells} == {"box", "gaussian"}
    # Each filter is measured against its own reference: a gaussian film spreads
    # every sample over ~4 pixels, so its per-pixel variance is several times lower.
    assert cells[("edge~gaussian", 1)]["variance"] < 0.6 * cells[("edge~box", 1)]["variance"]


def test_the_shipped_filters_config_loads():
    from mcrt.analysis.study.config import load_config

    config = load_config(ROOT / "configs" / "filters.toml", check_scenes=False)
    assert config.filters == FILTERS
    assert {s.rfilter for s in config.scenes} == set(FILTERS)
