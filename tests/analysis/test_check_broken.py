"""``mcrt check`` on samplers written from scratch against Mitsuba's interface.

A plain ``mi.Sampler`` subclass (not a :class:`McrtSampler`) of hashed white
noise, keyed by (seed, lane, dimension), with one mistake a researcher might
make switched on by ``bug``: dimension 2 repeats dimension 0, values 1.0 or NaN
once in 2^20, the same points in every pixel. Its ``seed`` does not call the
base class's (renders work without it: ``test_python_api``), so Mitsuba's
``wavefront_size()`` stays 0. Seeds are fixed, the budget is the quick one.
"""

from __future__ import annotations

import drjit as dr
import mitsuba as mi
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
            lane = self.lane % self.spp if bug == "same_pixel" else self.lane
            h = hash_keys(self.key, lane, dim * 2 + salt)
            odd = (h & 0xFFFFF) == 7  # once in 2^20
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
