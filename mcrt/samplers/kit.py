"""The building blocks of mcrt's samplers, for writing your own in Dr.Jit.

A sampler derived from :class:`mcrt.samplers.McrtSampler` implements two pure
functions of a per-(seed, pixel, dimension) ``key`` and a per-lane ``sample``
index: ``_sample_1d(key, sample, active) -> mi.Float`` and
``_sample_2d(key, sample, active) -> mi.Point2f``. The functions here are the
ones mcrt's own samplers are made of; they are stable API (the modules they
live in are not), and the rest of mcrt (the pass engine's seed keys, the render
features) imports them from here too.

=====================  =========================================================
``hash_keys(*k)``      hash an ordered tuple of 32-bit keys (starts a chain)
``hash_keys_int(*k)``  :func:`hash_keys` on Python ints (keys known at trace time)
``hash_extend(h, k)``  continue a 32-bit hash chain with more keys
``mix32(x)``           bijective 32-bit avalanche mix (lowbias32)
``unit_float(h)``      a uint32 hash to a float32 in [0, 1)
``permute(i, n, key)`` element ``i`` of a keyed pseudo-random permutation of [0, n)
``split_sample(j, n)`` ``(epoch, rank)``: pass ``j // n`` and index ``j % n``
``epoch_key(key, e)``  the key of one epoch (a fresh pattern per pass)
``stratified_1d``      one jittered point per stratum of ``n`` 1D strata per epoch
``stratified_2d``      one jittered point per cell of a ``k x k`` grid per epoch
=====================  =========================================================

Example: a sampler whose 2D dimensions are independent uniform points (white
noise) and whose 1D dimensions are stratified::

    from mcrt.samplers import McrtSampler, kit

    class WhiteNoise(McrtSampler):
        def _sample_1d(self, key, sample, active):
            return kit.stratified_1d(key, sample, self.sample_count(), 1.0, active)

        def _sample_2d(self, key, sample, active):
            h = kit.hash_extend(key, sample)
            return mi.Point2f(kit.unit_float(h), kit.unit_float(kit.mix32(h)))
"""

from __future__ import annotations

from ._hash import hash_extend, hash_keys, hash_keys_int, mix32, permute, unit_float
from ._stratified import epoch_key, split_sample, stratified_1d, stratified_2d

__all__ = ["epoch_key", "hash_extend", "hash_keys", "hash_keys_int", "mix32", "permute",
           "split_sample", "stratified_1d", "stratified_2d", "unit_float"]
