"""The one way every vigil node process starts and stops (ros2/examples talker.py).

Kept apart from the algorithm packages: only node files import it.

Shutdown: rclpy's own signal handler shuts the context down from inside the signal,
while a callback may still be publishing ("publisher's context is invalid", exit 1) and
before the node's last words (a zero velocity) can go out. So rclpy installs no handler
here: SIGINT and SIGTERM only set a flag that the spin loop checks (the executor wakes
every :data:`SPIN_WAKE_S`), ``on_exit`` publishes with the context still valid, and only
then is the node destroyed and the context shut down. The handler must not raise: an
exception raised while rclpy's C++ side is converting a message into Python turns into
pybind11's "Unable to convert call argument" RuntimeError and the node exits 1 (seen in
CI on the planner at shutdown). A
clean stop exits 0; a node that cannot start (bad configuration or file) prints one
``[FATAL]`` line naming what is wrong and exits 2; a node whose disk is full (ENOSPC or
EDQUOT, in a callback or in its last words) says so in one ``[FATAL]`` line if its log
has room, cleans up what it can and exits :data:`stack.exits.EXIT_DISK_FULL` (the code
alone tells the launcher, issue 23).

Teardown: once the last words are out and a :class:`Releasing` node's ``release()``
has closed what it holds (a bag, a trace, a stream), destroying the node and the
context is the middleware's business, and Fast DDS can deadlock there
(eProsima/Fast-DDS#6502: entity teardown against a dead peer's lease expiry, which a
node killed and restarted leaves behind; seen in CI as an observations node SIGKILLed
17 s after SIGINT). So the teardown has an alarm: after :data:`stack.exits.TEARDOWN_S`
the node's Python stacks go to its log (``faulthandler``, which needs no interpreter
lock) and SIGALRM's default action ends the process; the launcher reads that code as
"teardown hung", a warning, since nothing of the node's work is left undone by then.
SIGTERM also writes the stacks to the log (a node stuck before its teardown shows where
before the launcher's SIGKILL).
"""

from __future__ import annotations

import errno
import faulthandler
import signal
import sys
import threading
from collections.abc import Callable, Sequence
from typing import Any, TypeVar

import rclpy
from rclpy.executors import ExternalShutdownException, SingleThreadedExecutor
from rclpy.node import Node
from rclpy.signals import SignalHandlerOptions

from stack.exits import EXIT_BAD_CONFIG, EXIT_DISK_FULL, TEARDOWN_S, TEARDOWN_SIGNAL

DISK_FULL = (errno.ENOSPC, errno.EDQUOT)
# Python runs a signal handler only between bytecodes: a node without timers would
# otherwise sit in the executor's wait until SIGKILL (measured: table_player, -9)
SPIN_WAKE_S = 0.1


class _StopFlag:
    """Set by SIGINT/SIGTERM; checked by the spin loop between callbacks."""

    def __init__(self) -> None:
        self.signal: str | None = None
        self.cleaning = False  # a second signal must not cut the last words short

    def __call__(self, signum, frame) -> None:
        if not self.cleaning:
            self.signal = signal.Signals(signum).name


__all__ = ["EXIT_BAD_CONFIG", "EXIT_DISK_FULL", "BatchingExecutor", "Releasing", "spin_node"]


class BatchingExecutor(SingleThreadedExecutor):
    """A single-threaded executor that calls its :attr:`before_wait` hooks each time it
    has run every callback that was ready (one wake-up's batch), before it waits again.

    A lock-step participant acknowledges a batch in one message
    (:meth:`stack.ros_lockstep.Participant.ack_soon`) and the twin bridge checks its
    ledger once a batch, instead of once a callback.
    """

    def __init__(self, *, context=None, qos_events: bool = True) -> None:
        super().__init__(context=context)
        self.before_wait: list[Callable[[], None]] = []
        self.qos_events = qos_events

    def _wait_for_ready_callbacks(self, *args, **kwargs):  # type: ignore[override]
        # rclpy makes this generator anew once the previous one ran out of ready work:
        # its first step is the wait
        for hook in list(self.before_wait):
            hook()
        if not self.qos_events:
            self._drop_event_handlers()
        yield from super()._wait_for_ready_callbacks(*args, **kwargs)

    def _drop_event_handlers(self) -> None:
        """``qos_events`` False: the nodes' middleware-event handlers (rclpy gives every
        publisher and subscription two, which log an incompatible QoS or type) are not
        waited for. Each costs the executor Python work on every wait, and rclpy's
        check of them is quadratic: with the hundred and more publishers and
        subscriptions of one process holding every node of a run, it was most of the
        process's time (:mod:`vigil.container`)."""
        for node in self.get_nodes():
            entities: list[Any] = [*node.publishers, *node.subscriptions]
            for entity in entities:
                if entity.event_handlers:
                    for handler in entity.event_handlers:
                        node.remove_waitable(handler)
                        handler.destroy()
                    entity.event_handlers = []  # destroy_publisher() removes these too


class Releasing:
    """A node that holds files or devices (a bag, a trace, a stream): it closes them in
    ``_release()``, which runs once, from :func:`spin_node` before the middleware's
    teardown (and its alarm) or from ``destroy_node`` for a node destroyed otherwise.
    Put it before ``Node`` among the bases."""

    _released = False

    def _release(self) -> None:
        raise NotImplementedError

    def release(self) -> None:
        if not self._released:
            self._released = True
            self._release()

    def destroy_node(self) -> None:
        try:
            self.release()
        finally:
            super().destroy_node()  # type: ignore[misc]


N = TypeVar("N", bound=Node)


def spin_node(
    make_node: Callable[[], N],
    args: list[str] | None = None,
    on_exit: Callable[[N], None] | None = None,
) -> None:
    """Init rclpy, spin the node until SIGINT/SIGTERM or external shutdown, then clean up.

    Args:
        make_node: builds the node (called after rclpy.init).
        args: ROS command-line arguments.
        on_exit: last words while the context is still up (e.g. a zero velocity); runs
            on every way out once the node exists, a crash included.
    """
    spin_nodes([(make_node, on_exit)], args)


def spin_nodes(
    makers: Sequence[tuple[Callable[[], Any], Callable[[Any], None] | None]],
    args: list[str] | None = None,
    name: str = "",
    qos_events: bool = True,
) -> None:
    """:func:`spin_node` for several nodes in one process, on one executor (the twin's
    lock-step container, :mod:`vigil.container`): built in order; a node that
    cannot start ends the process (exit 2) with its name; on the way out every node's
    last words, then every node's release, then the teardown, each done for every node
    even when one of them fails (the first error is raised once all are done).

    Args:
        makers: (builds the node, its last words or None), in order.
        args: ROS command-line arguments (every node reads its own parameters).
        name: the process's name in a ``[FATAL]`` line raised after the start (default:
            the node's, with one node).
        qos_events: False: no handler of middleware events (an incompatible QoS logged)
            is waited for (:class:`BatchingExecutor`).
    """
    from stack.cells import ConfigError

    main_thread = threading.current_thread() is threading.main_thread()
    stop = _StopFlag()
    if main_thread:
        signal.signal(signal.SIGINT, stop)
        signal.signal(signal.SIGTERM, stop)
        # the stacks on SIGTERM, then the flag (chained): the launcher's second signal
        faulthandler.register(signal.SIGTERM, file=sys.stderr, all_threads=True, chain=True)
    rclpy.init(args=args, signal_handler_options=SignalHandlerOptions.NO)
    nodes: list[tuple[Any, Callable[[Any], None] | None]] = []
    making: Any = makers[0][0]  # the maker a [FATAL] line names
    code = 0
    try:
        executor = BatchingExecutor(qos_events=qos_events)
        for make, on_exit in makers:
            making = make
            nodes.append((make(), on_exit))
            executor.add_node(nodes[-1][0])
        if len(makers) > 1 and name:
            making = _Named(name)
        while stop.signal is None:  # wakes at least every SPIN_WAKE_S to check
            executor.spin_once(timeout_sec=SPIN_WAKE_S)
    except (KeyboardInterrupt, ExternalShutdownException):
        pass
    except (ConfigError, OSError) as err:
        if isinstance(err, OSError) and err.errno in DISK_FULL:
            _fatal(making, f"disk full: {err}")
            code = EXIT_DISK_FULL
        elif len(nodes) == len(makers):
            raise
        else:
            _fatal(making, str(err))
            code = EXIT_BAD_CONFIG
    finally:
        stop.cleaning = True
        errors: list[BaseException] = []

        def each(step: Callable[[Any, Callable[[Any], None] | None], None]) -> None:
            for node, on_exit in nodes:
                try:
                    step(node, on_exit)
                except Exception as err:  # noqa: BLE001 - raised once every node is done
                    errors.append(err)

        def last_words(node, on_exit) -> None:
            if on_exit is not None and rclpy.ok():
                on_exit(node)

        def release(node, _on_exit) -> None:
            if isinstance(node, Releasing):  # its files closed before the alarm is set
                node.release()

        try:
            each(last_words)
            each(release)
            if main_thread:
                _teardown_alarm()
            each(lambda node, _on_exit: node.destroy_node())
            if errors:
                raise errors[0]
        except OSError as err:  # closing files on a full disk
            if err.errno not in DISK_FULL:
                raise
            _fatal(making, f"disk full while closing: {err}")
            code = EXIT_DISK_FULL
        finally:
            rclpy.try_shutdown()
            if main_thread:
                _teardown_alarm(cancel=True)
    if code:
        sys.exit(code)


class _Named:
    """A name for :func:`_fatal` (it reads ``__name__``)."""

    def __init__(self, name: str):
        self.__name__ = name


def _teardown_alarm(cancel: bool = False) -> None:
    """From now on (the node's last words are out) at most TEARDOWN_S: the stacks to
    the log just before, then SIGALRM's default action ends the process; ``cancel``:
    the teardown is over."""
    if cancel:
        signal.setitimer(signal.ITIMER_REAL, 0.0)
        faulthandler.cancel_dump_traceback_later()
        return
    try:
        sys.stderr.flush()
    except OSError:
        pass
    faulthandler.dump_traceback_later(TEARDOWN_S - 0.5, file=sys.stderr)
    signal.signal(TEARDOWN_SIGNAL, signal.SIG_DFL)
    signal.setitimer(signal.ITIMER_REAL, TEARDOWN_S)


def _fatal(make_node, text: str) -> None:
    """One ``[FATAL]`` line; nothing if even that finds no room."""
    try:
        print(f"[FATAL] {getattr(make_node, '__name__', 'node')}: {text}", file=sys.stderr)
        sys.stderr.flush()
    except OSError:
        pass
