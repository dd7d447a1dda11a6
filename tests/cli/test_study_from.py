"""A study's results.csv and report.html say how they were made, and ``mcrt compare
--from results.csv`` (or ``results.json``) runs the study again from that alone.

results.csv is read back with ``csv`` (the command and the software on every row,
the command the one results.json records), report.html with ``html.parser``; the
commands run through ``mcrt``'s own entry point, in this process.
"""

from __future__ import annotations

import csv
import json
import shlex
from pathlib import Path

import pytest

from mcrt.cli import main
from mcrt.core.provenance import software_text
from tests.conftest import html_command_of, run_cli, untimed

ROOT = Path(__file__).resolve().parents[2]
CORNELL = ROOT / "scenes" / "cornell_box.xml"

#: A study of a few seconds: 8x8 pixels, two samplers, two sample counts, two seeds.
CONFIG = ('name = "s"\nspp = [1, 4]\nseeds = 2\nimage_spp = 4\ntime_rounds = 2\n'
          'samplers = ["jittered", "independent"]\n[reference]\nspp = 16\n'
          f'[[scenes]]\npath = "{CORNELL}"\nname = "box"\n'
          'params = { res = 8, max_depth = 2 }\n')


def _rows(path: Path) -> list[dict[str, str]]:
    with path.open(newline="", encoding="utf-8") as handle:
        return list(csv.DictReader(handle))


def _write(path: Path, rows: list[dict[str, str]]) -> None:
    with path.open("w", newline="", encoding="utf-8") as handle:
        writer = csv.DictWriter(handle, fieldnames=list(rows[0]))
        writer.writeheader()
        writer.writerows(rows)


@pytest.fixture(scope="module")
def study(tmp_path_factory) -> Path:
    """The study, run once from its own folder: its report directory."""
    home = tmp_path_factory.mktemp("made")
    with pytest.MonkeyPatch.context() as mp:
        mp.chdir(home)
        mp.setenv("MCRT_CACHE_DIR", str(tmp_path_factory.mktemp("cache")))
        Path("s.toml").write_text(CONFIG)
        assert main(["-q", "compare", "s.toml", "-o", "study"]) == 0
    return home / "study"


@pytest.fixture(autouse=True)
def _elsewhere(tmp_path, monkeypatch):
    """Each test in another folder than the study's, with its own cache."""
    monkeypatch.chdir(tmp_path)
    monkeypatch.setenv("MCRT_CACHE_DIR", str(tmp_path / "cache"))


def test_results_csv_and_report_html_record_the_study_s_command(study):
    command = json.loads((study / "results.json").read_text())["command"]
    assert shlex.split(command) == ["mcrt", "--variant", "llvm_ad_rgb", "compare",
                                    str(study.parent / "s.toml")]
    rows = _rows(study / "results.csv")
    assert len(rows) == 4 and list(rows[0])[-2:] == ["command", "software"]
    assert {(r["command"], r["software"]) for r in rows} == {(command, software_text())}
    assert html_command_of(study / "report.html") == command


def test_compare_from_results_csv_runs_the_study_again(capsys, study):
    """From another folder: the recorded study runs into -o and every cell's
    numbers are the same as written, the times aside."""
    code, out, err = run_cli(capsys, "compare", "--from", str(study / "results.csv"),
                             "-o", "again")
    assert code == 0, err
    assert "in all 4 cells, bit for bit (times aside)" in out, out
    assert "running again: mcrt --variant llvm_ad_rgb compare" in err
    old, new = _rows(study / "results.csv"), _rows(Path("again/results.csv"))
    assert untimed(new) == untimed(old) and old[0]["mse"]
    assert new[0]["command"] == old[0]["command"]


def test_compare_from_results_json_runs_the_study_again(capsys, study):
    """results.json records the same command: the study runs again and the new
    results.json's cells are the same as the old's, field by field, times aside."""
    code, out, err = run_cli(capsys, "compare", "--from", str(study / "results.json"),
                             "-o", "again")
    assert code == 0, err
    assert f"again/results.json: the same numbers as {study / 'results.json'} in all 4 " \
        "cells, bit for bit (times aside)" in out, out
    old = json.loads((study / "results.json").read_text())
    new = json.loads(Path("again/results.json").read_text())
    assert untimed(new["cells"]) == untimed(old["cells"]) and new["command"] == old["command"]


def _results_json(study: Path) -> dict:
    return json.loads((study / "results.json").read_text())


@pytest.mark.parametrize("name", ["results.csv", "results.json"])
def test_compare_from_says_which_cells_differ(capsys, study, tmp_path, name):
    """A results file whose numbers were changed, and whose software was another
    (results.csv's software column, results.json's environment): exit status 1,
    the cell and the field named, the software noted first; its default output is
    its folder + _again, beside it."""
    (tmp_path / "edited").mkdir()
    if name == "results.csv":
        rows = _rows(study / "results.csv")
        rows[1]["mse"] = "0.5"
        _write(tmp_path / "edited" / name, [{**r, "software": "mcrt 0.0.1"} for r in rows])
        other = "mcrt 0.0.1 (now mcrt "
    else:
        data = _results_json(study)
        data["cells"][1]["mse"] = 0.5
        data["environment"]["mcrt_source"] = "0123456789abcdef"
        other = "mcrt_source 0123456789abcdef (now "
        (tmp_path / "edited" / name).write_text(json.dumps(data))
    code, out, err = run_cli(capsys, "compare", "--from", f"edited/{name}")
    assert code == 1, err
    assert "1 of 4 cells differ" in out and "box/jittered/4 spp (mse)" in out, out
    assert "written by other software (noted above)" in out
    assert f"was written by other software: {other}" in " ".join(err.split()), err
    assert (tmp_path / "edited_again" / name).is_file()


_REFUSALS = [
    ("none", ["s.toml"], "drop CONFIG.toml"),
    ("none", ["--restart"], "drop --restart"),
    ("partial", [], "partial study"),
    ("no command", [], "records no command to run its study again (not written by mcrt"),
    ("render", [], "does not run a study"),
    ("missing", [], "cannot read"),
]


@pytest.mark.parametrize("edit, argv, message", [
    *_REFUSALS, ("two commands", [], "2 different commands")])
def test_compare_from_refuses_in_one_line(capsys, study, tmp_path, edit, argv, message):
    rows = _rows(study / "results.csv")
    if edit == "partial":
        rows[-1]["status"] = "pending"
    if edit == "no command":
        rows = [{k: v for k, v in r.items() if k != "command"} for r in rows]
    if edit == "two commands":
        rows[0]["command"] += " -q"
    if edit == "render":
        rows = [{**r, "command": f"mcrt render {CORNELL}"} for r in rows]
    if edit != "missing":
        _write(tmp_path / "results.csv", rows)
    code, _, err = run_cli(capsys, "compare", "--from", "results.csv", *argv)
    assert code == 2 and message in err and len(err.strip().splitlines()) == 1, err
    assert not (tmp_path.parent / f"{tmp_path.name}_again").exists()  # nothing ran


@pytest.mark.parametrize("edit, argv, message", [
    *_REFUSALS, ("no cells", [], "holds no cells: it is not a study's results.json"),
    ("not json", [], "cannot read results.json as a JSON file"),
    ("other file", [], "give a study's results.csv or results.json")])
def test_compare_from_results_json_refuses_in_one_line(capsys, study, tmp_path, edit, argv,
                                                       message):
    data = _results_json(study)
    if edit == "partial":
        data["partial"] = True
    if edit == "no command":
        del data["command"]
    if edit == "render":
        data["command"] = f"mcrt render {CORNELL}"
    if edit == "no cells":
        del data["cells"]
    name = "results.txt" if edit == "other file" else "results.json"
    if edit != "missing":
        (tmp_path / name).write_text("{" if edit == "not json" else json.dumps(data))
    code, _, err = run_cli(capsys, "compare", "--from", name, *argv)
    assert code == 2 and message in err and len(err.strip().splitlines()) == 1, err
    assert not (tmp_path.parent / f"{tmp_path.name}_again").exists()  # nothing ran


def test_compare_needs_a_configuration_or_from(capsys):
    code, _, err = run_cli(capsys, "compare")
    assert code == 2 and "give the study's configuration (CONFIG.toml), or --from" in err
