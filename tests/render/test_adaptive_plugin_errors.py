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
