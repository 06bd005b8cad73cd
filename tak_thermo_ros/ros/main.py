"""The ``compensator`` executable: the node, ended cleanly by a signal at any moment of its start-up.

``ros2 run tak_thermo_ros compensator`` (and launch) run :func:`main`. A SIGINT or SIGTERM may
come while the node is starting (a launch file shut down early, a supervisor's restart). With
Python's defaults, one during the imports (most of the start-up) ends the process with a
traceback (SIGINT) or kills it (SIGTERM), and one while rclpy builds the node leaves rcl calls
failing on a context the signal shut down. So :func:`main` installs
:class:`~tak_thermo_ros.ros.signals.SignalGuard` before it imports anything heavy;
:func:`tak_thermo_ros.ros.node.main` then ends with status 0 and one line, whatever the signal
interrupted. This module and :mod:`~tak_thermo_ros.ros.signals` import nothing but the standard
library.
"""

from __future__ import annotations

import sys
from typing import Sequence

from tak_thermo_ros.ros.signals import SignalGuard


def main(args: Sequence[str] | None = None) -> int:
    """Entry point of ``compensator``: :func:`tak_thermo_ros.ros.node.main` under a :class:`SignalGuard`."""
    signals = SignalGuard().install()
    try:
        from tak_thermo_ros.ros import node
    except BaseException:  # the KeyboardInterrupt, or what an extension module's import made of it
        if signals.received is None:
            raise
        signals.disarm()
        signals.say_stopped('compensator')
        return 0
    return node.main(args, signals=signals)


if __name__ == '__main__':
    sys.exit(main())
