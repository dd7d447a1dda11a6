"""One progress reporter for every long job: a tqdm bar on stderr, log lines, or nothing.

On a terminal it is a tqdm bar. When stderr is not a terminal (a log file, a CI
job, a pipe) a redrawn bar would fill the log with carriage returns, so it writes
a plain line instead at most every :data:`LOG_INTERVAL` seconds and at the end
("study: 120/480 renders (25%), 1m30s, about 4m30s left"). tqdm is imported only
when a bar is shown, so quiet runs and library use pay nothing for it.
"""

from __future__ import annotations

import logging
import sys
import time
from typing import Any

log = logging.getLogger("mcrt")

#: Seconds between two progress lines when stderr is not a terminal.
LOG_INTERVAL = 30.0


def _duration(seconds: float) -> str:
    minutes, secs = divmod(int(round(seconds)), 60)
    return f"{minutes}m{secs:02d}s" if minutes else f"{secs}s"


class _Lines:
    """tqdm's interface, as plain lines at most every :data:`LOG_INTERVAL` s."""

    def __init__(self, total: int, initial: int, unit: str, desc: str) -> None:
        self.total, self.n, self.unit, self.desc = total, initial, unit, desc
        self.start = self.last = time.monotonic()
        self.initial = initial
        self.postfix = ""

    def _line(self) -> None:
        elapsed = time.monotonic() - self.start
        share = self.n / self.total if self.total else 1.0
        done = self.n - self.initial
        left = (f", about {_duration(elapsed * (self.total - self.n) / done)} left"
                if done > 0 and self.n < self.total else "")
        extra = f" [{self.postfix}]" if self.postfix else ""
        units = self.unit + ("es" if self.unit.endswith("s") else "s")
        print(f"{self.desc}: {self.n}/{self.total} {units} ({100 * share:.0f}%), "
              f"{_duration(elapsed)}{left}{extra}", file=sys.stderr, flush=True)
        self.last = time.monotonic()

    def set_description(self, text: str, refresh: bool = True) -> None:
        self.desc = text

    def set_postfix_str(self, text: str, refresh: bool = True) -> None:
        self.postfix = text

    def write(self, text: str) -> None:
        print(text, file=sys.stderr, flush=True)

    def update(self, n: int = 1) -> None:
        self.n += n
        if time.monotonic() - self.last >= LOG_INTERVAL:
            self._line()

    def close(self) -> None:
        if self.n > self.initial:
            self._line()


class Progress:
    """A bar over ``total`` units (passes, renders, ...), or a silent stand-in.

    ``initial`` units are already done (a resumed job). Notes go above the bar,
    or to the log when no bar is shown.
    """

    def __init__(self, total: int, enabled: bool = True, unit: str = "pass",
                 desc: str = "render", initial: int = 0, leave: bool = False) -> None:
        self.bar: Any = None
        if enabled and not _terminal():
            self.bar = _Lines(total, initial, unit, desc)
        elif enabled:
            from tqdm import tqdm

            self.bar = tqdm(total=total, initial=initial, unit=unit, desc=desc, leave=leave,
                            dynamic_ncols=True)

    def describe(self, text: str) -> None:
        if self.bar is not None:
            self.bar.set_description(text, refresh=True)

    def note(self, text: str) -> None:
        if self.bar is not None:
            self.bar.write(text)
        else:
            log.info("%s", text)

    def postfix(self, text: str) -> None:
        if self.bar is not None:
            self.bar.set_postfix_str(text, refresh=False)

    def update(self, n: int = 1) -> None:
        if self.bar is not None:
            self.bar.update(n)

    def close(self) -> None:
        if self.bar is not None:
            self.bar.close()
            self.bar = None

    def __enter__(self) -> Progress:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()


def _terminal() -> bool:
    try:
        return sys.stderr.isatty()
    except (AttributeError, ValueError):  # replaced or closed
        return False
