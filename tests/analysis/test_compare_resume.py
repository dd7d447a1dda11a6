"""`mcrt compare`: Ctrl-C writes a partial report, the same command resumes.

The interrupt is simulated inside the n-th ``render_film`` call: its per-pass
hook raises ``KeyboardInterrupt``, as SIGINT does when Python delivers it
between two bytecodes of a render (between or right after its Dr.Jit kernels). The studies are tiny (64x48 checkerboard, 4 cells
of warm-up + 5 timed rounds, the first 2 of them the seeds): about 10 s for the whole file
on 2 cores. A study renders one group of cells per sample count (both samplers at 4 spp,
then both at 16 spp), their timed renders interleaved in shuffled rounds; the group is the
unit of resume.
"""

from __future__ import annotations

import csv
import json
import math
from pathlib import Path

import pytest

import mcrt.core.render as passes
from mcrt.analysis.study import (
    STATE_DIR,
    WARMUP_SEED,
    StudyState,
    load_config,
    study_key,
)
from mcrt.cli import main
from mcrt.core.sampling import sampler_name
from mcrt.errors import McrtError
from tests.conftest import CHECKERBOARD, study_toml, untimed

CONFIG = study_toml(CHECKERBOARD, name="resume")

#: Cell order of CONFIG (scene, sampler, spp): the order of a study's results.
CELLS = [("checkerboard", "jittered", 4), ("checkerboard", "jittered", 16),
         ("checkerboard", "independent", 4), ("checkerboard", "independent", 16)]

#: Cell values that depend only on the images (bit-identical renders, seeded
#: aliasing null), not on timing: a resumed study must reproduce them exactly.
DETERMINISTIC = ("spp", "seeds", "mse", "mse_sd", "mse_floor", "mse_excess", "mse_of_mean",
                 "resolved", "rel_mse", "rel_mse_sd", "variance", "bias", "bias_low",
                 "bias_high", "delta_e", "delta_e_sd", "aliasing_ratio", "aliasing_ratio_z",
                 "aliasing_peak", "aliasing_peak_z", "aliasing", "nonfinite")


class Renders:
    """Wraps ``render_film``: records (sampler, spp, seed) of every render and
    interrupts render number ``stop_at`` (1-based), if given, from inside the
    real ``render_film``: its per-pass hook raises KeyboardInterrupt, as a
    Ctrl-C during that pass would, so whatever the render module makes of a
    Ctrl-C (it may wrap it with its partial passes) reaches the study."""

    def __init__(self, monkeypatch, stop_at: int | None = None):
        self.calls: list[tuple[str, int, int]] = []
        self.stop_at = stop_at
        real = passes.render_film

        def ctrl_c(index: int, passes: int) -> None:
            raise KeyboardInterrupt

        def wrapper(scene, sampler=None, spp=None, seed=0, **kwargs):
            self.calls.append((sampler_name(sampler), int(sampler.sample_count()), int(seed)))
            if self.stop_at is not None and len(self.calls) == self.stop_at:
                kwargs["on_pass"] = ctrl_c
            return real(scene, sampler, spp=spp, seed=seed, **kwargs)

        monkeypatch.setattr(passes, "render_film", wrapper)

    def cells(self) -> list[tuple[str, int]]:
        """(sampler, spp) of every cell started (one warm-up render each)."""
        return [(name, spp) for name, spp, seed in self.calls if seed == WARMUP_SEED]


def _run(capsys, *argv: str) -> tuple[int, str, str]:
    code = main(list(argv))
    out, err = capsys.readouterr()
    return code, out, err


def _json(out: Path) -> dict:
    return json.loads((out / "results.json").read_text())


def _csv(out: Path) -> list[dict]:
    with open(out / "results.csv", newline="") as f:
        return list(csv.DictReader(f))


def _same(a, b) -> bool:
    if isinstance(a, float) and isinstance(b, float) and math.isnan(a) and math.isnan(b):
        return True
    return a == b


@pytest.fixture(scope="module")
def study(tmp_path_factory):
    """The config, a shared reference cache, and an uninterrupted run's results."""
    root = tmp_path_factory.mktemp("resume")
    config = root / "study.toml"
    config.write_text(CONFIG)
    with pytest.MonkeyPatch.context() as mp:
        mp.setenv("MCRT_CACHE_DIR", str(root / "cache"))
        assert main(["-q", "compare", str(config), "-o", str(root / "baseline")]) == 0
    return config, root / "cache", _json(root / "baseline")


def test_ctrl_c_writes_a_partial_report_and_the_same_command_resumes(study, tmp_path,
                                                                      monkeypatch, capsys):
    config, cache, baseline = study
    monkeypatch.setenv("MCRT_CACHE_DIR", str(cache))
    out = tmp_path / "report"

    # 1. Ctrl-C in the second group (16 spp): the first group took 2 warm-ups + 2 x 5 rounds
    # (the reference is cached); render 16 is the second cell's first timed render.
    renders = Renders(monkeypatch, stop_at=16)
    code, stdout, err = _run(capsys, "-q", "compare", str(config), "-o", str(out))
    assert code == 130
    lines = err.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith("mcrt: interrupted: wrote a partial report "
                                                    "(2 of 4 cells)")
    assert f"to resume, run: mcrt -q compare {config} -o {out}" in lines[0]
    assert "Traceback" not in err + stdout
    assert sorted(renders.cells()) == [("independent", 4), ("independent", 16),
                                       ("jittered", 4), ("jittered", 16)]

    data = _json(out)
    assert data["partial"] is True
    progress = data["progress"]
    assert (progress["cells_done"], progress["cells_total"], progress["cells_resumed"]) == (2, 4, 0)
    stop = progress["interrupted"]
    assert (stop["spp"], stop["seeds_done"], stop["seeds_total"]) == (16, 1, 2)
    other = "independent" if stop["sampler"] == "jittered" else "jittered"
    assert [(p["sampler"], p["spp"]) for p in progress["pending"]] == [
        ("jittered", 16), ("independent", 16)]
    assert "compare" in progress["resume"]
    assert [(c["sampler"], c["spp_requested"]) for c in data["cells"]] == [
        ("jittered", 4), ("independent", 4)]
    rows = _csv(out)
    status = {(r["sampler"], r["spp_requested"]): (r["status"], r["seeds_done"]) for r in rows}
    assert status == {("jittered", "4"): ("done", "2"), ("independent", "4"): ("done", "2"),
                      (stop["sampler"], "16"): ("interrupted", "1"), (other, "16"): ("pending", "0")}
    assert [(r["sampler"], r["spp_requested"]) for r in rows] == [(s, str(n)) for _, s, n in CELLS]
    assert rows[1]["mse"] == "" and float(rows[0]["mse"]) == data["cells"][0]["mse"]
    html = (out / "report.html").read_text()
    assert "(partial)</h1>" in html and "interrupted after 2 of 4 cells" in html
    assert html.count("pending") >= 1 and "1/2 seeds" in html
    assert (out / STATE_DIR / "state.npz").is_file()
    assert not list(out.rglob(".*.tmp"))  # atomic writes left nothing behind

    # 2. The same command: only the unfinished group (both cells at 16 spp) is rendered.
    renders = Renders(monkeypatch)
    code, stdout, err = _run(capsys, "-q", "compare", str(config), "-o", str(out))
    assert code == 0, err
    assert sorted(renders.cells()) == [("independent", 16), ("jittered", 16)]
    assert len(renders.calls) == 2 * (1 + 5)  # warm-up + 5 timed rounds per cell
    assert "(2 of 4 cells from the saved state)" in stdout
    data = _json(out)
    assert data["partial"] is False and data["progress"]["cells_resumed"] == 2
    assert [r["status"] for r in _csv(out)] == ["done"] * 4
    html = (out / "report.html").read_text()
    assert "(partial)" not in html and "measured by an earlier, interrupted run" in html

    # ... and its numbers are an uninterrupted run's, bit for bit (timings aside).
    assert len(data["cells"]) == len(baseline["cells"]) == 4
    for got, want in zip(data["cells"], baseline["cells"], strict=True):
        assert (got["scene"], got["sampler"], got["spp_requested"]) == (
            want["scene"], want["sampler"], want["spp_requested"])
        for key in DETERMINISTIC:
            assert _same(got[key], want[key]), (got["sampler"], got["spp"], key)
        for a, b in zip(got["per_seed"], want["per_seed"], strict=True):
            assert {k: v for k, v in a.items() if "seconds" not in k} == \
                   {k: v for k, v in b.items() if "seconds" not in k}
    for got, want in zip(data["fits"], baseline["fits"], strict=True):
        assert got["slope_spp"] == want["slope_spp"] and got["points"] == want["points"]

    # 3. Once more: everything is saved, nothing is rendered, the report is rewritten.
    renders = Renders(monkeypatch)
    code, stdout, _ = _run(capsys, "-q", "compare", str(config), "-o", str(out))
    assert code == 0 and renders.calls == []
    assert [c["mse"] for c in _json(out)["cells"]] == [c["mse"] for c in data["cells"]]

    # 4. --restart measures every cell again.
    renders = Renders(monkeypatch)
    assert _run(capsys, "-q", "compare", str(config), "-o", str(out), "--restart")[0] == 0
    assert sorted(renders.cells()) == sorted((s, n) for _, s, n in CELLS)


def test_interrupt_before_any_cell_still_writes_a_marked_report(study, tmp_path, monkeypatch,
                                                                capsys):
    """Ctrl-C while the first reference renders: no cell, no plot, but
    results.json/csv/html say what is missing, and a previous report's plots
    are not touched."""
    import mcrt.analysis.reference as reference

    config, cache, _ = study
    monkeypatch.setenv("MCRT_CACHE_DIR", str(cache))
    out = tmp_path / "report"
    out.mkdir()
    (out / "error_vs_spp.png").write_bytes(b"previous plot")

    def interrupted(*args, **kwargs):
        raise KeyboardInterrupt

    monkeypatch.setattr(reference, "get_reference", interrupted)
    code, _, err = _run(capsys, "compare", str(config), "-o", str(out))
    assert code == 130 and "Traceback" not in err
    last = err.strip().splitlines()[-1]  # after the (closed) progress bar and notes
    assert last.startswith("mcrt: interrupted: wrote a partial report (0 of 4 cells)")
    data = _json(out)
    assert data["partial"] and data["cells"] == [] and data["progress"]["interrupted"] is None
    assert [r["status"] for r in _csv(out)] == ["pending"] * 4
    assert "interrupted after 0 of 4 cells" in (out / "report.html").read_text()
    assert (out / "error_vs_spp.png").read_bytes() == b"previous plot"


# --------------------------------------------------------------------------- the saved state


def _fake_cell(scene: str, sampler: str, spp: int) -> dict:
    return {"scene": scene, "sampler": sampler, "spp_requested": spp, "spp": spp,
            "mse": 0.125, "efficiency": float("nan"), "seeds": [0, 1], "per_seed": []}


@pytest.fixture
def notes():
    """Messages logged under ``mcrt`` (the CLI stops them propagating to the root,
    so pytest's caplog would not see them)."""
    import logging

    class Keep(logging.Handler):
        def __init__(self):
            super().__init__(logging.INFO)
            self.messages: list[str] = []

        def emit(self, record):
            self.messages.append(record.getMessage())

    handler = Keep()
    logger = logging.getLogger("mcrt")
    old = logger.level
    logger.addHandler(handler)
    logger.setLevel(logging.INFO)
    yield handler.messages
    logger.removeHandler(handler)
    logger.setLevel(old)


def test_state_round_trips_and_belongs_to_one_configuration(tmp_path, notes):
    path = tmp_path / "study.toml"
    path.write_text(CONFIG)
    config = load_config(path)
    state = StudyState.open(tmp_path / "out", config)
    assert state.cells == {} and not state.directory.exists()  # nothing written before a cell
    state.add(_fake_cell("checkerboard", "jittered", 4), None, seconds=1.5)
    again = StudyState.open(tmp_path / "out", config)
    cell = again.cells[("checkerboard", "jittered", 4)]
    assert cell["mse"] == 0.125 and math.isnan(cell["efficiency"]) and again.seconds == 1.5

    # The key follows what the numbers depend on, not the comments or the name.
    same = load_config(_write(tmp_path / "b.toml", "# a comment\n" + CONFIG.replace(
        'name = "resume"', 'name = "other"')))
    assert study_key(same) == study_key(config)
    assert StudyState.open(tmp_path / "out", same).cells.keys() == again.cells.keys()
    for change in (("seeds = 2", "seeds = 3"), ("width = 64", "width = 96"),
                   ('"jittered", "independent"', '"independent", "jittered"')):
        other = load_config(_write(tmp_path / "c.toml", CONFIG.replace(*change)))
        assert study_key(other) != study_key(config), change
        assert StudyState.open(tmp_path / "out", other).cells == {}, change
    # ... another study's state is moved aside, not replaced, and comes back for its own.
    assert any("held the saved state of another study" in m for m in notes)
    assert (tmp_path / "out" / f"{STATE_DIR}-{state.key[:16]}" / "state.npz").is_file()
    assert StudyState.open(tmp_path / "out", config).cells.keys() == again.cells.keys()

    # A damaged state is ignored with a note, never a crash.
    state_file = tmp_path / "out" / STATE_DIR / "state.npz"
    for damage in (b"", b"{not json", b"\xff\xfe", b"[]", b'{"format": 1, "key": "x"}',
                   json.dumps({"format": 1, "key": state.key, "cells": [{"scene": 1}],
                               "references": {}}).encode()):
        state_file.write_bytes(damage)
        assert StudyState.open(tmp_path / "out", config).cells == {}, damage
    assert any("the work is done again" in m for m in notes)  # damaged: set aside

    # --restart deletes the saved state.
    state.add(_fake_cell("checkerboard", "jittered", 4), None, seconds=1.5)
    assert StudyState.open(tmp_path / "out", config).cells
    assert StudyState.open(tmp_path / "out", config, restart=True).cells == {}
    assert not state.directory.exists()


def test_a_failing_state_write_does_not_stop_the_study(tmp_path, monkeypatch, notes):
    """Disk full while saving: one warning, saving stops, the cells stay in memory."""
    path = _write(tmp_path / "study.toml", CONFIG)
    state = StudyState.open(tmp_path / "out", load_config(path))

    def full(self, seconds):
        raise McrtError("cannot write 'state.json': no space left on device")

    monkeypatch.setattr(StudyState, "save", full)
    state.add(_fake_cell("checkerboard", "jittered", 4), None, 1.0)
    state.add(_fake_cell("checkerboard", "jittered", 16), None, 2.0)
    assert len(state.cells) == 2 and not state.writable
    assert sum("cannot save the resume state" in m for m in notes) == 1


def _write(path: Path, text: str) -> Path:
    path.write_text(text)
    return path


def test_retime_times_the_saved_cells_again_and_keeps_their_errors(study, tmp_path,
                                                                  monkeypatch, capsys):
    """`--retime`: every saved cell is rendered again for timing only (a warm-up
    and the 5 timed rounds; nothing is scored), the errors stay bit for bit, the
    times and what derives from them are new. Without saved cells it refuses."""
    config, cache, baseline = study
    monkeypatch.setenv("MCRT_CACHE_DIR", str(cache))
    out = tmp_path / "report"
    code, _, err = _run(capsys, "-q", "compare", str(config), "-o", str(out), "--retime")
    assert code == 2 and "--retime needs every cell measured: 0 of 4" in err
    assert _run(capsys, "-q", "compare", str(config), "-o", str(out))[0] == 0
    first = _json(out)

    import mcrt.analysis.study.seeds as seeds

    scored = []
    monkeypatch.setattr(seeds, "score_seed", lambda *a, **k: scored.append(a))
    renders = Renders(monkeypatch)
    code, stdout, err = _run(capsys, "-q", "compare", str(config), "-o", str(out), "--retime")
    assert code == 0, err
    assert sorted(renders.cells()) == sorted((s, n) for _, s, n in CELLS)
    assert len(renders.calls) == 4 * (1 + 5) and scored == []
    again = _json(out)
    for got, want in zip(again["cells"], first["cells"], strict=True):
        for key in DETERMINISTIC:
            assert _same(got[key], want[key]), key
        assert got["per_seed"] == want["per_seed"]  # the seeds' own records are kept
        assert got["times"] != want["times"] and len(got["times"]) == 5
        assert got["seconds"] == sorted(got["times"])[2]  # the median of the new times
    code, _, err = _run(capsys, "compare", str(config), "-o", str(out), "--retime",
                        "--restart")
    assert code == 2 and "use one of the two" in err


def test_the_retime_command_printed_runs_in_the_study_s_variant(tmp_path, monkeypatch, capsys):
    """The command a disturbed timing tells the user to run (`... --retime`) is run as
    printed and times the saved cells again: it names the study's variant, as the
    resume command does (without it, it ran in llvm_ad_rgb and refused: '0 of 4 are
    saved'). The line is printed only under load, so the command is taken from the
    real timing_lines as the CLI calls it (a spy that calls through)."""
    import shlex

    import mcrt.cli.compare_cmd as compare_cmd

    monkeypatch.setenv("MCRT_CACHE_DIR", str(tmp_path / "cache"))
    config = _write(tmp_path / "study.toml",
                    study_toml(CHECKERBOARD, params="{ width = 16, height = 12 }"))
    out = tmp_path / "report"
    printed: list[str] = []
    real = compare_cmd.timing_lines

    def spy(timing, retime=""):
        printed.append(retime)
        return real(timing, retime)

    monkeypatch.setattr(compare_cmd, "timing_lines", spy)
    code, _, err = _run(capsys, "-q", "--variant", "llvm_ad_spectral", "compare", str(config),
                        "-o", str(out))
    assert code == 0, err
    words = shlex.split(printed[-1])
    assert words[0] == "mcrt" and words[-1] == "--retime"
    assert "--variant" in words and words[words.index("--variant") + 1] == "llvm_ad_spectral"
    code, _, err = _run(capsys, *words[1:])
    assert code == 0, err


def test_interrupt_while_the_report_is_written_says_how_to_write_it(study, tmp_path,
                                                                    monkeypatch, capsys):
    """Ctrl-C after the last cell, while the report is written: the cells are
    saved, and the message says the same command writes the report (it said
    only 'mcrt: interrupted'); that command then measures nothing again."""
    import mcrt.cli.compare_cmd as compare_cmd

    config, cache, baseline = study
    monkeypatch.setenv("MCRT_CACHE_DIR", str(cache))
    out = tmp_path / "report"
    real = compare_cmd.write_report

    def interrupted(*args, **kwargs):
        raise KeyboardInterrupt

    monkeypatch.setattr(compare_cmd, "write_report", interrupted)
    code, _, err = _run(capsys, "-q", "compare", str(config), "-o", str(out))
    last = err.strip().splitlines()[-1]
    assert code == 130 and last.startswith("mcrt: interrupted while writing the report; the 4 "
                                           "measured cells are saved: to write it, run: mcrt")
    assert f"compare {config} -o {out}" in last
    monkeypatch.setattr(compare_cmd, "write_report", real)
    code, _, err = _run(capsys, "compare", str(config), "-o", str(out))
    assert code == 0 and "resuming: 4 of 4 cells" in err
    assert [untimed(c) for c in _json(out)["cells"]] == [untimed(c) for c in baseline["cells"]]


def test_a_state_set_aside_by_its_own_command_says_what_resumes_it(tmp_path, notes):
    """The configuration edited in place: the same command line now makes another
    study, so "to resume it, run: <that command>" could not resume the state set
    aside; the note says to restore the inputs instead."""
    path = tmp_path / "study.toml"
    path.write_text(CONFIG)
    state = StudyState.open(tmp_path / "out", load_config(path))
    state.add(_fake_cell("checkerboard", "jittered", 4), None, seconds=1.5)
    path.write_text(CONFIG.replace("seeds = 2", "seeds = 3"))
    assert StudyState.open(tmp_path / "out", load_config(path)).cells == {}
    aside = [m for m in notes if "held the saved state of another study" in m]
    assert aside and "this same command saved it when its inputs were others" in aside[-1]
    assert "to resume it, run:" not in aside[-1]
