"""JSON files that strict parsers read: no NaN or Infinity in any file mcrt writes."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np

from mcrt.core.jsonfile import json_safe, write_json
from tests.conftest import run_cli


def _strict(path: Path):
    """Parse as jq or JavaScript would: NaN, Infinity and -Infinity are errors."""
    def refuse(name: str):
        raise ValueError(f"{path.name} holds {name}, which is not JSON")
    return json.loads(path.read_text(), parse_constant=refuse)


def test_non_finite_values_are_written_as_null(tmp_path):
    data = {"nan": float("nan"), "inf": np.float32(np.inf), "list": (1, -np.inf, np.int64(3)),
            "flag": np.bool_(True), 7: Path("a/b")}
    write_json(tmp_path / "x.json", data)
    assert _strict(tmp_path / "x.json") == {"nan": None, "inf": None, "list": [1, None, 3],
                                            "flag": True, "7": "a/b"}
    assert json_safe([np.float64(0.5)]) == [0.5]


def test_statistics_without_a_value_are_null_in_the_command_s_files(capsys, tmp_path):
    """One point per pixel has no nearest neighbour, no low frequencies and no
    anisotropy; one sample count has no slope: those were NaN and Infinity."""
    code, _, err = run_cli(capsys, "-q", "pattern", "sobol", "--spp", "1", "--pixels", "4",
                           "-o", str(tmp_path / "pattern"))
    assert code == 0, err
    summary = _strict(tmp_path / "pattern" / "summary.json")
    assert summary["rho_mean"] is None and summary["low_frequency_power"] is None
    code, _, err = run_cli(capsys, "-q", "integrate", "pi", "--sampler", "independent",
                           "--min-n", "64", "--max-n", "64", "-o", str(tmp_path / "integrate"))
    assert code == 0, err
    slopes = _strict(tmp_path / "integrate" / "integrate_pi.json")["slopes"]
    assert slopes["independent"]["slope"] is None
