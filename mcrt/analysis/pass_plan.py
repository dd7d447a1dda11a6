"""How a reference's samples per pixel are split into passes the sampler renders exactly.

Some samplers round their sample count (``jittered``/``uniform_grid``/``stratified``
to squares, ``orthogonal`` to prime squares, ``ldsampler`` to powers of 4,
``multijitter`` to products of near-equal factors); a point-set file's sampler
renders only its sets' sizes and refuses any other count. :func:`plan_passes` only
uses counts the sampler accepts *unchanged* (see :mod:`mcrt.analysis.reference`).
"""

from __future__ import annotations

import logging
from dataclasses import dataclass
from typing import Any

import numpy as np

from ..core.sampling import check_sampler_name, make_sampler, quiet_sampler_warnings
from ..errors import McrtError, SamplerError

log = logging.getLogger("mcrt.reference")

#: Default samples per pixel of one reference pass (one independent seed).
DEFAULT_PASS_SPP = 256

#: Largest wavefront (pixels x samples per pass) a pass traces in one kernel; the
#: default pass size shrinks so that ``pixels * pass_spp`` stays within it.
#: Larger user-chosen passes are split by :func:`render_stats` into sub-passes of
#: at most this many lanes (which changes the samples, hence part of the key).
LANE_BUDGET = 1 << 24




@dataclass(frozen=True)
class PassPlan:
    """How a reference's samples per pixel are split into passes.

    ``full_passes`` passes of ``pass_spp`` samples, then one pass per entry of
    ``tail``. Every count is one the sampler accepts unchanged.
    """

    requested_spp: int
    pass_spp: int
    full_passes: int
    tail: tuple[int, ...] = ()

    @property
    def passes(self) -> int:
        return self.full_passes + len(self.tail)

    @property
    def spp(self) -> int:
        """Effective total samples per pixel (``requested_spp`` unless noted)."""
        return self.pass_spp * self.full_passes + sum(self.tail)

    def spp_of(self, index: int) -> int:
        """Samples per pixel of pass ``index``."""
        if not 0 <= index < self.passes:
            raise IndexError(f"pass {index} of {self.passes}")
        return self.pass_spp if index < self.full_passes else self.tail[index - self.full_passes]

    def spp_before(self, index: int) -> int:
        """Samples per pixel of passes ``0 .. index - 1``."""
        full = min(index, self.full_passes)
        return full * self.pass_spp + sum(self.tail[:max(0, index - self.full_passes)])

    def describe(self) -> str:
        parts = []
        if self.full_passes:
            parts.append(f"{self.full_passes} x {self.pass_spp}")
        parts += [str(t) for t in self.tail]
        return " + ".join(parts) + " spp"


#: How far past a count a sampler that refuses counts is searched for one it takes.
SCAN_LIMIT = 4096


class _Counts:
    """The count ``sampler`` (with plugin ``params``) uses when asked for ``n``,
    each asked once (raises if it refuses ``n``).

    Most samplers round a count up. A point-set sampler instead refuses every
    count but its sets' sizes; once one has refused (``refused``: the first
    refusal), ``scan`` is set and the counts it takes are found by scanning, a
    refusal counting as none."""

    def __init__(self, sampler: str, params: dict[str, Any]) -> None:
        self.sampler, self.params = sampler, params
        self.known: dict[int, int | SamplerError] = {}
        self.scan = False
        self.refused: SamplerError | None = None

    def of(self, n: int) -> int:
        if n not in self.known:
            try:
                self.known[n] = make_sampler(self.sampler, n, **self.params).sample_count()
            except SamplerError as error:
                self.known[n] = error
                self.scan, self.refused = True, self.refused or error
        found = self.known[n]
        if isinstance(found, SamplerError):
            raise found
        return found

    def takes(self, n: int) -> bool:
        """Whether the sampler renders exactly ``n`` (a refusal: no)."""
        try:
            return self.of(n) == n
        except SamplerError:
            return False

    def round_up(self, n: int) -> int:
        """The count the sampler renders when asked for ``n``: its own rounding,
        or (``scan``) the least count from ``n`` on that it takes."""
        if not self.scan:
            try:
                return self.of(n)
            except SamplerError:
                pass  # (now scanning)
        found = next((m for m in range(n, n + SCAN_LIMIT) if self.takes(m)), None)
        if found is None:  # none at all is the parameters' fault, say: the first refusal
            raise self.refused or SamplerError(f"{self.sampler} takes no sample count from "
                                               f"{n} to {n + SCAN_LIMIT - 1}")
        return found


def _largest_accepted(counts: _Counts, n: int) -> int | None:
    """Largest count ``<= n`` that ``sampler`` takes unchanged (None if there is none).

    Samplers round *up* and monotonically (checked for every built-in and mcrt
    sampler up to 1100), so the accepted counts are the values of the rounding
    ``r`` and the answer is ``r(m)`` for the largest ``m`` with ``r(m) <= n``,
    found by bisection in O(log n) probes; a sampler that refuses counts is scanned.
    """
    if not counts.scan:
        try:
            return _bisect(counts, n)
        except SamplerError:
            pass  # (now scanning)
    return next((m for m in range(n, 0, -1) if counts.takes(m)), None)


def _bisect(counts: _Counts, n: int) -> int | None:
    """:func:`_largest_accepted` of a sampler that rounds counts up."""
    if counts.of(n) == n:
        return n
    lo, hi = 0, n  # invariant: r(lo) <= n (lo = 0 meaning "none yet"), r(hi) > n
    while hi - lo > 1:
        mid = (lo + hi) // 2
        if counts.of(mid) <= n:
            lo = mid
        else:
            hi = mid
    if lo == 0:
        return None
    best = counts.of(lo)
    if counts.of(best) != best:  # pragma: no cover - non-idempotent rounding
        raise SamplerError(f"sampler {counts.sampler!r} does not keep its own sample count {best}")
    return best


def _accepted_up_to(counts: _Counts, n: int, limit: int = 256) -> list[int]:
    """The (at most ``limit`` largest) counts ``<= n`` the sampler takes unchanged,
    descending."""
    found: list[int] = []
    while n >= 1 and len(found) < limit:
        a = _largest_accepted(counts, n)
        if a is None:
            break
        found.append(a)
        n = a - 1
    return found


def _exact_split(counts: _Counts, rest: int, max_parts: int = 8) -> tuple[int, ...] | None:
    """The fewest accepted counts (at most ``max_parts``) summing to ``rest``
    exactly, largest first; None if there are none. Breadth-first over sums of 1,
    2, ... parts (every integer is a sum of four squares, so square-only samplers
    need at most 4 when 1 is accepted)."""
    if rest == 0:
        return ()
    if counts.takes(rest):
        return (rest,)
    coins = _accepted_up_to(counts, rest)
    if not coins:
        return None
    layers = [np.zeros(rest + 1, bool)]
    layers[0][0] = True
    for _ in range(max_parts):
        prev, nxt = layers[-1], np.zeros(rest + 1, bool)
        for c in coins:
            nxt[c:] |= prev[:rest + 1 - c]
        layers.append(nxt)
        if nxt[rest]:
            parts, v = [], rest
            for k in range(len(layers) - 1, 0, -1):  # backtrack, largest coin first
                c = next(c for c in coins if c <= v and layers[k - 1][v - c])
                parts.append(c)
                v -= c
            return tuple(sorted(parts, reverse=True))
    return None


def _greedy_split(counts: _Counts, rest: int) -> tuple[int, ...]:
    """Largest accepted parts first; the last part rounded up by the sampler when
    it accepts nothing small enough (the total then exceeds ``rest``)."""
    parts = []
    while rest > 0:
        part = _largest_accepted(counts, rest)
        if part is None:
            parts.append(counts.round_up(rest))
            break
        parts.append(part)
        rest -= part
    return tuple(parts)


def plan_passes(sampler: str, spp: int, pixels: int, spp_per_pass: int | None = None,
                params: dict[str, Any] | None = None) -> PassPlan:
    """Split ``spp`` samples per pixel into passes that ``sampler`` (with plugin
    ``params``) renders exactly.

    ``spp_per_pass`` (default: 256, reduced so that ``pixels * pass_spp <=``
    :data:`LANE_BUDGET`) is lowered to the largest count the sampler accepts.
    """
    check_sampler_name(sampler)
    if spp < 1:
        raise McrtError(f"a reference needs at least 1 sample per pixel, got {spp}")
    if spp_per_pass is not None and spp_per_pass < 1:
        raise McrtError(f"samples per pass must be at least 1, got {spp_per_pass}")
    target = spp_per_pass or max(1, min(DEFAULT_PASS_SPP, LANE_BUDGET // max(1, pixels)))
    target = min(target, spp)
    counts = _Counts(sampler, dict(params or {}))
    with quiet_sampler_warnings():
        pass_spp = _largest_accepted(counts, target) or counts.round_up(target)
        full, rest = divmod(spp, pass_spp)
        tail = None
        for drop in range(min(full, 3) + 1):  # fold up to 3 full passes into the tail
            tail = _exact_split(counts, rest + drop * pass_spp)
            if tail is not None:
                full -= drop
                break
        if tail is None:
            tail = _greedy_split(counts, rest)
    plan = PassPlan(requested_spp=spp, pass_spp=pass_spp, full_passes=full, tail=tuple(tail))
    if spp_per_pass is not None and pass_spp != min(spp_per_pass, spp):
        log.info("%s takes %d samples per pixel per pass (requested %d)", sampler, pass_spp,
                 spp_per_pass)
    if plan.spp != spp:
        log.warning("%s cannot render exactly %d samples per pixel: the reference uses %d (%s)",
                    sampler, spp, plan.spp, plan.describe())
    return plan
