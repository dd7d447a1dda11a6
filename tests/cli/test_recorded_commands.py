"""The JSON files of ``mcrt pattern``, ``mcrt integrate`` and ``mcrt check`` say how
they were made: the ``command`` that runs them again (variant, plugins, every
setting, a point-set file by absolute path, no ``-o``) and the versions; run from
another folder with another ``-o``, that command writes the same numbers.

Files are read back with ``json``; the commands run through ``mcrt``'s own entry
point, in this process.
"""

from __future__ import annotations

import json
import shlex

import numpy as np
import pytest

from mcrt import __version__
from mcrt.core.provenance import png_text
from tests.conftest import png_text_of, run_cli

CASES = [
    (["pattern", "pointset", "--spp", "16", "--pixels", "16", "--seed", "2",
      "--param", "filename=sets.npz", "--param", "randomize=shift"], "summary.json"),
    (["integrate", "pi", "--sampler", "independent,jittered", "--min-n", "16", "--max-n", "64",
      "--trials", "32", "--seed", "1"], "integrate_pi.json"),
    (["integrate", "utk", "--sampler", "jittered", "--max-n", "256", "--trials", "2",
      "--integrands", "16"], "integrate_utk.json"),
    (["check", "jittered", "-P", "jitter=0.5", "--quick", "--seed", "1"], "results.json"),
]


#: Keys not compared: timings, and the parameters as typed (the point-set file's
#: relative name the first time, its absolute one in the recorded command).
_SKIPPED = ("time", "second", "params")


def _numbers(data):
    """``data`` without :data:`_SKIPPED`."""
    if isinstance(data, dict):
        return {k: _numbers(v) for k, v in data.items() if not any(s in k for s in _SKIPPED)}
    if isinstance(data, list):
        return [_numbers(v) for v in data]
    return data


@pytest.mark.parametrize(("argv", "name"), CASES, ids=[c[0][0] + "_" + c[0][1] for c in CASES])
def test_a_json_output_records_the_command_that_makes_it_again(capsys, tmp_path, monkeypatch,
                                                                argv, name):
    (tmp_path / "here").mkdir()
    (tmp_path / "there").mkdir()
    monkeypatch.chdir(tmp_path / "here")
    rng = np.random.default_rng(3)
    np.savez("sets.npz", rng.random((16, 16, 2)).astype(np.float32) * 0.99)
    code, _, err = run_cli(capsys, "-q", *argv, "-o", "first")
    assert code in (0, 1), err
    first = json.loads((tmp_path / "here" / "first" / name).read_text())
    assert first["mcrt_version"] == __version__ and first["variant"] == "llvm_ad_rgb"
    words = shlex.split(first["command"])
    for png in (tmp_path / "here" / "first").glob("*.png"):  # each figure says so too
        assert png_text_of(png) == png_text(first), png
    assert words[:4] == ["mcrt", "--variant", "llvm_ad_rgb", argv[0]] and "-o" not in words
    monkeypatch.chdir(tmp_path / "there")  # a colleague's folder, another output
    again_code, _, err = run_cli(capsys, "-q", *words[1:], "-o", "again dir")
    assert again_code == code, err
    again = json.loads((tmp_path / "there" / "again dir" / name).read_text())
    assert _numbers(again) == _numbers(first)
