"""NaN/Inf counts of a film that samples its border (a filter wider than a box
with ``sample_border``): every pass traces the border's pixels too, so their
non-finite samples are counted in the totals (EXR ``nonfinite_samples``, the
printed count, the passes' counts), while the ``nonfinite`` layer covers the
image's pixels, as the image does; the printed line names both shares."""

from __future__ import annotations

import re

import numpy as np
import pytest

from mcrt.io import read_exr
from mcrt.render.adaptive import AdaptiveSettings, render_adaptive
from mcrt.render.scene import load_scene
from tests.conftest import ROOT, run_cli

HARD = ROOT / "scenes" / "hard"
LINE = re.compile(r"non-finite samples: (\d+) \(NaN/Inf, left out of the image; (\d+) in (\d+) "
                  r"image pixels, (\d+) in the film's sampled border around the image")


@pytest.fixture
def bordered(tmp_path):
    """scenes/hard/degenerate.xml (NaN and +Inf panels) with a gaussian filter
    and a sampled border (2 pixels on each side)."""
    text = (HARD / "degenerate.xml").read_text()
    assert text.count('<rfilter type="box"/>') == 1
    text = text.replace('<rfilter type="box"/>', '<rfilter type="gaussian"/>'
                        '<boolean name="sample_border" value="true"/>')
    path = tmp_path / "bordered.xml"
    path.write_text(text.replace("meshes/", f"{HARD / 'meshes'}/"))
    return path


@pytest.mark.parametrize("mode", [["--spp", "16"], ["--adaptive", "--max-spp", "64"]],
                         ids=["fixed", "adaptive"])
def test_nonfinite_totals_count_a_sampled_border_and_say_so(bordered, tmp_path, capsys,
                                                            monkeypatch, mode):
    """The adaptive render's printed total, its warning and its EXR attribute
    counted the image's pixels only, while its passes counted the border's too;
    the fixed render counted the border's but failed to write its EXR (the
    `nonfinite` layer had the grid's shape, 36x68, not the image's 32x64)."""
    monkeypatch.setenv("MCRT_CACHE_DIR", str(tmp_path / "cache"))
    out = tmp_path / "out"
    code, stdout, stderr = run_cli(capsys, "render", str(bordered), "--sampler", "jittered",
                                   *mode, "-o", str(out))
    assert code == 0, stderr
    layers, meta = read_exr(out.with_suffix(".exr"))
    assert layers["nonfinite"].shape == layers["rgb"].shape[:2] == (32, 64)
    match = LINE.search(stdout)
    assert match, stdout
    total, inside, pixels, border = map(int, match.groups())
    assert border > 0 and total == inside + border == int(meta["nonfinite_samples"])
    assert inside == int(layers["nonfinite"].sum())
    assert pixels == int((layers["nonfinite"] > 0).sum())
    if "--adaptive" in mode:
        assert f"adaptive: {total} NaN/Inf samples left out ({border} in the film's sampled " \
               f"border; " in stderr


def test_adaptive_nonfinite_total_is_the_passes(bordered):
    scene = load_scene(bordered)
    result = render_adaptive(scene, "jittered", AdaptiveSettings(max_spp=64), seed=1)
    assert result.nonfinite.shape == result.spp.shape == (32, 64)
    traced = sum(p.nonfinite for p in result.passes)
    assert traced == result.nonfinite_samples == result.summary()["nonfinite_samples"]
    assert traced > int(result.nonfinite.sum()) > 0
    assert np.isfinite(result.image).all()
