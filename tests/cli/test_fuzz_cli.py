"""Property-based tests of the command line: bad arguments never crash mcrt.

For every subcommand, hypothesis draws argument lists that mix valid and
invalid values (unknown samplers, spp 0 / -1 / 1.5 / "abc" / huge, jitter 2 /
-1 / NaN / "x", negative or NaN adaptive thresholds, unknown flags, missing /
empty / directory / binary / malformed / unknown-plugin scene files, ``-D``
garbage, unwritable ``-o``, ...) and runs ``mcrt.cli.main(argv)`` in-process
with the expensive work stubbed out: ``render_film``, ``render_stats``,
``render_adaptive``, ``run_convergence`` and ``point_sets`` raise
:class:`StubReached` wherever mcrt imported them, so a valid command stops
right where the work would start. Every case must end in one of two ways:

* exit status 2 with exactly one stderr line ``mcrt: error: ...`` (or
  argparse's ``mcrt <cmd>: error: ...``; other stderr lines may only be
  ``mcrt: note:`` lines), or
* the stub reached (``mcrt plan`` and ``mcrt compare --check``, which
  render nothing: exit 0),

never a traceback; and every file that existed before is byte-identical
afterwards, with no new file anywhere (outputs are only written after the
work). Each drawn argument is labelled valid, invalid or either (where the
outcome depends on a combination the test does not model); a case with an
invalid argument must exit 2 and a case of valid arguments must reach the
stub. ``derandomize=True`` makes the examples the same on every run; the
``@example`` cases are the table in docs/bad-input.md.
About 15-25 s for the whole file on 2 cores.
"""

from __future__ import annotations

import importlib
import re
import sys
from collections import Counter
from pathlib import Path

import pytest
from hypothesis import example, given, settings
from hypothesis import strategies as st

import mcrt.cli
from mcrt.samplers import ALL_SAMPLERS, BUILTIN_SAMPLERS
from tests.conftest import FUZZ, TINY_SCENE, study_toml

OK, BAD, ANY = "valid", "invalid", "either"

#: Functions that start real work; stubbed in every mcrt module that holds them.
STUBBED = ("render_film", "render_stats", "render_adaptive", "run_convergence", "point_sets")
#: Modules imported up front, so that their bindings of the functions above get stubbed.
MODULES = ("mcrt.cli.render_cmd", "mcrt.cli.reference_cmd", "mcrt.cli.compare_cmd",
           "mcrt.cli.pattern_cmd", "mcrt.cli.integrate_cmd", "mcrt.cli.plan_cmd",
           "mcrt.cli.demo_cmd", "mcrt.analysis.reference", "mcrt.analysis.study",
           "mcrt.analysis.integrate", "mcrt.render.adaptive", "mcrt.core.render",
           "mcrt.samplers.points")

TINY = TINY_SCENE

#: Scene files (name in the work directory, validity). Built by the ``world`` fixture.
SCENES = {
    "tiny.xml": OK,
    "missing.xml": BAD,               # does not exist
    "empty.xml": BAD,                 # 0 bytes
    "folder.xml": BAD,                # a directory
    "binary.xml": BAD,                # random bytes with NULs
    "truncated.xml": BAD,             # malformed XML (cut in the middle of a tag)
    "unknown_plugin.xml": BAD,        # <bsdf type="nosuchbsdf"/>
    "undefined_param.xml": BAD,       # $nosuch without a <default>
    "not_a_scene.xml": BAD,           # the root is a <bsdf>
    "no_sensor.xml": BAD,             # a scene without a camera
    "missing_include.xml": BAD,       # <include> of a file that does not exist
    "text.xml": BAD,                  # "hello", not XML at all
}
#: A name longer than any file system allows (ENAMETOOLONG, which Path.exists() raises).
LONG = "a" * 300
#: Scene paths that are not files in the work directory.
ODD_SCENES = {LONG + ".xml": BAD, "": BAD, ".": BAD, "/": BAD}

#: Files that exist before every case and must be byte-identical after it.
PREVIOUS = ["tiny_jittered.exr", "tiny_jittered.png", "tiny_reference.exr",
            "out/img.exr", "out/img.png", "out/img_spp.png", "out/ref.exr",
            "out/report/report.html", "out/report/results.csv", "out/report/results.json",
            "out/report/summary.png", "out/report/error_vs_spp.png",
            "out/pattern/points.png", "out/pattern/summary.json", "out/pattern/radial.csv",
            "out/integrate/integrate_pi.csv", "out/integrate/integrate_pi.json",
            "out/demo/results.csv"]

GOOD_STUDY = study_toml("tiny.xml", params=None)


class StubReached(Exception):
    """The command got to the real work: its arguments were accepted."""


@pytest.fixture(scope="module")
def world(tmp_path_factory):
    """A work directory with every kind of scene and config file, and previous outputs."""
    root = tmp_path_factory.mktemp("fuzz_cli")
    (root / "tiny.xml").write_text(TINY)
    (root / "empty.xml").write_bytes(b"")
    (root / "folder.xml").mkdir()
    (root / "binary.xml").write_bytes(bytes(range(256)) * 4)
    (root / "truncated.xml").write_text(TINY[:300])
    (root / "unknown_plugin.xml").write_text(TINY.replace('"diffuse"', '"nosuchbsdf"'))
    (root / "undefined_param.xml").write_text(TINY.replace('value="40"', 'value="$nosuch"'))
    (root / "not_a_scene.xml").write_text('<bsdf version="3.0.0" type="diffuse"/>')
    no_sensor = TINY[:TINY.index("<sensor")] + TINY[TINY.index("</sensor>") + 9:]
    (root / "no_sensor.xml").write_text(no_sensor)
    (root / "missing_include.xml").write_text(
        TINY.replace("<emitter", '<include filename="nowhere.xml"/>\n    <emitter'))
    (root / "text.xml").write_text("hello")
    (root / "blocker").write_text("a file where a directory is expected")
    (root / "out" / "dir.exr").mkdir(parents=True)
    (root / "study.toml").write_text(GOOD_STUDY)
    for name, text in STUDIES.items():
        (root / name).write_bytes(text.encode() if isinstance(text, str) else text)
    (root / "folder.toml").mkdir()
    for name in PREVIOUS:
        path = root / name
        path.parent.mkdir(parents=True, exist_ok=True)
        path.write_bytes(f"previous content of {name}\n".encode())
    return root


@pytest.fixture
def env(world, monkeypatch, capfd):
    """Stubs installed, cwd = the work directory, a private cache."""
    monkeypatch.chdir(world)
    monkeypatch.setenv("MCRT_CACHE_DIR", str(world.parent / (world.name + "_cache")))
    reached: list[str] = []
    for name in MODULES:
        module = importlib.import_module(name)
        for attr in STUBBED:
            if callable(getattr(module, attr, None)):
                monkeypatch.setattr(module, attr, _stub(attr, reached))
    return world, capfd, reached


def _stub(name: str, reached: list[str]):
    def stub(*args, **kwargs):
        reached.append(name)
        raise StubReached(name)
    return stub


def _snapshot(root: Path) -> dict[str, bytes]:
    return {str(p.relative_to(root)): p.read_bytes() for p in root.rglob("*") if p.is_file()}


ERROR_LINE = re.compile(r"^mcrt(?: [a-z]+)?: error: \S")

#: (command, outcome) -> count over all cases run, outcome "error", "reached" or "ok".
OUTCOMES: Counter = Counter()


def run_case(env, argv: list[str], expected: str) -> None:
    """Run ``mcrt argv``; check the outcome (see the module doc)."""
    root, capfd, reached = env
    before = _snapshot(root)
    capfd.readouterr()
    reached.clear()
    try:
        code = mcrt.cli.main(list(argv))
    except SystemExit as stop:  # argparse
        code = stop.code
    except StubReached:
        code = "reached"
    out, err = capfd.readouterr()
    where = f"argv={argv!r} expected {expected}: got {code!r}\nstderr: {err}"
    assert "Traceback" not in out + err, where
    after = _snapshot(root)
    for name, data in before.items():
        assert after.get(name) == data, f"{name} was changed or removed; {where}"
    assert sorted(set(after) - set(before)) == [], f"new files; {where}"
    OUTCOMES[(_command(argv), "error" if code == 2 else "ok")] += 1
    if code == 2:
        assert expected != OK, where
        lines = [line for line in err.splitlines() if line.strip()]
        errors = [line for line in lines if ERROR_LINE.match(line)]
        assert len(errors) == 1, where
        assert all(line.startswith("mcrt: note: ") for line in lines if line not in errors), where
    else:
        renders_nothing = _command(argv) == "plan" or "--check" in argv
        assert code == (0 if renders_nothing else "reached"), where
        assert expected != BAD, where


def _command(argv: list[str]) -> str | None:
    return next((a for a in argv if a in ("render", "reference", "compare", "pattern",
                                          "integrate", "plan", "demo")), None)


# --------------------------------------------------------------------------- value pools
# (text, validity): validity of the value on its own, whatever else is on the line.

SAMPLERS = [(name, OK) for name in ALL_SAMPLERS] + [
    ("nope", BAD), ("", BAD), ("Jittered", BAD), ("uniform", BAD), ("jittered ", BAD),
    ("jittered,independent", BAD)]
SPP = [("1", OK), ("4", OK), ("16", OK), ("0", BAD), ("-1", BAD), ("1.5", BAD), ("abc", BAD),
       ("", BAD), ("1e3", BAD), ("nan", BAD), ("99999999999999999999", BAD)]
SEEDS = [("0", OK), ("7", OK), ("4294967295", OK), ("4294967296", BAD), ("-1", BAD),
         ("x", BAD), ("1.0", BAD), ("", BAD)]
DEFINES = [("spp=4", OK), ("jitter=0.25", OK), ("jitter=2", BAD), ("jitter=-1", BAD),
           ("jitter=nan", BAD), ("jitter=x", BAD), ("spp=0", BAD), ("spp=1.5", BAD),
           ("novalue", BAD), ("=3", BAD), ("1a=2", BAD), ("", BAD), ("foo=1", BAD),
           ("spp=", BAD)]
EFFECTS = [("dof=off", OK), ("motion=off,glossy=off", OK), ("", OK), ("aa=off", BAD),
           ("dof=maybe", BAD), ("nosuch=on", BAD), ("dof", BAD), ("dof=on", BAD),
           ("soft_shadows=on", BAD)]
THRESHOLDS = [("0.05", OK), ("0", OK), ("1e-3", OK), ("-1", BAD), ("nan", BAD), ("inf", BAD),
              ("abc", BAD), ("-0.5", BAD)]
CONFIDENCES = [("0.9", OK), ("1", BAD), ("0", BAD), ("nan", BAD), ("2", BAD)]
GROWTHS = [("2", OK), ("1", BAD), ("0.5", BAD), ("nan", BAD), ("inf", BAD)]
UNKNOWN_FLAGS = [["--bogus"], ["--spp2", "4"], ["-Z"], ["--jitter", "0.5"], ["--threads", "2"]]
EXTRA_WORD = st.text("abcxyz0123456789._/ ", min_size=1, max_size=8)


#: How the case being drawn picks values: "dirty" from whole pools, "clean" only
#: from valid (or either) values, "one" clean but for the pick numbered ``dirty_at``.
#: Set by :func:`_start` at the beginning of every case; without it, almost every
#: case would hold some invalid value and the accepted paths would go untested.
_MODE = {"mode": "dirty", "dirty_at": -1, "count": 0}


def _start(draw) -> None:
    _MODE.update(mode=draw(st.sampled_from(["dirty", "clean", "one"])),
                 dirty_at=draw(st.integers(0, 7)), count=0)


def _clean() -> bool:
    index = _MODE["count"]
    _MODE["count"] += 1
    return _MODE["mode"] == "clean" or (_MODE["mode"] == "one" and index != _MODE["dirty_at"])


def pick(pool):
    """A value from a pool of (text, validity): only valid ones in a clean pick."""
    if _clean():
        pool = [v for v in pool if v[1] != BAD] or pool
    return st.sampled_from(pool)


def optional(flag: str, pool):
    """``[flag, value]`` or nothing."""
    return st.one_of(st.just(([], OK)), pick(pool).map(lambda v: ([flag, v[0]], v[1])))


def combine(parts: list[tuple[list[str], str]]) -> tuple[list[str], str]:
    tokens = [t for p, _ in parts for t in p]
    labels = {label for _, label in parts}
    return tokens, BAD if BAD in labels else ANY if ANY in labels else OK


@st.composite
def noise(draw) -> tuple[list[str], str]:
    """Usually nothing; else an unknown flag, a stray word or a flag missing its value."""
    if _clean():
        return [], OK
    kind = draw(st.sampled_from(["none"] * 3 + ["flag", "word", "dangling"]))
    if kind == "flag":
        return draw(st.sampled_from(UNKNOWN_FLAGS)), BAD
    if kind == "word":
        return [draw(EXTRA_WORD)], BAD
    if kind == "dangling":
        return ["--seed"], BAD  # at the very end: "expected one argument"
    return [], OK


def _finish(draw, command: str, head: list, options: list) -> tuple[list[str], str]:
    quiet = draw(st.sampled_from([[], ["-q"]]))
    options = draw(st.permutations(options)) if options else []
    tail = draw(noise())
    argv, label = combine([(quiet + [command], OK), *head, *options, tail])
    return argv, label


# --------------------------------------------------------------------------- commands


@st.composite
def render_cases(draw):
    _start(draw)
    scene, scene_ok = draw(pick(sorted({**SCENES, **ODD_SCENES}.items())))
    sampler = draw(optional("--sampler", SAMPLERS))
    spp = draw(optional("--spp", SPP))
    defines = draw(st.lists(pick(DEFINES), max_size=2))
    adaptive = draw(st.booleans())
    extra = [draw(optional("--threshold", THRESHOLDS)), draw(optional("--confidence", CONFIDENCES)),
             draw(optional("--growth", GROWTHS))]
    out = draw(pick([([], OK), (["-o", "out/img"], OK), (["-o", "out/img.exr"], OK),
                     (["-o", "out/new/img"], OK), (["-o", ""], OK),
                     (["-o", "blocker/img"], BAD), (["-o", "out/dir.exr"], OK),
                     (["-o", "out/dir"], BAD), (["-o", "/"], ANY), (["-o", "."], OK),
                     (["-o", "out/.."], OK), (["-o", "out/new/"], OK), (["-o", LONG], BAD),
                     (["-o", f"out/{LONG}/img"], BAD)]))
    options = [sampler, spp, *[(["-D", d], v) for d, v in defines],
               draw(optional("--seed", SEEDS)), draw(optional("--effect", EFFECTS)), out]
    flags = [(["--adaptive"], OK)] if adaptive else []
    if _MODE["mode"] == "clean" and not adaptive:
        extra = []
    for tokens, label in extra:
        if tokens and not adaptive:
            label = BAD  # "--threshold: only with --adaptive"
        flags.append((tokens, label))
    if adaptive:
        given = spp[0][1] if spp[0] else None
        if given is not None and given.isdigit() and int(given) < 16:
            flags.append(([], BAD))  # max_spp (= --spp) below min_spp (16)
        if given is not None and len(given) > 10:
            flags.append(([], ANY))  # a huge budget is a valid budget for the adaptive renderer
        if sampler[0] and sampler[0][1] in BUILTIN_SAMPLERS:
            flags.append(([], ANY))  # Mitsuba's samplers cannot seed compacted wavefronts
    return _finish(draw, "render", [([scene], scene_ok)], options + flags)


@st.composite
def reference_cases(draw):
    _start(draw)
    scene = draw(pick(sorted(SCENES.items())))[0]
    sampler = draw(optional("--sampler", SAMPLERS))
    spp = draw(optional("--spp", [v for v in SPP if len(v[0]) < 10]
                        + [("99999999999999999999", ANY)]))
    options = [sampler, spp, draw(optional("--seed", SEEDS)),
               draw(optional("--spp-per-pass", [("16", OK), ("0", BAD), ("x", BAD)])),
               *[(["-D", d], v) for d, v in draw(st.lists(pick(DEFINES), max_size=2))],
               draw(pick([([], OK), (["-o", "out/ref.exr"], OK), (["-o", "out/ref"], OK),
                                     (["-o", "blocker/ref.exr"], BAD),
                                     (["-o", "out/dir.exr"], OK), (["-o", "out/refs/"], OK)])),
               draw(st.sampled_from([([], OK), (["--no-cache"], OK)]))]
    if sampler[0] and sampler[0][1] in set(BUILTIN_SAMPLERS) - {"independent"}:
        options.append(([], ANY))  # rounded sample counts: the pass plan may refuse some spp
    param = draw(st.one_of(st.just(None), st.sampled_from(PARAMS)))  # (the pattern's)
    if param is not None:  # valid for the one sampler it names
        used = sampler[0][1] if sampler[0] else "independent"
        options.append((["-P", param[0]], OK if param[1] == used else BAD))
    return _finish(draw, "reference", [([scene], SCENES[scene])], options)


#: Study configs (file name -> text) and whether `mcrt compare` accepts them.
STUDIES = {
    "jitter2.toml": GOOD_STUDY.replace('"jittered"', '{name = "jittered", params = {jitter = 2.0}}'),
    "jitter_nan.toml": GOOD_STUDY.replace('"jittered"',
                                          '{name = "jittered", params = {jitter = nan}}'),
    "unknown_sampler.toml": GOOD_STUDY.replace('"independent"', '"independant"'),
    "spp0.toml": GOOD_STUDY.replace("spp = [4, 16]", "spp = [0, 16]"),
    "spp_nan.toml": GOOD_STUDY.replace("spp = [4, 16]", "spp = [nan, 16]"),
    "seeds_negative.toml": GOOD_STUDY.replace("seeds = 2", "seeds = -2"),
    "malformed.toml": GOOD_STUDY.replace("[reference]", "[reference"),
    "wrong_type.toml": GOOD_STUDY.replace("seeds = 2", 'seeds = "two"'),
    "missing_scene.toml": GOOD_STUDY.replace("tiny.xml", "missing.xml"),
    "bad_scene.toml": GOOD_STUDY.replace("tiny.xml", "unknown_plugin.xml"),
    "empty.toml": "",
    "binary.toml": bytes(range(256)),
}
CONFIGS = {"study.toml": OK, "nowhere.toml": BAD, "folder.toml": BAD, LONG + ".toml": BAD,
           "": BAD,
           **{name: BAD for name in STUDIES}}


@st.composite
def compare_cases(draw):
    _start(draw)
    config = draw(pick(sorted(CONFIGS.items())))[0]
    check = draw(st.booleans())
    out = draw(pick([([], OK), (["-o", "out/report"], OK), (["-o", "blocker/report"], BAD),
                     (["-o", "out/img.exr"], BAD), (["-o", LONG], BAD)]))
    if check and out[1] == BAD:
        out = (out[0], OK)  # --check writes nothing, so -o is not looked at
    options = [out, draw(st.sampled_from([([], OK), (["--restart"], OK)]))]
    if check:
        options.append((["--check"], OK))
    return _finish(draw, "compare", [([config], CONFIGS[config])], options)


PARAMS = [("jitter=0.5", "jittered"), ("jitter=0", "jittered"), ("jitter=2", None),
          ("jitter=-1", None), ("jitter=nan", None), ("jitter=x", None), ("type=x", None),
          ("seed=3", None), ("noequals", None), ("1a=2", None), ("=1", None)]


@st.composite
def pattern_cases(draw):
    _start(draw)
    sampler_text, sampler_ok = draw(pick(SAMPLERS))
    spp = draw(optional("--spp", [("16", OK), ("4", OK), ("0", BAD), ("x", BAD),
                                  ("20000", BAD), ("99999999999999999999", BAD)]))
    pixels = draw(optional("--pixels", [("4", OK), ("0", BAD), ("x", BAD), ("70000", ANY)]))
    if pixels[0] and pixels[0][1] == "70000":  # Mitsuba's samplers: at most 2^16 pixels
        pixels = (pixels[0], BAD if sampler_text in BUILTIN_SAMPLERS else OK)
    params = PARAMS
    if _MODE["mode"] == "clean":
        params = [(text, needs) for text, needs in PARAMS if needs == sampler_text]
    param = draw(st.one_of(st.just(None), st.sampled_from(params))) if params else None
    options = [spp, pixels,
               draw(optional("--dimension", [("0", OK), ("3", OK), ("-1", BAD), ("x", BAD)])),
               draw(optional("--kmax", [("8", OK), ("5000", BAD), ("0", BAD)])),
               draw(optional("--seed", SEEDS)),
               draw(pick([([], OK), (["-o", "out/pattern"], OK),
                                     (["-o", "blocker/p"], BAD), (["-o", "out/img.exr"], BAD),
                           (["-o", LONG], BAD)]))]
    if param is not None:
        text, needs = param
        options.append((["--param", text], OK if needs == sampler_text else BAD))
    return _finish(draw, "pattern", [([sampler_text], sampler_ok)], options)


@st.composite
def integrate_cases(draw):
    _start(draw)
    integrand = draw(pick([("pi", OK), ("disk", OK), ("gaussian", OK), ("bogus", BAD),
                           ("", BAD)]))
    samplers = draw(optional("--sampler", [("independent", OK), ("jittered,poisson_disk", OK),
                                           ("nope", BAD), (",", BAD),
                                           ("jittered,jittered", BAD)]))
    min_n = draw(optional("--min-n", [("4", OK), ("256", OK), ("0", BAD), ("x", BAD)]))
    max_n = draw(optional("--max-n", [("64", OK), ("1024", OK), ("2000000", BAD), ("-4", BAD)]))
    low = int(min_n[0][1]) if min_n[0] and min_n[1] == OK else 16
    high = int(max_n[0][1]) if max_n[0] and max_n[1] == OK else 65536
    options = [samplers, min_n, max_n, ([], BAD if low > high else OK),
               draw(optional("--trials", [("16", OK), ("1", BAD), ("100000", BAD)])),
               draw(optional("--budget", [("4096", OK), ("0", BAD)])),
               draw(optional("--seed", SEEDS)),
               draw(pick([([], OK), (["-o", "out/integrate"], OK),
                                     (["-o", "blocker/i"], BAD), (["-o", LONG], BAD)]))]
    return _finish(draw, "integrate", [([integrand[0]], integrand[1])], options)


@st.composite
def plan_cases(draw):
    _start(draw)
    scene, scene_ok = draw(pick(sorted({**SCENES, **ODD_SCENES}.items())))
    options = [draw(optional("--sampler", SAMPLERS)), draw(optional("--spp", SPP)),
               draw(optional("--seed", SEEDS)), draw(optional("--effect", EFFECTS)),
               *[(["-D", d], v) for d, v in draw(st.lists(pick(DEFINES), max_size=2))],
               draw(st.sampled_from([([], OK), (["--json"], OK)]))]
    return _finish(draw, "plan", [([scene], scene_ok)], options)


@st.composite
def demo_cases(draw):
    _start(draw)
    options = [draw(pick([([], OK), (["-o", "out/demo"], OK),
                                     (["-o", "blocker/demo"], BAD), (["-o", LONG], BAD)])),
               draw(optional("--samplers", [("jittered", OK), ("jittered,independent", OK),
                                            ("nope", BAD), (",", BAD), ("", BAD)])),
               draw(pick([([], OK), (["--scenes", "nowhere"], BAD),
                                     (["--scenes", "out"], BAD)])),
               draw(optional("--reference-factor", [("2", OK), ("0", BAD), ("x", BAD)]))]
    return _finish(draw, "demo", [], options)


# --------------------------------------------------------------------------- the tests
# @example rows are the table of docs/bad-input.md; hypothesis adds its derandomized draws.


@settings(FUZZ, max_examples=400)
@given(case=render_cases())
@example(case=(["render", "tiny.xml", "-o", "out/img"], OK))
@example(case=(["render", "tiny.xml", "--sampler", "nope"], BAD))
@example(case=(["render", "tiny.xml", "--spp", "0"], BAD))
@example(case=(["render", "tiny.xml", "--spp", "-1"], BAD))
@example(case=(["render", "tiny.xml", "--spp", "1.5"], BAD))
@example(case=(["render", "tiny.xml", "--spp", "abc"], BAD))
@example(case=(["render", "tiny.xml", "--spp", "99999999999999999999"], BAD))
@example(case=(["render", "tiny.xml", "-D", "jitter=2"], BAD))
@example(case=(["render", "tiny.xml", "-D", "jitter=-1"], BAD))
@example(case=(["render", "tiny.xml", "-D", "jitter=nan"], BAD))
@example(case=(["render", "tiny.xml", "-D", "jitter=x"], BAD))
@example(case=(["render", "tiny.xml", "-D", "novalue"], BAD))
@example(case=(["render", "tiny.xml", "-D", "foo=1"], BAD))
@example(case=(["render", "tiny.xml", "--adaptive", "--threshold", "-1"], BAD))
@example(case=(["render", "tiny.xml", "--adaptive", "--threshold", "nan"], BAD))
@example(case=(["render", "tiny.xml", "--threshold", "0.05"], BAD))
@example(case=(["render", "tiny.xml", "--adaptive", "--threshold", "0.05"], OK))
@example(case=(["render", "tiny.xml", "--bogus"], BAD))
@example(case=(["render", "missing.xml"], BAD))
@example(case=(["render", "empty.xml"], BAD))
@example(case=(["render", "folder.xml"], BAD))
@example(case=(["render", "binary.xml"], BAD))
@example(case=(["render", "truncated.xml"], BAD))
@example(case=(["render", "unknown_plugin.xml"], BAD))
@example(case=(["render", "no_sensor.xml"], BAD))
@example(case=(["render", "tiny.xml", "-o", "blocker/img"], BAD))
@example(case=(["render", "tiny.xml", "-o", "out/dir.exr"], OK))  # a directory: written into
@example(case=(["render", "tiny.xml", "--effect", "aa=off"], BAD))
@example(case=(["render", "tiny.xml", "-o", "/"], ANY))  # writable for root only
@example(case=(["render", "tiny.xml", "-o", "."], OK))
@example(case=(["render", "tiny.xml", "-o", LONG], BAD))
@example(case=(["render", LONG + ".xml"], BAD))
def test_render(env, case):
    run_case(env, *case)


@settings(FUZZ, max_examples=200)
@given(case=reference_cases())
@example(case=(["reference", "tiny.xml", "-o", "out/ref.exr"], OK))
@example(case=(["reference", "tiny.xml", "--spp-per-pass", "0"], BAD))
@example(case=(["reference", "tiny.xml", "--sampler", "nope"], BAD))
@example(case=(["reference", "unknown_plugin.xml"], BAD))
@example(case=(["reference", "tiny.xml", "-o", "blocker/ref.exr"], BAD))
def test_reference(env, case):
    run_case(env, *case)


@settings(FUZZ, max_examples=200)
@given(case=compare_cases())
@example(case=(["compare", "study.toml", "-o", "out/report"], OK))
@example(case=(["compare", "study.toml", "--check"], OK))
@example(case=(["compare", "jitter2.toml", "--check"], BAD))
@example(case=(["compare", "jitter_nan.toml"], BAD))
@example(case=(["compare", "spp0.toml"], BAD))
@example(case=(["compare", "spp_nan.toml"], BAD))
@example(case=(["compare", "unknown_sampler.toml"], BAD))
@example(case=(["compare", "malformed.toml"], BAD))
@example(case=(["compare", "binary.toml"], BAD))
@example(case=(["compare", "folder.toml"], BAD))
@example(case=(["compare", "nowhere.toml"], BAD))
@example(case=(["compare", LONG + ".toml"], BAD))
@example(case=(["compare", "study.toml", "-o", "blocker/report"], BAD))
def test_compare(env, case):
    run_case(env, *case)


@settings(FUZZ, max_examples=200)
@given(case=pattern_cases())
@example(case=(["pattern", "jittered", "--param", "jitter=0.5", "-o", "out/pattern"], OK))
@example(case=(["pattern", "jittered", "--param", "jitter=2"], BAD))
@example(case=(["pattern", "jittered", "--param", "jitter=-1"], BAD))
@example(case=(["pattern", "jittered", "--param", "jitter=nan"], BAD))
@example(case=(["pattern", "jittered", "--param", "jitter=x"], BAD))
@example(case=(["pattern", "independent", "--param", "jitter=0.5"], BAD))
@example(case=(["pattern", "jittered", "--spp", "20000"], BAD))
@example(case=(["pattern", "nope"], BAD))
def test_pattern(env, case):
    run_case(env, *case)


@settings(FUZZ, max_examples=200)
@given(case=integrate_cases())
@example(case=(["integrate", "pi", "-o", "out/integrate"], OK))
@example(case=(["integrate", "bogus"], BAD))
@example(case=(["integrate", "pi", "--min-n", "256", "--max-n", "64"], BAD))
@example(case=(["integrate", "pi", "--trials", "1"], BAD))
def test_integrate(env, case):
    run_case(env, *case)


@settings(FUZZ, max_examples=200)
@given(case=plan_cases())
@example(case=(["plan", "tiny.xml", "--json"], OK))
@example(case=(["plan", "tiny.xml", "--effect", "dof=on"], BAD))
@example(case=(["plan", "tiny.xml", "--effect", "nosuch=on"], BAD))
@example(case=(["plan", "not_a_scene.xml"], BAD))
@example(case=(["plan", "missing_include.xml"], BAD))
def test_plan(env, case):
    run_case(env, *case)


@settings(FUZZ, max_examples=60)
@given(case=demo_cases())
@example(case=(["demo", "-o", "out/demo"], OK))
@example(case=(["demo", "--scenes", "nowhere"], BAD))
@example(case=(["demo", "--samplers", "nope"], BAD))
def test_demo(env, case):
    run_case(env, *case)


@pytest.mark.parametrize("argv, expected", [(["reference", "tiny.xml", "-o", "/"], ANY),
                                            (["reference", "tiny.xml", "-o", "."], OK),
                                            (["reference", LONG + ".xml"], BAD)],
                         ids=["slash", "dot", "long"])
def test_reference_odd_paths(env, argv, expected):
    run_case(env, argv, expected)


def test_no_subcommand_or_unknown_subcommand(env):
    run_case(env, [], BAD)
    run_case(env, ["bogus"], BAD)
    run_case(env, ["-q"], BAD)


def test_the_fuzzing_reached_both_outcomes_for_every_command():
    """Not vacuous: every command's cases above ended both in errors and in
    accepted arguments, in sensible proportions (runs after them: file order)."""
    commands = ("render", "reference", "compare", "pattern", "integrate", "plan", "demo")
    if not all(OUTCOMES[(c, "error")] + OUTCOMES[(c, "ok")] for c in commands):
        pytest.skip("run the whole file")
    for command in commands:
        errors, accepted = OUTCOMES[(command, "error")], OUTCOMES[(command, "ok")]
        assert min(errors, accepted) >= 0.15 * (errors + accepted), (command, errors, accepted)


if __name__ == "__main__":  # pragma: no cover
    sys.exit(pytest.main([__file__, "-q"]))
