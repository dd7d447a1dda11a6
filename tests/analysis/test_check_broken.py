"""``mcrt check`` on samplers written from scratch against Mitsuba's interface.

A plain ``mi.Sampler`` subclass (not a :class:`McrtSampler`) of hashed white
noise, keyed by (seed, lane, dimension), with one mistake a researcher might
make switched on by ``bug``: dimension 2 repeats dimension 0, a value of 1.0
once in 2^20 or NaN once in 2^12, the same points in every pixel, or in pixels 2k and 2k + 1
(a key of the pixel index halved). Its ``seed`` does not call the
base class's (renders work without it: ``test_python_api``), so Mitsuba's
``wavefront_size()`` stays 0. Seeds are fixed, the budget is the quick one.
"""

from __future__ import annotations

import drjit as dr
import mitsuba as mi
import numpy as np
import pytest

import mcrt
from mcrt.analysis.check import CONTRACT, QUICK, Subject
from mcrt.analysis.check_stats import check_unbiasedness
from mcrt.samplers import registry
from mcrt.samplers.kit import hash_keys, hash_keys_int, unit_float


def _plain_class(bug: str = "") -> type:
    class Plain(mi.Sampler):
        """Hashed white noise; ``bug`` as in the module doc."""

        def __init__(self, props):
            super().__init__(props)
            self.key, self.lane, self.dim = mi.UInt32(0), mi.UInt32(0), mi.UInt32(0)
            self.spp = 1

        def seed(self, seed, wavefront_size=2 ** 32 - 1):  # no super().seed()
            self.key = mi.UInt32(hash_keys_int(int(seed), 12345))
            self.lane = dr.arange(mi.UInt32, wavefront_size)
            self.dim, self.spp = mi.UInt32(0), self.sample_count()

        def _u(self, salt):
            dim = dr.select(self.dim == 2, 0, self.dim) if bug == "dim2eq0" else self.dim
            lane = (self.lane % self.spp if bug == "same_pixel" else
                    self.lane // (2 * self.spp) * self.spp + self.lane % self.spp
                    if bug == "pair_pixels" else self.lane)
            h = hash_keys(self.key, lane, dim * 2 + salt)
            odd = (h & (0xFFF if bug == "nan" else 0xFFFFF)) == 7  # once in 2^12 / 2^20
            return dr.select(odd, {"nan": dr.nan, "one": 1.0}.get(bug, 0.5), unit_float(h)) \
                if bug in ("nan", "one") else unit_float(h)

        def next_1d(self, active=True):
            u = self._u(0)
            self.dim += 1
            return u

        def next_2d(self, active=True):
            p = mi.Point2f(self._u(0), self._u(1))
            self.dim += 1
            return p

        def advance(self):
            self.dim, self.lane = mi.UInt32(0), self.lane + dr.width(self.lane)

        def schedule_state(self):
            pass

        def clone(self):
            twin = self.fork()
            twin.key, twin.lane = mi.UInt32(self.key), mi.UInt32(self.lane)
            twin.dim, twin.spp = mi.UInt32(self.dim), self.spp
            return twin

        def fork(self):
            fresh = Plain(mi.Properties())
            fresh.set_sample_count(self.sample_count())
            return fresh

        def to_string(self):
            return "Plain[]"
    return Plain


@pytest.fixture
def plain():
    """``plain(bug)``: the registered name of a Plain sampler with ``bug``."""
    names: list[str] = []

    def add(bug: str = "") -> str:
        names.append(mcrt.register_sampler(f"plain_{bug or 'ok'}_test",
                                           sampler=_plain_class(bug)))
        return names[-1]
    yield add
    for name in names:
        registry.unregister(name)


def test_a_plain_sampler_whose_seed_skips_the_base_passes_the_contract(plain):
    """The contract and unbiasedness rows took the lane count from Mitsuba's
    ``wavefront_size()``, 0 for this sampler, and failed a correct sampler six
    times with "returned 128 points for 0 lanes"; they now use the lanes they
    seeded (pixels x N)."""
    subject = Subject(plain())
    for check in (*CONTRACT, check_unbiasedness):
        result = check(subject, QUICK, 0)
        assert result.passed, (result.name, result.detail)


def test_a_dimension_that_repeats_an_earlier_one_fails_unbiasedness(plain):
    """Dimension 2 (call 3) equal to dimension 0 (the film): a path's camera and
    light samples would be one point. Only calls 1 x 4 were multiplied and all 9
    checks held. With call 3 = call 1, f(call 1) f(call 3) = f^2, whose mean is
    E[f^2] = I for the disk's indicator, not I^2: +99% (1 / 0.503 - 1); the quick
    budget's se of that term is ~3% (sd of a 16-point mean of f^2 / I^2 over 1024
    px), so t ~ 30 or more, far past Holm's limit of ~4."""
    result = check_unbiasedness(Subject(plain("dim2eq0")), QUICK)
    assert not result.passed
    disk = result.values["disk call 1 x 3"]
    assert 0.9 < disk["relative_bias"] < 1.1 and disk["t"] > 20
    assert "only products of two calls: the dimensions are not independent" in result.detail
    singles = [v["t"] for k, v in result.values.items() if " x " not in k]
    assert max(abs(t) for t in singles) < 4  # each call alone is uniform


def test_a_value_of_one_once_in_a_million_fails_the_range(plain):
    """The range row drew 4096 lanes (36864 values) and passed this sampler; a
    render of 512 x 512 px x 64 spp at ~25 values a path meets ~400 such values.
    On 2^20 lanes of 9 coordinates ~9 are expected (Poisson: none with
    probability e^-9 = 1e-4; seed 0 finds 6)."""
    from mcrt.analysis.check import FULL, check_range

    result = check_range(Subject(plain("one")), FULL)
    assert not result.passed and "outside [0, 1), e.g. 1.0" in result.detail


def test_nan_values_are_named_by_the_unbiasedness_row(plain):
    """A NaN made every mean NaN and the row said "bias +nan% (t = -inf)"; it
    now counts the values outside [0, 1) (16384 lanes x 7 coordinates / 2^12:
    ~28 expected, none with probability e^-28)."""
    result = check_unbiasedness(Subject(plain("nan")), QUICK)
    assert not result.passed and result.figure == "not tested"
    assert "values outside [0, 1), e.g. nan" in result.detail and "bias" not in result.detail


def test_mitsubas_stratified_fails_on_consecutive_dimensions():
    """Mitsuba's ``stratified`` permutes each dimension's strata with Kensler's
    permutation seeded by the dimension index: consecutive dimensions (calls 3
    and 4) are paired, -3.6% on the gaussian product (t ~ -14 at seeds 0 and 1;
    directly, without mcrt, -3.4% on dimensions 0 x 1, 1 x 2, 2 x 3, 3 x 4, t ~ -14,
    and 0 x 2, 0 x 4 within 1%). Only calls 1 x 4 were multiplied, and it passed.
    Bound t < -6: eight standard deviations from the measured value."""
    from mcrt.analysis.check import FULL

    result = check_unbiasedness(Subject("stratified"), FULL)
    assert not result.passed
    assert result.values["gaussian call 3 x 4"]["t"] < -6
    assert all(abs(v["t"]) < 4 for k, v in result.values.items() if " x " not in k)


def _global_rng_sets(count, n, rng):
    return np.random.random((count, n, 2))  # numpy's global RNG, not rng


def test_a_generator_on_numpys_global_rng_is_refused(capsys, cache):
    """Its first table was cached (keyed by the code) and every check held,
    while a cleared cache or a Dask worker made other points. Two calls for one
    set with equal rngs now must agree (they differ with probability 1 - 2^-64)."""
    from tests.conftest import run_cli

    mcrt.register_sampler("global_rng_test", points=_global_rng_sets)
    try:
        code, _, err = run_cli(capsys, "check", "global_rng_test", "--quick", "-q")
        assert code == 2 and "two calls with the same rng returned different points" in err
        assert len(err.strip().splitlines()) == 1
        mcrt.register_sampler("seeded_rng_test", points=lambda c, n, rng: rng.random((c, n, 2)))
        Subject("seeded_rng_test").make(16)  # a generator that uses rng is served
    finally:
        registry.unregister("global_rng_test")
        if "seeded_rng_test" in registry.names():
            registry.unregister("seeded_rng_test")


def test_rows_measured_on_points_outside_the_unit_square_say_they_cannot_be(plain):
    """NaN once in 2^12 values: the range row fails, rightly, but mse_rate was an
    "error" row (SamplerError from the bench's point check) and discrepancy and
    spectrum printed numpy's "ValueError: points must lie in the unit hypercube".
    Each now says, in one line, that it cannot be measured and why."""
    from mcrt.analysis.check import run_checks

    rows = {r.name: r for r in run_checks(plain("nan"), quick=True)}
    assert rows["range"].status == "FAIL"
    for name in ("mse_rate", "discrepancy", "spectrum"):
        row = rows[name]
        assert (row.status, row.figure) == ("FAIL", "not tested"), (name, row)
        assert row.detail.startswith("cannot be measured: ") and len(row.detail.splitlines()) == 1
        assert "outside [0, 1), e.g. nan (see range)" in row.detail, row.detail
        assert "Error" not in row.detail
    rows = {r.name: r for r in run_checks(plain(), quick=True)}  # a sound sampler is measured
    assert all(rows[n].status == "pass" for n in ("mse_rate", "discrepancy", "spectrum"))


def test_a_sampler_giving_every_pixel_the_same_points_fails_the_pixels_row(plain):
    """The pixel left out of the key: every pixel draws the same 16 values in
    every call. Only unbiasedness failed ("bias ..., no sampling error"), which
    does not name the cause; the pixels row finds 100% of values in other
    pixels where chance gives <= 0.01% (8 px x 16, quick) and says why."""
    from mcrt.analysis.check import run_checks

    rows = {r.name: r for r in run_checks(plain("same_pixel"), quick=True)}
    row = rows["pixels"]
    assert row.status == "FAIL" and row.values["shared"] == [1.0] * 6, row.detail
    assert "every pixel gets the same values in every call: the values do not depend on the " \
           "pixel" in row.detail and "hash the whole pixel into each value's key" in row.detail
    assert all(rows[n].status == "pass" for n in ("determinism", "range", "clone", "fork",
                                                   "seeding"))


def test_a_sampler_giving_pairs_of_pixels_the_same_points_fails_the_pixels_row(plain):
    """Pixels 2k and 2k + 1 draw the same values (a key of pixel // 2): every
    other row held, quick and full (pairs halve the independent trials, which
    no mean or rate test sees). The pixels row: 100% of values shared, at both
    budgets, naming a pair."""
    from mcrt.analysis.check import FULL, check_pixels, run_checks

    name = plain("pair_pixels")
    rows = {r.name: r for r in run_checks(name, quick=True)}
    assert [n for n, r in rows.items() if r.status != "pass"] == ["pixels"], {
        n: r.detail for n, r in rows.items() if r.status != "pass"}
    for row in (rows["pixels"], check_pixels(Subject(name), FULL)):
        assert not row.passed and row.values["shared"] == [1.0] * 6, row.detail
        assert "pixels share samples" in row.detail
        assert "e.g. pixels 0 and 1 have 16 of 16 values in common in call 1: pixels share " \
               "keys" in row.detail
