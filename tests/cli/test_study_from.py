"""A study's results.csv and report.html say how they were made, and ``mcrt compare
--from results.csv`` runs the study again from that alone.

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


def test_compare_from_says_which_cells_differ(capsys, study, tmp_path):
    """A results.csv whose numbers were changed: exit status 1, the cell and the
    column named; its default output is its folder + _again, beside it."""
    (tmp_path / "edited").mkdir()
    rows = _rows(study / "results.csv")
    rows[1]["mse"] = "0.5"
    _write(tmp_path / "edited" / "results.csv", rows)
    code, out, err = run_cli(capsys, "-q", "compare", "--from", "edited/results.csv")
    assert code == 1, err
    assert "1 of 4 cells differ" in out and "box/jittered/4 spp (mse)" in out, out
    assert (tmp_path / "edited_again" / "results.csv").is_file()


@pytest.mark.parametrize("edit, argv, message", [
    ("none", ["s.toml"], "drop CONFIG.toml"),
    ("none", ["--restart"], "drop --restart"),
    ("partial", [], "partial study"),
    ("no command", [], "records no command"),
    ("two commands", [], "2 different commands"),
    ("render", [], "does not run a study"),
    ("missing", [], "cannot read"),
])
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


def test_compare_needs_a_configuration_or_from(capsys):
    code, _, err = run_cli(capsys, "compare")
    assert code == 2 and "give the study's configuration (CONFIG.toml), or --from" in err
