"""What a scene's files are (:mod:`mcrt.core.scene_files`): the walk behind its
content digest (every cache key) and its bundle (what a cluster worker without the
client's files renders), checked against what Mitsuba 3.9 loads. The bundle tests
that need worker processes are in test_cluster.py and test_cluster_files.py."""

from __future__ import annotations

import mitsuba as mi
import pytest

from mcrt.core.scene_files import bundle_scene, materialize, scene_digest


def _loads_without_the_originals(bundle, tmp_path, monkeypatch, original):
    """The bundle written where a worker writes it, the scene's own folder moved
    away and the working directory elsewhere (Mitsuba's last resort): its scene."""
    copy = materialize(bundle, tmp_path / "worker")
    original.rename(tmp_path / "gone")
    monkeypatch.chdir(tmp_path / "worker")
    return mi.load_file(str(copy))


def test_a_spectrum_file_travels_and_keys_the_scene(tmp_path, monkeypatch):
    """``<spectrum name=... filename="..."/>`` (a tabulated spectrum, an attribute
    rather than a ``filename`` property) is a file of the scene: in its bundle and
    its content digest. The walk missed it, so a changed file kept a cached
    reference and a worker without the scene's folder could not load it."""
    folder = tmp_path / "scene"
    (folder / "spd").mkdir(parents=True)
    (folder / "spd" / "red.spd").write_text("400 0.1\n700 0.9\n")
    xml = folder / "s.xml"
    xml.write_text('<scene version="3.0.0"><shape type="sphere"><bsdf type="diffuse">'
                   '<spectrum name="reflectance" filename="spd/red.spd"/></bsdf></shape>'
                   '</scene>')
    bundle = bundle_scene(xml)
    assert sorted(name for name, _ in bundle.files) == ["s.xml", "spd/red.spd"]
    (folder / "spd" / "red.spd").write_text("400 0.9\n700 0.1\n")
    assert scene_digest(xml) != bundle.digest  # another spectrum is another scene
    scene = _loads_without_the_originals(bundle, tmp_path, monkeypatch, folder)
    assert len(scene.shapes()) == 1


def test_an_included_file_sees_the_defaults_of_the_file_including_it(tmp_path, monkeypatch):
    """Mitsuba keeps one parameter list for the whole parse: a ``<default>`` of the
    main scene names the mesh an included file loads (``$mesh``), and the first
    ``<default>`` of a name wins. The walk substituted each file's own defaults
    only, so the mesh was neither in the bundle nor in the digest."""
    folder = tmp_path / "scene"
    (folder / "parts").mkdir(parents=True)
    (folder / "tri.obj").write_text("v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 3\n")
    (folder / "big.obj").write_text("v 0 0 0\nv 9 0 0\nv 0 9 0\nf 1 2 3\n")
    (folder / "parts" / "geo.xml").write_text(
        '<scene version="3.0.0"><default name="mesh" value="big.obj"/>'
        '<shape type="obj"><string name="filename" value="$mesh"/></shape></scene>')
    xml = folder / "s.xml"
    xml.write_text('<scene version="3.0.0"><default name="mesh" value="tri.obj"/>'
                   '<include filename="parts/geo.xml"/></scene>')
    bundle = bundle_scene(xml)
    assert sorted(name for name, _ in bundle.files) == ["parts/geo.xml", "s.xml", "tri.obj"]
    assert [name for name, _ in bundle_scene(xml, {"mesh": "big.obj"}).files][-1] == "big.obj"
    before = scene_digest(xml)
    (folder / "tri.obj").write_text("v 0 0 0\nv 2 0 0\nv 0 1 0\nf 1 2 3\n")
    assert scene_digest(xml) != before
    (folder / "tri.obj").write_text("v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 3\n")
    scene = _loads_without_the_originals(bundle, tmp_path, monkeypatch, folder)
    assert float(scene.shapes()[0].surface_area()[0]) == pytest.approx(0.5)  # tri.obj
