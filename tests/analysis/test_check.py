"""``mcrt check``: the suite passes good samplers and catches broken ones.

Real samplers, fixed seeds, the quick budget (every shipped sampler also at the
full one). The broken samplers are made the way a user would make them:
``register_sampler`` with a point generator (points squeezed into [0, 0.9)^2:
biased; independent points that claim strata) and Dr.Jit :class:`McrtSampler`
subclasses that add a fresh Python random number on every call (not
deterministic), or claim quadrature with biased points in every dimension.
Samplers that serve only some counts: ``pointset`` files of 64-point sets and
of 16, 64 and 256-point sets.
"""

from __future__ import annotations

import importlib
import json
import random
import re

import drjit as dr
import mitsuba as mi
import numpy as np
import pytest

import mcrt
from mcrt.analysis.check import FULL, QUICK, Subject, run_checks
from mcrt.analysis.check_claims import EDGE_TOL, check_stratified, one_per_cell
from mcrt.analysis.check_stats import check_unbiasedness
from mcrt.samplers import registry
from mcrt.samplers.kit import hash_extend, unit_float
from mcrt.samplers.point_sources import jittered_sets
from tests.conftest import ROOT, run_cli


@pytest.fixture
def register():
    """``register(name, **how)``: a user's sampler, unregistered afterwards."""
    names: list[str] = []

    def add(name: str, **how) -> str:
        names.append(mcrt.register_sampler(name, **how))
        return name
    yield add
    for name in names:
        registry.unregister(name)


def _rows(out: str) -> dict[str, str]:
    """Printed table rows by property: their result column."""
    rows = {}
    for line in out.splitlines():
        parts = line.split()
        if len(parts) >= 2 and parts[1] in ("pass", "FAIL", "skip"):
            rows[parts[0]] = parts[1]
    return rows


def test_jittered_passes_and_writes_the_report(capsys, tmp_path):
    code, out, err = run_cli(capsys, "check", "jittered", "--quick", "-q", "-o", str(tmp_path))
    assert code == 0, out + err
    rows = _rows(out)
    assert set(rows.values()) == {"pass"}
    assert {"determinism", "range", "clone", "fork", "seeding", "pixels", "stratified",
            "unbiasedness", "mse_rate", "discrepancy", "spectrum"} == set(rows)
    assert "all 11 checks hold" in out
    data = json.loads((tmp_path / "results.json").read_text())
    assert data["passed"] and data["sampler"] == "jittered" and data["quick"]
    assert [c["name"] for c in data["checks"]] == list(rows)
    rate = next(c for c in data["checks"] if c["name"] == "mse_rate")["values"]
    assert -1.7 < rate["disk"]["slope"] < -1.3 and -2.2 < rate["gaussian"]["slope"] < -1.8
    for name in ("points.png", "mse.png", "radial.png"):
        assert (tmp_path / name).stat().st_size > 1000
        assert name in (tmp_path / "report.html").read_text()


def test_biased_sampler_fails_unbiasedness(capsys, register):
    register("biased_test", points=lambda c, n, rng: 0.9 * rng.random((c, n, 2)),
             randomize="none")
    code, out, _ = run_cli(capsys, "check", "biased_test", "--quick", "-q")
    assert code == 1
    rows = _rows(out)
    assert rows["unbiasedness"] == "FAIL" and rows["determinism"] == "pass"
    line = next(x for x in out.splitlines() if x.startswith("unbiasedness"))
    assert "biased: " in line
    assert re.search(r"disk: bias \+2[2-5]\.", line)  # 1 / 0.81: +23.5% on the disk
    assert "FAIL: " in out and "unbiasedness" in out.splitlines()[-1]


def _biased_1d_class() -> type:
    base = importlib.import_module("mcrt.samplers.base").McrtSampler

    class Biased1D(base):  # type: ignore[misc, valid-type]
        """Uniform 2D samples, but u^2 for every 1D sample (mean 1/3, not 1/2)."""

        plugin_name = "biased_1d_test"

        def _sample_1d(self, key, sample, active=True):
            u = unit_float(hash_extend(key, sample))
            return u * u

        def _sample_2d(self, key, sample, active=True):
            return mi.Point2f(unit_float(hash_extend(key, sample)),
                              unit_float(hash_extend(key, sample + 0x9E3779B9)))
    return Biased1D


def test_a_sampler_biased_in_its_1d_samples_fails_unbiasedness(capsys, register):
    """BSDF lobes and Russian roulette draw 1D samples: the 2D integrands alone
    passed this sampler (all 9 checks held)."""
    register("biased_1d_test", sampler=_biased_1d_class())
    code, out, _ = run_cli(capsys, "check", "biased_1d_test", "--quick", "-q")
    assert code == 1 and _rows(out)["unbiasedness"] == "FAIL"
    line = next(x for x in out.splitlines() if x.startswith("unbiasedness"))
    assert re.search(r"u call 2: bias -3[2-4]\.", line)  # E[u^2] = 1/3: -33.3%
    assert "pi:" not in line and "disk:" not in line  # the 2D calls stay unbiased


def _nondeterministic_class() -> type:
    base = importlib.import_module("mcrt.samplers.base").McrtSampler  # the active variant's

    class NonDeterministic(base):  # type: ignore[misc, valid-type]
        """Adds a fresh Python random number to every value (mod 1): uniform, unbiased,
        but two instances with the same seed never agree."""

        plugin_name = "nondet_test"

        def _sample_1d(self, key, sample, active=True):
            v = unit_float(hash_extend(key, sample)) + dr.opaque(mi.Float, random.random())
            return dr.select(v >= 1.0, v - 1.0, v)

        def _sample_2d(self, key, sample, active=True):
            return mi.Point2f(self._sample_1d(key, sample, active),
                              self._sample_1d(hash_extend(key, 0x2D), sample, active))
    return NonDeterministic


def test_nondeterministic_sampler_fails_determinism(capsys, register):
    register("nondet_test", sampler=_nondeterministic_class())
    code, out, _ = run_cli(capsys, "check", "nondet_test", "--quick", "-q")
    assert code == 1
    rows = _rows(out)
    assert rows["determinism"] == "FAIL" and rows["range"] == "pass"
    line = next(x for x in out.splitlines() if x.startswith("determinism"))
    assert "100% of values differ" in line


def test_a_claim_that_does_not_hold_fails(register):
    """Independent points that claim strata: the stratified row fails, with counts."""
    register("false_claim_test", points=lambda c, n, rng: rng.random((c, n, 2)),
             randomize="shift", claims=("stratified",))
    result = check_stratified(Subject("false_claim_test"), QUICK)
    assert not result.passed and "not one point per cell" in result.detail


@pytest.mark.slow
@pytest.mark.parametrize("quick", [True, False], ids=["quick", "full"])
@pytest.mark.parametrize("name", registry.names("mcrt"))
def test_every_shipped_sampler_passes(name, quick):
    results = run_checks(name, quick=quick)
    assert all(r.status == "pass" for r in results), [
        (r.name, r.status, r.detail) for r in results if r.status != "pass"]
    claims = registry.info(name).claims
    assert claims <= {r.name for r in results if not r.skipped}  # every claim was checked


def test_uniform_grid_reports_its_film_bias_without_failing():
    """Its film estimate is a fixed quadrature (no sampling error, biased by
    design, claimed): reported, not tested; the other dimensions are randomly
    shifted lattices, tested, unbiased, and independent of each other."""
    result = check_unbiasedness(Subject("uniform_grid"), QUICK)
    assert result.passed and "film terms (quadrature, biased by design, not tested)" in result.detail
    assert re.search(r"disk \+49\.\d\d%", result.detail)
    tested = {k for k, v in result.values.items() if v["tested"]}
    assert tested == {f"{g} {term}" for g in ("pi", "disk", "gaussian")
                      for term in ("call 4", "call 3 x 4")} | {"u call 2", "u < 1/3 call 2"}
    assert result.values["disk"]["relative_bias"] > 0.4 and result.values["disk"]["p"] is None


MITSUBA_SAMPLERS = ("independent", "stratified", "multijitter", "orthogonal", "ldsampler")


@pytest.mark.parametrize("name", [*registry.names("mcrt"), *MITSUBA_SAMPLERS])
def test_every_shipped_sampler_passes_the_pixels_row(name):
    """Each hashes (or scrambles by) the pixel: no tested call shares a value
    with another pixel (chance: <= 0.01% at 8 px x 16; a value in common would
    be 1.6%); the limit is 50% above chance."""
    from mcrt.analysis.check import check_pixels

    result = check_pixels(Subject(name), QUICK)
    assert result.passed, result.detail
    shared = [s for s, t in zip(result.values["shared"], result.values["tested"], strict=True)
              if t]
    assert shared and max(shared) < 0.05, result.detail


def test_pixels_shared_by_design_are_reported_not_tested(cache):
    """uniform_grid's film call is the same grid in every pixel (claimed, the
    quadrature row checks it): 100%, reported. A pointset of T = 16 sets with
    randomize none shares sets between pixels as documented, 1 - (15/16)^15 =
    62% expected at 16 px (44-62% seen, 88% in a quick call): its 2D calls are
    reported, its stratified 1D calls tested; with a shift every call is tested."""
    from mcrt.analysis.check import check_pixels
    from mcrt.samplers.point_sources import example_file

    grid = check_pixels(Subject("uniform_grid"), FULL)
    assert grid.passed and grid.values["shared"][0] == 1.0
    assert grid.values["tested"] == [False] + [True] * 5
    assert "call 1 (2d) 100% shared, not tested: quadrature" in grid.detail
    sets = str(example_file(16, sets=16))
    table = check_pixels(Subject("pointset", {"filename": sets, "randomize": "none"}), FULL)
    assert table.passed and table.values["tested"] == [c == "1d" for c in
                                                       ("2d", "1d", "1d", "2d", "2d", "1d")]
    assert max(table.values["shared"]) > 0.4, table.detail
    assert "16 unshifted table sets (randomize=none)" in table.detail
    assert "(~62.0% expected)" in table.detail
    shifted = check_pixels(Subject("pointset", {"filename": sets, "randomize": "shift"}), FULL)
    assert shifted.passed and all(shifted.values["tested"]), shifted.detail


def _biased_quadrature_class() -> type:
    base = importlib.import_module("mcrt.samplers.base").McrtSampler

    class BiasedQuadrature(base):  # type: ignore[misc, valid-type]
        """Claims quadrature, but every dimension (film or not) is squeezed into [0, 0.9)."""

        plugin_name = "biased_quadrature_test"
        claims = frozenset({"quadrature"})

        def _sample_1d(self, key, sample, active=True):
            return 0.9 * unit_float(hash_extend(key, sample))

        def _sample_2d(self, key, sample, active=True):
            return mi.Point2f(self._sample_1d(key, sample, active),
                              self._sample_1d(hash_extend(key, 0x2D), sample, active))
    return BiasedQuadrature


def test_claiming_quadrature_does_not_excuse_the_other_dimensions(capsys, register):
    register("biased_quadrature_test", sampler=_biased_quadrature_class())
    code, out, _ = run_cli(capsys, "check", "biased_quadrature_test", "--quick", "-q")
    assert code == 1
    rows = _rows(out)
    assert rows["unbiasedness"] == "FAIL" and rows["quadrature"] == "FAIL"
    line = next(x for x in out.splitlines() if x.startswith("unbiasedness"))
    assert re.search(r"disk call 4: bias \+2[2-5]\.", line)  # not a film term, tested
    assert "film terms (quadrature" in line


def _rate_line(out: str) -> str:
    return next(x for x in out.splitlines() if x.startswith("mse_rate"))


def test_a_file_of_64_point_sets_is_checked_at_64(capsys, tmp_path):
    path = tmp_path / "sets64.npy"
    np.save(path, jittered_sets(1024, 64, np.random.default_rng(5)).astype(np.float32))
    assert Subject("pointset", {"filename": str(path)}).served == (64,)
    assert mi.load_dict({"type": "pointset", "filename": str(path)}).sample_counts() == (64,)
    code, out, err = run_cli(capsys, "check", "pointset", "-P", f"filename={path}", "-q")
    assert code == 0, out + err
    rows = _rows(out)
    assert rows.pop("mse_rate") == "skip" and set(rows.values()) == {"pass"}
    assert "serves N = 64: 1 in 16..16384, a rate needs 3" in _rate_line(out)
    assert "x 64 spp" in next(x for x in out.splitlines() if x.startswith("unbiasedness"))
    assert "N = 64" in next(x for x in out.splitlines() if x.startswith("discrepancy"))
    assert "(1 skipped)" in out.splitlines()[-1]
    code, out, err = run_cli(capsys, "check", "pointset", "-P", f"filename={path}", "--spp",
                             "16", "-q")
    assert code == 2 and "pointset serves 64 samples per pixel, not 16" in err
    assert len(err.strip().splitlines()) == 1


def test_a_file_of_three_set_sizes_gets_a_rate_and_takes_spp(capsys, tmp_path):
    path = tmp_path / "sets.npz"
    np.savez(path, **{f"n{n}": jittered_sets(1024, n, np.random.default_rng(n)).astype(np.float32)
                      for n in (16, 64, 256)})
    code, out, err = run_cli(capsys, "check", "pointset", "-P", f"filename={path}", "--quick",
                             "-q", "--spp", "64", "-o", str(tmp_path / "report"))
    assert code == 0, out + err
    assert set(_rows(out).values()) == {"pass"}
    assert "N = 16..256" in _rate_line(out)
    assert "1024 px x 64 spp" in next(x for x in out.splitlines() if x.startswith("unbias"))
    data = json.loads((tmp_path / "report" / "results.json").read_text())
    assert data["spp"] == 64 and data["budget"]["contract_spp"] == 64


def test_one_per_cell_forgives_rounding_onto_a_border_only():
    k = 4
    cells = np.stack(np.meshgrid(np.arange(k), np.arange(k)), -1).reshape(-1, 2)
    points = (cells + np.random.default_rng(1).random((k * k, 2))) / k
    assert one_per_cell(points[None], k, k).all()
    rounded = points.copy()
    rounded[5] = (cells[5] + 1.0) / k  # u -> 1 rounded up onto the next cells' border
    assert one_per_cell(rounded[None], k, k).all()
    assert not one_per_cell(rounded[None], k, k, tol=0.0).all()
    moved = points.copy()
    moved[5] = (cells[5] + 1.0 + 4 * EDGE_TOL * k) / k  # really in the next cell
    assert not one_per_cell(moved[None], k, k).all()
    assert not one_per_cell(points[None, :-1], k, k).all()  # a point missing


@pytest.mark.parametrize("argv, message", [
    (("nope",), "unknown sampler 'nope'"),
    (("jittered", "-P", "jitter=2"), "jitter"),
    (("jittered", "-P", "seed=3"), "--param seed"),
])
def test_user_errors_exit_2(capsys, argv, message):
    code, out, err = run_cli(capsys, "check", *argv, "--quick", "-q")
    assert code == 2 and message in err and "Traceback" not in err


def test_ldsampler_fails_on_products_across_dimensions():
    """Mitsuba's ldsampler gives every dimension of a pixel the same points,
    reordered (docs/ldsampler-bias.md): each dimension alone is unbiased, the
    product of two is not (+4.5% on disk call 1 x 4, t ~ 10, at the full budget)."""
    result = check_unbiasedness(Subject("ldsampler"), FULL)
    assert not result.passed
    t = {name: v["t"] for name, v in result.values.items()}
    assert t["disk call 1 x 4"] > 6 and t["gaussian call 1 x 4"] > 6
    assert all(abs(value) < 3 for name, value in t.items() if " x " not in name)


@pytest.mark.parametrize("name, spp", [("jittered", 4), ("independent", 4), ("sobol", 2)])
def test_a_count_without_low_frequencies_skips_the_spectrum(capsys, name, spp):
    """At N <= 4 the lowest frequency 1 / sqrt(N) is 0.5 or more: the band
    0 < f < 0.5 is empty, so the spectrum is skipped with the reason (it was a
    NaN and a FAIL, for Mitsuba's own independent sampler too)."""
    code, out, _ = run_cli(capsys, "check", name, "--spp", str(spp), "--quick", "-q")
    assert code == 0, out
    line = next(x for x in out.splitlines() if x.startswith("spectrum"))
    assert "skip" in line and "has no frequency 0 < f < 0.5" in line


def _interrupted_generator(count, n, rng):
    raise KeyboardInterrupt  # what Ctrl-C raises in a slow point generator


def test_ctrl_c_inside_a_point_generator_interrupts_check_and_render(capsys, register,
                                                                     tmp_path):
    """Mitsuba hands a Ctrl-C inside a Python plugin on as a RuntimeError: `mcrt
    check` took it for the sampler's failure and ran to the end (exit 0), `mcrt
    render` said 'cannot create sampler' (exit 2). Both stop: exit 130."""
    from mcrt.core.sampling import make_sampler

    register("interrupted_test", points=_interrupted_generator)
    with pytest.raises(KeyboardInterrupt):
        make_sampler("interrupted_test", 16)
    code, _, err = run_cli(capsys, "check", "interrupted_test", "--quick", "-q")
    assert code == 130 and "interrupted" in err
    code, _, err = run_cli(capsys, "render", str(ROOT / "scenes" / "cornell_box.xml"), "-D",
                           "res=16", "--sampler", "interrupted_test", "--spp", "4", "-o",
                           str(tmp_path / "unused"))
    assert code == 130 and "interrupted" in err and "cannot create sampler" not in err


def _scalar_1d_class() -> type:
    base = importlib.import_module("mcrt.samplers.base").McrtSampler

    class Scalar1D(base):  # type: ignore[misc, valid-type]
        """One value for a whole wavefront of 1D samples."""

        plugin_name = "scalar_1d_test"

        def _sample_1d(self, key, sample, active=True):
            return mi.Float(0.25)

        def _sample_2d(self, key, sample, active=True):
            return mi.Point2f(unit_float(hash_extend(key, sample)),
                              unit_float(hash_extend(key, sample + 0x9E3779B9)))
    return Scalar1D


def test_a_sampler_returning_one_value_for_all_lanes_is_told_so(capsys, register):
    """The rows that draw it say what is wrong (they printed numpy's reshape and
    axis errors)."""
    register("scalar_1d_test", sampler=_scalar_1d_class())
    code, out, _ = run_cli(capsys, "check", "scalar_1d_test", "--quick", "-q")
    assert code == 1
    line = next(x for x in out.splitlines() if x.startswith("unbiasedness"))
    assert "call 2 (next_1d) returned 1 value for 16384 lanes" in line
    assert "reshape" not in out and "AxisError" not in out


def _half_2d_class() -> type:
    base = importlib.import_module("mcrt.samplers.base").McrtSampler

    class Half2D(base):  # type: ignore[misc, valid-type]
        """2D calls return a point for only the first half of the lanes."""

        plugin_name = "half_2d_test"

        def _sample_1d(self, key, sample, active=True):
            return unit_float(hash_extend(key, sample))

        def _sample_2d(self, key, sample, active=True):
            u = self._sample_1d(key, sample, active)
            first = dr.gather(mi.Float, u, dr.arange(mi.UInt32, dr.width(u) // 2))
            return mi.Point2f(first, first)
    return Half2D


def test_a_sampler_returning_too_few_points_is_told_so_everywhere(capsys, register, tmp_path):
    """A 2D call with half the lanes' points: check's contract rows counted the
    coordinates ("returned 128 values for 128 lanes"), its MSE rate, discrepancy and
    spectrum rows printed numpy's IndexError, and mcrt integrate and mcrt pattern
    ended in that traceback; point_sets now says so in one line."""
    register("half_2d_test", sampler=_half_2d_class())
    code, out, _ = run_cli(capsys, "check", "half_2d_test", "--quick", "-q")
    assert code == 1 and "call 1 (next_2d) returned 64 points for 128 lanes" in out
    assert "IndexError" not in out and "values for" not in out
    rate = next(x for x in out.splitlines() if x.startswith("mse_rate"))
    assert "half_2d_test: next_2d (dimension 0) returned 2048 points for 4096 lanes" in rate
    for argv in (["integrate", "disk", "--sampler", "half_2d_test", "--max-n", "16"],
                 ["pattern", "half_2d_test", "--spp", "16"]):
        code, _, err = run_cli(capsys, "-q", *argv, "-o", str(tmp_path / argv[0]))
        assert code == 2 and err.count("\n") == 1 and "Traceback" not in err, err
        assert "half_2d_test: next_2d (dimension 0) returned" in err


def test_a_shared_table_products_and_degrees_of_freedom_are_calibrated(register, cache):
    """40 tables of T = 16 i.i.d. sets (a correct sampler), 1024 pixels each: the
    tables' own error dominates every t. Both calls of a product see the one table's
    error e, so the product's error is 2 I e and its t must follow the single call's
    t (slope 1 across tables); its standard error used the product's own per-pixel
    SD, which is smaller than 2 I sd (disk: sqrt(4 I^2 sd^2 / sd_prod^2) = 1.16), so
    the product's t ran 1.15x the single call's (measured 1.16, 1.15) and false alarms
    reached ~0.9% at T = 16, P = 16384 (9 of 1000 tables), not 0.1%. t is nearly
    proportional between the two (correlation 0.99), so the slope over 40 tables is
    within +-0.03 of its value (measured 0.98, 1.00 now); bounds [0.9, 1.07]. The
    SDs behind the table's error come from T sets: T - 1 degrees of freedom. (Its 40
    tables go to a private cache, ``cache``.)"""
    from dataclasses import replace

    from mcrt.analysis.check_stats import ALPHA
    from mcrt.analysis.significance import t_quantile

    budget = replace(QUICK, unbiased_pixels=1024)
    rows = []
    for seed in range(40):
        register(f"table_{seed}_test", points=lambda c, n, rng: rng.random((c, n, 2)),
                 sets=16, seed=seed)
        result = check_unbiasedness(Subject(f"table_{seed}_test"), budget)
        rows.append([result.values[k]["t"] for k in ("disk", "disk call 1 x 4", "gaussian",
                                                    "gaussian call 1 x 4")])
    t = np.array(rows)
    for single, product in ((0, 1), (2, 3)):
        slope = np.sum(t[:, single] * t[:, product]) / np.sum(t[:, single] ** 2)
        assert 0.9 < slope < 1.07, slope
    limit = t_quantile(1 - ALPHA / (2 * len(result.values)), 15)
    assert f"|t| > {limit:.2f} fails" in result.detail and limit > 5
