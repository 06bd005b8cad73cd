"""The ``compensator`` executable: the node's executor and ``main``, ended cleanly by a signal at any moment.

``ros2 run tak_thermo_ros compensator`` (and launch) run :func:`main`. A SIGINT or SIGTERM may
come while the node is starting (a launch file shut down early, a supervisor's restart). With
Python's defaults, one during the imports (most of the start-up) ends the process with a
traceback (SIGINT) or kills it (SIGTERM), and one while rclpy builds the node leaves rcl calls
failing on a context the signal shut down. So :func:`main` installs
:class:`~tak_thermo_ros.ros.signals.SignalGuard` before it imports anything heavy, then ends with
status 0 and one line, whatever the signal interrupted. At its top this module (as
:mod:`~tak_thermo_ros.ros.signals`) imports nothing but the standard library: rclpy and the node
(:class:`~tak_thermo_ros.ros.node.CompensatorNode`) are imported inside the functions, after the
guard is installed.

:func:`make_executor` and :func:`spin` run the node (the ``executor`` parameter) until a stop
signal or a shutdown.
"""

from __future__ import annotations

import os
import signal
import sys
import time
from typing import TYPE_CHECKING, Any, Sequence

from tak_thermo_ros.ros.signals import SignalGuard

if TYPE_CHECKING:
    from rclpy.executors import Executor
    from rclpy.node import Node

EXIT_ERROR = 2
SPIN_PERIOD_S = 0.1
"""Longest wait of one ``spin_once``: how soon the loop notices a shutdown (SIGINT, SIGTERM)."""
ROSOUT_LINGER_S = 0.5
"""How long the node waits after its last line (the watch's verdict at shutdown) before its context goes:
/rosout is a reliable topic whose last sample the middleware sends after ``log`` returns; destroyed at once,
a loaded machine lost it (a recorder of /rosout missed the verdict)."""


def make_executor(kind: str, context: Any) -> Executor:
    """The executor named by the ``executor`` parameter."""
    from rclpy.executors import SingleThreadedExecutor
    from rclpy.experimental import EventsExecutor

    if kind == 'events':
        return EventsExecutor(context=context)
    return SingleThreadedExecutor(context=context)


def spin(node: Node, executor: Executor, signals: SignalGuard | None = None) -> bool:
    """Spin until a stop signal (``signals``: SIGINT or SIGTERM) or until the context shuts down.

    ``spin_once`` in a loop, not ``spin()``: the EventsExecutor's ``spin()`` stopped by a
    shutdown from another thread kept running at 100 % CPU in a trial; this loop notices the
    signal or the shutdown within :data:`SPIN_PERIOD_S`.

    :returns: whether the executor failed on the shutdown itself (it raised once the context was
        gone, e.g. while registering the node's entities): see :func:`main`.
    """
    from rclpy.executors import ExternalShutdownException

    executor.add_node(node)
    context = node.context
    while context.ok() and (signals is None or signals.received is None):
        try:
            executor.spin_once(timeout_sec=SPIN_PERIOD_S)
        except ExternalShutdownException:
            break
        except Exception:
            if context.ok():
                raise
            return True  # the executor noticed the shutdown first, in its own words
    return False


def _params_file_refused(args: Sequence[str]) -> str:
    """Why a ``--params-file`` of the command line is not read (a FIFO, socket, device, directory), or ``''``."""
    from tak_thermo_ros.formats.files import not_regular

    words = list(args)
    for word, value in zip(words, words[1:]):
        kind = not_regular(value) if word == '--params-file' else ''
        if kind:
            return f'--params-file {value}: is {kind}: only a regular file is read'
    return ''


def main(args: Sequence[str] | None = None, *, signals: SignalGuard | None = None) -> int:
    """Entry point of ``compensator`` (Jazzy node skeleton); 2 when it cannot start.

    A SIGINT or SIGTERM at any moment ends it with status 0 (``signals``, installed here, before
    the imports, when the caller has not). One that comes while it starts stops the imports or
    ``rclpy.init``, or the node once built, said in one line, no traceback.
    rclpy installs no signal handler of its own: the guard's stops the spin, so the node ends
    (the watch's verdict logged, what it learned written) while its context still holds, and its
    last lines reach /rosout (rclpy's handlers shut the context down first, and every line logged
    at shutdown printed "Failed to publish log message to rosout").
    """
    signals = signals if signals is not None else SignalGuard().install()
    try:  # the heavy imports: rclpy, the message packages, the node
        import rclpy
        from rclpy.executors import ExternalShutdownException
        from rclpy.signals import SignalHandlerOptions

        from tak_thermo_ros.errors import TakError
        from tak_thermo_ros.formats.calibration_file import NODE_NAME
        from tak_thermo_ros.ros.node import CompensatorNode
    except BaseException:  # the KeyboardInterrupt, or what an extension module's import made of it
        if signals.received is None:
            raise
        signals.disarm()
        signals.say_stopped('compensator')
        return 0
    node = executor = None
    running = failed_on_shutdown = False
    try:
        if signals.received:  # arrived at the end of the imports
            raise KeyboardInterrupt
        refused = _params_file_refused(sys.argv if args is None else args)
        if refused:  # rcl would wait on a FIFO's open inside rclpy.init
            print(f'[FATAL] [{NODE_NAME}]: cannot start: {refused}', file=sys.stderr)
            return EXIT_ERROR
        try:
            rclpy.init(args=args, signal_handler_options=SignalHandlerOptions.NO)
        except Exception as err:  # rcl refuses bad --ros-args or an unreadable params file
            if signals.received:
                raise KeyboardInterrupt from None
            detail = str(err).strip().splitlines()
            print(f'[FATAL] [{NODE_NAME}]: cannot start: {detail[0] if detail else type(err).__name__}',
                  file=sys.stderr)
            return EXIT_ERROR
        signals.disarm()  # from now on a signal is remembered: the spin below stops on it
        try:
            node = CompensatorNode()
        except (TakError, ValueError) as err:
            if signals.received or not rclpy.ok():
                raise KeyboardInterrupt from None
            rclpy.logging.get_logger(NODE_NAME).fatal(f'cannot start: {err}')
            return EXIT_ERROR
        if signals.received:  # while the node was built
            raise KeyboardInterrupt
        executor = make_executor(node.executor_kind, node.context)
        running = True
        failed_on_shutdown = spin(node, executor, signals)
    except (KeyboardInterrupt, ExternalShutdownException):
        pass
    except Exception:
        if signals.received is None and rclpy.ok():
            raise
        # a signal shut the context down under rclpy (RCLError: context is invalid)
    finally:
        # Ctrl-C under `ros2 launch` reaches the node twice (the terminal's process group, then
        # launch forwarding it): a second signal must not break the teardown with a traceback.
        signals.disarm()
        signal.signal(signal.SIGINT, signal.SIG_IGN)
        if executor is not None:
            executor.shutdown()
        if node is not None:
            node.finish()
            time.sleep(ROSOUT_LINGER_S)
            node.destroy_node()
        rclpy.try_shutdown()
        if not running and signals.received:
            signals.say_stopped(NODE_NAME)
        if failed_on_shutdown and node is not None and node.executor_kind == 'events':
            # rclpy's EventsExecutor that raised while registering the node's entities (a signal
            # shut the context down in the middle) can keep a callback it never recorded, and its
            # C++ destructor then aborts the process ("Destroying callback manager with callbacks
            # remaining"). Everything is torn down above; end here, before that destructor runs.
            sys.stdout.flush()
            sys.stderr.flush()
            os._exit(0)
    return 0


if __name__ == '__main__':
    sys.exit(main())
