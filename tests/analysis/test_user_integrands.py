"""A user's own integrands in the integration bench: made from a function, registered by
name (in Python or a plugin file), or named FILE.py:FUNCTION on the command line; an
unknown exact value estimated with its error, which the bench subtracts as a floor."""

from __future__ import annotations

import csv
import json
import math
import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from mcrt import plugins
from mcrt.analysis import integrands as ui
from mcrt.analysis import integrate as ib
from tests.conftest import run_cli

GAUSSIAN = ib.INTEGRANDS["gaussian"]

#: Ein(1) = integral of exp(-x y) over the unit square = sum_k (-1)^(k+1) / (k k!).
EXP_XY = sum((-1) ** (k + 1) / (k * math.factorial(k)) for k in range(1, 25))


def _exp_xy(x, y):
    return np.exp(-x * y)


@pytest.fixture
def registered():
    """Names registered by a test, unregistered after it."""
    names: list[str] = []
    yield names
    for name in names:
        if name in ui.integrand_names():
            ui.unregister_integrand(name)


def _same_points(a: ib.Convergence, b: ib.Convergence) -> None:
    assert len(a.points) == len(b.points) > 0
    for p, q in zip(a.points, b.points, strict=True):
        assert p.n == q.n and p.trials == q.trials and p.exact == q.exact
        assert np.array_equal(p.estimates, q.estimates)
        assert p.summary == q.summary  # mse, se_log, bias, trials: the same bits
        assert q.floor == 0.0 and q.resolved and q.mse_excess == q.summary.mse
    assert a.fit() == b.fit()


# --------------------------------------------------------------------------- Python API


def test_a_copy_of_the_gaussian_gives_the_same_bits(registered):
    """The built-in gaussian's function and exact value, registered under another name
    and made into an object: the bench's estimates, MSE summaries and fits are the
    built-in's bit for bit (a known exact value has no floor)."""
    registered.append(ui.register_integrand("gauss_copy", GAUSSIAN.function, GAUSSIAN.exact))
    made = ui.make_integrand(GAUSSIAN.function, GAUSSIAN.exact, name="gauss_object")
    res = ib.run_convergence("jittered", ["gaussian", "gauss_copy", made], counts=(16, 64, 256),
                             max_trials=64, seed=4, timed=False)
    assert list(res) == ["gaussian", "gauss_copy", "gauss_object"]
    _same_points(res["gaussian"], res["gauss_copy"])
    _same_points(res["gaussian"], res["gauss_object"])
    ib.time_samplers(res.values(), rounds=1)  # an unregistered object is timed too
    assert all(p.seconds > 0 for c in res.values() for p in c.points)


def test_an_unknown_exact_value_is_estimated_within_its_error():
    """exp(-x y) without its exact value: the estimate from 16 independent scramblings
    has (estimate - I) / s ~ Student t on 15 degrees of freedom, so with the fixed seed
    it must lie within t_15(0.9995) = 4.073 standard errors of Ein(1) (a 1-in-1000 miss
    over seeds). The error is not vacuous: s < 1e-10, where independent points (sd of
    exp(-x y) ~ 0.1) over the same 2^24 evaluations would give 2.4e-5."""
    made = ui.make_integrand(_exp_xy)
    assert made.name == "_exp_xy" and "Sobol'" in made.exact_method
    assert 0 < made.exact_error < 1e-10
    assert abs(made.exact - EXP_XY) <= 4.073 * made.exact_error
    again = ui.make_integrand(_exp_xy)  # a fixed seed: the same estimate
    assert (again.exact, again.exact_error) == (made.exact, made.exact_error)


def test_the_floor_is_subtracted_and_what_it_hides_is_flagged():
    """An exact value known only to +-0.01 (floor 1e-4): MSEs below 2e-4 (jittered on the
    gaussian from N = 64) are unresolved and left out of the fit, whose points are the
    resolved MSEs less the floor, with the floor's own spread (sqrt(2) floor) in their
    standard error."""
    rough = ui.Integrand("rough", "the gaussian, exact to +-0.01", GAUSSIAN.exact,
                         GAUSSIAN.function, exact_error=0.01, exact_method="a guess")
    conv = ib.run_convergence("independent", [rough], counts=(4, 16, 64, 1024),
                              max_trials=256, seed=2, timed=False)["rough"]
    flags = [p.resolved for p in conv.points]
    assert flags[0] and not flags[-1], [(p.n, p.summary.mse) for p in conv.points]
    kept = [p for p in conv.points if p.resolved]
    for p in conv.points:
        assert p.floor == 1e-4 and p.mse_excess == p.summary.mse - 1e-4
        assert p.resolved == (p.summary.mse > 2e-4)
    se = [math.hypot(p.summary.se_log * p.summary.mse, math.sqrt(2) * 1e-4) / p.mse_excess
          for p in kept]
    assert conv.fit() == ib.fit_slope([p.n for p in kept], [p.mse_excess for p in kept], se,
                                      [p.trials for p in kept])


def _scalar(x, y):
    return math.exp(-x * y)


def _raises(x, y):
    return np.reshape(x, (5,))  # an error inside numpy: the user's line is named


@pytest.mark.parametrize("function, options, message", [
    (_scalar, {}, r"integrand _scalar: f\(x, y\) raised TypeError: .*it is not vectorised.*"
                  r"vectorize=True"),
    (lambda x, y: 1.0, {"name": "constant"}, r"integrand constant: f\(x, y\) returned shape \(\) "
                                             r"for x and y of shape \(2, 3\).*np.full_like"),
    (lambda x, y: x[0], {"name": "row"}, r"returned shape \(3,\) for x and y of shape \(2, 3\)"),
    (lambda x, y: np.log(x - 0.5), {"name": "log"}, r"integrand log: f\(0.125, 0.25\) = nan"),
    (lambda x, y: x + 1j, {"name": "cplx"}, r"returned complex128 values, not real numbers"),
    (_raises, {}, r"integrand _raises: f\(x, y\) raised ValueError: .*test_user_integrands.py, "
                  r"line \d+\)"),
    (lambda x, y: x, {}, r"integrand name '<lambda>': .*name="),
    ("x * y", {"name": "text"}, r"integrand text: 'x \* y' is not a function"),
    (_exp_xy, {"exact": math.nan}, r"integrand _exp_xy: exact must be a finite number, got nan"),
])
def test_bad_functions_are_refused_in_one_line(function, options, message):
    with np.errstate(all="ignore"), pytest.raises(ui.IntegrandError, match=message) as error:
        ui.make_integrand(function, **({"exact": 1.0} | options))
    assert "\n" not in str(error.value)


def test_vectorize_runs_a_function_of_numbers():
    made = ui.make_integrand(_scalar, EXP_XY, vectorize=True)
    points = np.random.default_rng(1).random((3, 5, 2))
    assert np.allclose(made.estimates(points), np.exp(-points[..., 0] * points[..., 1]).mean(-1))


def test_a_bad_value_the_probe_missed_names_its_point_in_the_bench():
    """Finite on the probe, infinite near the origin: the bench's point is named."""
    spike = ui.make_integrand(lambda x, y: 1.0 / np.where(x < 0.05, 0.0, x), 1.0, name="spike")
    with np.errstate(divide="ignore"), pytest.raises(ui.IntegrandError,
                                                     match=r"integrand spike: f\(0\.0[0-4]\d*, "
                                                           r"[0-9.e-]+\) = inf"):
        ib.run_convergence("independent", [spike], counts=(64,), max_trials=16, timed=False)


def test_names_and_objects_are_resolved_or_refused(registered):
    registered.append(ui.register_integrand("twice", _exp_xy, 0.5))
    with pytest.raises(ui.IntegrandError, match="taken by mcrt's gaussian"):
        ui.register_integrand("gaussian", _exp_xy, 0.5)
    with pytest.raises(ib.McrtError, match="unknown integrand 'nope'; choose one of: pi, disk, "
                                           "gaussian, twice"):
        ib.run_convergence("independent", ["nope"])
    with pytest.raises(ib.McrtError, match="two integrands are named 'twice'"):
        ib.run_convergence("independent", ["twice", ui.make_integrand(_exp_xy, 0.5,
                                                                      name="twice")])
    with pytest.raises(ui.IntegrandError, match="is a function: give a name or an Integrand"):
        ib.run_convergence("independent", [_exp_xy])


# --------------------------------------------------------------------------- plugins

PLUGIN = '''\
import numpy as np
import mcrt
from mcrt.analysis.integrands import INTEGRANDS

GAUSSIAN = INTEGRANDS["gaussian"]
mcrt.register_integrand("gauss_copy", GAUSSIAN.function, GAUSSIAN.exact,
                        description="the gaussian again")


def bump(x, y):
    """exp(-x y)"""
    return np.exp(-x * y)


mcrt.register_integrand("bump", bump)
'''

#: The columns of integrate_*.csv that depend on the integrand's values only.
VALUES = ("n", "trials", "estimate_pixel0", "mean_estimate", "exact", "mse", "mse_low",
          "mse_high", "rmse", "se_log_mse", "bias", "mse_floor", "mse_excess", "resolved")


def _mcrt(*args: str, cwd: Path) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, "-m", "mcrt", "-q", *args], capture_output=True,
                          text=True, timeout=120, cwd=cwd,
                          env={**os.environ, "MCRT_PLUGINS": ""})


def _rows(path: Path) -> list[dict[str, str]]:
    with path.open(newline="", encoding="utf-8") as handle:
        return list(csv.DictReader(handle))


def test_a_plugin_integrand_runs_in_mcrt_integrate(tmp_path):
    """`mcrt integrate gauss_copy --plugin FILE.py` (a real process): its CSV's values
    are the built-in gaussian's, its JSON records the plugin in the command that runs
    it again; the plugin's integrand without an exact value says it was estimated."""
    plugin = tmp_path / "my_integrands.py"
    plugin.write_text(PLUGIN)
    common = ("--sampler", "jittered", "--max-n", "64", "--trials", "16")
    ours = _mcrt("integrate", "gauss_copy", "--plugin", str(plugin), *common, "-o", "copy",
                 cwd=tmp_path)
    assert ours.returncode == 0, ours.stderr
    builtin = _mcrt("integrate", "gaussian", *common, "-o", "builtin", cwd=tmp_path)
    assert builtin.returncode == 0, builtin.stderr
    copy, original = (_rows(tmp_path / d / f"integrate_{n}.csv")
                      for d, n in (("copy", "gauss_copy"), ("builtin", "gaussian")))
    assert len(copy) == 2 and [[r[k] for k in VALUES] for r in copy] == \
        [[r[k] for k in VALUES] for r in original]
    summary = json.loads((tmp_path / "copy" / "integrate_gauss_copy.json").read_text())
    assert summary["integrand"] == "gauss_copy" and summary["exact_method"] == "known"
    assert summary["description"] == "the gaussian again" and summary["exact_error"] == 0
    assert f"--plugin {plugin} integrate gauss_copy" in summary["command"]
    assert summary["slopes"]["jittered"]["unresolved"] == []


def test_plugin_integrands_are_listed_run_and_forgotten(tmp_path, capsys):
    """In one process: an unknown name's error lists the plugin's integrands; its
    estimated one runs; unloading the plugin forgets its integrands, a plugin that
    fails after registering leaves none, and another plugin may not take a name."""
    plugin = tmp_path / "my_integrands.py"
    plugin.write_text(PLUGIN)
    try:
        code, _, err = run_cli(capsys, "--plugin", str(plugin), "integrate", "nope")
        assert code == 2 and err.count("\n") == 1
        assert "choose one of: pi, disk, gaussian, gauss_copy, bump, utk, funcsamp2d" in err
        code, out, err = run_cli(capsys, "-q", "integrate", "bump", "--sampler", "independent",
                                 "--max-n", "64", "--trials", "16", "-o", str(tmp_path / "b"))
        assert code == 0, err
        assert "exact value 0.79659959929" in out and "scrambled Sobol'" in out
        assert "floor" in out and "unresolved" not in out.split("\n", 2)[2]
        other = tmp_path / "other.py"
        other.write_text("import mcrt\nmcrt.register_integrand('bump', lambda x, y: x, 0.5)\n")
        with pytest.raises(plugins.PluginError, match=r"other.py, line 2: .*'bump' is taken: "
                                                      r".*my_integrands.py registered it"):
            plugins.load_plugin(other)
    finally:
        plugins.unload_plugin(plugin)
    assert "bump" not in ui.integrand_names() and "gauss_copy" not in ui.integrand_names()
    failing = tmp_path / "failing.py"
    failing.write_text("import mcrt\nmcrt.register_integrand('half', lambda x, y: x, 0.5)\n"
                       "raise RuntimeError('broken')\n")
    with pytest.raises(plugins.PluginError, match="failing.py, line 3: RuntimeError: broken"):
        plugins.load_plugin(failing)
    assert "half" not in ui.integrand_names()


# --------------------------------------------------------------------------- FILE.py:FUNCTION

FUNCTIONS = '''\
import math
import numpy as np
from mcrt.analysis.integrands import Integrand, INTEGRANDS


def corner(x, y):
    """indicator of x + y < 1"""
    return (x + y < 1.0).astype(float)


def scalar(x, y):
    return math.exp(-x * y)


def broken(x, y):
    return np.where(x > 0.5, x, 0.0) / 0.0 * undefined


G = INTEGRANDS["gaussian"]
rough = Integrand("rough", "the gaussian, exact to +-0.01", G.exact, G.function, 0.01, "a guess")
'''


def test_file_function_runs_as_a_one_off(tmp_path, capsys):
    """`mcrt integrate FILE.py:corner --exact 0.5` and `FILE.py:rough` (an Integrand
    whose exact value is rough: its small MSEs are flagged unresolved); the recorded
    command names the file by absolute path."""
    functions = tmp_path / "functions.py"
    functions.write_text(FUNCTIONS)
    common = ("--sampler", "jittered", "--max-n", "256", "--trials", "32")
    code, out, err = run_cli(capsys, "-q", "integrate", f"{functions}:corner", "--exact", "0.5",
                             *common, "-o", str(tmp_path / "c"))
    assert code == 0 and err == "" and "integrand corner: indicator of x + y < 1; exact 0.5" in out
    summary = json.loads((tmp_path / "c" / "integrate_corner.json").read_text())
    assert f"integrate {functions}:corner --sampler jittered --exact 0.5" in summary["command"]
    code, out, err = run_cli(capsys, "-q", "integrate", f"{functions}:rough", *common,
                             "-o", str(tmp_path / "r"))
    assert code == 0, err
    assert "exact value" in out and "a guess" in out and out.count("  unresolved") >= 1
    rows = _rows(tmp_path / "r" / "integrate_rough.csv")
    assert [r["resolved"] for r in rows][-1] == "False" and rows[0]["mse_floor"] == "0.0001"
    assert "unresolved N left out" in out


@pytest.mark.parametrize("spec, extra, message", [
    ("{f}:scalar", (), "integrand scalar: f(x, y) raised TypeError"),
    ("{f}:broken", ("--exact", "1"), "integrand broken: f(x, y) raised NameError: name "
                                     "'undefined' is not defined"),
    ("{f}:missing", (), "defines no 'missing' (it defines: corner, scalar, broken, G, rough)"),
    ("{f}:corner", ("--exact", "inf"), "integrand corner: exact must be a finite number"),
    ("{f}:rough", ("--exact", "1"), "--exact: rough is an Integrand"),
    ("gaussian", ("--exact", "1"), "--exact: only for a FILE.py:FUNCTION integrand"),
    ("utk", ("--exact", "1"), "--exact: only for a FILE.py:FUNCTION integrand"),
    ("{d}/none.py:f", (), "none.py: no such file"),
])
def test_file_function_mistakes_are_one_line(tmp_path, capsys, spec, extra, message):
    functions = tmp_path / "functions.py"
    functions.write_text(FUNCTIONS)
    argv = ["integrate", spec.format(f=functions, d=tmp_path), *extra, "--max-n", "16",
            "-o", str(tmp_path / "x")]
    with np.errstate(all="ignore"):
        code, _, err = run_cli(capsys, *argv)
    assert code == 2 and err.count("\n") == 1 and message in err, err
    assert "Traceback" not in err and not (tmp_path / "x").exists()
