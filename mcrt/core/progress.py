"""One progress reporter for every long job: a tqdm bar on stderr, or nothing.

tqdm is imported only when a bar is shown, so quiet runs and library use pay
nothing for it.
"""

from __future__ import annotations

import logging
from typing import Any

log = logging.getLogger("mcrt")


class Progress:
    """A bar over ``total`` units (passes, renders, ...), or a silent stand-in.

    ``initial`` units are already done (a resumed job). Notes go above the bar,
    or to the log when no bar is shown.
    """

    def __init__(self, total: int, enabled: bool = True, unit: str = "pass",
                 desc: str = "render", initial: int = 0, leave: bool = False) -> None:
        self.bar: Any = None
        if enabled:
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
