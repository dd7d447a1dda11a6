"""Render plans: simulate only the distribution effects a scene calls for.

:func:`plan_scene` reads a Mitsuba XML scene once (:func:`mcrt.render.scene.read_scene`,
so ``$key`` parameters work as in ``mi.load_file``), finds which distribution
ray-tracing effects it contains, and builds the scene that renders exactly
those:

============  =====================================  ===================================
effect        on when the scene has                  switched off by
============  =====================================  ===================================
aa            always (the film position sample)      cannot be switched off
soft_shadows  an ``area`` emitter                    each area-lit shape -> a ``spot``
                                                     or ``point`` light (see below)
glossy        a rough BSDF (``roughconductor``,      rough -> smooth counterpart
              ``roughplastic``, ``roughdielectric``  (``conductor``, ``plastic``,
              with alpha >= 1e-3, ``principled``)    ``dielectric``)
dof           a ``thinlens`` camera whose circle of  ``thinlens`` -> ``perspective``
              confusion reaches 0.5 px somewhere in  (same fov, pose, clip, film)
              the visible depth range
motion        a moving shape (``mcrt_velocity`` ...) one sub-frame, shapes at their
              and an open shutter, streak >= 0.25 px shutter-open pose
indirect      a ``path`` integrator deeper than 2    the shortest path the remaining
              and at least two reflecting shapes     effects need (``path`` and
              (or one that may light itself: not     ``direct`` only: others are
              flat, nor convex, outward and opaque);
              any integrator (or one a wrapper       rendered as authored)
              holds) deeper than 2, with such
              shapes or participating media
============  =====================================  ===================================

Then the plan chooses:

* **integrator**: ``path`` at the author's depth when indirect light is on;
  else ``path`` at ``max_depth = 2 + k`` when glossy or specular surfaces must
  show other objects (``k = 1``, ``2`` with dielectrics: in and out); else
  ``direct`` with one emitter sample and a BSDF sample only when MIS needs one
  (glossy surfaces or emitters with area), so a scene lit by point lights
  draws film 2D + emitter 2D and nothing else;
  but a ``path`` scene with a cut-out (a ``mask`` BSDF) keeps its ``path``:
  Mitsuba 3.9's ``path`` weights the sampled light a cut-out reflects by its
  opacity twice, a bias the plan keeps so the image is ``mi.render``'s and says
  so (docs/mask-path-bias.md);
* **camera**: as authored, or ``perspective`` when depth of field is off;
* **shutter**: always closed in the rendered scene (Mitsuba's shapes ignore ray
  time, so a per-path time sample would be wasted); motion blur is rendered by
  time-stratified sub-frames (:mod:`mcrt.render.motion`).

``overrides`` (``{"dof": False, "motion": True}``) switch effects off or force
them on; forcing on an effect the scene does not have is an error, forcing on
one the plan found negligible keeps it. The plan lists the sample dimensions a
camera path consumes, in the order Mitsuba's integrators draw them (checked
against counted ``next_1d``/``next_2d`` calls in ``tests/render/test_plan.py``).

An area light switched off becomes a delta light of the same power
``pi L A`` at the centroid of its shape, which is removed from the scene. The
shape's mean normal (its vector area over ``A``, from uniform position samples)
says how: 1 for a flat shape (a ``rectangle``, a ``disk``, a quad mesh), which
emits ``L A cos(theta)`` into its front hemisphere: a ``spot`` along the normal
(cut off at 90 degrees, its falloff fitted to the cosine); 0 for a closed
shape, which emits ``L A / 4`` in every direction when convex: a ``point``
light. Any other shape is refused, with that reason.

The scene is read once and, unless a thin lens turns out negligible or area
lights are switched off, instantiated once: the decisions that need no
geometry (all but dof and motion) are made and their edits written into the
description first; moving shapes are posed in place (``mi.traverse``).

Scenes in Mitsuba 0.5/0.6's format are read as Mitsuba reads them (its own
upgrade of ``maxDepth``, ``toWorld``, ... runs before the plan looks).
Wrapper integrators (``moment``, ``aov``, ``adaptive``, any plugin holding
integrators) are rendered as authored; their indirect light is what the
integrators inside trace, and participating media scatter light again for the
volumetric ones (a plan note says which media render).

The package, one concern a module:

* :mod:`.model`: the plan (``Effect``, ``Dimension``, ``RenderPlan``) and overrides;
* :mod:`.nodes`: typed reading and editing of the parse state;
* :mod:`.scan`: what the scene description contains;
* :mod:`.camera`: projection, circle of confusion, motion streaks in pixels;
* :mod:`.effects`: one decision per effect;
* :mod:`.integrator`: the integrator the decided effects need;
* :mod:`.edits`: the edits of the description (pinhole, smooth BSDFs, point
  lights, baked poses, integrator);
* :mod:`.planned`: ``PlannedScene`` and its sub-frame schedule;
* :mod:`.planner`: ``plan_scene``, which runs the steps above in order.
"""

from .effects import DOF_NEGLIGIBLE_PX, GLOSSY_MIN_ALPHA
from .integrator import DEFAULT_INDIRECT_DEPTH
from .model import EFFECTS, Dimension, Effect, RenderPlan, parse_effect_overrides
from .planned import PlannedScene
from .planner import plan_scene

__all__ = [
    "DEFAULT_INDIRECT_DEPTH", "DOF_NEGLIGIBLE_PX", "EFFECTS", "GLOSSY_MIN_ALPHA", "Dimension",
    "Effect", "PlannedScene", "RenderPlan", "parse_effect_overrides", "plan_scene",
]
