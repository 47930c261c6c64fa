"""How a resource family plugs into the ROS worker: :class:`Family`, and the :class:`Core` it is given.

A family (medkit's naming: the same name in every layer) is one package of
``rosworker/`` whose ``__init__.py`` holds ``FAMILY``, an instance of a
:class:`Family` subclass::

    class Logs(Family):
        name = "logs"

        def start(self, core: Core) -> None:       # build, register, subscribe
            self.book = LogBook(core.node, core.executor, core.stats, ...)
            core.notifier.provide("logs", self.book.observable)
            self.commands = {"logs": self.book.query_cmd, ...}

        def shutdown(self) -> None:                # release what start made
            self.book.shutdown()

    FAMILY = Logs()

``main.py`` finds the families (:func:`discover`: every package but ``core`` and
``ros``), starts them in name order on the ROS thread before the loop runs,
hands every family's ``commands`` (name -> handler(task)) to the executor, and
after the loop shuts them down in the reverse order: the pair of Home
Assistant's ``async_setup_entry``/``async_unload_entry``, so nothing started is
forgotten at shutdown.  The start order carries no meaning: what needs every
family started (restoring what refers to other families' resources) goes in
:meth:`Core.on_started`.  A family imports no other family: it reaches their
resources through the registries of the core (``samplers``, ``notifier``).

A command's name must be declared in ``ipc/counters.py``'s ``COMMANDS`` (the
server refuses others) and its message in ``ipc/PROTOCOL.md``.
"""

from __future__ import annotations

import logging
import os
import time
from collections.abc import Callable
from typing import Any

import zmq

from common import families
from common import settings as config

from . import args
from .endpoints import Endpoints
from .events import EventsChannel
from .executor import RosExecutor
from .graph import GraphMonitor
from .notifier import ChangeNotifier
from .samplers import SamplerRegistry
from .state import RestartState
from .stats import Stats
from .store import Store
from .task import Task
from .topics import SharedTopics

log = logging.getLogger("sovd.rosworker.core")

STATE_SAVE_EVERY = 0.25  # seconds; the restart state is only written when it changed
STATE_FLUSH_WAIT = 2.0   # seconds the writer threads get to finish at shutdown
NOT_FAMILIES = ("core", "ros")


class Family:
    """A resource family of the ROS worker (see the module's docstring)."""

    name = ""

    def __init__(self) -> None:
        self.commands: dict[str, Callable[[Task], None]] = {}

    def start(self, core: Core) -> None:
        """Build the family's pieces, register them with the core, fill ``commands`` (ROS thread)."""

    def shutdown(self) -> None:
        """Release what :meth:`start` made (ROS thread, after the loop; the commands drained after it
        are answered ``shutdown``)."""


def discover(package: str = "rosworker") -> tuple[Family, ...]:
    """Every family of ``package``, in name order (``common/families.py``)."""
    return families.discover(package, Family, NOT_FAMILIES)


class Core:
    """What every family is given: the ROS worker's shared pieces (ROS thread unless said).

    - ``cfg`` (the settings), ``node``, ``restart`` (0 at a gateway's first boot), ``runtime_dir``,
      ``state_dir``;
    - ``executor`` (``core/executor.py``: timers, posting from other threads, pollers), ``stats``
      (``core/stats.py``: the counters of ``ipc/counters.py``), :meth:`every`, :meth:`on_started`;
    - ``graph`` (``core/graph.py``: its poll, ``on_change`` listeners) and ``endpoints``;
    - ``events``: the events channel to the HTTP workers (``core/events.py``);
    - ``store``: the state dir's SQLite store (``core/store.py``), ``restart_state``
      (``core/state.py``);
    - ``samplers`` (``core/samplers.py``) and ``notifier`` (``core/notifier.py``): what other
      families may stream and observe of a family's resources;
    - ``shared_topics`` (``core/topics.py``): subscriptions a family owns that the data family's
      pool reads through;
    - :meth:`extend` / :meth:`extensions`: the extension points a family offers by name (its
      docstring says what is added there: the faults family's ``fault_confirmed`` and
      ``fault_snapshots``).
    """

    def __init__(self, cfg: Any, node: Any, zctx: zmq.Context, executor: RosExecutor, stats: Stats,
                 restart: int = 0):
        self.cfg = cfg
        self.node = node
        self.restart = restart
        self.runtime_dir = cfg.runtime_dir
        self.state_dir = cfg.state_dir or config.default_state_dir(os.environ)
        self.executor = executor
        self.stats = stats
        self.endpoints = Endpoints(node)
        self.graph = GraphMonitor(node, stats)
        self.events = EventsChannel(zctx, cfg.runtime_dir, executor, stats)
        self.store = Store(self.state_dir, post=executor.post)
        self.restart_state = RestartState(cfg.runtime_dir, post=executor.post)
        self.samplers = SamplerRegistry()
        self.notifier = ChangeNotifier()
        self.shared_topics = SharedTopics()
        self._extensions: dict[str, list[Callable[..., Any]]] = {}
        self.commands: dict[str, Callable[[Task], None]] = {"graph": self.graph.command}
        if cfg.debug_commands:
            self.commands["debug_sleep"] = _debug_sleep
        self._started: list[Callable[[], None]] = []

    def every(self, seconds: float, fn: Callable[[], None]) -> None:
        """``fn()`` every ``seconds`` on the ROS thread, from the first round of the loop on."""
        def tick() -> None:
            self.executor.call_later(seconds, tick)
            fn()
        self.executor.call_later(seconds, tick)

    def on_started(self, fn: Callable[[], None]) -> None:
        """``fn()`` once every family has started, discovery has settled and the graph was polled once,
        before the sockets are bound (restoring what refers to other families' resources)."""
        self._started.append(fn)

    def extend(self, point: str, fn: Callable[..., Any]) -> None:
        """Add ``fn`` to the extension point ``point`` that another family offers (any start order)."""
        self.extensions(point).append(fn)

    def extensions(self, point: str) -> list[Callable[..., Any]]:
        """What was added to ``point``: a live list, which the family that offers it keeps and calls."""
        return self._extensions.setdefault(point, [])

    # ---- main.py's --------------------------------------------------------------------------------
    def open(self) -> None:
        """Before the families start: the store opened, the restart state read (or, at a gateway's
        first boot, removed: a clean start begins with no subscriptions and nothing to re-warm)."""
        self.store.open()
        if self.restart:
            self.restart_state.load()
        else:
            self.restart_state.discard()
        self.restart_state.part("nodes", lambda: self.graph.nodes)

    def started(self) -> None:
        """After the families started and discovery settled: the first graph poll, the timers, the
        families' ``on_started``, the writer threads."""
        self.executor.guarded("the first graph check", self.graph.tick)
        self.every(self.cfg.graph_poll_tick / 1000, self.graph.tick)
        self.every(STATE_SAVE_EVERY, self.restart_state.save)
        self.store.start()
        for fn in self._started:
            self.executor.guarded(f"starting {getattr(fn, '__qualname__', fn)}", fn)
        self.restart_state.start()

    def bind(self) -> None:
        self.executor.bind()
        self.events.bind()

    def closing(self) -> None:
        """After the loop, before the families' shutdown: new work is refused, what the restart state's
        writer holds is written (from here on a change is written on this thread)."""
        self.executor.closing = True
        self.restart_state.close(STATE_FLUSH_WAIT)
        self.executor.run_posted()

    def shutdown(self, families: list[Family]) -> None:
        """The families' shutdown, in the reverse order of their start (each one's failure contained)."""
        for family in reversed(families):
            self.executor.guarded(f"the {family.name} family's shutdown", family.shutdown)

    def close(self) -> None:
        """After the families' shutdown and the last answers: the store written and closed."""
        self.executor.guarded("the store's shutdown", self.store.close, STATE_FLUSH_WAIT)
        self.executor.run_posted()


def _debug_sleep(task: Task) -> None:
    """``debug_sleep`` (``--debug-commands`` only): hold the ROS thread, as a slow ROS call would."""
    time.sleep(args.number(task.args, "seconds", 1.0, 0, 600))
    task.reply({})

