"""A user's sampler class is fingerprinted by its own code, whatever name it is registered under."""

from __future__ import annotations

import mitsuba as mi
import pytest

import mcrt
from mcrt.core.sampling import sampler_fingerprint
from mcrt.samplers import McrtSampler, kit, registry


class NoPluginName(McrtSampler):
    """As docs/extending.md's WhiteNoise: no plugin_name, a name given at registration."""

    def _sample_1d(self, key, sample, active):
        return kit.stratified_1d(key, sample, self.sample_count(), 1.0, active)

    def _sample_2d(self, key, sample, active):
        h = kit.hash_extend(key, sample)
        return mi.Point2f(kit.unit_float(h), kit.unit_float(kit.mix32(h)))


@pytest.fixture
def name():
    yield "t_no_plugin_name"
    registry.unregister("t_no_plugin_name")


def test_a_class_registered_under_another_name_has_its_code_fingerprint(name):
    """register_class subclasses it to set plugin_name; the fingerprint and origin
    were the subclass's, made in mcrt.samplers.registry, whose source cannot be
    read: "", so results keyed by the code (resumed studies, cached references)
    were reused after the class was edited."""
    mcrt.register_sampler(name, sampler=NoPluginName)
    info = registry.info(name)
    assert info.origin == __name__
    assert info.fingerprint and info.fingerprint == registry.code_fingerprint(NoPluginName,
                                                                              __name__)
    assert sampler_fingerprint(name) == info.fingerprint
