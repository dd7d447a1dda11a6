"""``MCRT_*`` numbers: a bad value is one line naming the variable."""

from __future__ import annotations

import pytest

from mcrt.core.environ import env_number
from mcrt.errors import McrtError


@pytest.mark.parametrize("text, options, value", [
    ("", {}, 7.0), ("  ", {}, 7.0), ("2.5", {}, 2.5), ("0", {}, 0.0), ("3", {"integer": True}, 3),
])
def test_good_values_and_the_default(monkeypatch, text, options, value):
    monkeypatch.setenv("MCRT_TEST_NUMBER", text)
    assert env_number("MCRT_TEST_NUMBER", 7.0, **options) == value


@pytest.mark.parametrize("text, options, rule", [
    ("abc", {}, "a number >= 0"), ("-1", {}, "a number >= 0"), ("nan", {}, "a number >= 0"),
    ("inf", {}, "a number >= 0"), ("0", {"positive": True}, "a number > 0"),
    ("2.5", {"integer": True}, "an integer >= 0"), ("-3", {"integer": True}, "an integer >= 0"),
])
def test_bad_values_are_one_line_naming_the_variable(monkeypatch, text, options, rule):
    """(MCRT_CLUSTER_WORKER_WAIT=abc and MCRT_WORKER_THREADS=abc were tracebacks,
    MCRT_CLUSTER_TIMEOUT=-1 blamed the scheduler.)"""
    monkeypatch.setenv("MCRT_TEST_NUMBER", text)
    with pytest.raises(McrtError, match=rf"^\$MCRT_TEST_NUMBER must be {rule}, got '{text}'$"):
        env_number("MCRT_TEST_NUMBER", 7.0, **options)


@pytest.mark.parametrize("text, on", [
    ("", True), ("1", True), ("on", True), ("TRUE", True), (" yes ", True),
    ("0", False), ("off", False), ("False", False), ("no", False),
])
def test_replay_switch_understands_the_usual_spellings(monkeypatch, text, on):
    """(Only ``0`` switched replay off: ``MCRT_REPLAY=off`` left it on.)"""
    from mcrt.core import replay

    monkeypatch.setenv(replay.ENV, text)
    assert replay.switched_off() is not on


@pytest.mark.parametrize("text", ["2", "maybe", "-1", "0.0"])
def test_a_replay_value_that_is_no_switch_is_one_line_naming_the_variable(monkeypatch, text):
    """(Any value but ``0`` silently left replay on.)"""
    from mcrt.core import replay

    monkeypatch.setenv(replay.ENV, text)
    with pytest.raises(McrtError, match=rf"^\$MCRT_REPLAY must be 1 or 0 \(also on/off, "
                                        rf"true/false, yes/no\), got '{text}'$"):
        replay.switched_off()
