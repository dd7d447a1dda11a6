"""The peers' benchmarks: UTK's integrand families and Christensen's funcsamp2D."""

from __future__ import annotations

import json
import math

import numpy as np
import pytest

from mcrt.analysis import peers
from mcrt.samplers.points import point_sets
from tests.conftest import run_cli


def _grid(n: int) -> np.ndarray:
    g = (np.arange(n) + 0.5) / n
    x, y = np.meshgrid(g, g, indexing="ij")
    return np.stack([x.ravel(), y.ravel()], axis=1)


@pytest.mark.parametrize("a, b, c, area", [
    (1.0, 1.0, -1.0, 0.5),        # x + y > 1
    (1.0, 0.0, -0.3, 0.7),        # x > 0.3 (b = 0)
    (0.0, -1.0, 0.25, 0.25),      # y < 0.25
    (-1.0, -1.0, 0.5, 0.125),     # x + y < 0.5: corner triangle
    (2.0, -1.0, 0.0, 0.75),       # y < 2x: steep, the axes swap
    (1.0, 1.0, 5.0, 1.0), (1.0, 1.0, -5.0, 0.0),
])
def test_halfplane_area_exact_cases(a, b, c, area):
    assert peers.halfplane_area(np.array([a]), np.array([b]), np.array([c]))[0] == \
        pytest.approx(area, abs=1e-15)


def test_heaviside_family_matches_a_fine_grid():
    fam = peers.heaviside_family(64, seed=5)
    # midpoint grid of h = 1/1500: the error is at most the area of the cells the
    # edge crosses, <= (2 sqrt 2 / h) h^2 / 2 ~ 1e-3, typically far less
    est = fam.estimates(_grid(1500)[None])[0]
    assert np.max(np.abs(est - fam.exact)) < 1e-3
    assert np.allclose(fam.variance, fam.exact * (1 - fam.exact))
    # random edges through a uniform point: the area is symmetric about 1/2
    assert abs(np.mean(peers.heaviside_family(4096, seed=1).exact) - 0.5) < 0.02


@pytest.mark.slow
def test_gaussian_family_exact_values():
    fam = peers.gaussian_family(64, seed=3)
    est = fam.estimates(_grid(1500)[None])[0]   # midpoint rule: O(h^2) ~ 1e-6 for s >= 0.1
    assert np.max(np.abs(est - fam.exact)) < 2e-6
    second = peers.IntegrandFamily("sq", fam.exact, lambda x: fam.values(x) ** 2, fam.variance)
    var_grid = second.estimates(_grid(1500)[None])[0] - est ** 2
    assert np.max(np.abs(var_grid - fam.variance)) < 2e-6
    assert np.all(fam.exact > 0) and np.all(fam.exact <= 1)


def test_utk_mse_two_way_error():
    est = np.array([[1.0, 2.0], [3.0, 4.0]])
    fig = peers.utk_mse(est, np.zeros(2))
    assert fig.mse == pytest.approx(7.5)
    rows, cols = np.array([2.5, 12.5]), np.array([5.0, 10.0])
    assert fig.stderr == pytest.approx(math.sqrt(np.var(rows, ddof=1) / 2 + np.var(cols, ddof=1) / 2))


def test_white_noise_figure_matches_its_expectation():
    """Independent points: E[figure] = mean Var[f] / N exactly; the margin is 4
    two-way standard errors of the figure (a z-test)."""
    fam = peers.heaviside_family(512, seed=2)
    rng = np.random.default_rng(7)
    fig = peers.utk_mse(fam.estimates(rng.random((64, 64, 2))), fam.exact)
    assert abs(fig.mse - fam.white_noise_mse(64)) < 4 * fig.stderr


def test_jittered_reproduces_utk_stratified_heaviside():
    """Our jittered sampler on our Heaviside database against UTK's published
    stratified figures at N = 16 and 256: the published figure is assumed to have
    our standard error (same design), so the difference has se * sqrt 2; the test
    allows 4 of those. A wrong integrand family (another offset law, an area
    complement) moves the figure by far more."""
    fam = peers.heaviside_family(1024, seed=0)
    for n in (16, 256):
        fig = peers.utk_mse(fam.estimates(point_sets("jittered", 32, n, seed=n)), fam.exact)
        published = peers.UTK_PUBLISHED["stratified"]["heaviside"][n]
        assert abs(fig.mse - published) < 4 * math.sqrt(2) * fig.stderr, (n, fig, published)


def test_funcsamp_reference_values():
    pts = _grid(2000)
    x, y = pts[:, 0], pts[:, 1]
    for name, (f, ref) in peers.FUNCSAMP.items():
        # discontinuous: midpoint-grid error <= h * edge length / 2 (the triangle diagonal
        # runs through grid points: 1 / (2 n) = 2.5e-4); sininvr oscillates near 0
        tol = 6e-4 if name in ("fulldisk", "triangle", "stepx", "quarterdisk", "sininvr") else 2e-6
        assert float(np.mean(f(x, y))) == pytest.approx(ref, abs=tol), name


def test_funcsamp_errors_and_published_rows():
    exact = np.tile(np.array([[[0.25, 0.25], [0.75, 0.75]]]), (3, 1, 1))
    errors = peers.funcsamp_errors(exact)
    assert errors["bilinear"] == pytest.approx(abs((0.0625 + 0.5625) / 2 - 0.25))
    assert errors["lineary"] == pytest.approx(0.0)
    for values in peers.FUNCSAMP_PUBLISHED.values():
        assert len(values) == len(peers.FUNCSAMP_COUNTS) and list(values) == sorted(values)[::-1]


def test_integrate_utk_command(tmp_path, capsys):
    out = tmp_path / "utk"
    code, stdout, _ = run_cli(capsys, "-q", "integrate", "utk", "--sampler", "independent,sobol",
                              "--max-n", "256", "--trials", "4", "--integrands", "32",
                              "-o", str(out))
    assert code == 0
    assert "[UTK]" in stdout and "[E white]" in stdout and "white noise" in stdout
    rows = json.loads((out / "integrate_utk.json").read_text())["rows"]
    assert {(r["family"], r["sampler"], r["n"]) for r in rows} == {
        (f, s, n) for f in ("gaussian", "heaviside") for s in ("independent", "sobol")
        for n in (16, 256)}
    code, stdout, _ = run_cli(capsys, "-q", "integrate", "funcsamp2d", "--sampler", "sobol",
                              "--trials", "8", "-o", str(out))
    assert code == 0 and "sobol_dim01_owen" in stdout and "sininvr" in stdout
    code, _, stderr = run_cli(capsys, "integrate", "utk", "--min-n", "17", "--max-n", "255",
                              "-o", str(out))
    assert code == 2 and "no published sample count" in stderr
