"""Scenes written by others, their filters: references and studies with the scene's own
reconstruction filter (gaussian, tent, mitchell), checked against a
brute-force computation on a tiny image."""

from __future__ import annotations

import mitsuba as mi
import numpy as np
import pytest

from mcrt.core.engine import PassRun, pass_shape, run_passes
from mcrt.core.filtered import FilteredStats
from mcrt.core.render import render_film, render_stats
from mcrt.errors import McrtError
from mcrt.io import read_exr
from tests.conftest import ROOT, run_cli

SPHERE = ROOT / "scenes" / "foreign" / "sphere.xml"


def _scene(filter_name: str, width: int = 5, height: int = 4) -> mi.Scene:
    return mi.load_file(str(SPHERE), filter=filter_name, width=str(width), height=str(height))


class _Recorder:
    """A pass sink that keeps every sample's film position and RGB (numpy)."""

    def __init__(self) -> None:
        self.position: list[np.ndarray] = []
        self.rgb: list[np.ndarray] = []

    def add(self, samples, values, group) -> None:
        self.position.append(np.array(samples.position, np.float64).reshape(2, -1).T)
        self.rgb.append(np.array(mi.Color3f(*values[:3]), np.float64).reshape(3, -1).T)

    def commit(self) -> None:
        pass

    def state(self):
        return {}

    def restore(self, state) -> None:
        pass


def _brute_force(scene: mi.Scene, spp: int, seed: int):
    """Every (pixel, sample) pair: weights from the film's filter, float64 sums."""
    film = scene.sensors()[0].film()
    sampler = mi.load_dict({"type": "independent"})
    sampler.set_sample_count(spp)
    width, height = (int(v) for v in film.crop_size())
    recorder = _Recorder()
    run_passes(scene, sampler, recorder, PassRun(pass_shape(width * height, spp)), seed)
    pos, rgb = np.concatenate(recorder.position), np.concatenate(recorder.rgb)
    rfilter = film.rfilter()

    pos32 = pos.astype(np.float32)  # the film positions are float32

    def f(d: np.ndarray) -> np.ndarray:  # the filter itself, as Mitsuba evaluates it
        return np.array(rfilter.eval(mi.Float(d)), np.float32)

    mean = np.zeros((height, width, 3))
    var = np.zeros((height, width, 3))
    for y in range(height):
        for x in range(width):
            # float32 offsets and weight product, as a film computes them; sums in float64
            w = (f(np.float32(x + 0.5) - pos32[:, 0])
                 * f(np.float32(y + 0.5) - pos32[:, 1])).astype(np.float64)
            r = (w[:, None] * rgb).sum(0) / w.sum()
            mean[y, x] = r
            var[y, x] = (w[:, None] ** 2 * (rgb - r) ** 2).sum(0) / w.sum() ** 2
    return mean, var


@pytest.mark.slow
@pytest.mark.parametrize("filter_name", ["gaussian", "tent", "mitchell"])
def test_filtered_statistics_match_brute_force(filter_name):
    """The reference's per-pixel estimate and its variance equal a brute-force
    float64 computation over every sample (no reach cut-off there), and the
    estimate equals what the film itself develops from the same samples."""
    scene = _scene(filter_name)
    stats = render_stats(scene, mi.load_dict({"type": "independent"}), spp=8, seed=5,
                         filtered=True).stats
    assert isinstance(stats, FilteredStats)
    mean, var = _brute_force(scene, 8, 5)
    np.testing.assert_allclose(stats.mean, mean, rtol=1e-10, atol=1e-12)
    np.testing.assert_allclose(stats.variance_of_mean, var, rtol=1e-7, atol=1e-15)
    assert (stats.count == 8).all() and stats.samples == 8 * 20
    film = render_film(scene, mi.load_dict({"type": "independent"}), spp=8, seed=5)
    np.testing.assert_allclose(film.rgb, stats.mean, rtol=2e-6, atol=1e-7)


@pytest.mark.slow
def test_filtered_standard_error_is_calibrated():
    """Across 32 independent renders the spread of each filtered pixel matches
    its predicted variance, where the box-binned variance / spp does not.

    The ratio (empirical / predicted variance), averaged over 30 pixels x 3
    channels, has mean ~1 and a standard deviation near sqrt(2/31)/sqrt(30)
    ~ 0.05 (channels and neighbours are correlated, so allow about 5 of those):
    [0.75, 1.3]. The box-binned prediction counts only the pixel's own 16
    samples, overstating the variance of a gaussian-filtered pixel by ~2.5x."""
    scene = _scene("gaussian", 6, 5)
    runs = [render_stats(scene, mi.load_dict({"type": "independent"}), spp=16, seed=100 + k,
                         filtered=True).stats for k in range(32)]
    means = np.stack([r.mean for r in runs])
    empirical = means.var(axis=0, ddof=1)
    predicted = np.mean([r.variance_of_mean for r in runs], axis=0)
    lit = predicted > 1e-8
    ratio = float(np.mean(empirical[lit] / predicted[lit]))
    assert 0.75 < ratio < 1.3, ratio
    box = render_stats(scene, mi.load_dict({"type": "independent"}), spp=16, seed=7).stats
    naive = float(empirical[lit].sum() / box.variance_of_mean[lit].sum())
    assert naive < 0.6, naive


def test_reference_command_uses_the_film_filter(tmp_path, capsys, monkeypatch):
    """``mcrt reference`` of a tent-filtered scene: filtered estimate, its
    standard error and effective sample counts; a second run comes from the cache."""
    monkeypatch.setenv("MCRT_CACHE_DIR", str(tmp_path / "cache"))
    out = tmp_path / "ref.exr"
    args = ["-q", "reference", str(SPHERE), "-D", "filter=tent", "--spp", "32",
            "--spp-per-pass", "16", "-o", str(out)]
    code, _, stderr = run_cli(capsys, *args)
    assert code == 0, stderr
    layers, _ = read_exr(out)
    assert {"rgb", "variance", "stderr", "count", "effective_count"} <= set(layers)
    scene = mi.load_file(str(SPHERE), filter="tent")
    film = render_film(scene, mi.load_dict({"type": "independent"}), spp=256, seed=9)
    # The filtered reference estimates the tent-filtered image (5 SE margin on the
    # difference of two independent estimates; the 256-spp film's own error is
    # under half the 32-spp reference's).
    diff = np.abs(layers["rgb"] - film.rgb)
    assert np.mean(diff < 5 * 1.2 * layers["stderr"] + 1e-6) > 0.99
    # Tent's effective count exceeds the pixel's own 32 samples (neighbours share).
    assert (layers["effective_count"][1:-1, 1:-1] > 32).all()
    code, stdout, _ = run_cli(capsys, *args[:-1], str(tmp_path / "again.exr"))
    assert code == 0 and "found in cache" in stdout
    np.testing.assert_array_equal(read_exr(tmp_path / "again.exr")[0]["stderr"],
                                  layers["stderr"])


def test_study_accepts_filtered_scenes(tmp_path):
    from mcrt.analysis.study.config import load_config

    toml = tmp_path / "study.toml"
    toml.write_text(f'spp = [4, 16]\nseeds = 2\nsamplers = ["independent"]\n[reference]\nspp = 64\n'
                    f'[[scenes]]\npath = "{SPHERE}"\n'
                    f'params = {{ filter = "gaussian", width = 32, height = 32 }}\n')
    config = load_config(toml)
    assert len(config.scenes) == 1


@pytest.mark.parametrize("rfilter", [
    '<rfilter type="gaussian"><float name="stddev" value="0"/></rfilter>',
    '<rfilter type="gaussian"><float name="stddev" value="-1"/></rfilter>',
    '<rfilter type="tent"><float name="radius" value="0"/></rfilter>',
    '<rfilter type="lanczos"><integer name="lobes" value="0"/></rfilter>',
])
def test_a_filter_of_no_width_is_refused_in_one_line(tmp_path, capsys, rfilter):
    """Mitsuba takes a filter of no width and weighs no sample with it: stddev 0
    made an all-NaN image, a tent of radius 0 or lanczos of 0 lobes a black one
    (mcrt wrote them, exit 0), and a negative stddev a traceback (mi.render
    hangs). Every command refuses them before any work, as render_film does."""
    scene = tmp_path / "flat.xml"
    scene.write_text(SPHERE.read_text().replace('<rfilter type="$filter"/>', rfilter))
    for command in (["render"], ["render", "--adaptive"], ["reference", "--spp", "16"],
                    ["plan"]):
        out = [] if command == ["plan"] else ["-o", str(tmp_path / "out")]
        code, _, stderr = run_cli(capsys, *command, str(scene), *out)
        assert code == 2 and "Traceback" not in stderr, stderr
        assert stderr.count("\n") == 1 and "reconstruction filter has radius" in stderr
    assert not (tmp_path / "out.exr").exists()
    with pytest.raises(McrtError, match="gives no sample a weight"):
        render_film(mi.load_file(str(scene)), "independent", spp=1)
