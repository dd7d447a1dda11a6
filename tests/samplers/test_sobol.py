"""`sobol` and `zsobol`: the (0,m,2)-net property, progressive counts and Morton
order, what the sampler contract (tests/samplers/test_samplers.py, which covers them too) does
not say."""

from __future__ import annotations

import drjit as dr
import mitsuba as mi
import numpy as np
import pytest

from mcrt.core.render import render_film
from mcrt.core.sampling import bind_film_width
from mcrt.errors import SamplerError
from mcrt.samplers._sobol import laine_karras, shuffle_index, sobol_dim1_bits
from mcrt.samplers.points import point_sets
from mcrt.samplers.zsobol import permute_digit
from tests.samplers.test_samplers import arr2, load

SOBOLS = ("sobol", "zsobol")
#: zsobol needs the film width; 8 pixels wide unless a test says otherwise.
PARAMS = {"sobol": {}, "zsobol": {"width": 8}}


def make(name: str, spp: int, **params) -> mi.Sampler:
    return load(name, spp, **{**PARAMS[name], **params})


def points(name: str, pixels, spp: int, **kw) -> np.ndarray:
    return point_sets(name, pixels, spp, **{**PARAMS[name], **kw}).astype(np.float64)


def is_net(xy: np.ndarray) -> bool:
    """Whether the ``N = 2^m`` points ``xy`` (N, 2) form a (0,m,2)-net: each of
    the ``N`` elementary intervals ``2^-a x 2^-(m-a)`` of each of the ``m + 1``
    shapes holds exactly one point (cells computed in float64)."""
    n = len(xy)
    m = n.bit_length() - 1
    assert n == 1 << m
    if not ((xy >= 0) & (xy < 1)).all():
        return False
    for a in range(m + 1):
        cx = np.floor(xy[:, 0] * (1 << a)).astype(np.int64)
        cy = np.floor(xy[:, 1] * (1 << (m - a))).astype(np.int64)
        if np.unique(cx * (1 << (m - a)) + cy).size != n:
            return False
    return True


def test_is_net_can_fail():
    """The checker itself: random points fail it, a product grid fails the
    thin shapes, the Hammersley set passes."""
    rng = np.random.default_rng(1)
    assert not is_net(rng.random((64, 2)))
    g = (np.arange(8) + 0.5) / 8
    assert not is_net(np.stack(np.meshgrid(g, g), -1).reshape(-1, 2))
    i = np.arange(64)
    vdc = np.array([int(f"{k:06b}"[::-1], 2) for k in i]) / 64
    assert is_net(np.stack([(i + 0.5) / 64, vdc], -1))


# -- the building blocks ------------------------------------------------------------

def joe_kuo_dimension_2(index: np.ndarray) -> np.ndarray:
    """Sobol' dimension 2 (Joe & Kuo's numbering: s = 1, a = 0, m_1 = 1) by the
    textbook recurrence m_k = 2 m_{k-1} xor m_{k-1}, v_k = m_k / 2^k, as 32-bit ints."""
    m = [1]
    for _ in range(31):
        m.append((2 * m[-1]) ^ m[-1])
    v = [mk << (32 - k) for k, mk in enumerate(m, start=1)]
    out = np.zeros(index.shape, dtype=np.uint64)
    for bit in range(32):
        out ^= np.where((index >> bit) & 1, np.uint64(v[bit]), np.uint64(0))
    return out.astype(np.uint32)


def test_second_dimension_is_sobols():
    idx = np.concatenate([np.arange(4096), np.random.default_rng(2).integers(
        0, 2**32, 4096)]).astype(np.uint32)
    ours = np.array(dr.brev(sobol_dim1_bits(mi.UInt32(idx))), dtype=np.uint32)
    np.testing.assert_array_equal(ours, joe_kuo_dimension_2(idx.astype(np.uint64)))
    # m_1..m_3 = 1, 3, 5: points 1, 2, 4 are 1/2, 3/4, 5/8; the others are xors
    # (in natural index order, not the Gray-code order of Antonov-Saleev)
    np.testing.assert_array_equal(ours[:6] / 2**32, [0, 0.5, 0.75, 0.25, 0.625, 0.125])


def test_laine_karras_is_a_nested_scramble():
    """Low output bits depend on low input bits only, and the map is a bijection
    on every low-bit prefix: what nested (Owen) scrambling needs."""
    rng = np.random.default_rng(3)
    x = rng.integers(0, 2**32, 20000, dtype=np.uint64).astype(np.uint32)
    for seed in (0, 0x12345678, 0xFFFFFFFF):
        s = mi.UInt32(seed)
        full = np.array(laine_karras(mi.UInt32(x), s), dtype=np.uint32)
        for bits in (1, 5, 17):
            mask = np.uint32((1 << bits) - 1)
            low = np.array(laine_karras(mi.UInt32(x & mask), s), dtype=np.uint32)
            assert ((full & mask) == (low & mask)).all()
        ten = np.array(laine_karras(mi.UInt32(np.arange(1024, dtype=np.uint32)), s)) & 1023
        assert np.unique(ten).size == 1024


def test_index_shuffle_maps_prefixes_onto_aligned_blocks():
    keys = mi.UInt32(np.repeat(np.array([5, 99, 0xDEADBEEF], dtype=np.uint32), 256))
    shuffled = np.array(shuffle_index(mi.UInt32(np.tile(np.arange(256, dtype=np.uint32), 3)),
                                      keys), dtype=np.uint64).reshape(3, 256)
    for row in shuffled:
        for m in range(9):
            block = row[: 1 << m] >> np.uint64(m)
            assert (block == block[0]).all()  # one aligned block of 2^m indices
            assert np.unique(row[: 1 << m]).size == 1 << m
    assert len({tuple(r[:8]) for r in shuffled}) == 3  # keys give different orders


def test_digit_permutations_are_all_24():
    h = np.random.default_rng(4).integers(0, 2**32, 4000, dtype=np.uint64).astype(np.uint32)
    digits = np.array([np.array(permute_digit(mi.UInt32(np.full(h.size, d, np.uint32)),
                                              mi.UInt32(h))) for d in range(4)]).T
    assert (np.sort(digits, axis=1) == np.arange(4)).all()
    perms, counts = np.unique(digits, axis=0, return_counts=True)
    assert len(perms) == 24
    # 4000 draws over 24 equally likely permutations: 166.7 each, sd 12.7; the
    # bound is 5 sd.
    assert np.abs(counts - 4000 / 24).max() < 64


# -- the net property ---------------------------------------------------------------

@pytest.mark.parametrize("name", SOBOLS)
@pytest.mark.parametrize("dimension", [0, 1, 5])
def test_every_pixel_is_a_net(name, dimension):
    """At N = 2^m, every pixel's points of the first and later dimension pairs
    form a (0,m,2)-net (all m + 1 shapes of elementary intervals)."""
    for m in (0, 1, 4, 7, 10):
        xy = points(name, range(6), 1 << m, dimension=dimension)
        assert all(is_net(pixel) for pixel in xy), (m, dimension)


def test_sobol_is_progressive_at_any_count():
    """At 1000 spp (not a power of two), every power-of-two prefix of a pixel's
    samples and every aligned block of 2^m is a net; the 1D dimensions are
    stratified likewise."""
    xy = points("sobol", range(4), 1000, dimension=3)
    for pixel in xy:
        for m in range(10):
            n = 1 << m
            for start in range(0, 1000 - n + 1, n):
                assert is_net(pixel[start:start + n]), (m, start)
    v = points("sobol", range(4), 1000, dimension=2, ndim=1)[..., 0]
    for pixel in v:
        for m in range(10):
            cells = np.floor(pixel[: 1 << m] * (1 << m))
            assert np.unique(cells).size == 1 << m


@pytest.mark.parametrize("name", SOBOLS)
def test_nets_hold_when_split_in_passes(name):
    """1024 spp drawn in 4 passes of 256 (advance()) give each pixel the points
    of a one-pass render: a (0,10,2)-net in the first and in a later pair."""
    pixels, spp = 3, 1024
    sampler = make(name, spp)
    sampler.set_samples_per_wavefront(256)
    sampler.seed(9, pixels * 256)
    parts: list[list[np.ndarray]] = [[], []]
    for _ in range(4):
        parts[0].append(arr2(sampler.next_2d()).reshape(pixels, 256, 2))
        sampler.next_1d()
        parts[1].append(arr2(sampler.next_2d()).reshape(pixels, 256, 2))
        sampler.advance()
    one_pass = [points(name, range(pixels), spp, dimension=d, seed=9) for d in (0, 2)]
    for part, whole in zip(parts, one_pass, strict=True):
        split = np.concatenate(part, axis=1)
        assert all(is_net(p) for p in split)
        np.testing.assert_array_equal(np.sort(split, axis=1), np.sort(whole, axis=1))


@pytest.mark.parametrize("dimension", [0, 3])
def test_zsobol_pixel_blocks_are_nets(dimension):
    """The blue-noise mechanism: the samples of every aligned 2x2 and 4x4 block
    of pixels together form a net; a pixel pair across a block border need not.
    Width 12 (not a power of two) exercises the Morton tiling."""
    width, height, spp = 12, 8, 4
    xy = points("zsobol", range(width * height), spp, dimension=dimension, width=width)
    grid = xy.reshape(height, width, spp, 2)
    for size in (2, 4):
        for by in range(0, height, size):
            for bx in range(0, 8, size):  # 12 is not a power of 2: tiles are 16 wide
                block = grid[by:by + size, bx:bx + size].reshape(-1, 2)
                assert is_net(block), (size, bx, by)
    # a 2x2 set straddling block borders is not a net in general
    straddling = [grid[y:y + 2, x:x + 2].reshape(-1, 2) for y in (1, 3) for x in (1, 3, 5)]
    assert not all(is_net(b) for b in straddling)


# -- the sampler contract (as tests/samplers/test_samplers.py checks the other plugins) --------

def test_zsobol_without_width_says_so_in_one_line():
    sampler = mi.load_dict({"type": "zsobol", "sample_count": 4})  # no width
    with pytest.raises(SamplerError, match="'width'") as error:
        sampler.seed(0, 64)
    assert "\n" not in str(error.value)
    with pytest.raises(RuntimeError, match="width"):
        load("zsobol", 4, width=0)
    with pytest.raises(RuntimeError, match="width"):
        load("zsobol", 4, width=2.5)
    bind_film_width(sampler, 8)  # what mcrt does before it seeds
    sampler.seed(0, 64)
    assert sampler.to_string() == "ZSobolSampler[sample_count=4, seed=0, width=8]"
    other = load("sobol", 4)
    bind_film_width(other, 8)  # other samplers ignore it
    assert other.to_string() == "SobolSampler[sample_count=4, seed=0]"


def test_counts_sobol_any_zsobol_powers_of_two(caplog):
    assert load("sobol", 1000).sample_count() == 1000
    with caplog.at_level("WARNING", logger="mcrt"):
        assert make("zsobol", 10).sample_count() == 16
    assert "rounding up to 16" in caplog.text


@pytest.mark.parametrize("name", SOBOLS)
def test_exact_strata_histograms_mitsuba_style(name):
    sampler = make(name, 1024)
    sampler.set_samples_per_wavefront(1024)
    sampler.seed(0, 1024)
    for _ in range(4):
        h1 = np.bincount((np.array(sampler.next_1d()) * 16).astype(int), minlength=16)
        assert (h1 == 64).all()
        xy = (arr2(sampler.next_2d()) * 16).astype(int)
        assert (np.bincount(xy[:, 0] * 16 + xy[:, 1], minlength=256) == 4).all()


@pytest.mark.parametrize("name", SOBOLS)
def test_points_are_uniform_over_pixels(name):
    """One sample per pixel, 4096 pixels: every point is uniform. Chi-square
    over 16x16 cells divided by its 255 degrees of freedom is 1 +- 0.09 (sd)
    for independent uniform points; the bounds are 4 sd wide. zsobol's pixels
    are a net together (more even than random): it only has an upper bound."""
    xy = points(name, range(4096), 1, dimension=2, width=64) if name == "zsobol" \
        else points(name, range(4096), 1, dimension=2)
    cells = np.floor(xy.reshape(-1, 2) * 16).astype(int)
    counts = np.bincount(cells[:, 0] * 16 + cells[:, 1], minlength=256)
    chi2 = ((counts - 16) ** 2 / 16).sum() / 255
    assert chi2 < 1.36
    if name == "sobol":
        assert chi2 > 0.64


def _cornell(name: str, params: dict) -> mi.Scene:
    scene = mi.cornell_box()
    film = scene["sensor"]["film"]
    film.update(width=16, height=16, component_format="float32")
    scene["sensor"]["sampler"] = {"type": name, "sample_count": 16, **params}
    return mi.load_dict(scene)


def test_mcrt_fills_in_the_film_width():
    """A scene's zsobol without `width` renders through mcrt, which knows the film:
    the image of a zsobol given the film's width, and the scene's own sampler is
    left as it was (renders work on a clone)."""
    scene = _cornell("zsobol", {})
    image = render_film(scene, spp=16, seed=3).image
    assert np.isfinite(image).all()
    given = render_film(_cornell("zsobol", {"width": 16}), spp=16, seed=3).image
    assert np.array_equal(image.view(np.uint32), given.view(np.uint32))
    assert scene.sensors()[0].sampler().width == 0
