"""The sampler contract: strata, determinism, clone/fork, seeding, passes, layout."""

from __future__ import annotations

import subprocess
import sys

import drjit as dr
import mitsuba as mi
import numpy as np
import pytest

from mcrt.core.render import render_film
from mcrt.core.sampling import bind_film_width
from mcrt.errors import SamplerError
from mcrt.samplers import _layout, registry
from mcrt.samplers.points import point_sets
from tests.conftest import OUR_SAMPLERS, sampler_params, small_cornell

GRID_SAMPLERS = ("uniform_grid", "jittered")

#: Every mcrt sampler plugin (the registry's): the contract below holds for each.
CONTRACT = OUR_SAMPLERS


def load(name: str, spp: int, **params) -> mi.Sampler:
    return mi.load_dict({"type": name, "sample_count": spp, **sampler_params(name, spp),
                         **params})


def seeded(name: str, spp: int, lanes: int | None = None, seed: int = 0, **params):
    """A sampler seeded the way Mitsuba's own sampler tests seed one."""
    sampler = load(name, spp, **params)
    sampler.set_samples_per_wavefront(sampler.sample_count())
    sampler.seed(seed, lanes or sampler.sample_count())
    return sampler


def xml_params(params: dict) -> str:
    """Plugin parameters as XML elements."""
    return "".join(f'<{"integer" if isinstance(v, int) else "string"} name="{k}" value="{v}"/>'
                   for k, v in params.items())


def arr2(p) -> np.ndarray:
    return np.array(p, dtype=np.float64).T  # (lanes, 2)


# -- registration --------------------------------------------------------------

def test_names_are_free_in_mitsuba():
    """None of our plugin names is a Mitsuba plugin of any kind (e.g. the
    texture `uniform`), checked in a process that never imports mcrt."""
    code = (
        "import mitsuba as mi\n"
        "mi.set_variant('llvm_ad_rgb')\n"
        f"for name in {CONTRACT!r}:\n"
        "    try:\n"
        "        mi.load_dict({'type': name})\n"
        "    except RuntimeError as e:\n"
        "        assert 'not found' in str(e), str(e)\n"
        "    else:\n"
        "        raise SystemExit(name + ' exists in Mitsuba')\n"
        "mi.load_dict({'type': 'uniform', 'value': 0.5})  # control: a taken name loads\n")
    subprocess.run([sys.executable, "-c", code], check=True, capture_output=True, timeout=120)


@pytest.mark.parametrize("name", OUR_SAMPLERS)
def test_loads_from_dict_and_xml(name):
    assert load(name, 16).sample_count() == 16
    xml = (f'<sampler version="3.0.0" type="{name}">{xml_params(sampler_params(name, 16))}'
           '<integer name="sample_count" value="16"/><integer name="seed" value="3"/></sampler>')
    sampler = mi.load_string(xml)
    assert isinstance(sampler, mi.Sampler) and sampler.sample_count() == 16


@pytest.mark.slow
@pytest.mark.parametrize("name", CONTRACT)
def test_renders_in_mi_render_from_an_xml_scene(name):
    width = xml_params(sampler_params(name, 4))  # plain Mitsuba: what mcrt fills in is given
    xml = f"""<scene version="3.0.0">
        <integrator type="direct"/>
        <sensor type="perspective">
            <transform name="to_world"><lookat origin="0,0,4" target="0,0,0" up="0,1,0"/></transform>
            <film type="hdrfilm"><integer name="width" value="16"/><integer name="height" value="16"/></film>
            <sampler type="{name}"><integer name="sample_count" value="4"/>{width}</sampler>
        </sensor>
        <shape type="sphere"><bsdf type="diffuse"/></shape>
        <emitter type="constant"/>
    </scene>"""
    image = np.array(mi.render(mi.load_string(xml)))
    assert image.shape == (16, 16, 3) and np.isfinite(image).all() and image.mean() > 0.1


def test_register_after_variant_switch():
    code = (
        "import mitsuba as mi, mcrt\n"
        "mi.set_variant('llvm_ad_mono')\n"
        "mcrt.register()\n"
        "s = mi.load_dict({'type': 'jittered', 'sample_count': 4})\n"
        "assert isinstance(s, mi.Sampler), type(s).__mro__\n"
        "s.seed(0, 4)\n"
        "assert type(s.next_1d()) is mi.Float\n")
    subprocess.run([sys.executable, "-c", code], check=True, capture_output=True, timeout=120)


def test_adaptive_integrator_is_imported_on_first_use():
    """`import mcrt` registers `adaptive` without importing it (numpy, the renderer);
    the first load imports it, in whichever variant is active then."""
    code = (
        "import sys, mitsuba as mi, mcrt\n"
        "assert 'mcrt.render.adaptive_integrator' not in sys.modules\n"
        "a = mi.load_dict({'type': 'adaptive', 'integrator': {'type': 'path'}})\n"
        "assert type(a).__name__ == 'AdaptiveIntegrator', type(a)\n"
        "assert type(mi.load_dict({'type': 'adaptive'})) is type(a)\n"
        "mi.set_variant('llvm_ad_mono')\n"
        "mcrt.register()\n"
        "b = mi.load_dict({'type': 'adaptive'})\n"
        "assert isinstance(b, mi.SamplingIntegrator) and type(b) is not type(a)\n")
    subprocess.run([sys.executable, "-c", code], check=True, capture_output=True, timeout=120)


@pytest.mark.parametrize("params, message", [
    ({"jitter": 2.0}, "jitter"), ({"jitter": -0.1}, "jitter"), ({"jitter": "a"}, "jitter")])
def test_bad_parameters_are_refused(params, message):
    with pytest.raises(RuntimeError, match=message):
        load("jittered", 16, **params)


def test_unseeded_sampler_refuses_to_sample():
    with pytest.raises(SamplerError, match="seed"):
        load("jittered", 4).next_1d()


def test_non_square_count_is_rounded_up_with_a_note(caplog):
    with caplog.at_level("WARNING", logger="mcrt"):
        sampler = load("jittered", 10)
    assert sampler.sample_count() == 16
    assert "rounding up to 16" in caplog.text
    assert load("uniform_grid", 17).sample_count() == 25
    assert load("poisson_disk", 10).sample_count() == 10  # any count is fine here


# -- strata --------------------------------------------------------------------

@pytest.mark.parametrize("name", GRID_SAMPLERS + ("poisson_disk",))
def test_exact_strata_histograms_mitsuba_style(name):
    """Mitsuba's check: at 1024 spp, 16 bins per axis hold exactly 64 (1D) and
    4 (2D) samples, for the first and for later dimensions."""
    sampler = seeded(name, 1024)
    for _ in range(4):
        h1 = np.bincount((np.array(sampler.next_1d()) * 16).astype(int), minlength=16)
        assert (h1 == 64).all()
        xy = (arr2(sampler.next_2d()) * 16).astype(int)
        if name != "poisson_disk":  # Poisson sets are not grid-stratified in 2D
            h2 = np.bincount(xy[:, 0] * 16 + xy[:, 1], minlength=256)
            assert (h2 == 4).all()


@pytest.mark.parametrize("name", GRID_SAMPLERS)
@pytest.mark.parametrize("spp", [1, 9, 25, 49, 100, 961])
def test_every_point_lies_in_its_own_stratum(name, spp):
    """Per pixel and dimension, the k*k samples occupy all k*k cells once (2D)
    and all N strata once (1D); cells computed in float64, so a point rounding
    across a stratum border would be caught."""
    pixels = 8
    sampler = seeded(name, spp, lanes=pixels * spp, seed=7)
    k = int(round(spp ** 0.5))
    for _ in range(3):
        v = np.array(sampler.next_1d(), dtype=np.float64).reshape(pixels, spp)
        assert ((v >= 0) & (v < 1)).all()
        cells = np.floor(v * spp).astype(int)
        assert all(sorted(row) == list(range(spp)) for row in cells)
        xy = arr2(sampler.next_2d()).reshape(pixels, spp, 2)
        assert ((xy >= 0) & (xy < 1)).all()
        cells = np.floor(xy * k).astype(int)
        ids = cells[..., 1] * k + cells[..., 0]
        assert all(sorted(row) == list(range(spp)) for row in ids)


def test_uniform_grid_is_the_cell_centres():
    k = 7
    xy = point_sets("uniform_grid", range(3), k * k, dimension=0)
    centres = (np.arange(k, dtype=np.float32) + np.float32(0.5)) / np.float32(k)
    for pixel in xy:
        got = sorted(map(tuple, pixel.tolist()))
        want = sorted((float(x), float(y)) for x in centres for y in centres)
        # Dr.Jit divides by a constant via its reciprocal: allow one float32 ulp.
        np.testing.assert_allclose(np.array(got), np.array(want), rtol=0, atol=2 ** -24)
    v = point_sets("uniform_grid", range(3), k * k, dimension=0, ndim=1)[..., 0]
    np.testing.assert_allclose(np.sort(v, axis=1)[0],
                               (np.arange(k * k, dtype=np.float32) + 0.5) / np.float32(k * k),
                               rtol=0, atol=2 ** -24)


@pytest.mark.parametrize("jitter", [0.25, 0.5])
def test_jitter_amount_bounds_the_offset_in_the_cell(jitter):
    k = 8
    xy = point_sets("jittered", range(32), k * k, jitter=jitter).reshape(-1, 2).astype(np.float64)
    offset = xy * k - np.floor(xy * k)
    step = 2.0 ** -(22 - 3)  # the stratum's position grid (see _strata.offset_bits)
    assert (np.abs(offset - 0.5) <= jitter / 2 + step).all()
    # ... and uses the whole box, not just the centre
    assert np.abs(offset - 0.5).max() > 0.9 * jitter / 2


def test_stratum_border_cases_stay_inside():
    """Offsets at the very edges of a cell (t = 0 and t -> 1) for many strata
    counts, the case where naive float32 arithmetic leaves the stratum."""
    from mcrt.samplers._strata import MAX_STRATA, place_in_stratum

    for n in [1, 2, 3, 7, 10, 100, 1000, 1021, 4099, 65537, MAX_STRATA]:
        cells = np.unique(np.concatenate([np.arange(min(n, 64)), n - 1 - np.arange(min(n, 64))]))
        for t in (0.0, 1e-9, 0.5, 1 - 1e-7, 1.0):
            v = np.array(place_in_stratum(mi.UInt32(cells.astype(np.uint32)), n, mi.Float(t)),
                         dtype=np.float64)
            np.testing.assert_array_equal(np.floor(v * n), cells, err_msg=f"n={n} t={t}")
            assert (v < 1).all()


# -- decorrelation -------------------------------------------------------------

@pytest.mark.parametrize("name", CONTRACT)
def test_dimensions_and_pixels_are_decorrelated(name):
    """Padding: the sample->stratum assignment differs between dimension pairs
    and between pixels; correlation between dimensions is near zero."""
    spp, pixels = 64, 256
    sampler = seeded(name, spp, lanes=pixels * spp)
    a = arr2(sampler.next_2d())
    b = arr2(sampler.next_2d())
    # The same sample should not land in the same cell in both dimensions.
    same_cell = (np.floor(a * 8) == np.floor(b * 8)).all(axis=1).mean()
    assert same_cell < 4 / 64  # 1/64 expected for independent assignments
    corr = np.corrcoef(a[:, 0], b[:, 0])[0, 1]
    assert abs(corr) < 0.03  # |r| ~ N(0, 1/sqrt(16384)) = 0.008 sd under independence
    per_pixel = a.reshape(pixels, spp, 2)
    assert not np.array_equal(per_pixel[0], per_pixel[1])


def _permutations(n: int, keys: np.ndarray) -> np.ndarray:
    """(len(keys), n) rows: permute(0..n-1, n, key) for each key."""
    from mcrt.samplers._hash import permute

    idx = np.tile(np.arange(n, dtype=np.uint32), keys.size)
    out = permute(mi.UInt32(idx), n, mi.UInt32(np.repeat(keys, n)))
    return np.array(out, dtype=np.int64).reshape(keys.size, n)


def _chi2_per_dof(counts: np.ndarray) -> float:
    expected = counts.sum() / counts.size
    return float(((counts - expected) ** 2 / expected).sum() / (counts.size - 1))


@pytest.mark.parametrize("n", [2, 4, 16, 64, 256, 1024, 12, 100])
def test_permutation_is_a_bijection_for_every_key(n):
    keys = np.random.default_rng(n).integers(0, 2**32, 500, dtype=np.uint64).astype(np.uint32)
    assert (np.sort(_permutations(n, keys), axis=1) == np.arange(n)).all()


@pytest.mark.slow
def test_permutation_pairs_and_dimension_relations_look_random():
    """The power-of-two permutation behind every stratum assignment (padding),
    over 2e5 well-mixed keys: chi-square per degree of freedom (1 for a truly
    random permutation, sd sqrt(2/dof) = 0.02-0.09 here) of (a) the pair
    (perm(0), perm(1)) and (b) the relation between two dimensions' permutations
    of the same pixel, (perm_b(0) - perm_a(0), perm_b(1) - perm_a(1)) mod n.
    Measured with these keys: n = 64: 1.13 and 1.0; n = 16: 38 and 2.4 (at
    small n a 32-bit-keyed family of permutations is measurably non-uniform).
    Kensler's permutation (mi.permute_kensler) measures 5.2 and 1.0 at n = 64,
    272 and 14 at n = 16 and fails the bounds; an xor with the key
    (perm = i ^ key) measures 3077 and 2290 at n = 64. The keys are fixed, so
    the bounds are regression bounds on a deterministic quantity."""
    from mcrt.samplers._hash import hash_keys_int

    keys_a = np.array([hash_keys_int(7, i, 0) for i in range(200_000)], dtype=np.uint32)
    keys_b = np.array([hash_keys_int(7, i, 1) for i in range(200_000)], dtype=np.uint32)
    for n, pair_bound, relation_bound in ((64, 1.6, 1.3), (16, 60.0, 5.0)):
        a, b = _permutations(n, keys_a)[:, :2], _permutations(n, keys_b)[:, :2]
        pairs = np.bincount(a[:, 0] * n + a[:, 1], minlength=n * n).reshape(n, n)
        assert _chi2_per_dof(pairs[~np.eye(n, dtype=bool)]) < pair_bound, n
        d = (b - a) % n
        assert _chi2_per_dof(np.bincount(d[:, 0] * n + d[:, 1], minlength=n * n)) \
            < relation_bound, n


# -- determinism, seeding, clone/fork -------------------------------------------

@pytest.mark.parametrize("name", CONTRACT)
def test_same_seed_same_bits_other_seed_other_values(name):
    params = sampler_params(name, 16)
    a = point_sets(name, range(4), 16, seed=5, **params)
    b = point_sets(name, range(4), 16, seed=5, **params)
    c = point_sets(name, range(4), 16, seed=6, **params)
    assert a.tobytes() == b.tobytes()
    assert not np.array_equal(a, c)


@pytest.mark.parametrize("name", OUR_SAMPLERS)
def test_base_seed_parameter_changes_the_pattern(name):
    """The plugin's own `seed` property offsets the render seed."""
    s0, s1 = load(name, 16, seed=0), load(name, 16, seed=1)
    assert not np.array_equal(point_sets(s0, range(2), 16), point_sets(s1, range(2), 16))
    assert np.array_equal(point_sets(name, range(2), 16, **sampler_params(name, 16)),
                          point_sets(s0, range(2), 16))


@pytest.mark.parametrize("name", CONTRACT)
def test_clone_reproduces_and_fork_is_fresh(name):
    sampler = load(name, 1024, jitter=0.5) if name == "jittered" else load(name, 1024)
    sampler.set_samples_per_wavefront(64)
    sampler.seed(0, 64)
    for _ in range(5):
        sampler.next_1d()
        sampler.advance()
        sampler.next_2d()
    twin = sampler.clone()
    assert type(twin) is type(sampler) and twin.wavefront_size() == sampler.wavefront_size()
    for _ in range(10):
        assert dr.all(sampler.next_1d() == twin.next_1d())
        assert dr.all(sampler.next_2d() == twin.next_2d(), axis=None)
    fresh = sampler.fork()
    assert type(fresh) is type(sampler)
    assert fresh.sample_count() == sampler.sample_count()
    assert fresh.to_string() == sampler.to_string()  # same parameters (jitter, seed, ...)
    with pytest.raises(SamplerError):
        fresh.next_1d()


@pytest.mark.parametrize("name", CONTRACT)
def test_reseeding_does_not_recompile_or_touch_the_seed(name):
    sampler = load(name, 64)
    hashes = []
    with dr.scoped_set_flag(dr.JitFlag.KernelHistory, True):
        for i in range(4):
            seed = mi.UInt32(i)
            state = seed.state
            sampler.seed(seed, 64)
            assert seed.state == state
            dr.eval(sampler.next_1d(), sampler.next_2d())
            hashes.append(dr.kernel_history([dr.KernelType.JIT])[-1]["hash"])
    assert len(set(hashes)) == 1


def test_seed_variable_is_not_modified_when_unevaluated():
    sampler = load("jittered", 16)
    seed = mi.UInt32(3) + dr.opaque(mi.UInt32, 4)  # an unevaluated expression
    state = seed.state
    sampler.seed(seed, 16)
    dr.eval(sampler.next_1d())
    assert seed.state == state
    assert np.array_equal(np.array(point_sets(sampler, [0], 16, seed=7)),
                          np.array(point_sets("jittered", [0], 16, seed=7)))


@pytest.mark.parametrize("name", OUR_SAMPLERS)
def test_values_are_in_the_unit_interval(name):
    sampler = seeded(name, 256, lanes=256 * 512, seed=11)
    for _ in range(4):
        for v in (np.array(sampler.next_1d()), np.array(sampler.next_2d())):
            assert (v >= 0).all() and (v < 1).all()


# -- layout and passes ------------------------------------------------------------

@pytest.mark.parametrize("name", CONTRACT)
def test_pixel_major_layout_matches_point_sets(name):
    """Lane i is pixel i // spp, sample i % spp: the wavefront's points of pixel
    p are exactly point_sets(pixels=[p]) (the analysis layer's code path)."""
    spp, pixels = 16, 40
    sampler = load(name, spp)
    sampler.seed(2, pixels * spp)  # no set_samples_per_wavefront: inferred
    sampler.next_1d()
    wave = arr2(sampler.next_2d()).reshape(pixels, spp, 2).astype(np.float32)
    chosen = [0, 7, 39]
    np.testing.assert_array_equal(wave[chosen], point_sets(name, chosen, spp, dimension=1, seed=2,
                                                           **sampler_params(name, spp)))


@pytest.mark.parametrize("name", OUR_SAMPLERS)
def test_advance_continues_the_pattern_across_passes(name):
    """1024 spp drawn in 4 passes of 256 fill the 1024 strata exactly like one
    pass would; a 5th pass starts a fresh epoch: a new stratified pattern, no
    copy of any earlier point."""
    sampler = load(name, 1024)
    sampler.set_samples_per_wavefront(256)
    sampler.seed(0, 256)
    first = []
    for _ in range(4):
        first.append((np.array(sampler.next_1d()), arr2(sampler.next_2d())))
        sampler.advance()
    v1 = np.concatenate([f[0] for f in first])
    assert (np.bincount((v1 * 1024).astype(int), minlength=1024) == 1).all()
    xy = np.concatenate([f[1] for f in first])
    if registry.info(name).claims & {"stratified", "net"}:  # 2D: 32 x 32 strata
        assert (np.bincount((xy[:, 0] * 32).astype(int) * 32 + (xy[:, 1] * 32).astype(int),
                            minlength=1024) == 1).all()
    later = []
    for _ in range(4):
        later.append((np.array(sampler.next_1d()), arr2(sampler.next_2d())))
        sampler.advance()
    w1 = np.concatenate([f[0] for f in later])
    assert (np.bincount((w1 * 1024).astype(int), minlength=1024) == 1).all()
    # Not a copy: the same sample index lands in the same stratum no more often
    # than chance (1 in 1024 per sample: expected 1, Poisson; > 8 has p ~ 1e-6).
    assert ((v1 * 1024).astype(int) == (w1 * 1024).astype(int)).sum() <= 8
    # Fresh jitter: within a stratum a point takes one of 2^12 positions at 1024
    # strata (mcrt.samplers._strata.offset_bits), so each of the 1024 strata
    # repeats its earlier position with probability 1/4096: expected 0.25 equal
    # values (Poisson; >= 5 has p ~ 6e-6), where a copied pass gives 1024.
    assert np.intersect1d(v1, w1).size <= 4
    wxy = np.concatenate([f[1] for f in later])
    assert not (set(map(tuple, xy.tolist())) & set(map(tuple, wxy.tolist())))


@pytest.mark.parametrize("name", OUR_SAMPLERS)
def test_a_pass_past_32_bit_sample_indices_is_refused_not_repeated(name):
    """Sample indices are 32-bit: a pixel positioned at pass 2^32 / N of N samples
    per pass (a long progressive render driven by advance()/start_pass) drew
    exactly the samples of pass 0 again, silently. The last pass that fits still
    draws fresh samples; the next one is refused in one line when drawn (an
    advance() after a render's last pass, as Mitsuba makes, draws nothing)."""
    spp = 1024
    sampler = seeded(name, spp, seed=5)
    first = np.array(sampler.next_1d())
    last = (1 << 32) // spp - 1
    sampler.start_pass(last)
    assert np.intersect1d(first, np.array(sampler.next_1d())).size <= 4  # as advance's test
    sampler.advance()  # positioned past the limit: nothing drawn, no error
    with pytest.raises(SamplerError, match=r"pass 4194304 of 1024 samples per pixel .*"
                                           r"repeat the pixel's first samples"):
        sampler.next_1d()
    sampler.start_pass(0)  # back inside the range: drawable again, the same bits
    np.testing.assert_array_equal(np.array(sampler.next_1d()), first)


@pytest.mark.parametrize("name", CONTRACT)
def test_multi_pass_render_equals_single_pass(name):
    """Our pass renderer in 4 passes gives the one-pass image (the same samples;
    only float32 summation order differs), which equals mi.render's."""
    scene = small_cornell(16, name, 16)
    one = render_film(scene, spp=16, seed=3)
    four = render_film(scene, spp=16, seed=3, max_lanes=16 * 16 * 4)
    assert four.passes == 4 and one.passes == 1
    # Tolerance: the film's atomic float32 adds run in thread order, which moves
    # the last bits (~1e-6) between any two runs; different samples would differ
    # by the Monte Carlo noise, ~1e-1 here.
    np.testing.assert_allclose(four.image, one.image, rtol=1e-5, atol=1e-5)
    # mi.render needs zsobol's film width, which mcrt's renders bind on a clone only.
    bind_film_width(scene.sensors()[0].sampler(), 16)
    reference = np.array(mi.render(scene, spp=16, seed=3))
    np.testing.assert_allclose(one.image, reference, rtol=1e-5, atol=1e-5)


@pytest.mark.skipif(not _layout.probe_available(), reason="C++ field probe unavailable")
def test_mitsuba_split_passes_keep_the_strata():
    """When Mitsuba itself splits a render (here via the integrator's
    samples_per_pass), the plugin learns the samples per pass from the C++
    object and the passes still form one pattern: same image as one pass."""
    split = small_cornell(16, "jittered", 16,
                          {"type": "path", "max_depth": 8, "samples_per_pass": 4})
    whole = small_cornell(16, "jittered", 16)
    sensor = split.sensors()[0]
    image = np.array(split.integrator().render(split, sensor, seed=1, spp=16))
    assert sensor.sampler().layout == _layout.Layout(16 * 16 * 4, 4)
    reference = np.array(whole.integrator().render(whole, whole.sensors()[0], seed=1, spp=16))
    np.testing.assert_allclose(image, reference, rtol=1e-5, atol=1e-5)


def test_layout_rules():
    Layout, resolve = _layout.Layout, _layout.resolve_layout
    assert resolve(64 * 10, 64, None, True) == Layout(640, 64)  # pixel-major
    assert resolve(64, 1024, 64, True) == Layout(64, 64)  # explicit samples per wavefront
    assert resolve(100, 16, None, True) == Layout(100, 1)  # one sequence per lane
    big = _layout.SPLIT_MIN_LANES
    assert resolve(big, 16, None, True).group == 16  # probe present: Mitsuba told us
    with pytest.raises(SamplerError, match="split"):
        resolve(big, 16, None, False)  # without the probe: refuse, never guess
    with pytest.raises(SamplerError):
        resolve(100, 16, 16, True)


@pytest.mark.parametrize("name, limit", [("zsobol", 1 << 16), ("jittered", 1 << 20),
                                         ("poisson_disk", 16384)])
def test_a_count_beyond_the_patterns_limit_is_refused_with_a_remedy(name, limit):
    """The limit is the whole render's count (passes continue one pattern), so
    the error points at what helps: independent seeds, or sobol."""
    from mcrt.core.sampling import make_sampler

    assert make_sampler(name, limit).sample_count() == limit
    with pytest.raises(SamplerError, match=rf"{name}: at most {limit} samples per pixel \(.+\), "
                                           rf"got {limit + 1}; .*different seeds, or use sobol"):
        make_sampler(name, limit + 1)
