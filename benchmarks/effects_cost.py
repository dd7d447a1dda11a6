"""What does each distribution effect cost, and does an effect that is off cost nothing?

Four measurements, all through mcrt's planned renders (``plan_scene`` +
``render_film``, exactly what ``mcrt render`` runs), timed with
``dr.sync_thread()`` around each render after a warm-up that compiles and
caches every kernel; timed runs are interleaved (A, B, B, A, ...) and
medians reported:

1. *Off costs nothing*: ``dof.xml`` with ``dof=off`` against the same scene
   authored with a pinhole camera; ``motion.xml`` with ``motion=off`` (one
   sub-frame) against it authored static; direct-only plans against Mitsuba's
   own ``direct`` (``mi.render`` of the scene as authored, which draws a BSDF
   sample even where the plan draws none).
2. *Cost table*: each effect scene with its effect on and off, at equal spp
   (time, relMSE against a reference of the same variant at
   ``--reference-factor`` x spp) and at equal error (the time the "on" variant
   needs to reach the "off" variant's relMSE, from its measured convergence
   slope between spp/4 and spp).
3. *Scene times*: every shipped effect scene at its default settings.
4. *Strobing*: the streak profile of a moving bar with n sub-frames against a
   256-sub-frame reference (``strobing_index``), for shifted-lattice and
   per-stratum-jittered sub-frame times, and the shipped motion scene.

    python benchmarks/effects_cost.py [--rounds 5] [--width 160] [--height 120]
                                      [--reference-factor 16] [--only SECTION ...]
"""

from __future__ import annotations

import argparse
import math
import statistics
import tempfile
import time
from pathlib import Path

import drjit as dr
import mitsuba as mi
import numpy as np

import mcrt  # noqa: F401  (variant, plugins)
from mcrt.analysis.metrics import rel_mse
from mcrt.core.render import render_film
from mcrt.core.timing import round_orders
from mcrt.render.motion import strobing_index
from mcrt.render.plan import plan_scene
from mcrt.render.scene import load_scene

ROOT = Path(__file__).resolve().parents[1]
EFFECTS = ROOT / "scenes" / "effects"
CORNELL = ROOT / "scenes" / "cornell_box.xml"


def planned_render(path, params=None, overrides=None, spp=None, seed=0, subframes=None,
                   mode=None):
    """One render as ``mcrt render`` does it; returns (FilmRender, plan)."""
    planned = plan_scene(path, params, overrides)
    sampler = planned.scene.sensors()[0].sampler()
    passes, on_pass = planned.schedule(sampler, spp, seed, subframes=subframes,
                                       time_mode=mode or "shifted")
    result = render_film(planned.scene, sampler, spp=spp, seed=seed, passes=passes,
                         on_pass=on_pass)
    return result, planned.plan


def timed_mitsuba(scene: mi.Scene, spp: int, seed: int) -> float:
    dr.sync_thread()
    start = time.perf_counter()
    dr.eval(mi.render(scene, spp=spp, seed=seed))
    dr.sync_thread()
    return time.perf_counter() - start


def interleaved(runs: dict[str, callable], rounds: int) -> dict[str, list[float]]:
    """Warm every runner up once, then time them in the timing protocol's shuffled
    rounds (:func:`mcrt.core.timing.round_orders`)."""
    for run in runs.values():
        run(0)
    names = list(runs)
    times = {name: [] for name in names}
    for r, order in enumerate(round_orders(len(names), rounds)):
        for name in (names[i] for i in order):
            times[name].append(runs[name](r + 1))
    return times


def edited(source: Path, replacements: list[tuple[str, str]], tmp: Path) -> Path:
    text = source.read_text()
    for old, new in replacements:
        if old not in text:
            raise SystemExit(f"benchmark out of date: {old!r} not in {source}")
        text = text.replace(old, new)
    path = tmp / f"{source.stem}_edited.xml"
    path.write_text(text)
    return path


# ----------------------------------------------------------------------------
def off_costs_nothing(args, tmp: Path) -> None:
    small = {"width": str(args.width), "height": str(args.height)}
    pinhole = edited(EFFECTS / "dof.xml", [
        ('<sensor type="thinlens">', '<sensor type="perspective">'),
        ('<float name="aperture_radius" value="$aperture"/>', ''),
        ('<float name="focus_distance" value="6"/>', '')], tmp)
    static = edited(EFFECTS / "motion.xml", [
        ('<vector name="mcrt_velocity" value="$speed, 0, 0"/>', ''),
        ('<vector name="mcrt_angular_velocity" value="0, $spin, 0"/>', ''),
        ('<float name="shutter_close" value="1"/>', '')], tmp)
    print("### An effect that is off costs nothing\n")
    print(f"{args.width}x{args.height}, default spp (64, jittered), {args.rounds} interleaved "
          f"rounds after warm-up, Dr.Jit threads {dr.thread_count()}; medians.\n")
    print("| comparison | A [s] | B [s] | A/B (median of rounds) | passes A, B |")
    print("|---|---|---|---|---|")

    def pair(label, a, b):
        passes = {}

        def runner(key, fn):
            def run(seed):
                seconds, n = fn(seed)
                passes[key] = n
                return seconds
            return run
        times = interleaved({"A": runner("A", a), "B": runner("B", b)}, args.rounds)
        ratio = statistics.median(x / y for x, y in zip(times["A"], times["B"], strict=True))
        print(f"| {label} | {statistics.median(times['A']):.3f} | "
              f"{statistics.median(times['B']):.3f} | {ratio:.3f} | {passes['A']}, "
              f"{passes['B']} |")

    def mcrt_run(path, overrides=None):
        def fn(seed):
            result, _ = planned_render(path, small, overrides, seed=seed)
            return result.seconds, result.passes
        return fn

    pair("dof.xml dof=off (A) vs authored pinhole (B)",
         mcrt_run(EFFECTS / "dof.xml", {"dof": False}), mcrt_run(pinhole))
    pair("motion.xml motion=off (A) vs authored static (B)",
         mcrt_run(EFFECTS / "motion.xml", {"motion": False}), mcrt_run(static))
    pair("motion.xml motion=on (A) vs authored static (B)",
         mcrt_run(EFFECTS / "motion.xml"), mcrt_run(static))
    for name in ("aa", "soft_shadows"):
        path = EFFECTS / f"{name}.xml"
        plan = plan_scene(path, small).plan
        authored = load_scene(path, small)  # the scene's own `direct` (1 emitter + 1 BSDF sample)
        integ = ", ".join(f"{k} {v}" for k, v in plan.integrator.items() if k != "type")
        pair(f"{name}.xml direct plan ({integ}) (A) vs Mitsuba `direct` mi.render (B)",
             mcrt_run(path), lambda seed, s=authored: (timed_mitsuba(s, 64, seed), 1))
        planned_scene = plan_scene(path, small).scene
        pair(f"{name}.xml direct plan (A) vs mi.render of the planned scene, same "
             f"integrator (B)", mcrt_run(path),
             lambda seed, s=planned_scene: (timed_mitsuba(s, 64, seed), 1))
    t0 = time.perf_counter()
    for _ in range(5):
        plan_scene(EFFECTS / "combined.xml", small)
    print(f"\nPlanning (parse, analyse, build) combined.xml: "
          f"{(time.perf_counter() - t0) / 5 * 1000:.0f} ms per scene, outside the render "
          f"times above.\n")


# ----------------------------------------------------------------------------
COST_ROWS = [
    ("soft_shadows", EFFECTS / "soft_shadows.xml", {"soft_shadows": False}),
    ("glossy", EFFECTS / "glossy.xml", {"glossy": False}),
    ("dof", EFFECTS / "dof.xml", {"dof": False}),
    ("motion", EFFECTS / "motion.xml", {"motion": False}),
    ("indirect", CORNELL, {"indirect": False}),
    ("all (combined.xml)", EFFECTS / "combined.xml",
     {"soft_shadows": False, "glossy": False, "dof": False, "motion": False}),
]


def cost_table(args) -> None:
    spp = 64
    print("### Cost of each effect at equal spp and at equal error\n")
    print(f"{args.width}x{args.height} (Cornell: {args.height}^2), jittered, {spp} spp; "
          f"relMSE against a {args.reference_factor * spp}-spp render of the same variant; "
          f"time = median of {args.rounds} renders; equal-error time = time the 'on' variant "
          f"needs for the 'off' variant's relMSE at {spp} spp, from its measured slope "
          f"(relMSE ~ spp^-b between {spp // 4} and {spp} spp).\n")
    print("| effect | off [s] | on [s] | time on/off, equal spp | relMSE off | relMSE on | b (on) "
          "| time on/off, equal error |")
    print("|---|---|---|---|---|---|---|---|")
    for name, path, off in COST_ROWS:
        params = ({"res": str(args.height)} if path == CORNELL
                  else {"width": str(args.width), "height": str(args.height)})
        row = {}
        for key, overrides in (("off", off), ("on", {})):
            reference, _ = planned_render(path, params, overrides,
                                          spp=spp * args.reference_factor, seed=99)
            errors = {}
            for s in (spp // 4, spp):
                image, _ = planned_render(path, params, overrides, spp=s, seed=1)
                errors[s] = rel_mse(image.rgb, reference.rgb)
            times = interleaved({"t": lambda seed, p=path, q=params, o=overrides: planned_render(
                p, q, o, spp=spp, seed=seed)[0].seconds}, args.rounds)["t"]
            slope = math.log(errors[spp // 4] / errors[spp]) / math.log(4)
            row[key] = (statistics.median(times), errors[spp], slope)
        (t_off, e_off, _), (t_on, e_on, b_on) = row["off"], row["on"]
        equal_error = t_on * (e_on / e_off) ** (1 / b_on) / t_off if b_on > 0 else float("nan")
        print(f"| {name} | {t_off:.3f} | {t_on:.3f} | {t_on / t_off:.2f} | {e_off:.2e} | "
              f"{e_on:.2e} | {b_on:.2f} | {equal_error:.2f} |")
    print()


# ----------------------------------------------------------------------------
def scene_times(args) -> None:
    print("### Shipped effect scenes at default settings\n")
    print(f"Default resolution, sampler and spp; plan + render; median of {args.rounds} after "
          f"warm-up.\n")
    print("| scene | effects | integrator | passes | render [s] | plan + render [s] |")
    print("|---|---|---|---|---|---|")
    for path in sorted(EFFECTS.glob("*.xml")):
        renders, totals = [], []
        planned_render(path)  # warm-up
        for r in range(args.rounds):
            start = time.perf_counter()
            result, plan = planned_render(path, seed=r)
            totals.append(time.perf_counter() - start)
            renders.append(result.seconds)
        integ = plan.integrator["type"] + (f" {plan.integrator['max_depth']}"
                                           if "max_depth" in plan.integrator else "")
        print(f"| {path.name} | {', '.join(plan.effects_on)} | {integ} | {result.passes} | "
              f"{statistics.median(renders):.2f} | {statistics.median(totals):.2f} |")
    print()


# ----------------------------------------------------------------------------
STREAK_XML = """<scene version="3.0.0">
  <default name="spp" value="64"/>
  <default name="sampler" value="jittered"/>
  <integrator type="direct"/>
  <sensor type="orthographic">
    <float name="shutter_open" value="0"/><float name="shutter_close" value="1"/>
    <transform name="to_world"><scale x="2" y="2" z="1"/>
      <lookat origin="0,0,5" target="0,0,0" up="0,1,0"/></transform>
    <sampler type="$sampler"><integer name="sample_count" value="$spp"/></sampler>
    <film type="hdrfilm"><integer name="width" value="128"/><integer name="height" value="8"/>
      <string name="component_format" value="float32"/><rfilter type="box"/></film>
  </sensor>
  <shape type="rectangle" id="bar">
    <transform name="to_world"><scale x="0.25" y="2"/><translate x="-1"/></transform>
    <emitter type="area"><rgb name="radiance" value="1"/></emitter>
    <vector name="mcrt_velocity" value="1, 0, 0"/>
  </shape>
</scene>"""
STREAK_PX = 32.0  # 1 unit per unit time at 32 px per unit, shutter [0, 1]


def strobing(args, tmp: Path) -> None:
    path = tmp / "streak.xml"
    path.write_text(STREAK_XML)

    def profile(n, spp, seed, mode="shifted"):
        result, plan = planned_render(path, {"spp": str(spp)}, subframes=n, seed=seed,
                                      mode=mode)
        times = np.array(plan.subframe_times)
        return result.rgb[..., 0].mean(axis=0), STREAK_PX * (times.mean() - 0.5)

    print("### Strobing: sub-frames against a 256-sub-frame reference\n")
    refs = [profile(256, 1024, 100 + s)[0] for s in range(4)]
    reference = np.mean(refs, axis=0)
    floor = strobing_index(np.mean([profile(256, 1024, 200 + s)[0] for s in range(4)], axis=0),
                           reference)
    print(f"A bar 16 px wide moving 32 px over the shutter (orthographic, 128x8, jittered). "
          f"strobing_index = max |profile - reference| / peak after removing the sub-step "
          f"offset of the mean sub-frame time; renders at 1024 spp (4096 for 128 sub-frames) so "
          f"that noise stays small; median of 3 seeds. Noise floor (two 4-seed references): "
          f"{floor:.4f}.\n")
    print("| sub-frames | spacing [px] | shifted lattice (default) | jittered per stratum |")
    print("|---|---|---|---|")
    for n in (4, 8, 16, 32, 64, 128):
        spp = 1024 if n <= 64 else 4096
        cells = []
        for mode in ("shifted", "jittered"):
            values = []
            for seed in range(3):
                p, shift = profile(n, spp, seed, mode)
                values.append(strobing_index(p, reference, shift))
            cells.append(f"{statistics.median(values):.4f}")
        print(f"| {n} | {STREAK_PX / n:g} | {cells[0]} | {cells[1]} |")

    # The shipped motion scene: the ball's rows, default settings vs a reference.
    motion = EFFECTS / "motion.xml"
    small = {"width": "320", "height": "240"}
    plan = plan_scene(motion, small).plan
    ref_img = np.mean([planned_render(motion, {**small, "spp": "1024"}, subframes=256,
                                      seed=300 + s)[0].rgb for s in range(2)], axis=0)
    rows = slice(110, 150)  # through the ball's centre (y = 0.5)
    ref_profile = ref_img[rows, :, 0].mean(axis=0)
    speed_px = plan.streak_px  # bounding-box estimate, close to the ball's centre speed
    out = []
    for spp in (64, 1024):
        result, p2 = planned_render(motion, {**small, "spp": str(spp)},
                                    subframes=plan.subframes, seed=5)
        shift = speed_px * (np.mean(p2.subframe_times) - 0.5)
        out.append(strobing_index(result.rgb[rows, :, 0].mean(axis=0), ref_profile, shift))
    noise = strobing_index(np.mean([planned_render(motion, {**small, "spp": "1024"},
                                                   subframes=256, seed=400 + s)[0].rgb
                                    for s in range(2)], axis=0)[rows, :, 0].mean(axis=0),
                           ref_profile)
    print(f"\nmotion.xml (streak {plan.streak_px:.1f} px, default {plan.subframes} sub-frames, "
          f"rows 110-149 through the ball): strobing_index {out[0]:.4f} at the default 64 spp "
          f"(noise included), {out[1]:.4f} at 1024 spp with the same sub-frame count; "
          f"reference noise floor {noise:.4f}.\n")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--rounds", type=int, default=5)
    parser.add_argument("--width", type=int, default=160)
    parser.add_argument("--height", type=int, default=120)
    parser.add_argument("--reference-factor", type=int, default=16)
    parser.add_argument("--only", nargs="*", default=["off", "cost", "scenes", "strobing"],
                        choices=["off", "cost", "scenes", "strobing"])
    args = parser.parse_args()
    with tempfile.TemporaryDirectory() as tmp:
        tmp = Path(tmp)
        if "off" in args.only:
            off_costs_nothing(args, tmp)
        if "cost" in args.only:
            cost_table(args)
        if "scenes" in args.only:
            scene_times(args)
        if "strobing" in args.only:
            strobing(args, tmp)


if __name__ == "__main__":
    main()
