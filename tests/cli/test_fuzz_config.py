"""Property-based tests of study configurations (``mcrt compare CONFIG --check``).

Hypothesis draws three kinds of TOML input:

* random documents: random keys (the real ones and others), random types and
  values (integers of any size, floats with NaN/Inf, strings, booleans,
  dates, nested arrays and tables);
* the valid study with one field replaced, deleted or set to a known bad value
  (spp 0 / NaN / one count, seeds 1 / -2 / duplicates / the warm-up seed,
  jitter 2 / -1 / NaN / "x", unknown samplers and plugins, reserved sampler
  parameters, missing / directory / binary / malformed / unknown-plugin scene
  files, scene names that would escape the report directory, ...);
* garbage: the valid document cut at a random byte, random bytes, random text.

Every case must give exit status 0 (``... OK``) or 2 with exactly one line
``mcrt: error: ...``, never a traceback, and leave every file as it was
(``--check`` writes nothing). Known-bad values must give 2, the valid study 0.
``derandomize=True``: the same examples on every run (~15 s for the file).
"""

from __future__ import annotations

import datetime
import json
import math
import re
from pathlib import Path

import pytest
from hypothesis import example, given, settings
from hypothesis import strategies as st

from mcrt.analysis.study import WARMUP_SEED, ConfigError, parse_config
from mcrt.cli import main
from tests.conftest import FUZZ, TINY_SCENE

OK, BAD, ANY = "valid", "invalid", "either"

TINY = TINY_SCENE

GOOD = {"spp": [4, 16], "seeds": 2, "samplers": ["jittered", "independent"],
        "reference": {"spp": 64}, "scenes": [{"path": "tiny.xml"}]}


# --------------------------------------------------------------------------- TOML writing


def toml_key(key: str) -> str:
    return key if re.fullmatch(r"[A-Za-z0-9_-]+", key) else toml_string(key)


def toml_string(text: str) -> str:
    # JSON escapes are TOML escapes, except that TOML also wants DEL escaped.
    return json.dumps(text, ensure_ascii=False).replace("\x7f", "\\u007f")


def toml_value(value) -> str:
    if isinstance(value, bool):
        return "true" if value else "false"
    if isinstance(value, int):
        return str(value)
    if isinstance(value, float):
        if math.isnan(value):
            return "nan"
        if math.isinf(value):
            return "inf" if value > 0 else "-inf"
        return repr(value)
    if isinstance(value, str):
        return toml_string(value)
    if isinstance(value, (datetime.datetime, datetime.date)):
        return value.isoformat()
    if isinstance(value, list):
        return "[" + ", ".join(toml_value(v) for v in value) + "]"
    if isinstance(value, dict):
        return "{" + ", ".join(f"{toml_key(k)} = {toml_value(v)}" for k, v in value.items()) + "}"
    raise TypeError(value)


def toml_document(data: dict) -> str:
    """One ``key = value`` line per top-level key (tables inline): valid TOML."""
    return "".join(f"{toml_key(k)} = {toml_value(v)}\n" for k, v in data.items())


def test_the_toml_writer_round_trips():
    import tomllib

    data = {"a b": [1, 2.5, float("inf"), "x\"\\\n\x7f\x01"], "t": {"k": True, "n": []},
            "d": datetime.date(2020, 1, 2)}
    assert tomllib.loads(toml_document(data)) == data


# --------------------------------------------------------------------------- strategies

KEYS = ["name", "description", "spp", "seeds", "image_spp", "aliasing_draws", "samplers",
        "reference", "scenes", "path", "params", "label", "sampler", "seed", "spp_per_pass",
        "jitter", "type", "sample_count"]
NAMES = ["tiny.xml", "jittered", "independent", "poisson_disk", "orthogonal", "nope", "",
         "missing.xml", "folder.xml", "binary.xml", "truncated.xml", "unknown_plugin.xml"]

SCALARS = st.one_of(
    st.integers(min_value=-2**63, max_value=2**63 - 1),
    st.integers(min_value=-3, max_value=70),
    st.floats(allow_nan=True, allow_infinity=True),
    st.text(max_size=10),
    st.sampled_from(NAMES),
    st.booleans(),
    st.dates(min_value=datetime.date(1, 1, 1)),
)
VALUES = st.recursive(
    SCALARS,
    lambda inner: st.one_of(st.lists(inner, max_size=4),
                            st.dictionaries(st.sampled_from(KEYS) | st.text(max_size=4), inner,
                                            max_size=4)),
    max_leaves=10)


def _set(data: dict, path: tuple, value) -> dict:
    """A deep copy of ``data`` with ``path`` set to ``value`` (``DELETE``: removed)."""
    data = json.loads(json.dumps(data))
    *parents, last = path
    node = data
    for key in parents:
        node = node[key]
    if value is DELETE:
        del node[last]
    else:
        node[last] = value
    return data


DELETE = object()
NAN = float("nan")

#: (path, value, validity): one field of the good study changed.
MUTATIONS = [
    (("spp",), [0, 16], BAD), (("spp",), [-1, 16], BAD), (("spp",), [16], BAD),
    (("spp",), [], BAD), (("spp",), "4", BAD), (("spp",), [4.0, 16], BAD),
    (("spp",), [NAN, 16], BAD), (("spp",), [4, 2**20], BAD), (("spp",), [4, True], BAD),
    (("spp",), [1, 2], OK), (("spp",), [16, 4, 4], OK),
    (("seeds",), 1, BAD), (("seeds",), 0, BAD), (("seeds",), -2, BAD), (("seeds",), [0, 0], BAD),
    (("seeds",), [1], BAD), (("seeds",), 1001, BAD), (("seeds",), "2", BAD), (("seeds",), 2.5, BAD),
    (("seeds",), [2**32, 0], BAD), (("seeds",), [WARMUP_SEED, 1], BAD), (("seeds",), [3, 5], OK),
    (("samplers",), [], BAD), (("samplers",), ["nope"], BAD), (("samplers",), [1], BAD),
    (("samplers",), "jittered", BAD), (("samplers",), ["jittered", "jittered"], BAD),
    (("samplers", 0), {"name": "jittered", "params": {"jitter": 2.0}}, BAD),
    (("samplers", 0), {"name": "jittered", "params": {"jitter": -1.0}}, BAD),
    (("samplers", 0), {"name": "jittered", "params": {"jitter": NAN}}, BAD),
    (("samplers", 0), {"name": "jittered", "params": {"jitter": "x"}}, BAD),
    (("samplers", 0), {"name": "jittered", "params": {"jitter": True}}, BAD),
    (("samplers", 0), {"name": "jittered", "params": {"jitter": [0.5]}}, BAD),
    (("samplers", 0), {"name": "jittered", "params": {"sample_count": 5}}, BAD),
    (("samplers", 0), {"name": "jittered", "params": {"type": "independent"}}, BAD),
    (("samplers", 0), {"name": "independent", "params": {"jitter": 0.5}}, BAD),
    (("samplers", 0), {"name": "jittered", "label": "a/b"}, BAD),
    (("samplers", 0), {"name": "jittered", "label": ""}, BAD),
    (("samplers", 0), {"params": {}}, BAD), (("samplers", 0), {"name": "jittered", "x": 1}, BAD),
    (("samplers", 0), {"name": "jittered", "label": "j.5", "params": {"jitter": 0.5}}, OK),
    (("reference",), {"spp": 32}, BAD), (("reference",), {}, BAD), (("reference",), 5, BAD),
    (("reference", "sampler"), "nope", BAD), (("reference", "spp_per_pass"), 0, BAD),
    (("reference", "seed"), -1, BAD), (("reference", "extra"), 1, BAD),
    (("reference", "spp"), NAN, BAD), (("reference", "spp"), 2**40, BAD),
    (("reference", "sampler"), "jittered", OK), (("reference", "spp_per_pass"), 16, OK),
    (("reference", "params"), {"jitter": 0.5}, BAD), (("reference", "params"), {"seed": 3}, BAD),
    (("reference", "params"), [1], BAD), (("reference", "params"), {"jitter": [1]}, BAD),
    (("reference",), {"spp": 64, "sampler": "stratified", "params": {"jitter": False}}, OK),
    (("scenes",), [], BAD), (("scenes",), {"path": "tiny.xml"}, BAD),
    (("scenes", 0, "path"), "missing.xml", BAD), (("scenes", 0, "path"), "folder.xml", BAD),
    (("scenes", 0, "path"), "binary.xml", BAD), (("scenes", 0, "path"), "truncated.xml", BAD),
    (("scenes", 0, "path"), "unknown_plugin.xml", BAD), (("scenes", 0, "path"), "", BAD),
    (("scenes", 0, "path"), "~nobody_mcrt_fuzz/tiny.xml", BAD),
    (("scenes", 0, "path"), "a\x00b.xml", BAD), (("scenes", 0, "path"), 3, BAD),
    (("scenes", 0, "path"), "a" * 300 + ".xml", BAD), (("scenes", 0, "name"), "a" * 300, BAD),
    (("scenes", 0, "name"), "a/b", BAD), (("scenes", 0, "name"), "..", BAD),
    (("scenes", 0, "name"), "x\ny", BAD),
    (("scenes", 0, "params"), {"nosuch": 1}, BAD), (("scenes", 0, "params"), {"jitter": 2}, BAD),
    (("scenes", 0, "params"), {"spp": [1]}, BAD), (("scenes", 0, "params"), "x", BAD),
    (("scenes", 0, "params"), {"jitter": 0.25}, OK),
    (("scenes",), [{"path": "tiny.xml"}, {"path": "tiny.xml"}], BAD),
    (("scenes",), [{"path": "tiny.xml"}, {"path": "tiny.xml", "name": "again"}], OK),
    (("image_spp",), 8, BAD), (("image_spp",), 0, BAD), (("image_spp",), 16, OK),
    (("aliasing_draws",), 1, BAD), (("aliasing_draws",), "x", BAD), (("aliasing_draws",), 2, OK),
    (("name",), "", BAD), (("name",), "a/b", BAD), (("name",), 3, BAD), (("name",), "ok", OK),
    (("description",), 5, BAD), (("description",), "text", OK),
    (("sampler",), 1, BAD), (("spp",), DELETE, BAD), (("seeds",), DELETE, BAD),
    (("samplers",), DELETE, BAD), (("reference",), DELETE, BAD), (("scenes",), DELETE, BAD),
]


@st.composite
def mutated(draw) -> tuple[str, str]:
    path, value, label = draw(st.sampled_from(MUTATIONS))
    data = _set(GOOD, path, value)
    if draw(st.integers(0, 3)) == 0:  # and one more field replaced by a random value
        key = draw(st.sampled_from(sorted(data)))
        data[key] = draw(VALUES)
        label = ANY
    return toml_document(data), label


@st.composite
def garbage(draw) -> tuple[bytes, str]:
    text = toml_document(GOOD).encode()
    kind = draw(st.sampled_from(["cut", "bytes", "text", "line"]))
    if kind == "cut":
        return text[:draw(st.integers(0, len(text)))], ANY
    if kind == "bytes":
        return draw(st.binary(max_size=200)), ANY
    if kind == "text":
        return draw(st.text(max_size=200)).encode("utf-8", "surrogatepass"), ANY
    lines = text.split(b"\n")
    at = draw(st.integers(0, len(lines)))
    lines.insert(at, draw(st.text(max_size=40)).encode("utf-8", "surrogatepass"))
    return b"\n".join(lines), ANY


random_documents = st.dictionaries(st.sampled_from(KEYS) | st.text(max_size=6), VALUES,
                                   max_size=8).map(lambda d: (toml_document(d), ANY))


# --------------------------------------------------------------------------- checks


@pytest.fixture(scope="module")
def world(tmp_path_factory):
    root = tmp_path_factory.mktemp("fuzz_config")
    (root / "tiny.xml").write_text(TINY)
    (root / "folder.xml").mkdir()
    (root / "binary.xml").write_bytes(bytes(range(256)) * 4)
    (root / "truncated.xml").write_text(TINY[:300])
    (root / "unknown_plugin.xml").write_text(TINY.replace('"diffuse"', '"nosuchbsdf"'))
    (root / "out").mkdir()
    (root / "out" / "report.html").write_text("previous report\n")
    return root


@pytest.fixture
def env(world, monkeypatch, capfd):
    monkeypatch.chdir(world)
    monkeypatch.setenv("MCRT_CACHE_DIR", str(world.parent / (world.name + "_cache")))
    return world, capfd


def _snapshot(root: Path) -> dict[str, bytes]:
    return {str(p.relative_to(root)): p.read_bytes() for p in root.rglob("*")
            if p.is_file() and p.name != "fuzz.toml"}


def check_config(env, document: str | bytes, expected: str) -> None:
    root, capfd = env
    config = root / "fuzz.toml"
    config.write_bytes(document.encode() if isinstance(document, str) else document)
    before = _snapshot(root)
    capfd.readouterr()
    code = main(["compare", "fuzz.toml", "--check", "-o", "out"])
    out, err = capfd.readouterr()
    where = f"expected {expected}, got {code}\n--- fuzz.toml:\n{document!r}\n--- stderr:\n{err}"
    assert "Traceback" not in out + err, where
    assert _snapshot(root) == before, where
    if code == 0:
        assert expected != BAD and "OK" in out, where
    else:
        assert code == 2 and expected != OK, where
        lines = [line for line in err.splitlines() if line.strip()]
        errors = [line for line in lines if line.startswith("mcrt: error: ")]
        assert len(errors) == 1, where
        assert all(line.startswith("mcrt: note: ") for line in lines if line not in errors), where


@pytest.mark.slow
@settings(FUZZ, max_examples=300)
@given(case=mutated())
@example(case=(toml_document(GOOD), OK))
def test_one_field_wrong(env, case):
    check_config(env, *case)


@pytest.mark.slow
@settings(FUZZ, max_examples=200)
@given(case=random_documents)
def test_random_documents(env, case):
    check_config(env, *case)


@settings(FUZZ, max_examples=200)
@given(case=garbage())
@example(case=(b"", BAD))
@example(case=(b"\xff\xfe\x00garbage", BAD))
@example(case=(b"spp = [4, 16\n", BAD))
def test_garbage(env, case):
    check_config(env, *case)


@pytest.mark.slow
@settings(FUZZ, max_examples=300)
@given(data=st.dictionaries(st.sampled_from(KEYS), VALUES, max_size=9))
def test_parse_config_raises_only_config_errors(data):
    """The structure checks alone (no scene loading), on many more documents."""
    try:
        parse_config(data, base_dir=Path("/nonexistent"))
    except ConfigError as error:
        assert "\n" not in str(error)
