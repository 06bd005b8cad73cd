"""The ``compensator`` executable: the node, ended cleanly by a signal at any moment of its start-up.

``ros2 run tak_thermo_ros compensator`` (and launch) run :func:`main`. A SIGINT or SIGTERM may
come while the node is starting (a launch file shut down early, a supervisor's restart). With
Python's defaults, one during the imports (most of the start-up) ends the process with a
traceback (SIGINT) or kills it (SIGTERM), and one while rclpy builds the node leaves rcl calls
failing on a context the signal shut down. So :func:`main` installs :class:`SignalGuard` before it
imports anything heavy; :func:`tak_thermo_ros.node.main` then ends with status 0 and one line,
whatever the signal interrupted. This module imports nothing but the standard library.
"""

from __future__ import annotations

import signal
import sys
from typing import Any, Sequence

STOP_SIGNALS = (signal.SIGINT, signal.SIGTERM)


class SignalGuard:
    """SIGINT and SIGTERM while the node starts: remembered, and before rclpy is initialised, raised.

    Installed for both signals before the imports. Until :meth:`disarm` (called once rclpy is
    initialised), the first signal raises :class:`KeyboardInterrupt` in the main thread: the
    imports or ``rclpy.init`` stop there. From then on rclpy's own handlers, which call this
    one after theirs, shut the context down, and this one only remembers the signal: raising
    then could land inside rclpy's C++ (the EventsExecutor calls Python while it adds the
    node), which aborts the process; rcl calls on the shut-down context fail instead, and the
    node takes that failure for the stop it is.
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
        """From now on remember signals without raising (rclpy's handlers stop the node)."""
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


def main(args: Sequence[str] | None = None) -> int:
    """Entry point of ``compensator``: :func:`tak_thermo_ros.node.main` under a :class:`SignalGuard`."""
    signals = SignalGuard().install()
    try:
        from tak_thermo_ros import node
    except BaseException:  # the KeyboardInterrupt, or what an extension module's import made of it
        if signals.received is None:
            raise
        signals.disarm()
        signals.say_stopped('compensator')
        return 0
    return node.main(args, signals=signals)


if __name__ == '__main__':
    sys.exit(main())
