"""A scene's files: its content digest, and a bundle that travels to other machines.

A Mitsuba scene is an XML file plus what it includes (``<include
filename=...>``) and the files it names (``<string name="filename" .../>``:
meshes, textures, spectra, volumes; ``<spectrum filename=.../>``), resolved as
Mitsuba resolves them (an include relative to the file including it, any other
file in the folders of ``<path>`` elements and then the main scene's folder)
with the scene's ``$params`` and ``<default>`` values substituted. :func:`walk_scene`
lists them once; :func:`scene_digest` (the identity of a scene's content in
every cache key) and :func:`bundle_scene` (the files a worker without a shared
file system needs) are both built on that walk.

A :class:`SceneBundle` holds the files relative to their common folder, so the
scene's relative references (``../textures/...`` too) resolve the same way
where :func:`materialize` writes them. Absolute references stay absolute: such
files must exist at that path on every worker.
"""

from __future__ import annotations

import hashlib
import os
import re
import xml.etree.ElementTree as ET
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from .atomic import atomic_path

_VAR = re.compile(r"\$(\w+)")


def _substitute(text: str, values: dict[str, str]) -> str:
    for _ in range(8):  # defaults may refer to other parameters ($width = $res)
        new = _VAR.sub(lambda m: values.get(m.group(1), m.group(0)), text)
        if new == text:
            break
        text = new
    return text


@dataclass(frozen=True)
class SceneFile:
    """One step of :func:`walk_scene`: an XML file read (``data`` set), or a
    reference ``name`` found in one, resolved to ``target``."""

    path: Path                 # the XML file (data) or the referenced file (ref)
    data: bytes | None = None  # an XML file's bytes
    name: str | None = None    # a reference as written (after substitution)
    exists: bool = True
    xml: bool = False          # a reference walked as XML (an include or a .xml file)
    #: a reference found only in the working directory (Mitsuba's last resort)
    in_cwd: bool = False


def _resolve(name: str, folder: Path, search: list[Path]) -> tuple[Path, bool]:
    """Where Mitsuba finds ``name``: the folders of ``<path value=...>`` elements, the
    last one first (each is prepended to its file resolver), then ``folder``, then
    the working directory (where its file resolver looks last); and whether it was
    found there only."""
    if os.path.isabs(name):
        return Path(name), False
    for base in (*reversed(search), folder):
        if (base / name).is_file():
            return base / name, False
    if (Path.cwd() / name).is_file():
        return Path.cwd() / name, True
    return folder / name, False


def walk_scene(path: str | Path, params: dict[str, str] | None = None,
               seen: set[Path] | None = None, search: list[Path] | None = None,
               top: Path | None = None, values: dict[str, str] | None = None
               ) -> Iterator[SceneFile]:
    """The scene's XML files (with their bytes) and, in document order, every
    reference in them; included XML files are walked in place, once each.

    Resolved as Mitsuba 3.9 does: an include relative to the file that includes
    it, any other file (a mesh, a texture, a spectrum's ``<spectrum
    filename=...>``) relative to the main scene's folder ``top``, even when an
    included file names it; ``<path value=...>`` elements add folders to look in
    before that one. ``$params`` are Mitsuba's one list for the whole parse:
    ``params`` first, then each ``<default>`` in document order where its name is
    not set yet, included files' too (an included file sees the defaults of the
    file including it, and the rest of that file sees the included file's)."""
    seen = set() if seen is None else seen
    search = [] if search is None else search
    values = dict(params or {}) if values is None else values
    path = Path(path).resolve()
    top = path.parent if top is None else top
    if path in seen:
        return
    seen.add(path)
    data = path.read_bytes()
    yield SceneFile(path, data=data)
    try:
        root = ET.fromstring(data)
    except ET.ParseError:
        return  # Mitsuba will report it; the bytes are in the walk anyway
    for el in root.iter():
        if el.tag == "default":
            values.setdefault(el.get("name", ""), el.get("value", ""))
            continue
        if el.tag == "path" and el.get("value"):
            search.append(path.parent / _substitute(el.get("value", ""), values))
            continue
        if el.tag in ("include", "spectrum"):
            name = el.get("filename")
        elif el.get("name") == "filename":
            name = el.get("value")
        else:
            continue
        if not name:
            continue
        name = _substitute(name, values)
        target, in_cwd = _resolve(name, path.parent if el.tag == "include" else top, search)
        exists = target.is_file()
        xml = exists and (el.tag == "include" or target.suffix.lower() == ".xml")
        yield SceneFile(target.resolve() if exists else target, name=name, exists=exists,
                        xml=xml, in_cwd=in_cwd)
        if xml:
            yield from walk_scene(target, params, seen, search, top, values)


def scene_digest(scene_path: str | Path, params: dict[str, str] | None = None) -> str:
    """SHA-256 of a scene's content: the XML, the XML files it includes and the
    files it names, as :func:`walk_scene` finds them."""
    digest = hashlib.sha256()
    for item in walk_scene(scene_path, params):
        if item.data is not None:
            digest.update(b"file\0%d\0" % len(item.data) + item.data)
            continue
        assert item.name is not None
        digest.update(b"ref\0" + item.name.encode() + b"\0")
        if not item.exists:
            digest.update(b"missing\0")
        elif not item.xml:
            digest.update(hashlib.sha256(item.path.read_bytes()).digest())
    return digest.hexdigest()


def working_directory_files(scene_path: str | Path, params: dict[str, str] | None = None
                            ) -> set[str]:
    """The references (as written, after substitution) that the scene finds only in
    the working directory, e.g. ``-D mesh=my.obj`` naming a file there: a command
    that renders the scene again from elsewhere must name them by absolute path."""
    try:
        return {item.name for item in walk_scene(scene_path, params)
                if item.in_cwd and item.name is not None}
    except (OSError, ValueError):  # a scene gone or unreadable: its load reports it
        return set()


@dataclass(frozen=True)
class SceneBundle:
    """A scene's files, to render it where they are not: ``files`` maps paths
    relative to their common folder to bytes; ``scene`` is the main XML's."""

    digest: str
    scene: str
    files: tuple[tuple[str, bytes], ...]

    @property
    def size(self) -> int:
        return sum(len(data) for _, data in self.files)


def bundle_scene(scene_path: str | Path, params: dict[str, str] | None = None) -> SceneBundle:
    """Every file of the scene (as :func:`walk_scene` finds them) with its bytes."""
    main = Path(scene_path).resolve()
    paths = [main]
    for item in walk_scene(main, params):
        if item.data is None and item.exists and item.name is not None and not item.in_cwd \
                and not os.path.isabs(item.name) and item.path not in paths:
            paths.append(item.path)
    root = Path(os.path.commonpath([str(p.parent) for p in paths]))
    files = tuple((str(p.relative_to(root)), p.read_bytes()) for p in paths)
    return SceneBundle(scene_digest(main, params), str(main.relative_to(root)), files)


def materialize(bundle: SceneBundle, base: str | Path | None = None) -> Path:
    """Write the bundle's files (once per digest) under ``base`` (default: the
    system's temporary folder) and return the path of its scene file."""
    import tempfile  # here: a render that never ships its scene does not import it

    folder = Path(base or tempfile.gettempdir()) / "mcrt-scenes" / bundle.digest
    for name, data in bundle.files:
        target = folder / name
        if target.is_file() and target.stat().st_size == len(data):
            continue
        target.parent.mkdir(parents=True, exist_ok=True)
        with atomic_path(target, fsync=False) as tmp:
            Path(tmp).write_bytes(data)
    return folder / bundle.scene


def describe(bundle: Any) -> str:
    """A short name for logs: the scene file and its size."""
    return f"{bundle.scene} ({bundle.size / 2**20:.1f} MiB)"


@dataclass(frozen=True)
class SceneSource:
    """A scene on this machine, as a job's shared input: in-process tasks read it
    from ``path``; a cluster executor sends :meth:`bundle` to each worker once."""

    path: str
    params: tuple[tuple[str, str], ...] = ()  # the $params its file names may use
    digest: str = ""                          # scene_digest(path, params)

    @classmethod
    def of(cls, path: str | Path, params: dict[str, str] | None = None) -> SceneSource:
        params = dict(params or {})
        return cls(str(path), tuple(sorted(params.items())), scene_digest(path, params))

    def bundle(self) -> SceneBundle:
        return bundle_scene(self.path, dict(self.params))


def local_scene(scene: SceneSource | SceneBundle) -> tuple[Path, str]:
    """Where a task finds its scene, and the scene's digest: a source's own
    path, or the bundle written to this machine's temporary folder (once)."""
    if isinstance(scene, SceneBundle):
        return materialize(scene), scene.digest
    return Path(scene.path), scene.digest
