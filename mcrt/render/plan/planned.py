"""A scene built to follow its plan, and the sub-frames of a render of it."""

from __future__ import annotations

import math
from collections.abc import Callable

import mitsuba as mi

from ...core.sampling import make_sampler, quiet_sampler_warnings, sampler_name
from ...errors import McrtError
from ..motion import Motion, MotionDriver, SubframeHook, subframe_count, subframe_times
from .model import RenderPlan

#: Prefix of the note a schedule adds when sub-frames are too far apart.
_GAP_NOTE = "sub-frames are"


class PlannedScene:
    """A scene built to follow its plan, ready for :func:`render_film`.

    ``schedule(sampler, spp, seed)`` fixes the sub-frames for a render (it
    fills ``plan.spp``, ``plan.subframes`` and ``plan.subframe_times``) and
    returns the ``passes`` and ``on_pass`` arguments of ``render_film`` /
    ``render_stats``.
    """

    def __init__(self, plan: RenderPlan, scene: mi.Scene, motions: list[Motion],
                 step_px: float) -> None:
        self.plan = plan
        self.scene = scene
        self.step_px = step_px
        self.driver = MotionDriver(scene, motions if plan.on("motion") else [])

    def subframes_for(self, spp: int) -> int:
        if not self.plan.on("motion"):
            return 1
        return subframe_count(self.plan.streak_px, spp, self.step_px)

    def schedule(self, sampler: mi.Sampler | str | None = None, spp: int | None = None,
                 seed: int = 0, subframes: int | None = None, time_mode: str = "shifted"
                 ) -> tuple[int | None, Callable[[int, int], None] | None]:
        """``(passes, on_pass)`` for rendering this scene with ``sampler`` at ``spp``.

        ``sampler`` is a sampler plugin, the name of one (``"jittered"``: made
        with :func:`~mcrt.core.sampling.make_sampler` at ``spp``, default the
        scene's sample count) or None (the scene's own sampler); it is left as it
        is: render at ``spp`` (``render_film(..., spp=spp)``) when it has another count.
        ``subframes`` forces the sub-frame count (it must divide the sample count);
        ``time_mode`` is :func:`~mcrt.render.motion.subframe_times`' ``mode``.
        """
        scene_sampler = self.scene.sensors()[0].sampler()
        if isinstance(sampler, str):
            with quiet_sampler_warnings():  # as below: the render reports any rounding
                sampler = make_sampler(sampler, spp if spp is not None else
                                       scene_sampler.sample_count())
        sampler = sampler if sampler is not None else scene_sampler
        if spp is not None and spp != sampler.sample_count():
            sampler = sampler.clone()  # the caller's (or the scene's) keeps its count
            with quiet_sampler_warnings():  # the render that follows reports any rounding
                sampler.set_sample_count(spp)
        spp = sampler.sample_count()
        self.plan.spp, self.plan.sampler = spp, sampler_name(sampler)
        if not self.plan.on("motion"):
            if subframes not in (None, 1):
                raise McrtError("sub-frames need motion blur: the plan has motion off")
            self.plan.subframes, self.plan.subframe_times = 1, []
            return None, None
        n = self.subframes_for(spp) if subframes is None else int(subframes)
        if n < 1 or spp % n:
            raise McrtError(f"cannot split {spp} samples per pixel into {n} sub-frames")
        self._note_gap(spp, n, forced=subframes is not None)
        t0, t1 = self.plan.shutter
        times = subframe_times(n, t0, t1, sampler, seed, mode=time_mode)
        self.driver.times = times
        self.plan.subframes, self.plan.subframe_times = n, [float(t) for t in times]
        return n, SubframeHook(self.driver)

    def _note_gap(self, spp: int, n: int, forced: bool) -> None:
        """Note (once) when ``n`` sub-frames of the default count are further
        apart than ``step_px``."""
        gap = self.plan.streak_px / n
        self.plan.notes = [s for s in self.plan.notes if not s.startswith(_GAP_NOTE)]
        if not forced and gap > self.step_px:
            want = math.ceil(self.plan.streak_px / self.step_px)
            self.plan.notes.append(
                f"{_GAP_NOTE} {gap:.2f} px apart (> {self.step_px} px): {spp} spp allow "
                f"at most {spp} sub-frames; a strobe-free streak needs {want} or more")
