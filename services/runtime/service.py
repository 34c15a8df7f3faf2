"""One program for every service: the framework owns the life cycle, a service declares its parts.

A service is a subclass of :class:`ArmService`. It names its :class:`Service`,
its default real-time priority and its own options, and its :meth:`~ArmService.start`
declares its parts on the :class:`ServiceContext`: the interfaces it answers, the
threads to watch, the periodic jobs, and what to close. The framework does the
rest, the same way for all four services (as every zenoh-python example is one
skeleton):

1. parse the shared options and the service's own; log to stderr;
2. open the session; log records also go to ``JARA_ARM/<arm>/log/<service>``;
3. one heartbeat per arm served (the servo process may serve several);
4. ``start(ctx)``: the service declares its parts;
5. the heartbeats start; every other thread of the process gets real-time
   priority P-1 (the service's own real-time thread sets P itself); a
   liveliness token per arm (a token up means the service answers); the
   service's up lines;
6. the watchdog loop, every ``WATCHDOG_PERIOD`` or sooner when a periodic job
   is due: each watched thread must be alive, each periodic job runs when due,
   the main loop's pulse beats;
7. on a stop (SIGINT, SIGTERM, the launcher gone) or a failure: a last
   ``leaving`` beat and the tokens deleted (a departure, not a loss), the
   heartbeats closed, the parts closed in the reverse order of their
   declaration, the session closed, the query workers joined.

A failure (an exception out of ``start`` or a watched thread dead) ends the
process with exit code 1, and the launcher restarts it.
"""

from __future__ import annotations

import abc
import argparse
import contextlib
import faulthandler
import gc
import logging
import sys
import threading
import time
from collections.abc import Callable, Iterator, Mapping, Sequence
from typing import Any, ClassVar, TypeVar

import zenoh

from jara_arm.robots import DEFAULT_ROBOT, ROBOTS, RobotModel, robot
from jara_arm.schema.encoding import Encoding
from jara_arm.schema.errors import JaraArmError
from jara_arm.schema.keys import DEFAULT_ARM, ArmKeys, Service, check_arm
from jara_arm.schema.operations import Operation

from .cell import SERVICE_IDENTITY
from .heartbeat import Heartbeat, Pulse
from .logs import ZenohLogHandler, setup_stderr
from .realtime import realtime_process
from .rpc import Answer, InterfaceServer, QueryServer
from .stop_signals import StopSignals
from .timing import Health, add_health_arguments, health_from_args
from .zenoh_args import add_zenoh_arguments, config_from_args

log = logging.getLogger(__name__)

#: The watchdog loop's period [s]: how soon a dead thread ends the process.
WATCHDOG_PERIOD = 0.2

E = TypeVar("E")


def service_parser(service: Service, description: str) -> argparse.ArgumentParser:
    """The options every service takes (arm, robot, logging, Zenoh, health profile)."""
    p = argparse.ArgumentParser(prog=f"jara-arm service {service.value}", description=description)
    p.add_argument("--arm", default=DEFAULT_ARM, help=f"arm id (default: {DEFAULT_ARM})")
    p.add_argument("--robot", default=DEFAULT_ROBOT, choices=list(ROBOTS),
                   help=f"robot model (default: {DEFAULT_ROBOT})")
    p.add_argument("--log-level", default="INFO",
                   choices=["DEBUG", "INFO", "WARNING", "ERROR"], help="default: INFO")
    p.add_argument("--exit-with-parent", action="store_true",
                   help="exit when the launching process dies (set by the launcher)")
    add_zenoh_arguments(p, default_identity=SERVICE_IDENTITY)
    add_health_arguments(p)
    return p


class ServiceContext:
    """What a service's :meth:`ArmService.start` gets, and where it declares its parts."""

    def __init__(self, session: zenoh.Session, arms: Sequence[tuple[str, RobotModel]], health: Health,
                 stop: threading.Event, options: argparse.Namespace, realtime_priority: int,
                 service: Service, stack: contextlib.ExitStack) -> None:
        self.session = session
        #: Every arm the process serves, the main one first, with its robot model.
        self.arms = tuple(arms)
        self.keys = ArmKeys(self.arms[0][0])
        self.model = self.arms[0][1]
        self.health = health
        self.stop = stop
        #: The service's own options (``ArmService.add_arguments``), parsed.
        self.options = options
        #: SCHED_FIFO priority of the service's own real-time thread (0: normal scheduling).
        self.realtime_priority = realtime_priority
        self.service = service
        self.heartbeats: dict[str, Heartbeat] = {
            arm: Heartbeat(session, ArmKeys(arm), service, max(0, realtime_priority - 1), health)
            for arm, _ in self.arms}
        self._stack = stack
        self._watched: list[tuple[str, Callable[[], bool], Callable[[], BaseException | None]]] = []
        self._jobs: list[list[Any]] = []  # [period [s], due [s], job], due updated in place
        self._servers: list[QueryServer] = []
        self._up_lines: list[tuple[str, str]] = []

    def heartbeat(self, arm: str | None = None) -> Heartbeat:
        """The heartbeat of ``arm`` (default: the main one), e.g. for a :meth:`Heartbeat.pulse`."""
        return self.heartbeats[arm or self.keys.arm]

    def serve(self, key_all: str, table: Mapping[str, Operation], handler: object,
              name: str) -> InterfaceServer:
        """Answer an IDL interface (``key_all`` = ``.../<Interface>/*``) with ``handler``'s methods."""
        server = InterfaceServer(self.session, key_all, table, handler, name)
        self._add_server(server)
        return server

    def serve_key(self, key: str, answer: Answer, name: str, encoding: Encoding | None = None) -> QueryServer:
        """Answer the queries on ``key`` with ``answer`` (an internal endpoint, e.g. ``Planner/plan``), in
        ``encoding`` (the key's own, ``keys.encoding_of``) or, if None, in the request's."""
        server = QueryServer(self.session, key, answer, name, encoding)
        self._add_server(server)
        return server

    def _add_server(self, server: QueryServer) -> None:
        self._servers.append(server)
        self._stack.callback(server.close)

    def watch(self, name: str, alive: Callable[[], bool],
              cause: Callable[[], BaseException | None] = lambda: None) -> None:
        """End the process (exit code 1, restarted by the launcher) once ``alive()`` is false.

        ``name`` says what died, e.g. "the servo clock thread"; ``cause()`` the exception that ended it."""
        self._watched.append((name, alive, cause))

    def every(self, period: float, job: Callable[[], None]) -> None:
        """Run ``job`` on the main thread every ``period`` [s] (at the watchdog's granularity)."""
        self._jobs.append([period, time.monotonic() + period, job])

    def closing(self, close: Callable[[], object]) -> None:
        """Call ``close`` at shutdown: the parts close in the reverse order of their declaration."""
        self._stack.callback(close)

    def enter(self, entity: contextlib.AbstractContextManager[E]) -> E:
        """Use ``entity`` (e.g. a Zenoh publisher) until shutdown, then leave it (undeclare)."""
        return self._stack.enter_context(entity)

    def up(self, line: str, arm: str | None = None) -> None:
        """A line to log once the service is announced (on the key of ``arm``, default the main one)."""
        self._up_lines.append((arm or self.keys.arm, line))

    # -- driven by run() ---------------------------------------------------------------------
    def _wait(self) -> float:
        """[s] until the next periodic job is due, at most ``WATCHDOG_PERIOD``."""
        now = time.monotonic()
        wait: float = max(0.0, min([WATCHDOG_PERIOD, *(due - now for _, due, _ in self._jobs)]))
        return wait

    def _check(self) -> None:
        for name, alive, cause in self._watched:
            if not alive():
                raise RuntimeError(f"{name} died") from cause()
        now = time.monotonic()
        for entry in self._jobs:
            period, due, job = entry
            if now >= due:
                entry[1] = max(due + period, now)
                job()


class ArmService(abc.ABC):
    """One service: a subclass names it and declares its parts in :meth:`start`."""

    #: Which service this is (its key chunk and ``jara-arm service`` name).
    SERVICE: ClassVar[Service]
    #: Default SCHED_FIFO priority of the service's own real-time thread (0: normal scheduling).
    REALTIME_PRIORITY: ClassVar[int] = 0
    #: What ``--realtime-priority`` sets, for its help.
    REALTIME_WHAT: ClassVar[str] = "the service's threads"

    @classmethod
    def add_arguments(cls, parser: argparse.ArgumentParser) -> None:
        """The service's own options (besides the shared ones and ``--realtime-priority``)."""

    @classmethod
    def parser(cls) -> argparse.ArgumentParser:
        """The shared options, ``--realtime-priority`` and the service's own."""
        about = (sys.modules[cls.__module__].__doc__ or cls.SERVICE.value).splitlines()[0]  # the module's first line
        p = service_parser(cls.SERVICE, about)
        p.add_argument("--realtime-priority", type=int, default=cls.REALTIME_PRIORITY, metavar="N",
                       help=f"SCHED_FIFO priority of {cls.REALTIME_WHAT}, 1..99; 0 for normal "
                       f"scheduling (default: {cls.REALTIME_PRIORITY})")
        cls.add_arguments(p)
        return p

    def arms(self, arm: str, model: RobotModel, options: argparse.Namespace) -> list[tuple[str, RobotModel]]:
        """Every arm this process serves, ``arm`` first (the servo process may serve several)."""
        return [(arm, model)]

    @abc.abstractmethod
    def start(self, ctx: ServiceContext) -> None:
        """Declare the service's parts on ``ctx``; an exception fails the start."""

    def before_session(self, model: RobotModel, options: argparse.Namespace) -> None:
        """Before the session opens: start child processes here (spawned, never forked after a
        session is open)."""

    def after_session(self) -> None:
        """Once the session is closed (e.g. end the child processes)."""


@contextlib.contextmanager
def _session(conf: zenoh.Config, arms: Sequence[str], service: Service) -> Iterator[zenoh.Session]:
    """An open session whose log records also go to ``JARA_ARM/<arm>/log/<service>`` (or to
    the key of the arm a record names, for a process that serves several)."""
    with zenoh.open(conf) as session:
        handler = ZenohLogHandler(session, ArmKeys(arms[0]), service, tuple(ArmKeys(a) for a in arms))
        logging.getLogger().addHandler(handler)
        try:
            yield session
        finally:
            logging.getLogger().removeHandler(handler)
            handler.close()


def _announce(session: zenoh.Session, keys: ArmKeys, service: Service) -> zenoh.LivelinessToken:
    """Declare the liveliness token: a token up means the service answers queries."""
    return session.liveliness().declare_token(keys.alive(service))


def _depart(stop: threading.Event, heartbeat: Heartbeat, token: zenoh.LivelinessToken) -> None:
    """Delete the token; first, if ``stop`` was asked for (not a failure), say so in a last
    heartbeat, so that the watchers see a departure, not a loss."""
    if stop.is_set():
        heartbeat.leave()
    token.undeclare()


def stop_event(exit_with_parent: bool = False) -> threading.Event:
    """An event set by SIGINT/SIGTERM (logged; see :class:`StopSignals`), and by the parent's death if asked."""
    signals = StopSignals(lambda name: log.info("received %s, shutting down", name))
    if exit_with_parent:
        signals.exit_with_parent(lambda parent: log.warning("launcher (pid %d) is gone, shutting down", parent))
    return signals.stop


_SHARED = {"arm", "robot", "log_level", "exit_with_parent", "mode", "listen", "connect", "config",
           "multicast", "secure", "identity", "timing", "hung_after", "realtime_priority"}


def run(service: ArmService, argv: Sequence[str] | None = None) -> int:
    """Run ``service`` as a process (see the module docstring); returns the exit code."""
    cls = type(service)
    parser = cls.parser()
    args = parser.parse_args(argv)
    setup_stderr(args.log_level)
    try:
        check_arm(args.arm)
        model: RobotModel = robot(args.robot)
        conf = config_from_args(args)
        health = health_from_args(args)
        options = argparse.Namespace(**{k: v for k, v in vars(args).items() if k not in _SHARED})
        arms = service.arms(args.arm, model, options)
    except (JaraArmError, zenoh.ZError, OSError, ValueError) as exc:
        parser.error(str(exc))
    stop = stop_event(args.exit_with_parent)
    name = cls.SERVICE.value
    try:
        service.before_session(model, options)
        _serve(service, conf, arms, health, stop, options, args.realtime_priority)
    except Exception:
        log.exception("%s (%s) failed", name, args.arm)
        return 1
    finally:
        service.after_session()
    return 0


#: A service that has not finished starting (session opened, parts declared, tokens declared, up lines
#: said) this long after it began dumps every thread's stack to stderr (Python's ``faulthandler``: from a
#: C thread, so also while a thread holds the GIL) [s]. A servo serving two arms once never declared its tokens beside a busy loop
#: per core, and said nothing more; the launcher shows a child's last lines when it is not ready
#: (``jara-arm up``), so the dump names where it hangs. A start takes 2-7 s here beside busy loops.
START_STUCK_AFTER = 20.0


def _serve(service: ArmService, conf: zenoh.Config, arms: Sequence[tuple[str, RobotModel]], health: Health,
           stop: threading.Event, options: argparse.Namespace, priority: int) -> None:
    kind = type(service).SERVICE
    servers: list[QueryServer] = []
    # Again every START_STUCK_AFTER while stuck: the last lines a launcher keeps show where it is now.
    faulthandler.dump_traceback_later(START_STUCK_AFTER, repeat=True)  # cancelled once up, or by a failed start
    with _session(conf, [a for a, _ in arms], kind) as session:
        with contextlib.ExitStack() as stack:
            stack.callback(faulthandler.cancel_dump_traceback_later)  # also on a failed start
            ctx = ServiceContext(session, arms, health, stop, options, priority, kind, stack)
            for heartbeat in ctx.heartbeats.values():
                stack.callback(heartbeat.close)  # also on a failed start
            servers = ctx._servers
            # Collected before the service starts its loops: a full collection here took 20-26 ms, and after
            # the start it held the servo's running clock that long (and said so, at every start).
            gc.collect()
            service.start(ctx)
            main_pulses: list[Pulse] = [h.pulse("the main loop") for h in ctx.heartbeats.values()]
            for heartbeat in ctx.heartbeats.values():
                heartbeat.start()
            # Every other thread just below the service's own real-time thread: Zenoh's carry
            # its samples, and a Python thread preempted while holding the GIL holds it back too.
            realtime_process(max(0, priority - 1), kind.value)
            # What was built so far lives as long as the process: out of the collector's sight,
            # a full collection scans only what the loops allocate, not PyBullet's or Pinocchio's modules.
            # Freezing scans nothing (the start's little garbage is frozen with the rest).
            gc.freeze()
            tokens: list[tuple[Heartbeat, zenoh.LivelinessToken]] = []
            try:
                for arm, _ in arms:
                    tokens.append((ctx.heartbeats[arm], _announce(session, ArmKeys(arm), kind)))
                for arm, line in ctx._up_lines:
                    log.info(line, extra={"arm": arm})
                faulthandler.cancel_dump_traceback_later()
                while not stop.wait(ctx._wait()):
                    for pulse in main_pulses:
                        pulse.beat()
                    ctx._check()
            finally:
                for heartbeat, token in tokens:
                    _depart(stop, heartbeat, token)
                for heartbeat in ctx.heartbeats.values():
                    heartbeat.close()
        log.info("%s down", kind.value)
    for server in servers:
        server.join()


def entry(service_class: type[ArmService]) -> Callable[[Sequence[str] | None], int]:
    """The ``run(argv)`` entry of a service module."""

    def _run(argv: Sequence[str] | None = None) -> int:
        return run(service_class(), argv)

    return _run


if __name__ == "__main__":  # pragma: no cover
    sys.exit("run a service with `jara-arm service NAME` or `python -m jara_arm.services.NAME`")
