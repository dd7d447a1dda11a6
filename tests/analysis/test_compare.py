"""`mcrt compare`: configuration checks, and the quick study's report end to end."""

from __future__ import annotations

import contextlib
import csv
import fnmatch
import io
import json
import math
import os
import re
import types
import typing
from pathlib import Path

import numpy as np
import pytest

from mcrt.analysis.study import (
    CellScores,
    ConfigError,
    ReferenceImage,
    SamplerSpec,
    fit_sampler,
    load_config,
    study_key,
    summarise_cell,
)
from mcrt.analysis.study.fields import (
    CELL_COLUMNS,
    CELL_FIELDS,
    CELL_KEYS,
    CSV_COLUMNS,
    DEFINITIONS,
    FIT_FIELDS,
    FIT_KEYS,
    Cell,
    record,
)
from mcrt.cli import main
from mcrt.core.provenance import png_text
from mcrt.core.stats import PixelStats
from mcrt.samplers import ALL_SAMPLERS
from tests.conftest import CHECKERBOARD, ROOT, png_text_of, scene_xml, study_toml

QUICK = ROOT / "configs" / "quick.toml"

#: What a module fixture's command printed, by fixture name.
PRINTED: dict[str, str] = {}
FULL = ROOT / "configs" / "full.toml"

GOOD = study_toml(CHECKERBOARD)


def _config(tmp_path: Path, text: str) -> Path:
    path = tmp_path / "study.toml"
    path.write_text(text)
    return path


def test_shipped_configs_are_valid():
    quick = load_config(QUICK)
    assert quick.name == "quick" and len(quick.scenes) == 2 and len(quick.seeds) >= 2
    assert quick.effective_spp[("orthogonal", 16)] == 25  # recorded, not silently used as 16
    full = load_config(FULL)
    # The full study compares every sampler mcrt knows, ours and Mitsuba's, in that order.
    assert tuple(s.name for s in full.samplers) == ALL_SAMPLERS
    assert {s.name for s in full.scenes} == {"checkerboard", "cornell_box"}
    # The 12-seed rerun of the close Cornell cells renders the full study's scene against
    # the same reference settings, so it reuses the full study's cached reference.
    best = load_config(ROOT / "configs" / "cornell_best.toml")
    assert best.reference == full.reference
    cornell = next(s for s in full.scenes if s.name == "cornell_box")
    assert [(s.path, s.params) for s in best.scenes] == [(cornell.path, cornell.params)]
    assert len(best.seeds) > len(full.seeds)


@pytest.mark.parametrize("change, message", [
    (("seeds = 2", "seeds = 2\nsampler = 1"), "unknown key 'sampler'"),
    (('"independent"]', '"independant"]'), "unknown sampler 'independant'"),
    (("checkerboard.xml", "missing.xml"), "scene file not found"),
    (("spp = [4, 16]", "spp = [16]"), "at least two distinct"),
    (("spp = [4, 16]", "spp = [0, 16]"), "spp[] must be in"),
    (("spp = [4, 16]", 'spp = [4, "16"]'), "must be an integer"),
    (("seeds = 2", "seeds = 1"), "at least 2"),
    (("seeds = 2", "seeds = [3, 3]"), "distinct"),
    (("spp = 64", "spp = 32"), "at least 4 x the largest spp"),
    (('"jittered", "independent"', '"jittered", "jittered"'), "appears twice"),
    (('"jittered"', '{name = "jittered", params = {jitter = 2.0}}'), "jitter"),
    (("seeds = 2", "seeds = 2\nimage_spp = 8"), "image_spp"),
    (("[reference]", "[reference\n"), "invalid TOML"),
    (("width = 64", "width = 0"), "the film has 0x48 pixels"),
    (("seeds = 2", "seeds = 2\ntime_rounds = 1"), "time_rounds"),
    (("seeds = 2", "seeds = 2\nbaseline = \"sobol\""), "baseline 'sobol' is not one of"),
])
def test_bad_configs_fail_before_rendering_with_one_line(tmp_path, capsys, change, message):
    path = _config(tmp_path, GOOD.replace(*change))
    with pytest.raises(ConfigError) as error:
        load_config(path)
    assert message in str(error.value) and "\n" not in str(error.value)
    code = main(["-q", "compare", str(path), "-o", str(tmp_path / "out")])
    err = capsys.readouterr().err.strip()
    assert code == 2 and err.startswith("mcrt: error:") and message in err
    assert len(err.splitlines()) == 1
    assert not (tmp_path / "out" / "results.csv").exists()


@pytest.mark.parametrize("variant", ["llvm_ad_mono", "llvm_ad_mono_polarized"])
def test_a_monochrome_variant_is_refused_naming_the_variant(tmp_path, capsys, variant):
    """A monochrome variant develops luminance whatever the film's pixel_format says
    (the checkerboard's is rgb), so the one-line refusal names the variant and does
    not ask for a pixel_format the film already has."""
    code = main(["-q", "--variant", variant, "compare", str(_config(tmp_path, GOOD)),
                 "-o", str(tmp_path / "out")])
    err = capsys.readouterr().err.strip()
    assert code == 2 and len(err.splitlines()) == 1, err
    assert f"the {variant} variant develops luminance only" in err
    assert "llvm_ad_rgb" in err and "pixel_format" not in err
    assert not (tmp_path / "out" / "results.csv").exists()


def test_a_scene_without_box_filter_is_accepted(tmp_path):
    """References develop with the film's own filter: no refusal."""
    scene = tmp_path / "gaussian.xml"
    scene.write_text(CHECKERBOARD.read_text().replace('<rfilter type="box"/>',
                                                      '<rfilter type="gaussian"/>'))
    config = load_config(_config(tmp_path, GOOD.replace(str(CHECKERBOARD), str(scene))))
    assert len(config.scenes) == 1


def test_check_only(tmp_path, capsys):
    code = main(["compare", str(_config(tmp_path, GOOD)), "--check"])
    out = capsys.readouterr().out
    # 4 cells x (warm-up + 5 timed rounds: the 2 seeds' renders and 3 timing-only ones)
    assert code == 0 and "OK" in out and "5 timed rounds: 24 renders" in out


def test_a_tiny_study_survives_nan_pixels(tmp_path, monkeypatch):
    """A render with a NaN pixel is counted, logged and measured as zero error
    there; every metric stays finite and the report is written (~5 s)."""
    import mcrt.core.render as passes
    from mcrt.analysis.report import write_report
    from mcrt.analysis.study import run_study

    monkeypatch.setenv("MCRT_CACHE_DIR", str(tmp_path / "cache"))
    real = passes.render_film

    def poisoned(scene, sampler=None, spp=None, seed=0, **kwargs):
        result = real(scene, sampler, spp=spp, seed=seed, **kwargs)
        if seed == 1:
            result.image[3, 5, 1] = np.nan
        return result

    monkeypatch.setattr(passes, "render_film", poisoned)
    result = run_study(load_config(_config(tmp_path, GOOD)))
    assert [c["nonfinite"] for c in result.cells] == [1, 1, 1, 1]
    for c in result.cells:
        assert all(math.isfinite(c[k]) for k in ("mse", "variance", "aliasing_ratio", "delta_e"))
    files = write_report(result, tmp_path / "report")
    assert files["report"].stat().st_size > 0
    # The runner's cells and fits have exactly the declared fields, and so do the files.
    assert [tuple(c) for c in result.cells] == [CELL_KEYS] * 4
    assert [tuple(f) for f in result.fits] == [FIT_KEYS] * 2
    data = json.loads(files["json"].read_text())
    assert [tuple(c) for c in data["cells"]] == [CELL_KEYS] * 4
    with open(files["csv"], newline="") as f:
        assert tuple(next(csv.reader(f))) == CSV_COLUMNS


def test_a_film_under_32_pixels_is_studied_without_an_aliasing_score(tmp_path, capsys,
                                                                     monkeypatch):
    """A 24 x 16 film (third-party scenes are often small): the study runs, its
    errors are measured, the aliasing verdict is 'n/a' with NaN measures, and the
    CLI says so in a note (it refused such scenes before)."""
    monkeypatch.setenv("MCRT_CACHE_DIR", str(tmp_path / "cache"))
    path = _config(tmp_path, GOOD.replace("width = 64, height = 48", "width = 24, height = 16"))
    code = main(["compare", str(path), "-o", str(tmp_path / "out")])
    err = capsys.readouterr().err
    assert code == 0 and "renders 24x16 pixels: its cells get no aliasing score (n/a" in err
    data = json.loads((tmp_path / "out" / "results.json").read_text())
    assert len(data["cells"]) == 4
    # results.json says how to run the study again, from any folder
    assert data["command"].split() == ["mcrt", "--variant", "llvm_ad_rgb", "compare",
                                       str(path.resolve())]
    figures = sorted((tmp_path / "out").glob("*.png"))  # ... and so does every figure
    assert len(figures) == 4 and all(png_text_of(f) == png_text(data) for f in figures)
    for cell in data["cells"]:
        assert cell["aliasing"] == "n/a" and cell["mse"] > 0 and cell["delta_e"] > 0
        assert cell["aliasing_ratio"] is None or math.isnan(cell["aliasing_ratio"])
    assert "n/a" in (tmp_path / "out" / "report.html").read_text()


# --------------------------------------------------------------------------- declared fields


def _synthetic_cell(spp: int, seeds: int = 2) -> Cell:
    """A cell summarised by the study's own code from synthetic renders."""
    rng = np.random.default_rng(spp)
    ref = rng.random((32, 32, 3))
    renders = [ref + rng.normal(0.0, 0.1 / spp, ref.shape) for _ in range(seeds)]
    per_seed = [{"seed": s, "spp": spp, "seconds": 1e-3 * spp, "nonfinite": 0,
                 "mse": float(np.mean((r - ref) ** 2)), "mean_error": float(np.mean(r - ref)),
                 "rel_mse": 0.1, "delta_e": 1.0,
                 "aliasing": {"ratio": 1.0, "ratio_z": 0.1, "peak": 2.0, "peak_z": -0.2}}
                for s, r in enumerate(renders)]
    sampler = SamplerSpec("jittered", "jittered", {})
    return summarise_cell(CellScores("scene", sampler, spp, per_seed,
                                     PixelStats.from_images(renders)),
                          ReferenceImage(ref, np.full_like(ref, 1e-8), 1e-8))


def test_cell_and_fit_fields_are_declared_once():
    """A cell and a fit have exactly the declared keys, in the declared order;
    results.csv, the definitions and the report's tables use declared fields only."""
    from mcrt.analysis import report

    cells = [_synthetic_cell(spp) for spp in (4, 16)]
    assert all(tuple(c) == CELL_KEYS for c in cells)
    assert tuple(Cell.__annotations__) == CELL_KEYS  # the type the consumers are checked on
    assert Cell.__required_keys__ == frozenset(CELL_KEYS)
    # Each value has the type the declaration says (the per-seed records: dicts).
    hints = typing.get_type_hints(Cell)
    for key, value in cells[0].items():
        expected = typing.get_origin(hints[key]) or hints[key]
        if expected in (typing.Union, types.UnionType):
            expected = tuple(typing.get_origin(t) or t for t in typing.get_args(hints[key]))
        assert isinstance(value, expected) or (expected is float and isinstance(value, int)), key
    assert tuple(fit_sampler("scene", "jittered", cells)) == FIT_KEYS
    with pytest.raises(ValueError, match="undeclared"):
        record(CELL_FIELDS, {**cells[0], "new_metric": 1.0})
    with pytest.raises(ValueError, match="missing"):
        record(CELL_FIELDS, {k: v for k, v in cells[0].items() if k != "mse"})

    names = {f.name for f in CELL_FIELDS}
    assert len(names) == len(CELL_FIELDS) and len(FIT_KEYS) == len(set(FIT_KEYS))
    assert report.CSV_COLUMNS == CSV_COLUMNS and set(CSV_COLUMNS) <= names
    assert [c for c in CSV_COLUMNS if c not in CELL_KEYS] == ["status", "seeds_done",
                                                              "seeds_total", "command",
                                                              "software"]
    assert "per_seed" in CELL_KEYS and "per_seed" not in CSV_COLUMNS
    # Every defined term names declared fields ("aliasing_*_z": both z-scores).
    keys = CELL_KEYS + FIT_KEYS
    for term in DEFINITIONS:
        assert fnmatch.filter(keys, term), term
    assert fnmatch.filter(keys, "aliasing_*_z") == ["aliasing_ratio_z", "aliasing_peak_z"]
    assert {"mse", "resolved", "efficiency", "aliasing", "slope_spp"} <= set(DEFINITIONS)
    # Every companion a table column shows (mse_sd, bias_low, ...) is a declared field.
    suffixes = {"sd": ("_sd",), "se": ("_se",), "interval": ("_low", "_high"), "z": ("_z",)}
    for fields in (CELL_FIELDS, FIT_FIELDS):
        declared = {f.name for f in fields}
        for f in fields:
            if f.column is not None:
                assert {f.name + s for s in suffixes.get(f.column.show, ())} <= declared, f.name
    assert len(report.cell_header()) == len(CELL_COLUMNS) > 4  # scene, sampler, spp, ...


# --------------------------------------------------------------------------- the quick study


@pytest.fixture(scope="module")
def quick(tmp_path_factory):
    """Run configs/quick.toml through the CLI once (references rendered into an
    empty cache, so the test is hermetic)."""
    out = tmp_path_factory.mktemp("quick")
    printed = io.StringIO()
    with pytest.MonkeyPatch.context() as mp, contextlib.redirect_stdout(printed):
        mp.setenv("MCRT_CACHE_DIR", str(tmp_path_factory.mktemp("cache")))
        assert main(["-q", "compare", str(QUICK), "-o", str(out)]) == 0
    PRINTED["quick"] = printed.getvalue()
    data = json.loads((out / "results.json").read_text())
    with open(out / "results.csv", newline="") as f:
        rows = list(csv.DictReader(f))
    return out, data, rows


@pytest.mark.slow
def test_the_printed_efficiency_table_keeps_its_columns_apart(quick):
    """Each row of the efficiency-ratio table has one interval per sample count,
    each ending in ']' and separated from the next by a space, whatever the
    widths the intervals' precision gives them ("0.789 [0.769, 0.810]" ran into its
    neighbour in a 20-character column)."""
    config = load_config(QUICK)
    lines = PRINTED["quick"].splitlines()
    heads = [i for i, line in enumerate(lines) if line.startswith("  efficiency = 1/")]
    assert len(heads) == len(config.scenes)
    for head in heads:
        header = lines[head + 1]
        assert header.split()[1:] == [w for n in config.spp for w in (str(n), "spp")]
        for line in lines[head + 2:head + 2 + len(config.samplers)]:
            cells = re.findall(r"(\S+ \[\S+, \S+\]|unresolved|pending)", line)
            assert len(cells) == len(config.spp), line
            assert all(line.find(c) > 0 and line[line.find(c) - 1] == " " for c in cells), line
            assert len(line) == len(header), (line, header)  # right-aligned in the columns


def _cells(data, scene, sampler):
    return sorted((c for c in data["cells"] if c["scene"] == scene and c["sampler"] == sampler),
                  key=lambda c: c["spp"])


@pytest.mark.slow
def test_quick_study_writes_a_self_contained_report(quick):
    """Slow (~40 s on 2 cores, most of it the study itself, shared by the tests
    below): this is the issue's "the quick study runs in CI time" check."""
    from PIL import Image

    out, data, rows = quick
    names = ["report.html", "results.csv", "results.json", "summary.png", "error_vs_spp.png",
             "error_vs_time.png", "images_checkerboard.png", "images_cornell_box.png"]
    for name in names:
        assert (out / name).stat().st_size > 0, name
    for name in names[3:]:
        with Image.open(out / name) as image:
            assert image.format == "PNG" and min(image.size) > 100
    html = (out / "report.html").read_text()
    assert html.count("data:image/png;base64,") == 3  # summary and error plots
    assert html.count("class='mcrt-viewer'") == 2     # the images: one viewer per scene
    assert len(list((out / "exr").glob("*/*.exr"))) == 2 * (1 + 5 * 3 * 2)
    assert "src='http" not in html and 'src="http' not in html and "<link" not in html
    for label in ("uniform_grid", "jittered", "poisson_disk", "independent", "orthogonal",
                  "checkerboard", "cornell_box", "dr.sync_thread", "warm-up"):
        assert label in html
    assert not list(out.glob(".*.tmp"))  # atomic writes left nothing behind


@pytest.mark.slow
def test_csv_and_json_hold_the_same_cells(quick):
    _, data, rows = quick
    assert len(rows) == len(data["cells"]) == 2 * 5 * 3
    for row, cell in zip(rows, data["cells"], strict=True):
        assert (row["scene"], row["sampler"], int(row["spp"])) == (cell["scene"], cell["sampler"],
                                                                   cell["spp"])
        for key in ("seconds", "mse", "mse_excess", "variance", "efficiency", "aliasing_ratio"):
            if cell[key] is None:
                assert row[key] == "nan"
            else:
                assert float(row[key]) == cell[key]  # repr round-trips exactly


@pytest.mark.slow
def test_numbers_are_finite_and_consistent(quick):
    """Every identity the report relies on, on every cell:
    efficiency = 1 / (excess MSE x time); excess = MSE - floor; the per-seed MSEs
    average to the cell's; and the bias/variance split
    mean_k MSE_k = MSE(mean image) + (K - 1) / K x mean per-pixel variance,
    which holds exactly (up to rounding) when the variance is the unbiased
    between-seed variance of the pixel estimates."""
    _, data, _ = quick
    k = len(data["study"]["seeds"])
    for c in data["cells"]:
        name = (c["scene"], c["sampler"], c["spp"])
        for key in ("seconds", "mse", "mse_floor", "mse_excess", "mse_of_mean", "rel_mse",
                    "variance", "bias", "bias_low", "bias_high", "delta_e", "aliasing_ratio",
                    "aliasing_ratio_z", "aliasing_peak", "aliasing_peak_z"):
            assert c[key] is not None and math.isfinite(c[key]), (name, key)
        assert c["seconds"] > 0 and c["mse"] > 0 and c["variance"] >= 0 and c["nonfinite"] == 0
        assert c["bias_low"] <= c["bias"] <= c["bias_high"]
        assert c["mse_excess"] == pytest.approx(c["mse"] - c["mse_floor"], rel=1e-12)
        assert c["mse"] == pytest.approx(sum(r["mse"] for r in c["per_seed"]) / k, rel=1e-12)
        # the cell's time: the median of its timed renders, the seeds' among them
        assert len(c["times"]) == data["study"]["time_rounds"] >= k
        assert c["seconds"] == pytest.approx(float(np.median(c["times"])), rel=1e-12)
        assert [r["seconds"] for r in c["per_seed"]] == c["times"][:k]
        assert c["seconds_low"] <= c["seconds"] <= c["seconds_high"]
        assert c["mse"] == pytest.approx(c["mse_of_mean"] + (k - 1) / k * c["variance"],
                                         rel=1e-9), name
        if c["resolved"]:
            assert c["efficiency"] == pytest.approx(1 / (c["mse_excess"] * c["seconds"]),
                                                    rel=1e-12), name
            assert c["efficiency_low"] < c["efficiency"] < c["efficiency_high"], name
        else:  # flagged, not silently fitted: too close to the reference's own noise
            assert c["efficiency"] is None and c["mse"] <= 2 * c["mse_floor"], name
    floors = {c["scene"]: c["mse_floor"] for c in data["cells"]}
    for scene, ref in data["references"].items():
        assert ref["noise_floor"] == floors[scene] and ref["spp"] == 1024


@pytest.mark.slow
def test_effective_sample_counts_are_recorded(quick):
    _, data, _ = quick
    for c in data["cells"]:
        expected = {16: 25, 64: 121}.get(c["spp_requested"], c["spp_requested"])
        assert c["spp"] == (expected if c["sampler"] == "orthogonal" else c["spp_requested"])


@pytest.mark.slow
def test_error_falls_with_spp_and_the_uniform_grid_is_deterministic(quick):
    """Jittered's MSE must fall at every step (x4 samples: ~x4-x8 less error,
    while the seed-to-seed spread is < 40% even on the path-traced box). The
    uniform grid puts the film samples at the same cell centres whatever the
    seed (only the pairing of strata across dimensions is seeded), so on the
    checkerboard, where only the film position matters, its renders are
    identical: zero variance between seeds (float32 summation order aside),
    all of its error is bias, and that error is moire."""
    _, data, _ = quick
    for scene in ("checkerboard", "cornell_box"):
        mse = [c["mse_excess"] for c in _cells(data, scene, "jittered")]
        assert mse[0] > 2 * mse[1] > 4 * mse[2] > 0, (scene, mse)
    for c in _cells(data, "checkerboard", "uniform_grid"):
        assert c["variance"] < 1e-9 * c["mse"]
        assert c["mse_of_mean"] == pytest.approx(c["mse"], rel=1e-9)
    assert all(c["variance"] > 0.01 * c["mse"] for c in _cells(data, "cornell_box", "jittered"))
    grid = _cells(data, "checkerboard", "uniform_grid")
    assert grid[0]["aliasing"] == "aliased" and grid[1]["aliasing"] == "aliased"
    for sampler in ("jittered", "poisson_disk", "independent"):
        assert all(c["aliasing"] == "noise" for c in _cells(data, "checkerboard", sampler))


@pytest.mark.slow
def test_independent_sampling_converges_at_minus_one(quick):
    """MSE of independent sampling is sigma^2 / N exactly once the reference's
    noise is removed, so the fitted slope's expectation is -1. The fit's own
    standard error (residuals over 3 spp x 3 seeds, 7 degrees of freedom)
    sets the margin: 5 se is beyond the t(7) 99.9% quantile (5.4 se is 0.1%),
    and se must be small for the check to mean anything (~0.006 measured on
    the checkerboard; the path-traced box is heavier-tailed, ~0.1)."""
    _, data, _ = quick
    for scene, max_se in (("checkerboard", 0.03), ("cornell_box", 0.25)):
        fit = next(f for f in data["fits"] if f["scene"] == scene
                   and f["sampler"] == "independent")
        assert fit["slope_spp_se"] < max_se, fit
        assert abs(fit["slope_spp"] + 1.0) < 5 * fit["slope_spp_se"], fit
        assert fit["points"] == 3 * fit["cells_used"] and fit["cells_used"] == 3
    for fit in data["fits"]:  # every sampler's error falls with samples and with time
        assert fit["slope_spp"] < -0.5 and fit["slope_seconds"] < -0.5, fit
        assert fit["points"] == 3 * fit["cells_used"]


@pytest.mark.slow
def test_a_biased_sampler_is_named_where_people_look(tmp_path, monkeypatch, capsys):
    """configs/bias.toml: Mitsuba's ldsampler is biased on scenes/glossy_bias.xml
    (docs/ldsampler-bias.md). Every ldsampler cell is flagged (|t| of 25-45
    against a Holm threshold of about 7 for t on 3 degrees of freedom over 12
    cells) and no other sampler's: in the console, the
    verdict of results.csv/json, the report's banner and its summary table.
    The others are unbiased by construction, so a flag there would be a false
    alarm, which Holm keeps at 5% per study (benchmarks/bias_false_alarms.py
    measures it over 20 null studies); this study's seeds are fixed, so the
    outcome is too."""
    monkeypatch.setenv("MCRT_CACHE_DIR", str(tmp_path / "cache"))
    out = tmp_path / "bias"
    assert main(["-q", "compare", str(ROOT / "configs" / "bias.toml"), "-o", str(out)]) == 0
    console = capsys.readouterr().out
    data = json.loads((out / "results.json").read_text())
    flagged = {(c["sampler"], c["spp"]) for c in data["cells"] if c["biased"]}
    assert flagged == {("ldsampler", n) for n in (16, 64, 256)}
    for c in data["cells"]:
        assert c["verdict"].endswith("; biased") == c["biased"]
        if c["biased"]:
            assert abs(c["bias_z"]) > 6 and not c["bias_low"] <= 0 <= c["bias_high"]
    assert {(b["sampler"], b["spp"]) for b in data["biased_cells"]} == flagged
    line = next(x for x in console.splitlines() if x.startswith("bias: "))
    assert line.startswith("bias: ldsampler is biased on glossy_bias at 16 spp: ")
    assert "(t = -" in line and "Holm-corrected over 12 cells" in line
    html = (out / "report.html").read_text()
    assert "<b>Bias found.</b>" in html and "ldsampler is biased on glossy_bias" in html
    assert "<b>biased</b> at 16, 64, 256 spp" in html  # the summary table's verdict
    assert "sobol is biased" not in html and "independent is biased" not in html


def test_a_study_plans_each_scene_once(tmp_path, monkeypatch):
    """The checks, the references, the cells and the report's headers share one
    plan of each scene (:func:`mcrt.render.loaded.planned_scene`)."""
    from tests.render.test_loaded import count_plans

    second = f'[[scenes]]\nname = "small"\npath = "{CHECKERBOARD}"\n' \
             'params = { width = 32, height = 24 }\n'
    config = _config(tmp_path, study_toml(CHECKERBOARD) + second)
    monkeypatch.setenv("MCRT_CACHE_DIR", str(tmp_path / "cache"))
    counts = count_plans(monkeypatch)
    assert main(["-q", "compare", str(config), "-o", str(tmp_path / "out")]) == 0
    assert counts == {str(CHECKERBOARD): 2}  # two scenes: one plan each


def test_two_scenes_of_one_file_each_warm_their_cells_up(tmp_path, monkeypatch):
    """The warm-up before a cell's timed renders is per scene, parameters
    included: the second size of one file was taken as warm, and its first timed
    round traced its kernels (148 ms against 1.3 ms for the rounds after)."""
    import mcrt.core.render as passes
    from mcrt.analysis.study.config import WARMUP_SEED

    second = f'[[scenes]]\nname = "small"\npath = "{CHECKERBOARD}"\n' \
             'params = { width = 32, height = 24 }\n'
    config = _config(tmp_path, study_toml(CHECKERBOARD) + second)
    monkeypatch.setenv("MCRT_CACHE_DIR", str(tmp_path / "cache"))
    real, warm_ups = passes.render_film, []

    def counted(scene, sampler=None, spp=None, seed=0, **kwargs):
        result = real(scene, sampler, spp=spp, seed=seed, **kwargs)
        if seed == WARMUP_SEED:
            warm_ups.append((result.image.shape[:2], result.spp))
        return result

    monkeypatch.setattr(passes, "render_film", counted)
    assert main(["-q", "compare", str(config), "-o", str(tmp_path / "out")]) == 0
    # 2 scenes x 2 samplers x 2 sample counts, one warm-up each
    assert sorted(warm_ups) == sorted([(shape, spp) for shape in ((48, 64), (24, 32))
                                       for spp in (4, 16) for _ in range(2)])


def test_a_black_scene_is_studied_to_the_end(tmp_path):
    """A scene without a light renders black, as does its reference: HDR-FLIP
    has no exposure range for such a reference and its library aborted the
    process (no exception: a subprocess here, so the suite survives that). Now
    the study completes, every error is 0 and the error plots say so."""
    import subprocess
    import sys

    scene = tmp_path / "unlit.xml"
    scene.write_text(scene_xml('<shape type="sphere"><bsdf type="diffuse"/></shape>', size=32))
    config = _config(tmp_path, study_toml(scene, params=None))
    env = {**os.environ, "MCRT_CACHE_DIR": str(tmp_path / "cache")}
    run = subprocess.run([sys.executable, "-m", "mcrt", "-q", "compare", str(config),
                          "-o", str(tmp_path / "out")], capture_output=True, text=True,
                         env=env, timeout=600)
    assert run.returncode == 0, run.stderr[-2000:]
    assert "Warning" not in run.stderr  # (matplotlib's about log axes without data)
    data = json.loads((tmp_path / "out" / "results.json").read_text())
    assert len(data["cells"]) == 4
    assert all(cell["mse"] == 0 and cell["delta_e"] == 0 for cell in data["cells"])
    assert (tmp_path / "out" / "report.html").stat().st_size > 0


def test_a_config_s_files_are_found_from_any_folder(tmp_path, monkeypatch):
    """A sampler's point-set file (``params.filename``) is relative to the
    configuration's folder, as its scenes and plugins are, and the recorded
    ``config_path`` is absolute: a study run from another folder finds both."""
    folder = tmp_path / "cfg"
    folder.mkdir()
    (folder / "s.toml").write_text(
        'name = "s"\nspp = [4, 16]\nseeds = 2\n'
        'samplers = ["jittered", {name = "pointset", params = { filename = "sets.npz" }}]\n'
        f'[reference]\nspp = 64\n[[scenes]]\npath = "{CHECKERBOARD}"\n')
    (tmp_path / "elsewhere").mkdir()
    monkeypatch.chdir(tmp_path / "elsewhere")
    config = load_config(Path("../cfg/s.toml"), check_scenes=False)
    assert config.samplers[1].params == {"filename": str(folder.resolve() / "sets.npz")}
    assert config.as_dict()["config_path"] == str(folder.resolve() / "s.toml")
    assert "params" not in config.as_dict()["reference"]  # (results.json as before)


def test_a_reference_sampler_takes_parameters_checked_before_rendering(tmp_path, monkeypatch):
    """``[reference] params``: the reference sampler's plugin parameters (a point-set
    file relative to the configuration's folder), recorded in the configuration's
    record; a parameter the sampler refuses fails the checks in one line."""
    monkeypatch.setenv("MCRT_CACHE_DIR", str(tmp_path / "cache"))
    text = ('name = "s"\nspp = [4, 16]\nseeds = 2\nsamplers = ["jittered"]\n'
            '[reference]\nspp = 64\nsampler = "pointset"\nspp_per_pass = 4\n'
            'params = { filename = "sets.npy" }\n'
            f'[[scenes]]\npath = "{CHECKERBOARD}"\nparams = {{ width = 32, height = 24 }}\n')
    rng = np.random.default_rng(2)
    np.save(tmp_path / "sets.npy", rng.random((16, 4, 2)).astype(np.float32))
    config = load_config(_config(tmp_path, text))
    sets = str(tmp_path.resolve() / "sets.npy")
    assert config.reference.params == {"filename": sets}
    assert config.as_dict()["reference"]["params"] == {"filename": sets}
    key = study_key(config)  # a saved study is not resumed against other points
    np.save(tmp_path / "sets.npy", rng.random((16, 4, 2)).astype(np.float32))
    assert study_key(load_config(_config(tmp_path, text))) != key
    with pytest.raises(ConfigError, match="reference of scene 'checkerboard': .*randomize"):
        load_config(_config(tmp_path, text.replace('"sets.npy"', '"sets.npy", randomize = "no"')))
