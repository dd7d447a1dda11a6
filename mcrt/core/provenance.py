"""What every EXR file mcrt writes says about how it was made.

Each writer (``mcrt render``, ``mcrt reference``, a study's report) puts these
keys in its file's header, beside its own settings:

================  ============================================================
``mcrt_kind``     what wrote it: ``render``, ``render_adaptive``, ``reference``,
                  ``study_mean``, ``study_seed`` or ``study_reference``
``command``       an ``mcrt`` command line that renders the same pixels (the
                  scene and plugin files by absolute path, no ``-o``); for a
                  ``study_mean`` file the command of one seed's render without
                  ``--seed``, run once for each seed of ``seeds``
``scene_digest``  SHA-256 of the scene's content (its XML, the files it
                  includes and names: :func:`~mcrt.core.scene_files.scene_digest`)
``variant``       Mitsuba's variant
``*_version``     ``mcrt_version``, ``mitsuba_version``, ``drjit_version``
``mcrt_source``   SHA-256 (16 hex digits) of mcrt's own source files: the
                  version number stays while the code changes between releases
================  ============================================================

``mcrt render --from FILE.exr`` runs a file's ``command`` again and says
whether the pixels came out the same (:mod:`mcrt.cli.reproduce`), and first
notes a file written by other software (:func:`software_changes`).

The other formats carry the ``command`` where each has room for it: a PNG's text
chunks (:func:`png_text`), a JSON file's key, a CSV's last columns on every row
(:data:`CSV_COLUMNS`), an HTML report's note (:func:`html_note`). ``mcrt compare
--from`` runs a study again from its results.csv or results.json
(:mod:`mcrt.cli.reproduce_study`).
"""

from __future__ import annotations

import functools
import hashlib
import shlex
from collections.abc import Iterable
from pathlib import Path
from typing import Any

from ..errors import McrtError

#: The header key of the command line that reproduces a file's pixels.
COMMAND = "command"


def software() -> dict[str, str]:
    """The variant and the versions of mcrt, Mitsuba and Dr.Jit in this process."""
    import drjit as dr
    import mitsuba as mi

    from .._version import __version__

    return {"variant": str(mi.variant() or ""), "mcrt_version": __version__,
            "mcrt_source": source_digest(), "mitsuba_version": str(mi.__version__),
            "drjit_version": str(dr.__version__)}  # type: ignore[attr-defined]


@functools.cache
def source_digest() -> str:
    """SHA-256 (first 16 hex digits) of mcrt's Python files and the data files
    beside them (the report viewer's scripts), by path within the package and
    content: two processes give the same digest exactly when they run the same
    mcrt code, whatever its version number says."""
    package = Path(__file__).resolve().parents[1]
    digest = hashlib.sha256()
    for path in sorted(p for p in package.rglob("*")
                       if p.is_file() and p.suffix in (".py", ".js", ".css", ".html")):
        digest.update(path.relative_to(package).as_posix().encode() + b"\0")
        digest.update(path.read_bytes() + b"\0")
    return digest.hexdigest()[:16]


#: The header keys that name the software a file was made with (see :func:`software`).
SOFTWARE_KEYS = ("mcrt_source", "mitsuba_version", "drjit_version")


def software_text() -> str:
    """The software of this process in one line: ``mcrt 0.1.0 (source 1a2b...),
    Mitsuba 3.9.1 (llvm_ad_rgb), Dr.Jit 1.5.0`` (a PNG's ``Software``, a CSV's
    ``software`` column, an HTML report's note)."""
    now = software()
    return (f"mcrt {now['mcrt_version']} (source {now['mcrt_source']}), "
            f"Mitsuba {now['mitsuba_version']} ({now['variant']}), "
            f"Dr.Jit {now['drjit_version']}")


def png_text(record: dict[str, Any]) -> dict[str, str]:
    """The text chunks of a PNG mcrt writes: ``command`` (``record``'s, if it has
    one: what makes the file again) and ``Software`` (:func:`software_text`), so a
    picture pasted elsewhere still says how it was made
    (``PIL.Image.open(path).text``)."""
    text = {"Software": software_text()}
    if record.get(COMMAND):
        text[COMMAND] = str(record[COMMAND])
    return text


#: The last columns of every CSV mcrt writes, the same on every row: a CSV has no
#: header for them, and a column stays with the numbers wherever they are copied
#: (``csv.DictReader`` and pandas read it like any other).
CSV_COLUMNS = (COMMAND, "software")


def csv_values(record: dict[str, Any]) -> dict[str, str]:
    """The values of :data:`CSV_COLUMNS`: ``record``'s command ("" without one)
    and :func:`software_text`."""
    return {COMMAND: str(record.get(COMMAND) or ""), "software": software_text()}


def html_note(record: dict[str, Any]) -> str:
    """The paragraph of an HTML report that says how it was made: ``record``'s
    command (in ``<code>``, the paragraph's id ``command``) and the software."""
    import html

    made = (f"Made by <code>{html.escape(str(record[COMMAND]))}</code> with "
            if record.get(COMMAND) else "Made with ")
    return f"<p class='note' id='{COMMAND}'>{made}{html.escape(software_text())}.</p>"


def software_changes(header: dict[str, Any]) -> list[str]:
    """What differs between the software that wrote ``header`` and this process's,
    e.g. ``["mcrt_source 1a2b... (now 3c4d...)"]``; a key the file lacks (written
    before it was recorded) is not a difference."""
    now = software()
    return [f"{key} {header[key]} (now {now[key]})" for key in SOFTWARE_KEYS
            if header.get(key) and str(header[key]) != now[key]]


def scene_facts(scene: str | Path, params: dict[str, str]) -> dict[str, str]:
    """``scene_digest`` of a scene with its parameters (``scene_problem`` instead
    when its files cannot be read: the output is written all the same)."""
    from .scene_files import scene_digest

    try:
        return {"scene_digest": scene_digest(scene, params)}
    except Exception as error:  # a scene gone or unreadable: say so, keep going
        return {"scene_problem": f"no digest: {' '.join(str(error).split())}"}


def command_text(command: str, *words: Any, plugins: Iterable[str | Path] = (),
                 variant: str = "") -> str:
    """``mcrt --variant V [--plugin P]... COMMAND WORDS...`` as one shell-quoted
    line (plugin files by absolute path, so that it runs from any directory;
    ``variant`` default: this process's)."""
    import mitsuba as mi

    prefix = ["mcrt", "--variant", variant or str(mi.variant() or "llvm_ad_rgb")]
    files = dict.fromkeys(absolute(p) for p in plugins)
    prefix += [w for p in files for w in ("--plugin", p)]
    return shlex.join([*prefix, command, *(str(w) for w in words)])


def plugin_files(*samplers: str) -> list[str]:
    """The plugin files that registered the user's samplers among ``samplers``
    (what a command line needs to load them again)."""
    from ..samplers import registry

    files = []
    for name in samplers:
        origin = registry.info(name).origin if name in registry.names() else ""
        if origin.endswith(".py") and Path(origin).is_file():
            files.append(origin)
    return files


def absolute(path: str | Path) -> str:
    """A scene path as a recorded command names it: absolute."""
    return str(Path(path).expanduser().resolve())


#: Sampler parameters that name a file (the ``pointset`` sampler's point sets,
#: read relative to the working directory).
FILE_PARAMS = ("filename",)


def param_word(item: str) -> str:
    """A ``-P key=value`` item as a recorded command gives it: a parameter that
    names a file (:data:`FILE_PARAMS`) by absolute path, so that the command
    runs from any directory; any other item as it is."""
    key, sep, value = item.partition("=")
    if sep and key.strip() in FILE_PARAMS and value.strip():
        return f"{key.strip()}={absolute(value.strip())}"
    return item


def define_word(item: str, local: Iterable[str]) -> str:
    """A ``-D key=value`` item as a recorded command gives it: a value among
    ``local``, files the scene finds only in the working directory
    (:func:`~mcrt.core.scene_files.working_directory_files`), by absolute path, so
    that the command renders the same scene from any directory; any other item
    as it is."""
    key, sep, value = item.partition("=")
    return f"{key}={absolute(value)}" if sep and value in set(local) else item


def define_words(scene: str | Path, params: dict[str, str]) -> list[str]:
    """``-D key=value`` for each of a scene's ``params``, as :func:`define_word`
    gives them."""
    return [w for k, v in located(scene, params).items() for w in ("-D", f"{k}={v}")]


def located(scene: str | Path, params: dict[str, str]) -> dict[str, str]:
    """A scene's ``params`` with each value that names a file the scene finds only
    in the working directory by absolute path (:func:`define_word`): what a render
    loads, keys and records (its scene digest too), so that its command, run from
    another directory, renders and digests the same scene."""
    from .scene_files import working_directory_files

    local = working_directory_files(scene, params)
    return {k: absolute(v) if v in local else v for k, v in params.items()}


def command_words(header: dict[str, Any], path: str | Path,
                  purpose: str = "render it again") -> list[str]:
    """The words of a header's ``command`` after ``mcrt`` (an error naming the
    file if it has none: not written by mcrt, or by a version before commands
    were recorded; ``purpose`` says what the command was wanted for, as fits
    the file: an image's renders it again, a study's results run the study)."""
    text = header.get(COMMAND)
    if not isinstance(text, str) or not text.strip():
        raise McrtError(f"{path} records no command to {purpose} (not written by mcrt, or "
                        f"by an older version of it)")
    words = shlex.split(text)
    if not words or words[0] != "mcrt":
        raise McrtError(f"{path}: its command {text!r} is not an mcrt command")
    return words[1:]


__all__ = ["COMMAND", "CSV_COLUMNS", "FILE_PARAMS", "absolute", "command_text", "command_words",
           "csv_values", "define_word", "define_words", "html_note", "located", "param_word",
           "plugin_files", "png_text", "scene_facts", "software", "software_text"]
