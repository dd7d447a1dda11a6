"""What does planning cost on a large scene, against loading it?

A many-mesh scene is generated (``--meshes`` OBJ spheres, default 400 of ~3000
triangles each (``--segments``), in
a grid under an environment light and one area light, with a path integrator),
then three measurements run in every round, in a shuffled order:

* **load**: ``mi.load_file(scene)`` in this process;
* **plan**: :func:`mcrt.render.plan.plan_scene` (reads the XML once, decides
  the effects, edits the description, instantiates once);
* **end to end** (``--render``): a whole ``mcrt -q render`` process against a
  plain script doing ``mi.load_file`` + ``mi.render`` + writing a float32 EXR,
  each from start to exit.

Every measurement runs once as a warm-up (Dr.Jit's kernel cache, the page
cache), then ``--rounds`` rounds in an order shuffled per round (the timing
protocol's, ``mcrt.core.timing``). Prints the
medians and the median of the per-round ratios with their spread (min..max).
Goals: plan <= 1.1x one load; render end to end <= 1.1x plain.

    python benchmarks/plan_cost.py [--meshes 400] [--rounds 5] [--render]
    python benchmarks/plan_cost.py --quick    # smoke run: 40 meshes, 2 rounds
"""

from __future__ import annotations

import argparse
import statistics
import subprocess
import sys
import tempfile
import time
from collections.abc import Callable
from pathlib import Path

PLAN_GOAL = 1.1
RENDER_GOAL = 1.1

PLAIN_SCRIPT = '''\
import sys
import mitsuba as mi
mi.set_variant("llvm_ad_rgb")
import numpy as np
import OpenEXR
scene = mi.load_file(sys.argv[1])
image = np.asarray(mi.render(scene, spp=int(sys.argv[3])), dtype=np.float32)
header = {"compression": OpenEXR.ZIP_COMPRESSION, "type": OpenEXR.scanlineimage}
with OpenEXR.File(header, {"RGB": image[..., :3]}) as f:
    f.write(sys.argv[2])
'''


def sphere_obj(x: float, z: float, radius: float, segments: int) -> str:
    """A closed UV sphere (``2 segments (segments - 1)`` triangles) as OBJ text."""
    import numpy as np

    theta = np.linspace(0, np.pi, segments + 1)[1:-1]
    phi = np.linspace(0, 2 * np.pi, 2 * segments, endpoint=False)
    t, p = np.meshgrid(theta, phi, indexing="ij")
    ring = np.stack([np.sin(t) * np.cos(p), np.cos(t), np.sin(t) * np.sin(p)], -1).reshape(-1, 3)
    verts = np.vstack([[0, 1, 0], ring, [0, -1, 0]]) * radius + [x, radius, z]
    m, rings = 2 * segments, segments - 1
    faces = [(1, 2 + (k + 1) % m, 2 + k) for k in range(m)]
    for r in range(rings - 1):
        for k in range(m):
            a, b = 2 + r * m + k, 2 + r * m + (k + 1) % m
            faces += [(a, b, b + m), (a, b + m, a + m)]
    last = len(verts)
    faces += [(last, 2 + (rings - 1) * m + k, 2 + (rings - 1) * m + (k + 1) % m)
              for k in range(m)]
    lines = [f"v {a:.5f} {b:.5f} {c:.5f}" for a, b, c in verts]
    lines += [f"f {a} {b} {c}" for a, b, c in faces]
    return "\n".join(lines) + "\n"


def write_many_mesh_scene(folder: Path, meshes: int, segments: int, res: int = 64,
                          spp: int = 4) -> Path:
    """A scene of ``meshes`` small spheres on a floor, each its own OBJ file."""
    side = max(1, int(meshes ** 0.5 + 0.999))
    shapes = []
    for i in range(meshes):
        x, z = (i % side - side / 2) * 0.5, (i // side - side / 2) * 0.5
        (folder / f"m{i}.obj").write_text(sphere_obj(x, z, 0.2, segments))
        shapes.append(f'<shape type="obj"><string name="filename" value="m{i}.obj"/>'
                      f'<bsdf type="diffuse"><rgb name="reflectance" value="0.{i % 7 + 2}"/>'
                      f'</bsdf></shape>')
    extent = side * 0.5
    path = folder / "many_meshes.xml"
    path.write_text(f'''<scene version="3.0.0">
  <integrator type="path"><integer name="max_depth" value="4"/></integrator>
  <sensor type="perspective">
    <float name="fov" value="50"/>
    <transform name="to_world"><lookat origin="0,{extent},{extent * 1.2}" target="0,0,0"
        up="0,1,0"/></transform>
    <sampler type="independent"><integer name="sample_count" value="{spp}"/></sampler>
    <film type="hdrfilm"><integer name="width" value="{res}"/><integer name="height"
        value="{res}"/><rfilter type="box"/></film>
  </sensor>
  <emitter type="constant"><rgb name="radiance" value="0.5"/></emitter>
  <shape type="rectangle">
    <transform name="to_world"><scale value="{extent}"/><rotate x="1" angle="-90"/></transform>
    <bsdf type="diffuse"/>
  </shape>
  <shape type="sphere">
    <point name="center" value="0,{extent},0"/><float name="radius" value="0.5"/>
    <emitter type="area"><rgb name="radiance" value="4"/></emitter>
  </shape>
  {chr(10).join(shapes)}
</scene>
''')
    return path


def timed(fn: Callable[[], object]) -> float:
    import drjit as dr

    dr.sync_thread()
    start = time.perf_counter()
    fn()
    dr.sync_thread()
    return time.perf_counter() - start


def run_process(cmd: list[str]) -> float:
    start = time.perf_counter()
    subprocess.run(cmd, check=True, stdout=subprocess.DEVNULL)
    return time.perf_counter() - start


def interleaved(cases: dict[str, Callable[[], float]], rounds: int) -> dict[str, list[float]]:
    """Times of every case per round, in the timing protocol's order shuffled per
    round (:func:`mcrt.core.timing.round_orders`)."""
    from mcrt.core.timing import round_orders

    for case in cases.values():
        case()  # warm-up
    names = list(cases)
    times: dict[str, list[float]] = {name: [] for name in names}
    for order in round_orders(len(names), rounds):
        for name in (names[i] for i in order):
            times[name].append(cases[name]())
    return times


def report(times: dict[str, list[float]], pairs: list[tuple[str, str, float]]) -> bool:
    ok = True
    for name, values in times.items():
        print(f"{name:>10s}: median {statistics.median(values):.3f} s "
              f"(min {min(values):.3f}, max {max(values):.3f})")
    for num, den, goal in pairs:
        ratios = [a / b for a, b in zip(times[num], times[den], strict=True)]
        median = statistics.median(ratios)
        verdict = "PASS" if median <= goal else "FAIL"
        ok &= median <= goal
        print(f"{num}/{den}: median ratio {median:.3f} (per round {min(ratios):.3f}.."
              f"{max(ratios):.3f}), goal <= {goal}: {verdict}")
    return ok


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--meshes", type=int, default=400)
    ap.add_argument("--segments", type=int, default=40, help="sphere segments (2s(s-1) triangles)")
    ap.add_argument("--rounds", type=int, default=5)
    ap.add_argument("--render", action="store_true", help="also time mcrt render end to end")
    ap.add_argument("--spp", type=int, default=4)
    ap.add_argument("--quick", action="store_true")
    args = ap.parse_args()
    if args.quick:
        args.meshes, args.segments, args.rounds = 40, 8, 2

    import mitsuba as mi

    import mcrt  # noqa: F401  (variant, plugins)
    from mcrt.render.plan import plan_scene

    with tempfile.TemporaryDirectory() as tmp:
        folder = Path(tmp)
        scene = write_many_mesh_scene(folder, args.meshes, args.segments, spp=args.spp)
        cases: dict[str, Callable[[], float]] = {
            "load": lambda: timed(lambda: mi.load_file(str(scene))),
            "plan": lambda: timed(lambda: plan_scene(scene)),
        }
        pairs = [("plan", "load", PLAN_GOAL)]
        if args.render:
            plain = folder / "plain.py"
            plain.write_text(PLAIN_SCRIPT)
            cases["mcrt"] = lambda: run_process(
                [sys.executable, "-m", "mcrt", "-q", "render", str(scene), "--sampler",
                 "independent", "--spp", str(args.spp), "-o", str(folder / "mcrt_out")])
            cases["plain"] = lambda: run_process(
                [sys.executable, str(plain), str(scene), str(folder / "plain.exr"),
                 str(args.spp)])
            pairs.append(("mcrt", "plain", RENDER_GOAL))
        print(f"{args.meshes} meshes, {args.rounds} rounds")
        ok = report(interleaved(cases, args.rounds), pairs)
    return 0 if ok else 1


if __name__ == "__main__":
    sys.exit(main())
