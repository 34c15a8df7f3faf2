"""The skeleton every service shares: arguments, session, logging, liveliness, shutdown.

Each service module defines ``main(conf, arm, robot, stop, health, **options)`` that
opens its session with :func:`service_session` and runs until ``stop`` is set,
and a ``run(argv)`` entry built with :func:`run_service`.
"""

from __future__ import annotations

import argparse
import contextlib
import gc
import logging
import os
import signal
import sys
import threading
from collections.abc import Callable, Iterator, Sequence

import zenoh

from jara_arm.robots import DEFAULT_ROBOT, ROBOTS, RobotModel, robot
from jara_arm.schema.errors import JaraArmError
from jara_arm.schema.keys import DEFAULT_ARM, ArmKeys, Service, check_arm

from .heartbeat import Heartbeat
from .logs import ZenohLogHandler, setup_stderr
from .timing import add_health_arguments, health_from_args
from .zenoh_args import add_zenoh_arguments, config_from_args

log = logging.getLogger(__name__)

ServiceMain = Callable[..., None]


def service_parser(service: Service, description: str) -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(prog=f"jara-arm service {service.value}", description=description)
    p.add_argument("--arm", default=DEFAULT_ARM, help=f"arm id (default: {DEFAULT_ARM})")
    p.add_argument("--robot", default=DEFAULT_ROBOT, choices=list(ROBOTS),
                   help=f"robot model (default: {DEFAULT_ROBOT})")
    p.add_argument("--log-level", default="INFO",
                   choices=["DEBUG", "INFO", "WARNING", "ERROR"], help="default: INFO")
    p.add_argument("--exit-with-parent", action="store_true",
                   help="exit when the launching process dies (set by the launcher)")
    add_zenoh_arguments(p)
    add_health_arguments(p)
    return p


@contextlib.contextmanager
def service_session(conf: zenoh.Config, arm: str, service: Service,
                    also: tuple[str, ...] = ()) -> Iterator[tuple[zenoh.Session, ArmKeys]]:
    """An open session whose log records also go to ``JARA_ARM/<arm>/log/<service>`` (or to
    the key of one of the ``also`` arms, for records that name it).

    The caller declares its queryables inside the block, then :func:`announce`
    the liveliness token, so that a token up means the service answers.
    """
    keys = ArmKeys(arm)
    with zenoh.open(conf) as session:
        handler = ZenohLogHandler(session, keys, service, tuple(ArmKeys(a) for a in also))
        logging.getLogger().addHandler(handler)
        try:
            yield session, keys
        finally:
            logging.getLogger().removeHandler(handler)
            handler.close()


def announce(session: zenoh.Session, keys: ArmKeys, service: Service) -> zenoh.LivelinessToken:
    """Declare the liveliness token: call it once the service answers queries.

    Everything set up so far (modules, models, worlds) lives as long as the
    process: it is moved out of the garbage collector's sight, so that a full
    collection scans only what the service's loops allocate, not PyBullet's or
    Pinocchio's modules as well.
    """
    gc.collect()
    gc.freeze()
    return session.liveliness().declare_token(keys.alive(service))


def depart(stop: threading.Event, heartbeat: Heartbeat, token: zenoh.LivelinessToken) -> None:
    """Delete the token; first, if ``stop`` was asked for (not a failure), say so in a last
    heartbeat, so that the watchers see a departure, not a loss."""
    if stop.is_set():
        heartbeat.leave()
    token.undeclare()


def stop_event(exit_with_parent: bool = False) -> threading.Event:
    """An event set by SIGINT/SIGTERM (and by the parent's death, if asked)."""
    stop = threading.Event()

    def _handle(signum: int, _frame: object) -> None:
        log.info("received %s, shutting down", signal.Signals(signum).name)
        stop.set()

    signal.signal(signal.SIGINT, _handle)
    signal.signal(signal.SIGTERM, _handle)
    if exit_with_parent:
        parent = os.getppid()

        def _watch() -> None:
            while not stop.wait(0.5):
                if os.getppid() != parent:
                    log.warning("launcher (pid %d) is gone, shutting down", parent)
                    stop.set()

        threading.Thread(target=_watch, name="parent-watch", daemon=True).start()
    return stop


def run_service(service: Service, description: str, main: ServiceMain,
                argv: Sequence[str] | None = None,
                extend: Callable[[argparse.ArgumentParser], None] | None = None) -> int:
    """Parse the shared arguments (plus the service's own, via ``extend``) and run ``main``."""
    parser = service_parser(service, description)
    if extend:
        extend(parser)
    args = parser.parse_args(argv)
    setup_stderr(args.log_level)
    try:
        check_arm(args.arm)
        model: RobotModel = robot(args.robot)
        conf = config_from_args(args)
        health = health_from_args(args)
    except (JaraArmError, zenoh.ZError, OSError, ValueError) as exc:
        parser.error(str(exc))
    stop = stop_event(args.exit_with_parent)
    extra = {k: v for k, v in vars(args).items() if k not in _SHARED}
    try:
        main(conf, args.arm, model, stop, health=health, **extra)
    except Exception:
        log.exception("%s (%s) failed", service.value, args.arm)
        return 1
    return 0


_SHARED = {"arm", "robot", "log_level", "exit_with_parent", "mode", "listen", "connect", "config",
           "multicast", "timing", "hung_after"}


if __name__ == "__main__":  # pragma: no cover
    sys.exit("run a service with `jara-arm service NAME` or `python -m jara_arm.services.NAME`")
