"""Every benchmark script starts, and takes every option BENCHMARKS.md quotes for it.

Each ``benchmarks/*.py`` runs with ``--help`` in a subprocess, from a directory
outside the repository (a script must not depend on the working directory to
import), and must exit 0. The options of each command that
BENCHMARKS.md quotes - its code lines ``python benchmarks/X.py ...`` (continued
by a trailing backslash) and its inline code spans that name ``X.py`` with options
- and of the ``python benchmarks/X.py ...`` lines of the scripts' own docstrings
must all be in that script's help. Comments (``# ...``) are not options.
"""

from __future__ import annotations

import ast
import functools
import os
import re
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
BENCHMARKS = ROOT / "benchmarks"
SCRIPTS = sorted(p.stem for p in BENCHMARKS.glob("*.py") if not p.name.startswith("_"))

#: A script named as ``benchmarks/X.py`` or ``X.py`` (not ``some/other/X.py``).
SCRIPT_REF = re.compile(r"(?<![\w/.-])(benchmarks/)?([A-Za-z_]\w*)\.py\b")
OPTION = re.compile(r"(?<![\w-])--[A-Za-z][\w-]*")
SPAN = re.compile(r"`([^`]+)`")


def _options(text: str) -> list[str]:
    return OPTION.findall(text.split("#", 1)[0])


def quoted_commands(text: str, source: str) -> list[tuple[str, str, list[str]]]:
    """(where, script, options) of every benchmark command quoted in ``text``:
    lines that start with ``python benchmarks/`` (with the lines a trailing
    backslash continues them onto, or further indented lines of ``[--options]``),
    and inline code spans."""
    text = text.replace("``", "`")  # (reStructuredText's inline literals)
    found = []

    def take(segment: str, where: str, need_python: bool) -> None:
        refs = list(SCRIPT_REF.finditer(segment))
        for i, ref in enumerate(refs):
            name = ref.group(2)
            if need_python and not segment[:ref.start()].rstrip().endswith("python"):
                continue
            if name not in SCRIPTS and not ref.group(1):
                continue  # another file, e.g. ``plain.py``
            end = refs[i + 1].start() if i + 1 < len(refs) else len(segment)
            found.append((where, name, _options(segment[ref.end():end])))

    lines = text.splitlines()
    for i, line in enumerate(lines):
        if not line.strip().startswith("python benchmarks/"):
            continue
        command, j, indent = line.strip(), i, len(line) - len(line.lstrip())
        while j + 1 < len(lines):  # continued: after a backslash, or a usage's "[--more]"
            after = lines[j + 1]
            if not (command.endswith("\\") or (after.lstrip().startswith("[")
                                               and len(after) - len(after.lstrip()) > indent)):
                break
            j += 1
            command = command.removesuffix("\\") + " " + after.strip()
        take(command, f"{source}:{i + 1}", need_python=True)
    for span in SPAN.finditer(text):
        take(" ".join(span.group(1).split()), f"{source}:{text.count(chr(10), 0, span.start()) + 1}",
             need_python=False)
    return found


@functools.cache
def all_quoted() -> list[tuple[str, str, list[str]]]:
    """BENCHMARKS.md's commands, then those of the scripts' docstrings."""
    commands = quoted_commands((ROOT / "BENCHMARKS.md").read_text(encoding="utf-8"),
                               "BENCHMARKS.md")
    for name in SCRIPTS:
        path = BENCHMARKS / f"{name}.py"
        doc = ast.get_docstring(ast.parse(path.read_text(encoding="utf-8"))) or ""
        commands += quoted_commands(doc, f"benchmarks/{name}.py (docstring)")
    return commands


def test_benchmark_md_quotes_commands() -> None:
    """The parser finds BENCHMARKS.md's commands (a guard against matching nothing),
    and every script it names exists."""
    commands = quoted_commands((ROOT / "BENCHMARKS.md").read_text(encoding="utf-8"),
                               "BENCHMARKS.md")
    named = {name for _, name, _ in commands}
    assert len(named) >= 15, named
    assert not named - set(SCRIPTS), f"BENCHMARKS.md names missing scripts: {named - set(SCRIPTS)}"
    options = {(name, opt) for _, name, opts in commands for opt in opts}
    assert ("adaptive_efficiency", "--thresholds") in options  # (a continued line)
    assert ("replay_cost", "--baseline") in options  # (an inline span over two lines)


@pytest.mark.parametrize("name", SCRIPTS)
def test_help_lists_quoted_options(name: str, tmp_path: Path) -> None:
    """``--help`` from an empty directory (~0.4 s a script; one process each, so
    that pytest's workers share them out)."""
    env = {**os.environ, "MCRT_CACHE_DIR": str(tmp_path / "cache"), "MPLBACKEND": "Agg"}
    done = subprocess.run([sys.executable, str(BENCHMARKS / f"{name}.py"), "--help"],
                          cwd=tmp_path, env=env, capture_output=True, text=True, timeout=120)
    assert done.returncode == 0, f"{name}.py --help exit {done.returncode}:\n{done.stderr[-3000:]}"
    available = set(OPTION.findall(done.stdout))
    missing = [(where, opt) for where, script, opts in all_quoted() if script == name
               for opt in opts if opt not in available]
    assert not missing, f"{name}.py --help lacks options quoted for it: {missing}"
