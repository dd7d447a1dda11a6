"""The files of ``mcrt pattern``, ``mcrt integrate``, ``mcrt check`` and ``mcrt
demo`` say how they were made: the ``command`` that runs them again (variant,
plugins, every setting, a point-set file by absolute path, no ``-o``) and the
versions, in each format's own place (a JSON key, a PNG text chunk, a CSV column
on every row, an HTML report's paragraph); run from another folder with another
``-o``, that command writes the same numbers.

Files are read back with ``json``, ``csv``, Pillow and ``html.parser``; the
commands run through ``mcrt``'s own entry point, in this process.
"""

from __future__ import annotations

import csv
import json
import re
import shlex
from pathlib import Path

import numpy as np
import pytest

from mcrt import __version__
from mcrt.core.provenance import png_text, software_text
from tests.conftest import html_command_of, png_text_of, run_cli

ROOT = Path(__file__).resolve().parents[2]

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
    _csv_and_html_say(tmp_path / "here" / "first", first["command"])
    assert words[:4] == ["mcrt", "--variant", "llvm_ad_rgb", argv[0]] and "-o" not in words
    monkeypatch.chdir(tmp_path / "there")  # a colleague's folder, another output
    again_code, _, err = run_cli(capsys, "-q", *words[1:], "-o", "again dir")
    assert again_code == code, err
    again = json.loads((tmp_path / "there" / "again dir" / name).read_text())
    assert _numbers(again) == _numbers(first)


def _csv_and_html_say(folder: Path, command: str) -> None:
    """Every CSV in ``folder`` has ``command`` and the software on every row (as
    ``csv.DictReader`` reads them), every HTML report ``command`` in its note."""
    for table in folder.glob("*.csv"):
        with table.open(newline="") as handle:
            rows = list(csv.DictReader(handle))
        assert rows, table
        assert {(r["command"], r["software"]) for r in rows} == {(command, software_text())}
        assert list(rows[0])[-2:] == ["command", "software"]  # the data's columns come first
    for page in folder.glob("*.html"):
        assert html_command_of(page) == command, page


def test_demo_s_contact_sheets_and_results_csv_record_the_demo_command(capsys, tmp_path,
                                                                      monkeypatch):
    """``mcrt demo``'s own files (each scene's contact sheet, results.csv) record
    the demo's command (its images record their renders'); run from another
    folder, it writes the same relMSE."""
    scenes = tmp_path / "scenes"
    scenes.mkdir()
    for name, small in (("cornell_box.xml", {"spp": "4", "res": "8"}),
                        ("checkerboard.xml", {"spp": "4", "width": "16", "height": "12"})):
        text = (ROOT / "scenes" / name).read_text()
        for key, value in small.items():
            text = re.sub(f'<default name="{key}" value="[^"]*"/>',
                          f'<default name="{key}" value="{value}"/>', text)
        (scenes / name).write_text(text)
    monkeypatch.chdir(tmp_path)
    code, _, err = run_cli(capsys, "-q", "demo", "--samplers", "independent", "--rounds", "1",
                           "--reference-factor", "2", "--scenes", "scenes", "-o", "first")
    assert code == 0, err
    command = shlex.join(["mcrt", "--variant", "llvm_ad_rgb", "demo", "--samplers", "independent",
                          "--scenes", str(scenes), "--reference-factor", "2", "--rounds", "1"])
    sheets = sorted(Path("first").glob("*_comparison.png"))
    assert len(sheets) == 2
    for sheet in sheets:
        assert png_text_of(sheet) == png_text({"command": command}), sheet
    _csv_and_html_say(Path("first"), command)
    (tmp_path / "there").mkdir()
    monkeypatch.chdir(tmp_path / "there")
    assert run_cli(capsys, "-q", *shlex.split(command)[1:], "-o", "again")[0] == 0
    rows = [list(csv.DictReader((tmp_path / d / "results.csv").open(newline="")))
            for d in ("first", "there/again")]
    assert [r["rel_mse"] for r in rows[0]] == [r["rel_mse"] for r in rows[1]]
