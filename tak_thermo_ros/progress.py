"""Progress for long reads: a bar on a terminal, nothing otherwise."""

from __future__ import annotations

import sys
import time
from typing import TextIO


class Progress:
    """A minimal progress bar on ``stream`` (stderr), drawn only when it is a terminal.

    :param total: number of steps expected.
    :param label: text before the bar.
    """

    def __init__(self, total: int, label: str, *, stream: TextIO | None = None,
                 enabled: bool | None = None) -> None:
        self.total = max(int(total), 1)
        self.label = label
        self.stream = stream or sys.stderr
        self.enabled = self.stream.isatty() if enabled is None else enabled
        self._done = 0
        self._last_draw = 0.0

    def advance(self, steps: int = 1) -> None:
        """Count ``steps`` more; redraw at most ten times a second."""
        self._done += steps
        if self.enabled:
            now = time.monotonic()
            if now - self._last_draw >= 0.1:
                self._last_draw = now
                self._draw()

    def _draw(self) -> None:
        fraction = min(self._done / self.total, 1.0)
        filled = int(30 * fraction)
        self.stream.write(f'\r{self.label} [{"#" * filled}{"." * (30 - filled)}] {100 * fraction:5.1f}%')
        self.stream.flush()

    def close(self) -> None:
        """Finish the line."""
        if self.enabled:
            self._done = self.total
            self._draw()
            self.stream.write('\n')
            self.stream.flush()

    def __enter__(self) -> Progress:
        return self

    def __exit__(self, *exc_info: object) -> None:
        self.close()
