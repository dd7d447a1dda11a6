"""The plan's data model: effect decisions, sample dimensions, the render plan."""

from __future__ import annotations

import json
from collections.abc import Iterable
from dataclasses import dataclass, field

from ...errors import McrtError
from ..motion import Motion

#: Effect names in the order plans list them, with a one-line description.
EFFECTS: dict[str, str] = {
    "aa": "antialiasing: samples over the pixel area",
    "soft_shadows": "soft shadows: samples over area lights",
    "glossy": "glossy reflection: samples over rough BSDF lobes",
    "dof": "depth of field: samples over the thin lens",
    "motion": "motion blur: time-stratified sub-frames",
    "indirect": "indirect light: paths longer than direct lighting",
}

#: An integrator as the plan renders it: plugin name under "type", then its properties.
IntegratorSpec = dict[str, bool | int | float | str]

#: Distinct objects a reason names one by one; the others are counted.
LISTED = 6


def listing(items: Iterable[str], limit: int = LISTED) -> str:
    """``items`` (objects of the scene) as a reason names them: each distinct one
    once, in order, with its count when it repeats (``roughplastic (roughplastic,
    alpha 0.1) x500``), and past ``limit`` distinct ones only how many are left
    (``..., and 994 more``), so that a scene of thousands of shapes, lights or
    BSDFs gets a line, not a page."""
    counts: dict[str, int] = {}
    for item in items:
        counts[item] = counts.get(item, 0) + 1
    parts = [item if n == 1 else f"{item} x{n}" for item, n in counts.items()]
    if len(parts) > limit:
        rest = sum(list(counts.values())[limit:])
        parts = [*parts[:limit], f"and {rest} more"]
    return ", ".join(parts)


@dataclass
class Effect:
    """One effect's decision: whether the scene has it, whether it renders, why."""

    name: str
    present: bool
    on: bool
    reason: str
    forced: bool | None = None  # the user's override, if any

    def to_dict(self) -> dict[str, bool | str]:
        out: dict[str, bool | str] = {"on": self.on, "present": self.present,
                                      "reason": self.reason}
        if self.forced is not None:
            out["forced"] = "on" if self.forced else "off"
        return out


@dataclass
class Dimension:
    """A group of sampler calls of one camera path: ``label`` drawn ``ndim``-D."""

    label: str
    ndim: int


def _dims(dims: Iterable[Dimension]) -> list[list[str | int]]:
    return [[d.label, d.ndim] for d in dims]


def _dims_text(dims: Iterable[Dimension]) -> str:
    return ", ".join(f"{d.label} {d.ndim}D" for d in dims)


@dataclass
class RenderPlan:
    """What mcrt renders for a scene (see :mod:`mcrt.render.plan`)."""

    scene: str
    effects: dict[str, Effect]
    camera: str                 # sensor plugin rendered with
    scene_camera: str           # sensor plugin of the scene as authored
    integrator: IntegratorSpec
    integrator_reason: str
    scene_integrator: str
    shutter: tuple[float, float]        # the scene's shutter (open, close)
    sampler: str
    spp: int
    motions: list[Motion] = field(default_factory=list)
    streak_px: float = 0.0              # longest screen-space motion over the shutter
    coc_px: tuple[float, float] | None = None   # circle of confusion over visible depths
    subframes: int = 1
    subframe_times: list[float] = field(default_factory=list)
    notes: list[str] = field(default_factory=list)
    #: Where the image is ``mi.render``'s but known wrong (a Mitsuba bug): said by
    #: ``mcrt plan`` and in a render's plan line.
    caveats: list[str] = field(default_factory=list)
    aperture_sample: bool = False       # the rendered sensor draws a 2D aperture sample
    wavelength_sample: bool = False     # a spectral variant draws the wavelengths (1D)

    # -- queries --------------------------------------------------------------
    def on(self, effect: str) -> bool:
        return self.effects[effect].on

    @property
    def effects_on(self) -> list[str]:
        return [name for name, e in self.effects.items() if e.on]

    def summary(self) -> str:
        """One line for a render's log: the effects on, and the integrator when it
        is not the scene's own (``mcrt plan`` says why at length)."""
        text = ", ".join(self.effects_on) or "no effect"
        kind = str(self.integrator["type"])
        if not self.scene_integrator.startswith(kind):  # "path (default)", "moment(path)"
            text += (f"; integrator {kind} in place of the scene's {self.scene_integrator}: "
                     f"{self.integrator_reason}")
        return "; caveat: ".join([text, *self.caveats])

    def camera_dimensions(self) -> list[Dimension]:
        """Sampler calls a camera sample makes before the integrator runs."""
        dims = [Dimension("film", 2)]
        if self.aperture_sample:  # a thin lens's; an irradiance meter's direction
            dims.append(Dimension("lens" if self.camera == "thinlens" else "aperture", 2))
        # the rendered shutter is closed: no per-path time sample
        if self.wavelength_sample:  # spectral variants, after the aperture (core/trace.py)
            dims.append(Dimension("wavelength", 1))
        return dims

    def bounce_dimensions(self) -> tuple[list[Dimension], int | None]:
        """Sampler calls per integrator step and the number of steps (None:
        unbounded). Orders as Mitsuba 3.9.1 draws them (``direct`` passes
        ``next_1d(), next_2d()`` as arguments of one call, which this build
        evaluates right to left)."""
        kind = self.integrator["type"]
        emitter, lobe, direction = (Dimension("emitter", 2), Dimension("BSDF lobe", 1),
                                    Dimension("BSDF direction", 2))
        if kind == "direct":
            e = int(self.integrator.get("emitter_samples", 1))
            b = int(self.integrator.get("bsdf_samples", 1))
            return [emitter] * e + [direction, lobe] * b, 1
        if kind == "distribution":
            return [emitter, lobe, direction], int(self.integrator["max_depth"])
        if kind == "path":
            depth = int(self.integrator.get("max_depth", -1))
            return ([emitter, lobe, direction, Dimension("roulette", 1)],
                    None if depth < 0 else depth)
        return [], None

    def max_calls(self) -> tuple[int, int] | None:
        """(sampler calls, scalar dimensions) of the longest camera path, or
        None when unbounded or unknown."""
        per, steps = self.bounce_dimensions()
        if steps is None:
            return None
        dims = self.camera_dimensions() + per * steps
        return len(dims), sum(d.ndim for d in dims)

    # -- output ---------------------------------------------------------------
    def to_dict(self) -> dict[str, object]:
        per, steps = self.bounce_dimensions()
        out: dict[str, object] = {
            "scene": self.scene,
            "effects": {name: e.to_dict() for name, e in self.effects.items()},
            "effects_on": self.effects_on,
            "camera": self.camera, "scene_camera": self.scene_camera,
            "integrator": self.integrator, "integrator_reason": self.integrator_reason,
            "scene_integrator": self.scene_integrator,
            "shutter": list(self.shutter), "subframes": self.subframes,
            "subframe_times": [round(t, 9) for t in self.subframe_times],
            "sampler": self.sampler, "spp": self.spp,
            "dimensions": {"camera": _dims(self.camera_dimensions()),
                           "per_step": _dims(per), "steps": steps},
            "streak_px": round(self.streak_px, 4),
            "motions": [m.to_dict() for m in self.motions],
            "notes": self.notes,
            "caveats": self.caveats,
        }
        if self.coc_px is not None:
            out["coc_px"] = [round(c, 4) for c in self.coc_px]
        return out

    def to_json(self) -> str:
        return json.dumps(self.to_dict(), separators=(",", ":"))

    def describe(self) -> str:
        """The plan as ``mcrt plan`` prints it."""
        lines = [f"plan for {self.scene}", "effects:"]
        for name, e in self.effects.items():
            state = "on " if e.on else "off"
            forced = f" (forced {'on' if e.forced else 'off'})" if e.forced is not None else ""
            lines.append(f"  {name:13s} {state}  {e.reason}{forced}")
        integ = ", ".join(f"{k} {v}" for k, v in self.integrator.items() if k != "type")
        lines.append(f"integrator:   {self.integrator['type']}"
                     f"{f' ({integ})' if integ else ''} - {self.integrator_reason}"
                     f" [scene: {self.scene_integrator}]")
        lines.append(f"camera:       {self.camera} [scene: {self.scene_camera}]")
        lines.append(f"shutter:      {self._describe_shutter()}")
        lines.append(f"sampler:      {self.sampler}, {self.spp} spp")
        lines += self._describe_dimensions()
        lines += [f"note: {n}" for n in self.notes]
        lines += [f"caveat: {c}" for c in self.caveats]
        return "\n".join(lines)

    def _describe_shutter(self) -> str:
        t0, t1 = self.shutter
        if not self.on("motion"):
            return f"closed (instant {t0:g}); one sub-frame"
        per = self.spp // self.subframes
        return (f"[{t0:g}, {t1:g}] in {self.subframes} time-stratified sub-frames of {per} spp "
                f"(streak up to {self.streak_px:.1f} px)")

    def _describe_dimensions(self) -> list[str]:
        lines = ["dimensions per camera path (sampler calls in order):"]
        camera = _dims_text(self.camera_dimensions())
        per, steps = self.bounce_dimensions()
        if self.integrator["type"] == "direct":
            lines.append(f"  {camera}, {_dims_text(per)}")
        elif per:
            count = "unbounded, until roulette or escape" if steps is None else f"up to {steps}"
            lines.append(f"  {camera}, then per path vertex ({count}): {_dims_text(per)}")
        else:
            lines.append(f"  {camera}, then whatever '{self.integrator['type']}' draws")
        calls = self.max_calls()
        if calls is not None:
            lines.append(f"  = at most {calls[0]} calls, {calls[1]} scalar dimensions")
        if self.on("motion"):
            lines.append(f"  + per sub-frame: time 1D ({self.subframes} stratified values, "
                         f"not a per-path dimension)")
        return lines


# ----------------------------------------------------------------------------
# Overrides
# ----------------------------------------------------------------------------
def _unknown_effect(name: str) -> McrtError:
    return McrtError(f"unknown effect {name!r}; effects: {', '.join(EFFECTS)}")


def parse_effect_overrides(items: Iterable[str] | None) -> dict[str, bool]:
    """``["dof=off,motion=on", "glossy=off"]`` -> ``{"dof": False, ...}``."""
    out: dict[str, bool] = {}
    for item in items or []:
        for part in item.split(","):
            part = part.strip()
            if not part:
                continue
            name, sep, value = part.partition("=")
            name, value = name.strip().replace("-", "_"), value.strip().lower()
            if not sep or value not in ("on", "off"):
                raise McrtError(f"--effect expects NAME=on|off, got {part!r}")
            if name not in EFFECTS:
                raise _unknown_effect(name)
            if name == "aa" and value == "off":
                raise McrtError("antialiasing cannot be switched off: every camera sample "
                                "draws its position in the pixel (film 2D)")
            out[name] = value == "on"
    return out


def check_overrides(overrides: dict[str, bool] | None) -> dict[str, bool]:
    """A copy of ``overrides`` once every name is an effect and aa stays on."""
    out = dict(overrides or {})
    for name in out:
        if name not in EFFECTS:
            raise _unknown_effect(name)
    if out.get("aa") is False:
        raise McrtError("antialiasing cannot be switched off")
    return out
