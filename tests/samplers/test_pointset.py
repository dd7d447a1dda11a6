"""Users' point sets as samplers: the ``pointset`` plugin (files) and generators
registered with ``mcrt.register_sampler``: formats, errors, randomisations,
caching, variant switches and the variance they render with."""

from __future__ import annotations

import subprocess
import sys

import mitsuba as mi
import numpy as np
import pytest
from scipy.stats import qmc

import mcrt
from mcrt.core.render import render_film
from mcrt.core.sampling import make_sampler, mitsuba_message
from mcrt.errors import SamplerError
from mcrt.samplers import registry
from mcrt.samplers.point_sources import GeneratorSource, jittered_sets, read_point_file
from mcrt.samplers.points import point_sets
from tests.conftest import small_cornell

#: Calls of the cached generator below.
CALLS: list[int] = []


def save(path, points) -> str:
    np.save(path, np.asarray(points, dtype=np.float32))
    return str(path)


def load_error(**params) -> str:
    with pytest.raises(RuntimeError) as error:
        mi.load_dict({"type": "pointset", "sample_count": 16, **params})
    return mitsuba_message(error.value)


@pytest.fixture
def jittered_file(tmp_path):
    return save(tmp_path / "jit.npy", jittered_sets(64, 16, np.random.default_rng(3)))


@pytest.fixture
def unregister():
    names: list[str] = []
    yield names.append
    for name in names:
        registry.unregister(name)


# -- formats --------------------------------------------------------------------

def test_npy_npz_and_utk_text_give_the_same_tables(tmp_path):
    rng = np.random.default_rng(0)
    a, b = rng.random((3, 4, 2)), rng.random((2, 9, 2))
    np.savez(tmp_path / "sets.npz", small=a, large=b)
    tables = read_point_file(tmp_path / "sets.npz")
    assert sorted(tables) == [4, 9]
    np.testing.assert_array_equal(tables[9], b.astype(np.float32))
    text = "\n".join("#\n" + "\n".join(f"{x:.17g} {y:.17g}" for x, y in s) for s in a) + "\n"
    (tmp_path / "sets.dat").write_text(text)
    np.testing.assert_array_equal(read_point_file(tmp_path / "sets.dat")[4], a.astype(np.float32))
    np.save(tmp_path / "one.npy", a[0])  # (N, 2): one set
    assert read_point_file(tmp_path / "one.npy")[4].shape == (1, 4, 2)


@pytest.mark.parametrize("points, message", [
    (np.zeros((3, 16, 3)), "shape (sets, points, 2), got (3, 16, 3)"),
    (np.zeros((16,)), "shape (sets, points, 2), got (16,)"),
    (np.full((20, 16, 2), np.nan), "point 0 of set 0 is not a number"),
    (np.ones((20, 16, 2)), "outside [0, 1)"),
    (np.full((20, 16, 2), -0.25), "outside [0, 1)"),
    (np.zeros((0, 16, 2)), "holds no points"),
    (np.full((4, 16, 2), 0.5), "only 4 set(s) of 16 points with randomize='symmetry'"),
])
def test_bad_point_files_are_refused_in_one_line(tmp_path, points, message):
    text = load_error(filename=save(tmp_path / "bad.npy", points))
    assert message in text and "\n" not in text and "bad.npy" in text


def test_float64_just_below_one_is_kept_below_one_in_float32(tmp_path):
    """1 - 1e-9 is in [0, 1) but rounds to 1.0 in float32: it is stored as the largest
    float32 below 1. It used to be refused, and rng.random() gives such a value about
    once in 2^25 draws: the plain generator below, 256 sets at N = 16384 (8.4M values),
    was refused at its default seed, so mcrt check and integrate skipped that count."""
    points = np.full((20, 16, 2), 0.5)
    points[3, 5] = (0.3, 1 - 1e-9)
    np.save(tmp_path / "p.npy", points)  # float64 (save() writes float32)
    table = read_point_file(tmp_path / "p.npy")[16]
    assert table[3, 5, 1] == np.float32(np.nextafter(np.float32(1), np.float32(0)))
    assert table.max() < 1 and table[3, 5, 0] == np.float32(0.3)
    assert "outside [0, 1)" in load_error(filename=save(tmp_path / "one.npy",
                                                         np.ones((20, 16, 2))))

    def uniform(count, n, rng):
        return rng.random((count, n, 2))
    table = GeneratorSource(uniform, sets=256, name="uniform_test").generate(16384)
    assert table.shape == (256, 16384, 2) and table.min() >= 0 and table.max() < 1


def test_other_file_errors(tmp_path, jittered_file):
    assert "no such point-set file" in load_error(filename=str(tmp_path / "missing.npy"))
    (tmp_path / "p.csv").write_text("0.1 0.2\n")
    assert "unknown point-set format '.csv'" in load_error(filename=str(tmp_path / "p.csv"))
    (tmp_path / "p.dat").write_text("0.1 0.2\n0.3 x\n")
    assert "line 2 is not a point" in load_error(filename=str(tmp_path / "p.dat"))
    assert "give the point sets' file" in load_error()
    assert "'randomize' must be one of" in load_error(filename=jittered_file, randomize="twist")
    with pytest.raises(SamplerError, match=r"holds \d+ sets of 16 points, not 9: render with "
                                           r"--spp 16"):
        make_sampler("pointset", 9, filename=jittered_file)


def test_a_file_of_uneven_set_sizes_suggests_the_size_with_the_most_sets(tmp_path):
    """UTK text of 1 set of 15 points and 19 of 16: the advice and the default
    count are 16 (15 was suggested, and then refused: one set is too few)."""
    rng = np.random.default_rng(3)
    sets = [rng.random((15, 2))] + [rng.random((16, 2)) for _ in range(19)]
    path = tmp_path / "uneven.dat"
    path.write_text("#\n".join("".join(f"{x} {y}\n" for x, y in points) for points in sets))
    with pytest.raises(SamplerError, match=r"holds 1 set of 15, 19 sets of 16 points, not 9: "
                                           r"render with --spp 16"):
        make_sampler("pointset", 9, filename=str(path))
    assert mi.load_dict({"type": "pointset", "filename": str(path)}).sample_count() == 16


# -- what each randomisation keeps ----------------------------------------------

def cells(points: np.ndarray, kx: int, ky: int) -> np.ndarray:
    """Points per cell of a kx x ky grid, per pixel: (pixels, kx * ky)."""
    index = (points[..., 0] * kx).astype(int) * ky + (points[..., 1] * ky).astype(int)
    return np.stack([np.bincount(row, minlength=kx * ky) for row in index])


def test_none_serves_the_files_sets_exactly(jittered_file):
    table = np.load(jittered_file)
    drawn = point_sets("pointset", range(50), 16, filename=jittered_file, randomize="none")
    as_sets = {tuple(sorted(map(tuple, s.tolist()))) for s in table}
    for s in drawn:  # each pixel: one of the file's sets, in a permuted order
        assert tuple(sorted(map(tuple, s.tolist()))) in as_sets


def test_symmetry_keeps_strata_and_shift_moves_them(jittered_file):
    kept = point_sets("pointset", range(200), 16, filename=jittered_file, randomize="symmetry")
    assert (cells(kept, 4, 4) == 1).all()
    moved = point_sets("pointset", range(200), 16, filename=jittered_file, randomize="shift")
    # A toroidal shift by u leaves a 4 x 4 stratification only when u is on the
    # 1/4 grid (probability ~2^-28 per pixel): nearly every pixel loses it.
    assert (cells(moved, 4, 4) != 1).any(axis=1).mean() > 0.9


def test_xor_keeps_every_elementary_interval_of_a_net(tmp_path):
    """The first 16 points of scrambled Sobol' (scipy) are a (0,4,2)-net; a digital
    shift keeps one point in every elementary interval of area 1/16."""
    nets = np.stack([qmc.Sobol(2, scramble=True, seed=s).random(16) for s in range(20)])
    path = save(tmp_path / "nets.npy", nets)
    drawn = point_sets("pointset", range(100), 16, filename=path, randomize="xor")
    for i in range(5):
        assert (cells(drawn, 2 ** i, 2 ** (4 - i)) == 1).all(), i
    shifted = point_sets("pointset", range(100), 16, filename=path, randomize="shift")
    assert not all((cells(shifted, 2 ** i, 2 ** (4 - i)) == 1).all() for i in range(5))


def test_every_randomisation_stays_in_the_unit_square(tmp_path):
    edges = np.zeros((20, 16, 2), dtype=np.float32)  # the worst case: 1 - 0 = 1
    path = save(tmp_path / "zeros.npy", edges)
    for randomize in ("none", "symmetry", "shift", "xor", "symmetry_shift"):
        points = point_sets("pointset", range(64), 16, filename=path, randomize=randomize)
        assert points.min() >= 0 and points.max() < 1, randomize


def test_projection_uses_the_sets_x_and_stratified_1d_fills_n_strata(jittered_file):
    proj = point_sets("pointset", range(64), 16, dimension=1, ndim=1, filename=jittered_file,
                      dims1d="projection", randomize="none")
    xs = set(np.load(jittered_file)[..., 0].ravel().tolist())
    assert set(proj.ravel().tolist()) <= xs
    strat = point_sets("pointset", range(64), 16, dimension=1, ndim=1, filename=jittered_file)
    assert (cells(np.concatenate([strat, strat], -1), 16, 1) == 1).all()


# -- generators -------------------------------------------------------------------

def test_generator_is_tabulated_once_cached_on_disk_and_keyed_by_its_parameters(
        tmp_path, monkeypatch):
    monkeypatch.setenv("MCRT_CACHE_DIR", str(tmp_path))
    calls = CALLS
    calls.clear()

    def make(scale):
        def points(count, n, rng):
            if count > 1:  # a table, not the one-set repeatability probe
                CALLS.append(n)  # a global: not part of the cache key (closure values are)
            return scale * rng.random((count, n, 2))
        return points

    first = GeneratorSource(make(0.5), sets=32, name="g")
    table = first.table(16)
    assert first.cache_path(16).is_file() and calls == [16]
    again = GeneratorSource(make(0.5), sets=32, name="g")
    np.testing.assert_array_equal(again.table(16), table)
    assert calls == [16]  # read back, not generated again
    other = GeneratorSource(make(0.25), sets=32, name="g")  # another closure value
    assert other.digest != first.digest
    other.table(16)
    assert calls == [16, 16]


@pytest.mark.parametrize("points, message", [
    (lambda c, n, rng: rng.random((c, n)), "shape (sets, points, 2)"),
    (lambda c, n, rng: rng.random((c + 1, n, 2)), "asked for 32 sets of 16 points, returned 33"),
    (lambda c, n, rng: 1 / 0, "failed for n=16: ZeroDivisionError"),
])
def test_a_bad_generator_is_named_in_the_error(unregister, points, message):
    unregister(mcrt.register_sampler("bad_gen", points=points, sets=32))
    with pytest.raises(SamplerError, match="bad_gen") as error:
        make_sampler("bad_gen", 16)
    assert message in str(error.value)


def test_register_sampler_refuses_taken_names_and_bad_calls():
    with pytest.raises(SamplerError, match="taken"):
        mcrt.register_sampler("sobol", points=lambda c, n, rng: rng.random((c, n, 2)))
    with pytest.raises(SamplerError, match="exactly one"):
        mcrt.register_sampler("x_y")
    with pytest.raises(SamplerError, match="lower-case"):
        mcrt.register_sampler("My Sampler", points=lambda c, n, rng: rng.random((c, n, 2)))


@pytest.mark.parametrize("how, message", [
    ({"name": ""}, "the name must be a non-empty string"),
    ({"seed": -1}, r"seed must be an integer in \[0, 2\^32\), got -1"),
    ({"seed": 1 << 32}, "seed must be an integer"),
    ({"sets": 0}, r"sets must be an integer in \[1, 65536\], got 0"),  # was the default, silently
    ({"claims": "stratified"}, r"claims=\('stratified',\), not the string"),
])
def test_register_sampler_names_the_bad_argument_at_once(how, message):
    """Refused when registered, naming the argument: a negative seed failed only
    at the first render ('expected non-negative integer'), sets=0 meant 256 and
    claims='stratified' listed its letters as unknown claims."""
    how = {"name": "arg_test", "points": lambda c, n, rng: rng.random((c, n, 2))} | how
    with pytest.raises(SamplerError, match=message):
        mcrt.register_sampler(**how)


def test_a_generator_sampler_survives_a_variant_switch():
    code = (
        "import mitsuba as mi, mcrt\n"
        "mcrt.register_sampler('iid_sets', points=lambda c, n, rng: rng.random((c, n, 2)))\n"
        "mi.set_variant('llvm_ad_mono')\n"
        "mcrt.register()\n"
        "s = mi.load_dict({'type': 'iid_sets', 'sample_count': 8})\n"
        "s.seed(0, 8)\n"
        "assert type(s.next_2d()) is mi.Point2f and isinstance(s, mi.Sampler)\n")
    subprocess.run([sys.executable, "-c", code], check=True, capture_output=True, timeout=120)


# -- the variance a point file renders with -----------------------------------------

@pytest.mark.slow
def test_point_files_render_with_the_variance_of_the_sampler_that_made_them(tmp_path):
    """Goal: a file of jittered sets renders with the variance of ``jittered``, a
    file of i.i.d. sets with that of ``independent``.

    Variance here: per pixel across 16 seeds (15 degrees of freedom), averaged over
    the 32 x 32 Cornell box (direct light, 16 spp). The ratios measure 0.98
    (jittered file / jittered) and 1.07 (i.i.d. file / independent). Their noise:
    a per-pixel variance with 15 dof has relative sd sqrt(2/15) = 0.37, and the
    ~500 pixels that are not flat average that to ~2-3%; the finite tables (256
    sets, 8 symmetries) add a fixed draw of the same order. The band [0.8, 1.25]
    is several times that, while the two samplers differ by 3x, so a file served
    with the wrong variance (e.g. strata broken by a shift: 1.25-1.33x) or from
    the wrong sampler fails."""
    n, seeds = 16, 16
    rng = np.random.default_rng(11)
    jit = save(tmp_path / "jit.npy", jittered_sets(256, n, rng))
    iid = save(tmp_path / "iid.npy", rng.random((256, n, 2)))
    scene = small_cornell(32, "independent", n, integrator={"type": "direct"})

    def variance(name, **params):
        sampler = make_sampler(name, n, **params)
        images = np.stack([render_film(scene, sampler, spp=n, seed=s).image
                           for s in range(seeds)])
        return float(images.var(axis=0, ddof=1).mean())

    jittered, independent = variance("jittered"), variance("independent")
    assert independent > 2 * jittered  # the test can tell the two apart
    assert 0.8 < variance("pointset", filename=jit) / jittered < 1.25
    assert 0.8 < variance("pointset", filename=iid, dims1d="projection") / independent < 1.25


def test_a_clone_keeps_its_tables_when_the_file_is_gone_or_changed(jittered_file, tmp_path):
    # A render works on a clone of its sampler: the clone must draw what the
    # original draws, from the tables the original read, not read the file again
    # (a cluster bundle's copy may be gone; a file rewritten since is another sampler).
    scene = small_cornell(8)
    original = mi.load_dict({"type": "pointset", "sample_count": 16, "filename": jittered_file})
    expected = render_film(scene, original.clone(), spp=16, seed=3).image
    save(jittered_file, jittered_sets(64, 16, np.random.default_rng(99)))  # rewritten
    np.testing.assert_array_equal(render_film(scene, original, spp=16, seed=3).image, expected)
    (tmp_path / "jit.npy").unlink()  # gone
    np.testing.assert_array_equal(render_film(scene, original.clone(), spp=16, seed=3).image,
                                  expected)
