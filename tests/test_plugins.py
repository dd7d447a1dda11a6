"""Users' sampler plugins (:mod:`mcrt.plugins`): a file registering samplers works
by name in every command, from ``--plugin``, ``$MCRT_PLUGINS``, a study's
``plugins`` and installed packages' entry points; on Dask workers; after a
variant switch. Broken plugins are one-line errors."""

from __future__ import annotations

import argparse
import json
import os
import re
import shlex
import subprocess
import sys
import textwrap
import threading
from pathlib import Path

import mitsuba as mi
import numpy as np
import pytest

import mcrt
from mcrt import plugins
from mcrt.analysis.study.config import ConfigError, load_config
from mcrt.cli import build_parser, command_of
from mcrt.core.sampling import check_sampler_name, make_sampler
from mcrt.errors import SamplerError
from mcrt.io import read_exr
from mcrt.samplers import registry
from tests.conftest import ROOT, TINY_SCENE, run_cli

#: A plugin serving numpy point sets from a generator (``{name}``: the sampler).
#: With ``$MCRT_TEST_MARKERS`` set it leaves a file named after its process there.
GENERATOR_PLUGIN = '''
import os
import re
from pathlib import Path

import mcrt

if os.environ.get("MCRT_TEST_MARKERS"):
    Path(os.environ["MCRT_TEST_MARKERS"], str(os.getpid())).touch()


def iid_sets(count, n, rng):
    """count sets of n independent uniform points"""
    return rng.random((count, n, 2))


mcrt.register_sampler("{name}", points=iid_sets)
'''

#: A Dr.Jit sampler written with mcrt's public API only.
DRJIT_PLUGIN = '''
import drjit as dr
import mitsuba as mi

import mcrt
from mcrt.samplers import McrtSampler


def mix(a, b):
    """A 32-bit integer hash of two lanes' keys (wrapping multiplications)."""
    h = a ^ (b * 0x9E3779B1)
    h = h ^ (h >> 16)
    h = h * 0x7FEB352D
    h = h ^ (h >> 15)
    h = h * 0x846CA68B
    return h ^ (h >> 16)


def unit(h):
    return mi.Float(h >> 8) * (1.0 / (1 << 24))


class HashNoise(McrtSampler):
    """White noise: a hash of (seed, pixel, dimension) and the sample index."""

    def _sample_1d(self, key, sample, active):
        return unit(mix(key, sample))

    def _sample_2d(self, key, sample, active):
        h = mix(key, sample)
        return mi.Point2f(unit(h), unit(mix(h, dr.opaque(mi.UInt32, 0x68E31DA4))))


mcrt.register_sampler("{name}", sampler=HashNoise)
'''


def parent_sets(count: int, n: int, rng: np.random.Generator) -> np.ndarray:
    """A generator registered in this process, without a plugin file."""
    return rng.random((count, n, 2))


@pytest.fixture(autouse=True)
def _own_plugins(tmp_path, monkeypatch):
    """Each test starts without $MCRT_PLUGINS, with its own cache, and leaves no
    plugin or sampler of its own behind."""
    monkeypatch.setenv("MCRT_CACHE_DIR", str(tmp_path / "cache"))
    monkeypatch.delenv(plugins.ENV, raising=False)
    files, names = set(plugins.loaded_plugins()), set(registry.names())
    yield
    for path in plugins.loaded_plugins():
        if path not in files:
            plugins.unload_plugin(path)
    for name in registry.names():
        if name not in names:
            registry.unregister(name)
    plugins._UNAVAILABLE.clear()
    plugins._FAILED.clear()


def write_plugin(directory: Path, text: str, name: str, file: str | None = None) -> Path:
    path = directory / (file or f"{name}_plugin.py")
    path.write_text(text.replace("{name}", name))
    return path


@pytest.fixture
def scene(tmp_path) -> Path:
    """The tests' tiny scene at 16x16 pixels."""
    path = tmp_path / "tiny.xml"
    path.write_text(TINY_SCENE.replace('value="32"', 'value="16"'))
    return path


def _run(argv: list[str], env: dict | None = None) -> subprocess.CompletedProcess:
    return subprocess.run(argv, capture_output=True, text=True, timeout=600,
                          env={**os.environ, **(env or {})})


def _mcrt(*args: str, env: dict | None = None) -> subprocess.CompletedProcess:
    return _run([sys.executable, "-m", "mcrt", *args], env)


# --------------------------------------------------------------------------- the command line


def test_render_with_plugins_before_and_after_the_command(tmp_path, scene, capsys):
    """`mcrt --plugin A render ... --plugin B`: both load (after the variant is
    chosen, before the command); the render writes its image and records the
    plugins in its header."""
    points = write_plugin(tmp_path, GENERATOR_PLUGIN, "mine")
    drjit = write_plugin(tmp_path, DRJIT_PLUGIN, "hash_noise")
    for sampler in ("mine", "hash_noise"):
        out = tmp_path / f"img_{sampler}"
        code, stdout, err = run_cli(capsys, "-q", "--plugin", str(points), "render", str(scene),
                                    "--sampler", sampler, "--spp", "4", "-o", str(out),
                                    "--plugin", str(drjit))
        assert code == 0, err
        layers, meta = read_exr(out.with_suffix(".exr"))
        rgb = layers["rgb"]
        assert rgb.shape == (16, 16, 3) and np.isfinite(rgb).all() and rgb.mean() > 0.01
        assert meta["sampler"] == sampler
        assert json.loads(meta["plugins"]) == [str(points), str(drjit)]
        assert out.with_suffix(".png").stat().st_size > 0
        assert f"sampler {sampler}" in stdout
    assert plugins.loaded_plugins()[-2:] == [points, drjit]
    assert registry.info("mine").origin == str(points) and registry.info("mine").kind == "points"
    assert registry.info("hash_noise").origin == str(drjit)


def test_plugin_is_a_global_option():
    args = build_parser().parse_args(["--plugin", "a.py", "-q", "render", "x.xml",
                                      "--plugin", "b.py"])
    assert args.plugins == ["a.py"] and args.plugins_after == ["b.py"] and args.quiet
    assert command_of(["--plugin", "a.py", "render", "x.xml"]) == "render"
    assert command_of(["--plugin=a.py", "--variant", "llvm_ad_rgb", "plan"]) == "plan"


def test_recorded_command_lines_load_the_same_plugins(tmp_path):
    """A render's recorded command line and a study's resume command carry the
    plugins the command line loaded (absolute paths)."""
    from mcrt.cli._render_record import job_text
    from mcrt.cli.compare_cmd import resume_command

    plugin = tmp_path / "p.py"
    args = argparse.Namespace(scene="s.xml", sampler="mine", seed=3, defines=None, effect=None,
                              sampler_params=None, multisample=False, adaptive=False,
                              plugin_files=[plugin])
    words = shlex.split(job_text(args, 16, Path("o/img")))
    assert words[:5] == ["mcrt", "--variant", mi.variant(), "--plugin", str(plugin)]
    assert words[5] == "render"
    line = resume_command(argparse.Namespace(config="s.toml", quiet=False, variant=None,
                                             plugin_files=[plugin]), Path("out"))
    assert shlex.split(line) == ["mcrt", "--plugin", str(plugin), "compare", "s.toml", "-o",
                                 "out"]


RAISING = "import mcrt\n\nvalue = 1\nraise RuntimeError('no points today')\n"
SYNTAX = "import mcrt\n\ndef points(count, n, rng:\n    pass\n"
TAKEN = ("import mcrt\nfrom mcrt.samplers import McrtSampler\n\n\nclass J(McrtSampler):\n"
         "    pass\n\n\nmcrt.register_sampler('jittered', sampler=J)\n")


@pytest.mark.parametrize("text, expected", [
    (None, "no such file"),
    (RAISING, "line 4: RuntimeError: no points today"),
    (SYNTAX, "line 3: SyntaxError"),
    (TAKEN, "line 9: sampler name 'jittered' is taken by mcrt's jittered"),
])
def test_a_broken_plugin_is_one_line_and_exit_2(tmp_path, scene, capsys, text, expected):
    plugin = tmp_path / "broken.py"
    if text is not None:
        plugin.write_text(text)
    code, out, err = run_cli(capsys, "--plugin", str(plugin), "plan", str(scene))
    assert code == 2 and out == ""
    assert err.count("\n") == 1 and "Traceback" not in err
    assert err.startswith(f"mcrt: error: plugin {plugin}") and expected in err, err
    assert plugin not in plugins.loaded_plugins()
    assert "jittered" in registry.names() and registry.info("jittered").kind == "mcrt"


def test_a_plugin_may_not_take_another_plugins_name(tmp_path):
    first = write_plugin(tmp_path, GENERATOR_PLUGIN, "mine", "first.py")
    second = write_plugin(tmp_path, DRJIT_PLUGIN, "mine", "second.py")
    plugins.load_plugin(first)
    assert plugins.load_plugin(first) is plugins.load_plugin(str(first))  # once per file
    with pytest.raises(SamplerError, match=r"second\.py, line \d+: sampler name 'mine' is "
                                           r"taken: .*first\.py registered it"):
        plugins.load_plugin(second)
    assert registry.info("mine").origin == str(first)
    assert plugins.plugin_names(first) == ("mine",)


@pytest.mark.slow
def test_pattern_integrate_and_reference_take_the_name(tmp_path, scene, capsys):
    points = write_plugin(tmp_path, GENERATOR_PLUGIN, "mine")
    drjit = write_plugin(tmp_path, DRJIT_PLUGIN, "hash_noise")
    load = ["-q", "--plugin", str(points), "--plugin", str(drjit)]
    code, out, err = run_cli(capsys, *load, "pattern", "hash_noise", "--spp", "16", "--pixels",
                             "4", "-o", str(tmp_path / "pattern"))
    assert code == 0, err
    summary = json.loads((tmp_path / "pattern" / "summary.json").read_text())
    assert summary["sampler"] == "hash_noise" and summary["n_points"] == 16
    code, out, err = run_cli(capsys, *load, "integrate", "pi", "--sampler", "mine,hash_noise",
                             "--min-n", "16", "--max-n", "64", "--trials", "16",
                             "-o", str(tmp_path / "integrate"))
    assert code == 0, err
    assert "mine" in out and "hash_noise" in out
    assert (tmp_path / "integrate" / "integrate_pi.csv").is_file()
    code, out, err = run_cli(capsys, *load, "reference", str(scene), "--sampler", "mine",
                             "--spp", "16", "-o", str(tmp_path / "ref"))
    assert code == 0, err
    layers, meta = read_exr(tmp_path / "ref.exr")
    assert meta["sampler"] == "mine" and np.isfinite(layers["rgb"]).all()


# --------------------------------------------------------------------------- other processes


def test_mcrt_plugins_in_the_environment(tmp_path, scene):
    """$MCRT_PLUGINS loads before the command; in Python, on the first unknown name."""
    points = write_plugin(tmp_path, GENERATOR_PLUGIN, "mine")
    drjit = write_plugin(tmp_path, DRJIT_PLUGIN, "hash_noise")
    env = {plugins.ENV: os.pathsep.join([str(points), str(drjit)])}
    proc = _mcrt("-q", "render", str(scene), "--sampler", "hash_noise", "--spp", "4", "-o",
                 str(tmp_path / "img"), env=env)
    assert proc.returncode == 0, proc.stderr
    assert (tmp_path / "img.exr").is_file()
    script = ("import sys, mcrt\n"
              "from mcrt.core.sampling import make_sampler\n"
              "assert 'mcrt.plugins' not in sys.modules  # import mcrt loads nothing\n"
              "print(make_sampler('mine', 16).sample_count())\n")
    proc = _run([sys.executable, "-c", script], env)
    assert proc.returncode == 0 and proc.stdout.split() == ["16"], proc.stderr
    proc = _mcrt("plan", str(scene), env={plugins.ENV: str(tmp_path / "gone.py")})
    assert proc.returncode == 2
    assert proc.stderr.strip() == (f"mcrt: error: plugin {tmp_path / 'gone.py'}: no such file "
                                   f"(from ${plugins.ENV})")


ENTRY_MODULE = '''
import mcrt

mcrt.register_sampler("ep_points", points=lambda count, n, rng: rng.random((count, n, 2)))
'''

ENTRY_CALLABLE = '''
import mitsuba as mi

import mcrt


def register():
    """Defines its class when called: a variant switch calls it again."""
    from mcrt.samplers import McrtSampler

    class Shifted(McrtSampler):
        def _sample_1d(self, key, sample, active):
            return mi.Float(((key ^ sample) * 0x9E3779B1) >> 8) * (1.0 / (1 << 24))

        def _sample_2d(self, key, sample, active):
            return mi.Point2f(self._sample_1d(key, sample, active),
                              self._sample_1d(key ^ 0x5BD1E995, sample, active))

    mcrt.register_sampler("ep_drjit", sampler=Shifted)
'''


def test_installed_packages_bring_samplers_by_entry_points(tmp_path, scene):
    """A package with entry points in the group ``mcrt.samplers`` (a module that
    registers on import, a function to call): its names work with no --plugin,
    in the command line and in Python, and survive a variant switch."""
    site = tmp_path / "site"
    package = site / "mcrt_ep_demo"
    package.mkdir(parents=True)
    (package / "__init__.py").write_text(ENTRY_MODULE)
    (package / "more.py").write_text(ENTRY_CALLABLE)
    info = site / "mcrt_ep_demo-0.1.dist-info"
    info.mkdir()
    (info / "METADATA").write_text("Metadata-Version: 2.1\nName: mcrt-ep-demo\nVersion: 0.1\n")
    (info / "entry_points.txt").write_text(
        "[mcrt.samplers]\npoints = mcrt_ep_demo\ndrjit = mcrt_ep_demo.more:register\n")
    env = {"PYTHONPATH": os.pathsep.join([str(site), os.environ.get("PYTHONPATH", "")])}
    proc = _mcrt("plan", str(scene), "--sampler", "ep_points", env=env)
    assert proc.returncode == 0, proc.stderr
    script = textwrap.dedent("""
        import mitsuba as mi
        import mcrt
        from mcrt.core.sampling import make_sampler
        from mcrt.samplers import registry

        make_sampler("ep_drjit", 4)  # an unknown name: the entry points load
        print(registry.info("ep_points").origin)
        mi.set_variant("llvm_ad_mono")
        mcrt.register()
        sampler = make_sampler("ep_drjit", 4)
        sampler.seed(0, 8)
        print(mi.Sampler in type(sampler).__mro__, type(sampler.next_1d()) is mi.Float)
    """)
    proc = _run([sys.executable, "-c", script], env)
    assert proc.returncode == 0, proc.stderr
    origin, switched = proc.stdout.strip().splitlines()
    assert origin == "entry point points = mcrt_ep_demo of mcrt-ep-demo"
    assert switched == "True True"


def test_a_variant_switch_recreates_the_plugins_classes(tmp_path):
    """Mitsuba binds a Python sampler class to the variant it was defined in:
    after switching to llvm_ad_mono, ``mcrt.register()`` runs the plugin again,
    and its samplers load and draw the new variant's ``mi.Float``."""
    points = write_plugin(tmp_path, GENERATOR_PLUGIN, "mine")
    drjit = write_plugin(tmp_path, DRJIT_PLUGIN, "hash_noise")
    script = textwrap.dedent(f"""
        import mitsuba as mi
        import mcrt
        from mcrt.core.sampling import make_sampler
        from mcrt.plugins import load_plugin

        load_plugin({str(points)!r})
        load_plugin({str(drjit)!r})
        before = type(make_sampler("hash_noise", 4))
        mi.set_variant("llvm_ad_mono")
        mcrt.register()
        for name in ("hash_noise", "mine"):
            sampler = make_sampler(name, 4)
            sampler.seed(1, 16)
            value, point = sampler.next_1d(), sampler.next_2d()
            assert isinstance(sampler, mi.Sampler) and mi.Sampler in type(sampler).__mro__
            assert type(value) is mi.Float and type(point) is mi.Point2f
            assert 0 <= min(value) and max(value) < 1
            print(name, type(sampler) is not before)
    """)
    proc = _run([sys.executable, "-c", script])
    assert proc.returncode == 0, proc.stderr
    assert proc.stdout.split() == ["hash_noise", "True", "mine", "True"]


# --------------------------------------------------------------------------- studies and workers


STUDY = """
name = "plugged"
spp = [4, 16]
seeds = 2
time_rounds = 2
samplers = ["mine", "parent_points"]
plugins = ["plugins/mine_plugin.py"]

[reference]
spp = 64

[[scenes]]
path = "tiny.xml"
"""


def test_study_plugins_are_checked_loaded_and_recorded(tmp_path, scene):
    (tmp_path / "plugins").mkdir()
    plugin = write_plugin(tmp_path / "plugins", GENERATOR_PLUGIN, "mine")
    config = tmp_path / "study.toml"
    config.write_text(STUDY.replace('"mine", "parent_points"', '"mine", "independent"'))
    study = load_config(config, check_scenes=False)
    assert study.plugins == (plugin,) and plugin in plugins.loaded_plugins()
    recorded = study.as_dict()["plugins"]
    assert recorded == [{"path": str(plugin), "sha256": plugins.file_digest(plugin)}]
    for value, message in (('"mine_plugin.py"', "must be a list of plugin files"),
                           ('["nowhere.py"]', "plugins[0]: plugin file not found"),
                           ("[1]", "must be a list of plugin files")):
        config.write_text(STUDY.replace('["plugins/mine_plugin.py"]', value))
        with pytest.raises(ConfigError, match=re.escape(message)):
            load_config(config, check_scenes=False)


@pytest.mark.slow
def test_a_study_with_plugins_runs_on_a_local_dask_cluster(tmp_path, scene, capsys, monkeypatch):
    """`mcrt compare` with ``plugins = [...]`` and ``--cluster local:2``: the
    worker processes load the plugin file before building its sampler, and get
    the generator this process registered without a file (sent by value)."""
    pytest.importorskip("distributed")
    markers = tmp_path / "markers"
    markers.mkdir()
    monkeypatch.setenv("MCRT_TEST_MARKERS", str(markers))
    (tmp_path / "plugins").mkdir()
    plugin = write_plugin(tmp_path / "plugins", GENERATOR_PLUGIN, "mine")
    mcrt.register_sampler("parent_points", points=parent_sets)
    config = tmp_path / "study.toml"
    config.write_text(STUDY)
    out = tmp_path / "report"
    code, stdout, err = run_cli(capsys, "-q", "compare", str(config), "-o", str(out),
                                "--cluster", "local:2")
    assert code == 0, err
    results = json.loads((out / "results.json").read_text())
    assert results["study"]["plugins"][0]["path"] == str(plugin)
    cells = results["cells"]
    assert sorted({c["sampler"] for c in cells}) == ["mine", "parent_points"] and len(cells) == 4
    workers = {int(p.name) for p in markers.iterdir()} - {os.getpid()}
    assert workers, "no worker process loaded the plugin"


def test_what_a_worker_gets_of_this_processes_samplers(tmp_path):
    """:func:`worker_state` / :func:`install_worker_state` (what a Dask worker
    runs at setup): plugin files load again, a generator registered here comes
    back by value, one that cannot be pickled is a clear error naming plugin files."""
    plugin = write_plugin(tmp_path, DRJIT_PLUGIN, "hash_noise")
    plugins.load_plugin(plugin)
    mcrt.register_sampler("parent_points", points=parent_sets)
    lock = threading.Lock()
    mcrt.register_sampler("locked",
                          points=lambda count, n, rng, lock=lock: rng.random((count, n, 2)))
    state = plugins.worker_state()
    assert str(plugin) in state["files"]
    assert "parent_points" in dict(state["shipped"]) and "hash_noise" not in dict(state["shipped"])
    assert "plugin file" in state["unavailable"]["locked"]
    registry.unregister("parent_points")
    registry.unregister("locked")
    plugins.install_worker_state(state)
    assert make_sampler("parent_points", 16).sample_count() == 16
    assert registry.info("parent_points").kind == "points"
    with pytest.raises(SamplerError, match="'locked' was registered in the client .* cannot be "
                                           "sent to the Dask workers .*--plugin FILE.py"):
        check_sampler_name("locked")


@pytest.mark.slow
def test_workers_that_outlive_a_command_run_the_edited_plugin(tmp_path):
    """Workers of an external cluster outlive commands: after the plugin file
    was edited (and loaded again here), they run its new code, not the code they
    loaded for an earlier command; a worker that reads other code than the client
    ran (a restarted worker, the file edited once more) refuses it in one line."""
    pytest.importorskip("distributed")
    from mcrt.analysis.reference import get_reference
    from mcrt.core.cluster import DaskExecutor
    from tests.conftest import same_stats

    plugin = write_plugin(tmp_path, GENERATOR_PLUGIN, "edited_between")
    scene, params = ROOT / "scenes" / "cornell_box.xml", {"res": "16"}

    def reference(executor=None):
        return get_reference(scene, params, spp=8, sampler="edited_between", spp_per_pass=4,
                             cache=False, executor=executor)

    plugins.load_plugin(plugin)
    cluster = DaskExecutor.connect("local:1")
    try:
        before = reference(cluster)
        same_stats(reference(), before)
        plugins.unload_plugin(plugin)
        plugin.write_text(plugin.read_text().replace("return rng.random",
                                                     "return 0.5 * rng.random"))
        plugins.load_plugin(plugin)
        after = reference()
        assert not np.array_equal(after.stats.mean, before.stats.mean)
        same_stats(after, reference(cluster))
        plugin.write_text(plugin.read_text().replace("0.5 *", "0.25 *"))
        cluster.client.restart()  # a fresh worker loads the file as it is now
        with pytest.raises(SamplerError) as refused:
            reference(cluster)
        message = str(refused.value)
        assert "\n" not in message and str(plugin) in message, message
        assert "is not the code the client loaded" in message, message
    finally:
        cluster.close()


def test_a_scene_naming_an_unloaded_users_sampler_points_to_plugin(scene, capsys):
    """Mitsuba only says 'Plugin "mine" not found'; mcrt says how to load it."""
    scene.write_text(scene.read_text().replace('type="jittered"', 'type="not_loaded_here"')
                     .replace('<float name="jitter" value="$jitter"/>', ""))
    code, _, err = run_cli(capsys, "render", str(scene), "-o", str(scene.parent / "out"))
    assert code == 2 and len(err.strip().splitlines()) == 1
    assert "'not_loaded_here' is your own sampler" in err and "--plugin FILE.py" in err


def test_a_changed_plugin_or_point_file_is_another_sampler_in_every_key(tmp_path):
    """Resumed renders, cached references and saved studies are keyed by a user's
    sampler code and point file too: editing either must not reuse old results."""
    from mcrt.analysis.pass_plan import plan_passes
    from mcrt.analysis.reference import reference_key
    from mcrt.analysis.study.config import parse_config
    from mcrt.analysis.study.store import study_key
    from mcrt.core.render_job import render_key
    from mcrt.core.sampling import sampler_fingerprint
    from mcrt.samplers.point_sources import jittered_sets

    assert sampler_fingerprint("jittered") == ""  # ours: the versions key them
    points = tmp_path / "sets.npy"
    np.save(points, jittered_sets(32, 16, np.random.default_rng(0)).astype(np.float32))
    plugin = write_plugin(tmp_path, GENERATOR_PLUGIN, "edited")
    plugins.load_plugin(plugin)
    scene = str(ROOT / "scenes" / "checkerboard.xml")
    config = parse_config({"spp": [16, 32], "seeds": 2, "reference": {"spp": 128},
                           "samplers": ["edited", {"name": "pointset",
                                                   "params": {"filename": str(points)}}],
                           "scenes": [{"path": scene}]})

    def keys() -> tuple[str, ...]:
        return (render_key(scene, {}, {}, "edited", 4, 0, 1, sampler_params="{}"),
                render_key(scene, {}, {}, "pointset", 16, 0, 1,
                           sampler_params=f'{{"filename": "{points}"}}'),
                reference_key(scene, {}, "edited", 0, plan_passes("edited", 16, 64)),
                study_key(config))

    before = keys()
    plugins.unload_plugin(plugin)
    plugin.write_text(plugin.read_text().replace("return rng.random", "return 0.5 * rng.random"))
    plugins.load_plugin(plugin)
    np.save(points, jittered_sets(32, 16, np.random.default_rng(1)).astype(np.float32))
    after = keys()
    assert all(a != b for a, b in zip(before, after, strict=True)), (before, after)
