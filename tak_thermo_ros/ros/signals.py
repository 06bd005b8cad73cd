"""Stop signals while the node starts: :class:`SignalGuard` (the standard library only).

``tak_thermo_ros.ros.main`` installs it before any heavy import; :func:`tak_thermo_ros.ros.node.main`
disarms it once rclpy is initialised, stops on it, and says a stop during start-up in one line.
"""

from __future__ import annotations

import signal
import sys
from typing import Any

STOP_SIGNALS = (signal.SIGINT, signal.SIGTERM)


class SignalGuard:
    """SIGINT and SIGTERM while the node starts: remembered, and before rclpy is initialised, raised.

    Installed for both signals before the imports. Until :meth:`disarm` (called once rclpy is
    initialised), the first signal raises :class:`KeyboardInterrupt` in the main thread: the
    imports or ``rclpy.init`` stop there. From then on it only remembers the signal (raising
    then could land inside rclpy's C++: the EventsExecutor calls Python while it adds the
    node, which aborts the process); the node, built without rclpy's own handlers, stops
    spinning on :attr:`received` and ends while its context still holds.
    """

    def __init__(self) -> None:
        self.received: str | None = None
        """Name of the first signal received (``'SIGTERM'``), or ``None``."""
        self._armed = True

    def install(self) -> SignalGuard:
        """Handle both signals from now on; the guard itself."""
        for number in STOP_SIGNALS:
            signal.signal(number, self._on_signal)
        return self

    def disarm(self) -> None:
        """From now on remember signals without raising (the node's spin stops on them)."""
        self._armed = False

    def _on_signal(self, number: int, frame: Any) -> None:
        if self.received is None:
            self.received = signal.Signals(number).name
        if self._armed:
            self._armed = False
            raise KeyboardInterrupt

    def say_stopped(self, name: str) -> None:
        """One line saying the node stopped on the signal before it was running."""
        print(f'[INFO] [{name}]: stopped by {self.received or "a signal"} while starting', file=sys.stderr)
