"""``mi.render`` on mcrt's ``adaptive`` integrator plugin with a budget it
refuses: Mitsuba runs the plugin inside a Dr.Jit custom operation, which turns
every exception into ``RuntimeError('... error while performing a custom
differentiable operation. (see above).')``. The user must still read why: the
reason names mi.render's ``spp`` and is logged at error level as well as being
the wrapper's cause."""

from __future__ import annotations

import logging

import mitsuba as mi
import pytest

from mcrt.errors import McrtError


def _scene() -> mi.Scene:
    return mi.load_dict({
        "type": "scene",
        "integrator": {"type": "adaptive", "nested": {"type": "path"}},
        "sensor": {"type": "perspective",
                   "film": {"type": "hdrfilm", "width": 4, "height": 4},
                   "sampler": {"type": "independent"}},
        "light": {"type": "constant"}})


def test_a_budget_below_min_spp_is_said_in_words_the_user_gave(caplog):
    scene = _scene()
    with caplog.at_level(logging.ERROR, logger="mcrt.render"), \
            pytest.raises(RuntimeError) as raised:
        mi.render(scene, spp=8)
    cause = raised.value.__cause__
    assert isinstance(cause, McrtError)
    assert "spp=8" in str(cause) and "min_spp (16)" in str(cause)
    logged = [r.getMessage() for r in caplog.records
              if r.name == "mcrt.render" and r.levelno == logging.ERROR]
    assert logged == [str(cause)]  # seen without digging into __cause__


def test_a_budget_of_min_spp_renders(caplog):
    with caplog.at_level(logging.ERROR, logger="mcrt.render"):
        image = mi.render(_scene(), spp=16)
    assert image.shape == (4, 4, 3)
    assert not [r for r in caplog.records if r.levelno >= logging.ERROR]


def _aov_scene(integrator: dict) -> dict:
    return {"type": "scene", "integrator": integrator,
            "sensor": {"type": "perspective",
                       "to_world": mi.ScalarTransform4f().look_at(origin=[0, 0, 4],
                                                                  target=[0, 0, 0], up=[0, 1, 0]),
                       "film": {"type": "hdrfilm", "width": 6, "height": 4},
                       "sampler": {"type": "independent", "sample_count": 4}},
            "light": {"type": "constant"}, "ball": {"type": "sphere"}}


def test_an_aov_integrator_without_an_image_integrator_is_refused(tmp_path, capsys, caplog):
    """A bare ``aov`` renders AOVs only: its image is black, and the adaptive
    renderer keeps no AOVs, so ``mcrt render --adaptive`` traced the whole budget
    into a black image (with a warning that ``-q`` hides). It is refused before
    any work, by render_adaptive, the ``adaptive`` plugin and the command; an
    ``aov`` wrapping ``path`` still renders, with its AOV warning."""
    from mcrt.cli import main
    from mcrt.render.adaptive import AdaptiveSettings, render_adaptive

    bare = {"type": "aov", "aovs": "dd.y:depth"}
    words = ("no nested image integrator", 'type="path"', "without --adaptive")
    with pytest.raises(McrtError) as raised:
        render_adaptive(mi.load_dict(_aov_scene(bare)), settings=AdaptiveSettings(max_spp=32))
    assert len(str(raised.value).splitlines()) == 1 and all(w in str(raised.value) for w in words)
    with pytest.raises(Exception, match="no nested image integrator"):
        mi.load_dict(_aov_scene({"type": "adaptive", "nested": bare}))

    scene = tmp_path / "bare_aov.xml"
    scene.write_text("""<scene version="3.0.0">
      <integrator type="aov"><string name="aovs" value="dd.y:depth"/></integrator>
      <sensor type="perspective"><transform name="to_world"><lookat origin="0, 0, 4"
        target="0, 0, 0" up="0, 1, 0"/></transform><film type="hdrfilm"><integer name="width" value="6"/>
        <integer name="height" value="4"/></film></sensor>
      <emitter type="constant"/><shape type="sphere"/></scene>""")
    out = tmp_path / "out"
    assert main(["-q", "render", str(scene), "--adaptive", "-o", str(out)]) == 2
    err = capsys.readouterr().err.strip()
    assert err.startswith("mcrt: error: adaptive:") and len(err.splitlines()) == 1, err
    assert all(w in err for w in words) and not list(tmp_path.glob("out*"))

    wrapped = mi.load_dict(_aov_scene({**bare, "image": {"type": "path"}}))
    with caplog.at_level(logging.WARNING):
        result = render_adaptive(wrapped, settings=AdaptiveSettings(max_spp=32))
    assert result.image.mean() > 0.1
    assert "AOVs (image.R, image.G, image.B, image.A, dd.y.T) are not kept" in caplog.text
