"""``mcrt compare --from results.csv``: run a study again from what its results.csv
records, and say whether every cell's numbers came out the same.

Every row of a study's ``results.csv`` records the ``command`` that runs the study
(its configuration and plugin files by absolute path, no ``-o``) and the
``software`` that ran it (:data:`mcrt.core.provenance.CSV_COLUMNS`). ``--from``
runs that command into ``-o DIR`` (default: the study's folder with ``_again``
added, beside it) and compares the two files on the columns a run repeats
(:data:`~mcrt.analysis.study.fields.REPEATED_COLUMNS`: all but the times), as
written (a float's repr: bit for bit). Exit status 0 when every cell is the same,
1 when one differs (the note says which, and in what), 2 when the file cannot be
run again.
"""

from __future__ import annotations

import argparse
import csv
import logging
from pathlib import Path

from ..core.provenance import COMMAND, command_words, software_text
from ..errors import McrtError
from .reproduce import _mcrt

log = logging.getLogger("mcrt.compare")

#: The options that set what a study measures, by ``argparse`` destination.
_SETTINGS = {"config": "CONFIG.toml", "check": "--check", "restart": "--restart",
             "retime": "--retime"}

#: The columns that name a cell.
_CELL = ("scene", "sampler", "spp_requested")

#: At most this many differing cells are named.
_NAMED = 5


def run_from(args: argparse.Namespace) -> int:
    from . import command_of

    source = Path(args.from_csv)
    given = [flag for dest, flag in _SETTINGS.items() if getattr(args, dest, None)]
    if given:
        raise McrtError(f"--from {source} takes every setting from the file; drop "
                        f"{', '.join(given)} (only -o, -q and --cluster go with it)")
    rows = _rows(source)
    commands = {row.get(COMMAND) or "" for row in rows}
    if len(commands) > 1:
        raise McrtError(f"{source}: its rows record {len(commands)} different commands (one "
                        f"study's file has one)")
    text = commands.pop() if commands else ""
    words = command_words({COMMAND: text}, source)
    if command_of(words) != "compare":
        raise McrtError(f"{source}: its command {text!r} does not run a study (mcrt compare)")
    if any(row.get("status") != "done" for row in rows):
        raise McrtError(f"{source} is a partial study (interrupted): its own command finishes "
                        f"it: {text} -o {source.resolve().parent}")
    folder = source.resolve().parent
    out = Path(args.output) if args.output else folder.with_name(f"{folder.name}_again")
    if out.resolve() == folder:
        raise McrtError(f"-o {args.output}: that is {source}'s own study; write elsewhere")
    before, now = rows[0].get("software") or "", software_text()
    if before and before != now:
        log.warning("%s was written by other software: %s (now %s); the numbers may differ "
                    "for that reason", source, before, now)
    extra = ["--cluster", args.cluster] if getattr(args, "cluster", None) else []
    log.info("running again: %s", text)
    code = _mcrt([*words, *extra, "-o", str(out)], args.quiet)
    if code:
        return code
    return _compare(out / "results.csv", source, bool(before) and before != now)


def _rows(path: Path) -> list[dict[str, str]]:
    """The rows of a results.csv, as ``csv.DictReader`` reads them."""
    try:
        with open(path, newline="", encoding="utf-8") as handle:
            return list(csv.DictReader(handle))
    except (OSError, UnicodeDecodeError, csv.Error) as error:
        raise McrtError(f"cannot read {path} as a CSV file: "
                        f"{getattr(error, 'strerror', None) or error}") from None


def _compare(new: Path, old: Path, other_software: bool) -> int:
    """Say whether ``new`` holds the same cells as ``old`` with the same values in
    every column a run repeats."""
    from ..analysis.study.fields import REPEATED_COLUMNS

    def cells(path: Path) -> dict[tuple[str, ...], dict[str, str]]:
        return {tuple(row.get(c, "") for c in _CELL): row for row in _rows(path)}

    a, b = cells(new), cells(old)
    differ = {key: [c for c in REPEATED_COLUMNS if a[key].get(c) != b[key].get(c)]
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
          + (" -- it was written by other software (noted above)" if other_software else ""))
    return 1


__all__ = ["run_from"]
