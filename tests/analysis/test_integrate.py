"""The integration bench: integrands, MSE statistics, slope fits, `mcrt integrate`."""

from __future__ import annotations

import csv
import json
import math
from pathlib import Path

import numpy as np
import pytest
from scipy import integrate as sci_integrate

from mcrt.analysis import integrate as ib
from mcrt.cli.integrate_cmd import sample_counts
from mcrt.core.provenance import software_text
from tests.conftest import run_cli


def _csv_rows(path: Path) -> list[dict[str, str]]:
    """An integrate CSV's rows, read with ``csv``: its ``command`` column may hold
    commas (``--sampler a,b``), quoted."""
    with path.open(newline="", encoding="utf-8") as handle:
        return list(csv.DictReader(handle))

# --------------------------------------------------------------------------- integrands

def test_gaussian_exact_value_matches_quadrature():
    f = ib.INTEGRANDS["gaussian"].function
    value, error = sci_integrate.dblquad(lambda y, x: float(f(np.array(x), np.array(y))),
                                         0, 1, 0, 1, epsabs=1e-13, epsrel=1e-13)
    assert error < 1e-10
    assert ib.INTEGRANDS["gaussian"].exact == pytest.approx(value, abs=1e-10)


@pytest.mark.parametrize("name", ["pi", "disk"])
def test_indicator_exact_values_match_a_fine_grid(name):
    """Midpoint rule on a 4096^2 grid: an indicator's error is bounded by the cells
    the boundary crosses, ~ perimeter x h = 2 pi r / 4096 < 2e-3 (x4 for pi)."""
    integrand = ib.INTEGRANDS[name]
    t = (np.arange(4096) + 0.5) / 4096
    total = sum(np.mean(integrand.function(np.full_like(t, x), t)) for x in t) / 4096
    assert total == pytest.approx(integrand.exact, abs=(8e-3 if name == "pi" else 2e-3))
    assert ib.INTEGRANDS["pi"].exact == math.pi


def test_estimates_are_means_over_each_trial():
    pts = np.random.default_rng(0).random((5, 10, 2)).astype(np.float32)
    est = ib.INTEGRANDS["disk"].estimates(pts)
    direct = [np.mean([(x - 0.5) ** 2 + (y - 0.5) ** 2 <= 0.16 for x, y in p.astype(np.float64)])
              for p in pts]
    assert est.shape == (5,) and np.allclose(est, direct)


# --------------------------------------------------------------------------- statistics

def test_mse_summary_standard_error_for_gaussian_errors():
    """For Gaussian errors se_log -> sqrt(2 / P). se_log is itself estimated from
    the sample SD of e^2: with Y = e^2, E[(Y - EY)^4] / Var[Y]^2 = 60 / 4 = 15, so
    the sample variance of Y has relative SD sqrt(14 / P) and its root half of
    that, 2.9% at P = 4096 (the mean adds ~1%); we allow 15% (5 sigma)."""
    p = 4096
    errors = np.random.default_rng(1).normal(0.0, 0.3, p)
    s = ib.mse_summary(errors)
    assert s.mse == pytest.approx(np.mean(errors ** 2))
    assert s.rmse == pytest.approx(math.sqrt(s.mse))
    assert s.trials == p
    assert s.se_log == pytest.approx(math.sqrt(2 / p), rel=0.15)


def test_mse_summary_of_a_deterministic_estimator():
    s = ib.mse_summary(np.full(10, 0.25))
    assert s.mse == 0.0625 and s.se_log == 0.0 and s.bias == 0.25
    with pytest.raises(ValueError):
        ib.mse_summary(np.array([1.0]))


def test_fit_slope_recovers_an_exact_power_law():
    n = 4.0 ** np.arange(2, 9)
    fit = ib.fit_slope(n, 3.0 * n ** -1.5, np.full(n.size, 0.05))
    assert fit.slope == pytest.approx(-1.5, abs=1e-12)
    assert fit.mse_at(100.0) == pytest.approx(3.0 * 100 ** -1.5)
    unweighted = ib.fit_slope(n, 3.0 * n ** -1.5)
    assert unweighted.slope == pytest.approx(-1.5, abs=1e-12) and unweighted.stderr < 1e-9
    assert math.isnan(ib.fit_slope([16], [0.1]).slope)


def test_fit_slope_standard_error_is_calibrated():
    """Simulate 2000 data sets with known per-point standard errors: the spread of
    the fitted slopes must match the reported stderr. The sample SD of 2000
    draws is uncertain by 1/sqrt(2 x 2000) = 1.6%; we allow 8% (5 sigma)."""
    rng = np.random.default_rng(2)
    n = 4.0 ** np.arange(2, 9)
    se = np.array([0.04, 0.04, 0.04, 0.04, 0.04, 0.09, 0.18])
    slopes, chi2 = [], []
    for _ in range(2000):
        mse = np.exp(np.log(2.0) - np.log(n) + se * rng.normal(size=n.size))
        fit = ib.fit_slope(n, mse, se)
        slopes.append(fit.slope)
        chi2.append(fit.chi2_dof)
    reported = ib.fit_slope(n, n ** -1.0, se).stderr
    assert np.std(slopes) == pytest.approx(reported, rel=0.08)
    assert abs(np.mean(slopes) + 1.0) < 5 * reported / math.sqrt(2000)
    # chi2/dof of a true power law: mean 1, SD sqrt(2 / 5) per fit, 0.014 over 2000
    assert np.mean(chi2) == pytest.approx(1.0, abs=0.07)


def test_fit_slope_flags_curvature():
    """A bent curve (slope -1 then -2) fitted with tiny errors: chi2/dof >> 1 and
    the scaled standard error grows by sqrt(chi2/dof)."""
    n = 4.0 ** np.arange(2, 9)
    mse = np.where(n < 1000, 1 / n, 1000 / n ** 2)
    fit = ib.fit_slope(n, mse, np.full(n.size, 0.01))
    assert fit.chi2_dof > 100
    assert fit.stderr_scaled == pytest.approx(fit.stderr * math.sqrt(fit.chi2_dof))
    exact = ib.fit_slope(n, 1 / n, np.full(n.size, 0.01))
    assert exact.chi2_dof < 1e-20 and exact.stderr_scaled == exact.stderr


def test_trials_and_counts():
    assert ib.trials_for(16) == 1024
    assert ib.trials_for(65536) == 64
    assert ib.trials_for(1 << 20, budget=1 << 10) == 16  # never fewer than 16
    assert sample_counts(16, 65536) == [16, 64, 256, 1024, 4096, 16384, 65536]
    assert sample_counts(10, 100) == [10, 40]
    assert ib.effective_count("orthogonal", 16) == 25
    assert ib.effective_count("jittered", 50) == 64
    assert ib.effective_count("ldsampler", 16) == 16


# --------------------------------------------------------------------------- the bench

def test_run_convergence_independent_is_unbiased():
    """The trials' mean estimate of pi is within 4 standard errors of pi, the
    standard error being the RMSE / sqrt(P) (the estimator is unbiased)."""
    res = ib.run_convergence("independent", ["pi", "gaussian"], counts=(16, 64), seed=5,
                             timed=False)
    assert set(res) == {"pi", "gaussian"}
    for conv in res.values():
        assert [p.n for p in conv.points] == [16, 64] and not conv.skipped
        for p in conv.points:
            assert p.trials == 1024 and p.estimates.shape == (1024,)
            se = p.summary.rmse / math.sqrt(p.trials)
            assert abs(np.mean(p.estimates) - p.exact) < 4 * se
            assert not p.deterministic
    # both integrands are evaluated on the same points, in the same timed call
    pi16, gauss16 = res["pi"].points[0], res["gaussian"].points[0]
    assert pi16.seconds == gauss16.seconds


def test_run_convergence_skips_counts_a_sampler_refuses():
    res = ib.run_convergence("poisson_disk", ["disk"], counts=(16, 65536), budget=1 << 12,
                             timed=True)
    conv = res["disk"]
    assert [p.n for p in conv.points] == [16]
    assert conv.skipped and conv.skipped[0][0] == 65536 and "16384" in conv.skipped[0][1]
    assert conv.points[0].seconds > 0 and conv.points[0].ns_per_sample > 0


def test_run_convergence_uniform_grid_is_deterministic():
    conv = ib.run_convergence("uniform_grid", ["disk"], counts=(16, 64, 256), timed=False)["disk"]
    assert conv.deterministic
    for p in conv.points:
        assert p.summary.mse == pytest.approx(p.summary.bias ** 2, rel=1e-9)
    fit = conv.fit()
    assert fit.points == 3 and math.isfinite(fit.slope)


def test_a_tiny_integrand_is_not_deterministic(monkeypatch):
    """The Gaussian times 1e-30 on the same points: every error scales by 1e-30, so
    the weighted fit is the Gaussian's (ln MSE shifts by a constant). The spread of
    the estimates (~1e-31) was compared with 1e-12 x max(1, |I|), which called the
    trials identical: an unweighted fit, no chi2/dof, and "deterministic" printed."""
    gaussian = ib.INTEGRANDS["gaussian"]
    monkeypatch.setitem(ib.INTEGRANDS, "tiny", ib.Integrand(
        "tiny", "1e-30 x gaussian", 1e-30 * gaussian.exact,
        lambda x, y: 1e-30 * gaussian.function(x, y)))
    res = ib.run_convergence("independent", ["gaussian", "tiny"], counts=(16, 64, 256),
                             max_trials=256, seed=3, timed=False)
    tiny, reference = res["tiny"], res["gaussian"]
    assert not tiny.deterministic and not any(p.deterministic for p in tiny.points)
    fit, ref = tiny.fit(), reference.fit()
    assert fit.slope == pytest.approx(ref.slope, rel=1e-9)
    assert fit.stderr == pytest.approx(ref.stderr, rel=1e-9)
    assert math.isfinite(fit.chi2_dof) and fit.chi2_dof == pytest.approx(ref.chi2_dof, rel=1e-6)


def test_run_convergence_rejects_unknown_integrands():
    with pytest.raises(ib.McrtError, match="unknown integrand"):
        ib.run_convergence("independent", ["nope"])


# --------------------------------------------------------------------------- CLI

def test_integrate_command(tmp_path, capsys):
    out = tmp_path / "int"
    code, stdout, _ = run_cli(capsys, "-q", "integrate", "pi", "--sampler",
                              "independent,orthogonal,uniform_grid", "--max-n", "256",
                              "--trials", "64", "-o", str(out))
    assert code == 0
    assert "MSE slope" in stdout and "published rate -1" in stdout
    assert "deterministic" in stdout  # uniform_grid
    assert " 289 " in stdout  # orthogonal's effective N for 256 requested
    png = out / "integrate_pi.png"
    assert png.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    summary = json.loads((out / "integrate_pi.json").read_text())
    assert set(summary["slopes"]) == {"independent", "orthogonal", "uniform_grid"}
    slope = summary["slopes"]["independent"]
    assert slope["slope_low"] < slope["slope"] < slope["slope_high"]
    rows = _csv_rows(out / "integrate_pi.csv")
    assert list(rows[0])[:4] == ["sampler", "n_requested", "n", "trials"] and len(rows) == 3 * 3
    assert "mse_low" in rows[0] and "mse_high" in rows[0]
    # the command (its --sampler list has commas) and the software, the same on every row
    assert "independent,orthogonal,uniform_grid" in summary["command"]
    assert {(r["command"], r["software"]) for r in rows} == {(summary["command"], software_text())}
    assert "RMSE 95% interval" in stdout and "exact" in stdout  # uniform_grid's MSE
    assert not list(out.glob(".*.tmp"))


@pytest.mark.parametrize("argv, message", [
    (["integrate", "pi", "--sampler", "nosuch"], "unknown sampler"),
    (["integrate", "pi", "--min-n", "256", "--max-n", "16"], "larger than"),
    (["integrate", "pi", "--sampler", "jittered,jittered"], "twice"),
    (["integrate", "cube"], "unknown integrand 'cube'; choose one of: pi, disk, gaussian"),
    (["integrate", "pi", "--trials", "1"], "--trials"),
])
def test_integrate_command_errors_are_one_line(tmp_path, capsys, argv, message):
    code, _, stderr = run_cli(capsys, *argv, "-o", str(tmp_path / "x"))
    assert code == 2
    assert stderr.count("\n") == 1 and message in stderr and "Traceback" not in stderr


def test_time_samplers_times_every_point_by_the_protocol(monkeypatch):
    """The timing pass replaces each point's seconds by the median of its
    interleaved rounds and leaves the estimates alone; every sampler of a sample
    count is one case of the same interleaved run."""
    import mcrt.core.timing as timing

    runs = []
    real = timing.run_interleaved

    def spy(cases, rounds, **kwargs):
        runs.append((len(cases), rounds))
        return real(cases, rounds, **kwargs)

    monkeypatch.setattr(timing, "run_interleaved", spy)
    convs = [ib.run_convergence(name, ["disk"], counts=(16, 64), timed=False)["disk"]
             for name in ("independent", "jittered")]
    before = [p.estimates.copy() for c in convs for p in c.points]
    for p in (p for c in convs for p in c.points):
        p.seconds = -1.0
    ib.time_samplers(convs, rounds=3)
    assert runs == [(2, 3), (2, 3)]  # per count: both samplers, 3 rounds
    points = [p for c in convs for p in c.points]
    assert all(p.seconds > 0 for p in points)
    for p, old in zip(points, before, strict=True):
        np.testing.assert_array_equal(p.estimates, old)


def _off_square_class(value: float) -> type:
    """A user's Dr.Jit sampler whose film x is ``value`` (NaN, or past 1) for the
    lanes whose hashed uniform falls below 1/16, white noise elsewhere."""
    import importlib

    import drjit as dr
    import mitsuba as mi

    from mcrt.samplers.kit import hash_extend, mix32, unit_float

    base = importlib.import_module("mcrt.samplers.base").McrtSampler  # the active variant's

    class OffSquare(base):  # type: ignore[misc, valid-type]
        def _sample_1d(self, key, sample, active=True):
            return unit_float(hash_extend(key, sample))

        def _sample_2d(self, key, sample, active=True):
            h = hash_extend(key, sample)
            u = unit_float(h)
            return mi.Point2f(dr.select(u < 1.0 / 16.0, value, u), unit_float(mix32(h)))
    return OffSquare


@pytest.mark.parametrize("value, shown", [(math.nan, "e.g. nan"), (1.25, "e.g. 1.25")])
def test_points_off_the_unit_square_are_refused(tmp_path, capsys, value, shown):
    """A sampler breaking the [0, 1) contract made a NaN MSE (the plot then crashed
    with a traceback and the slope read "fewer than two sample counts"), or
    silently integrated off the square (values past 1: a wrong MSE); `mcrt check`'s
    MSE rate was skipped as "makes 0 of N". Now a one-line error names the sampler."""
    import mcrt
    from mcrt.samplers import registry

    mcrt.register_sampler("off_square_test", sampler=_off_square_class(value))
    try:
        with pytest.raises(ib.SamplerError, match=r"off_square_test: \d+ of 2048 film "
                                                  r"coordinates at N = 16 are outside \[0, 1\)"):
            ib.run_convergence("off_square_test", ["gaussian"], counts=(16,), max_trials=64,
                               timed=False)
        code, _, stderr = run_cli(capsys, "-q", "integrate", "gaussian", "--sampler",
                                  "off_square_test", "--max-n", "64", "-o", str(tmp_path / "x"))
        assert code == 2 and stderr.count("\n") == 1 and shown in stderr
        assert "Traceback" not in stderr
    finally:
        registry.unregister("off_square_test")


def test_integrate_takes_your_point_sets_with_p(tmp_path, capsys):
    """``-P`` gives every --sampler its parameters: the pointset sampler reads the
    user's file (here 16 copies of one set per N, randomize none, so every trial's
    estimate is that set's mean of the integrand, computed again here); the command
    recorded names the file by absolute path, and a sampler that cannot take a
    parameter is refused in one line before any work."""
    rng = np.random.default_rng(3)
    sets = {f"n{n}": rng.random((1, n, 2)).astype(np.float32) for n in (16, 64)}
    np.savez(tmp_path / "mine.npz", **{k: np.repeat(v, 16, axis=0) for k, v in sets.items()})
    out = tmp_path / "int"
    code, _, err = run_cli(capsys, "-q", "integrate", "disk", "--sampler", "pointset",
                           "-P", f"filename={tmp_path / 'mine.npz'}", "-P", "randomize=none",
                           "--max-n", "64", "--trials", "32", "-o", str(out))
    assert code == 0, err
    rows = {int(r["n"]): r for r in _csv_rows(out / "integrate_disk.csv")}
    assert set(rows) == {16, 64}
    for points in sets.values():
        expected = float(ib.INTEGRANDS["disk"].estimates(points.astype(np.float64))[0])
        assert float(rows[points.shape[1]]["mean_estimate"]) == \
            pytest.approx(expected, rel=1e-12, abs=1e-12)
    command = json.loads((out / "integrate_disk.json").read_text())["command"]
    assert f"-P filename={tmp_path / 'mine.npz'}" in command
    assert {r["command"] for r in rows.values()} == {command}
    code, _, err = run_cli(capsys, "integrate", "disk", "--sampler", "pointset,jittered",
                           "-P", f"filename={tmp_path / 'mine.npz'}", "-o", str(tmp_path / "x"))
    assert code == 2 and err.count("\n") == 1
    assert "jittered" in err and "filename" in err and not (tmp_path / "x").exists()
