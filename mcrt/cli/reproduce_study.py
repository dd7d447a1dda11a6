"""``mcrt compare --from results.csv`` (or ``results.json``): run a study again
from what its results record, and say whether every cell's numbers came out the
same.

A study writes its command into both of these files (:data:`CARRIERS`):
``results.csv`` on every row, beside the ``software`` that ran it
(:data:`mcrt.core.provenance.CSV_COLUMNS`), and ``results.json`` once, beside the
``environment`` (the software's versions). The command names the configuration
and plugin files by absolute path, with no ``-o``. ``--from`` runs it into
``-o DIR`` (default: the study's folder with ``_again`` added, beside it) and
compares the new file of the same kind with the old one, cell by cell, on the
fields a run repeats (:data:`~mcrt.analysis.study.fields.REPEATED_COLUMNS`: all but
the times and the provenance), as written (a CSV's text, a JSON value's text: a
float's repr, bit for bit). Exit status 0 when every cell is the same, 1 when
one differs (the note says which, and in what), 2 when the file cannot be run
again.
"""

from __future__ import annotations

import argparse
import csv
import json
import logging
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from ..core.provenance import COMMAND, command_words, software_changes, software_text
from ..errors import McrtError

log = logging.getLogger("mcrt.compare")

#: The files of a study that ``--from`` runs it again from, by suffix.
CARRIERS = {".csv": "results.csv", ".json": "results.json"}

#: How ``--from``'s help and errors name them.
CARRIERS_TEXT = "|".join(CARRIERS.values())

#: The options that set what a study measures, by ``argparse`` destination.
_SETTINGS = {"config": "CONFIG.toml", "check": "--check", "restart": "--restart",
             "retime": "--retime"}

#: The fields that name a cell.
_CELL = ("scene", "sampler", "spp_requested")

#: At most this many differing cells are named.
_NAMED = 5


@dataclass
class _Study:
    """What a study's file says: its command, whether it is partial, how its
    software differs from this process's ("" when it does not, or is not
    recorded), and its cells by name (None: the file holds none)."""

    command: str
    partial: bool
    other_software: str
    cells: dict[tuple[str, ...], dict[str, Any]] | None


def run_from(args: argparse.Namespace) -> int:
    from . import command_of
    from .reproduce import _mcrt

    source = Path(args.from_file)
    given = [flag for dest, flag in _SETTINGS.items() if getattr(args, dest, None)]
    if given:
        raise McrtError(f"--from {source} takes every setting from the file; drop "
                        f"{', '.join(given)} (only -o, -q and --cluster go with it)")
    kind = _kind(source)
    study = _read(source, kind)
    text = study.command
    words = command_words({COMMAND: text}, source, purpose="run its study again")
    if command_of(words) != "compare":
        raise McrtError(f"{source}: its command {text!r} does not run a study (mcrt compare)")
    if study.partial:
        raise McrtError(f"{source} is a partial study (interrupted): its own command finishes "
                        f"it: {text} -o {source.resolve().parent}")
    if study.cells is None:
        raise McrtError(f"{source} holds no cells: it is not a study's {CARRIERS[kind]}")
    folder = source.resolve().parent
    out = Path(args.output) if args.output else folder.with_name(f"{folder.name}_again")
    if out.resolve() == folder:
        raise McrtError(f"-o {args.output}: that is {source}'s own study; write elsewhere")
    if study.other_software:
        log.warning("%s was written by other software: %s; the numbers may differ for that "
                    "reason", source, study.other_software)
    extra = ["--cluster", args.cluster] if getattr(args, "cluster", None) else []
    log.info("running again: %s", text)
    code = _mcrt([*words, *extra, "-o", str(out)], args.quiet)
    if code:
        return code
    return _compare(out / CARRIERS[kind], kind, source, study)


def _kind(path: Path) -> str:
    """The suffix of :data:`CARRIERS` that ``path`` has (a one-line error if none)."""
    kind = path.suffix.lower()
    if kind not in CARRIERS:
        raise McrtError(f"--from {path}: give a study's {' or '.join(CARRIERS.values())} "
                        f"(a file ending in {' or '.join(CARRIERS)})")
    return kind


def _read(path: Path, kind: str) -> _Study:
    return _read_csv(path) if kind == ".csv" else _read_json(path)


def _name(cell: dict[str, Any]) -> tuple[str, ...]:
    return tuple(str(cell.get(c, "")) for c in _CELL)


def _read_csv(path: Path) -> _Study:
    """A results.csv: the command and software on every row, a status per row."""
    try:
        with open(path, newline="", encoding="utf-8") as handle:
            rows = list(csv.DictReader(handle))
    except (OSError, UnicodeDecodeError, csv.Error) as error:
        raise McrtError(f"cannot read {path} as a CSV file: "
                        f"{getattr(error, 'strerror', None) or error}") from None
    commands = {row.get(COMMAND) or "" for row in rows}
    if len(commands) > 1:
        raise McrtError(f"{path}: its rows record {len(commands)} different commands (one "
                        f"study's file has one)")
    before, now = (rows[0].get("software") or "") if rows else "", software_text()
    return _Study(commands.pop() if commands else "",
                  any(row.get("status") != "done" for row in rows),
                  f"{before} (now {now})" if before and before != now else "",
                  {_name(row): row for row in rows})


#: The keys of a study's ``environment`` that name its software, as
#: :func:`~mcrt.core.provenance.software_changes` names them.
_ENVIRONMENT = {"mcrt_source": "mcrt_source", "mitsuba": "mitsuba_version",
                "drjit": "drjit_version"}


def _read_json(path: Path) -> _Study:
    """A results.json: the command, ``partial`` and the environment once, the
    finished cells in ``cells``."""
    try:
        data = json.loads(path.read_text(encoding="utf-8"))
    except (OSError, UnicodeDecodeError, ValueError) as error:
        raise McrtError(f"cannot read {path} as a JSON file: "
                        f"{getattr(error, 'strerror', None) or error}") from None
    if not isinstance(data, dict):
        raise McrtError(f"{path} is not a study's results.json (not a JSON object)")
    environment = data.get("environment")
    environment = environment if isinstance(environment, dict) else {}
    header = {key: environment.get(name) for name, key in _ENVIRONMENT.items()}
    cells: Any = data.get("cells")
    listed = isinstance(cells, list) and all(isinstance(c, dict) for c in cells)
    return _Study(str(data.get(COMMAND) or ""), data.get("partial") is True,
                  "; ".join(software_changes(header)),
                  {_name(cell): cell for cell in cells} if listed else None)


def _written(value: Any, kind: str) -> str:
    """A field's value as its file writes it (a CSV's text already is)."""
    return value if kind == ".csv" and isinstance(value, str) else json.dumps(value)


def _compare(new: Path, kind: str, old: Path, before: _Study) -> int:
    """Say whether ``new`` holds the same cells as ``old`` (read as ``before``)
    with the same values in every field a run repeats."""
    from ..analysis.study.fields import CELL_KEYS, REPEATED_COLUMNS

    fields = REPEATED_COLUMNS if kind == ".csv" else \
        tuple(c for c in REPEATED_COLUMNS if c in CELL_KEYS)
    a, b = _read(new, kind).cells or {}, before.cells or {}
    differ = {key: [c for c in fields
                    if _written(a[key].get(c), kind) != _written(b[key].get(c), kind)]
              for key in a.keys() & b.keys()}
    differ = {key: columns for key, columns in differ.items() if columns}
    if a.keys() == b.keys() and not differ:
        print(f"{new}: the same numbers as {old} in all {len(a)} cells, bit for bit (times "
              f"aside)")
        return 0
    if a.keys() != b.keys():
        print(f"{new}: other cells than {old} ({len(a.keys() - b.keys())} new, "
              f"{len(b.keys() - a.keys())} missing): the study's configuration changed")
        return 1
    named = "; ".join(f"{'/'.join(key)} spp ({', '.join(columns)})"
                      for key, columns in sorted(differ.items())[:_NAMED])
    more = f"; and {len(differ) - _NAMED} more" if len(differ) > _NAMED else ""
    print(f"{new}: {len(differ)} of {len(a)} cells differ from {old}: {named}{more}"
          + (" -- it was written by other software (noted above)"
             if before.other_software else ""))
    return 1


__all__ = ["CARRIERS", "CARRIERS_TEXT", "run_from"]
