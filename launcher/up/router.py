"""The launcher's Zenoh router session, shared by ``jara-arm up`` and ``jara-arm router``, and the
``router`` command.

Clients and peers that connect to any of its listen endpoints reach every
service that joined through it: the router routes between its clients.
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import logging
import re
import sys

import zenoh

from jara_arm.schema.errors import JaraArmError
from jara_arm.schema.keys import any_arm_alive, parse_alive
from jara_arm.services.runtime.cell import ROUTER_IDENTITY, CellError
from jara_arm.services.runtime.stop_signals import StopSignals
from jara_arm.services.runtime.zenoh_args import add_zenoh_arguments, default_endpoint, zenoh_config

from ..command import Command, setup_logging
from ..secure.refusals import RefusalLog
from .gateway import GATEWAY_ZID, FeedbackRelay, bus_config, gateway_config

log = logging.getLogger("jara_arm.launcher")

DEFAULT_LISTEN = default_endpoint(None)
LOG_LEVELS = ("DEBUG", "INFO", "WARNING", "ERROR")  #: ``--log-level`` of ``up`` and ``router``
_RUST_LOCATION = re.compile(r"\s+at \S+\.rs:\d+\.?")
_JSON5_MESSAGE = re.compile(r'msg: "(.*?)", location')
#: Unspecified addresses a router may listen on, and what a local process connects to instead.
_UNSPECIFIED = {"0.0.0.0": "127.0.0.1", "[::]": "[::1]"}


class RouterError(JaraArmError):
    """The router session could not be opened (bad endpoint, port in use, bad config file)."""


def zerror_text(exc: BaseException) -> str:
    """A Zenoh error without the Rust source locations and debug wrapping it carries."""
    text = _RUST_LOCATION.sub("", str(exc)).strip()
    wrapped = _JSON5_MESSAGE.search(text)  # Json5Err(Message { msg: "...", location: ... })
    return wrapped.group(1) if wrapped else text


@dataclasses.dataclass(frozen=True)
class RouterSettings:
    """The Zenoh options of ``up`` and ``router`` (the mode is always ``router``)."""

    listen: tuple[str, ...] = ()
    connect: tuple[str, ...] = ()
    config: str | None = None
    multicast: bool = False
    secure: str | None = None  #: the cell directory (``--secure``); None: an open cell
    identity: str = ROUTER_IDENTITY
    #: a client gateway (``--gateway``): best effort to every client, never waiting on one (launcher/up/gateway.py)
    gateway: bool = False
    #: a router of the cell bus (``--bus``): its blocking publications reach the gateways as best effort
    bus: bool = False
    #: the Zenoh id of the gateway (``gateway``), or of the gateways the bus knows (``bus``)
    gateway_ids: tuple[str, ...] = (GATEWAY_ZID,)

    def endpoints(self) -> tuple[str, ...]:
        """The endpoints to listen on: ``--listen``, else the config file's, else the default."""
        if self.listen:
            return self.listen
        if self.config:
            try:
                listen = json.loads(zenoh.Config.from_file(self.config).get_json("listen/endpoints"))
            except (zenoh.ZError, ValueError) as exc:
                raise RouterError(f"cannot read Zenoh config {self.config}: {zerror_text(exc)}") from exc
            if isinstance(listen, list) and listen:  # not the per-mode default map
                return tuple(str(e) for e in listen)
        return (default_endpoint(self.secure),)

    def config_object(self) -> zenoh.Config:
        try:
            conf = zenoh_config("router", self.endpoints(), self.connect, self.config, self.multicast,
                                self.secure, self.identity)
            if self.gateway:
                gateway_config(conf, self.gateway_ids[0])
            if self.bus:
                bus_config(conf, self.gateway_ids)
            return conf
        except zenoh.ZError as exc:
            raise RouterError(f"bad Zenoh settings: {zerror_text(exc)}") from exc
        except CellError as exc:
            raise RouterError(str(exc)) from exc

    def announce(self) -> None:
        """Say at start how open the cell is: an open one lets anyone who reaches it move the arm."""
        if self.bus and not self.gateway and all(e.startswith("unixsock-stream/") for e in self.endpoints()):
            return  # the launcher's private bus: no client reaches it
        if self.secure:
            log.info("secure cell %s: mutual TLS as %r; roles enforced on every link", self.secure, self.identity)
        else:
            log.warning("the cell is OPEN: anyone who reaches %s can move the arms (no authentication, no "
                        "access control); `jara-arm certs init DIR` and --secure DIR close it",
                        ", ".join(self.endpoints()))


def open_router(settings: RouterSettings) -> zenoh.Session:
    """Open the router session (RouterError, readable, if it cannot); a secure one logs its refusals."""
    conf = settings.config_object()
    settings.announce()
    if settings.secure:
        RefusalLog().start()
    try:
        return zenoh.open(conf)
    except zenoh.ZError as exc:
        raise RouterError(f"cannot open the Zenoh router on {', '.join(settings.endpoints())}: "
                          f"{zerror_text(exc)}") from exc


def local_endpoint(endpoint: str) -> str:
    """The endpoint a process on this host connects to, for a router listening on ``endpoint``."""
    for unspecified, loopback in _UNSPECIFIED.items():
        proto, sep, rest = endpoint.partition("/")
        if sep and rest.startswith(unspecified + ":"):
            return f"{proto}/{loopback}{rest[len(unspecified):]}"
    return endpoint


class Presence:
    """Which ``(arm, service)`` liveliness tokens are up, from a liveliness subscriber."""

    def __init__(self, session: zenoh.Session, capacity: int = 1024) -> None:
        self.alive: set[tuple[str, str]] = set()
        # history=True: tokens declared before this subscriber are reported too.
        self._sub = session.liveliness().declare_subscriber(
            any_arm_alive(), zenoh.handlers.FifoChannel(capacity), history=True)

    def drain(self) -> list[tuple[bool, str, str]]:
        """The changes since the last call: ``(up, arm, service)``, in order."""
        changes: list[tuple[bool, str, str]] = []
        while (sample := self._sub.try_recv()) is not None:
            try:
                arm, service = parse_alive(str(sample.key_expr))
            except JaraArmError:
                continue  # someone else's token under our prefix
            up = sample.kind == zenoh.SampleKind.PUT
            if up != ((arm, service) in self.alive):
                (self.alive.add if up else self.alive.discard)((arm, service))
                changes.append((up, arm, service))
        return changes

    def close(self) -> None:
        self._sub.undeclare()


def say(line: str) -> None:
    """One line on stdout, flushed; a closed stdout (``| head``) is not an error."""
    try:
        print(line, flush=True)
    except (BrokenPipeError, ValueError):
        pass


def run_router(settings: RouterSettings, signals: StopSignals) -> int:
    """``jara-arm router``: route until SIGINT/SIGTERM, reporting services that join or leave."""
    with open_router(settings) as session:
        presence = Presence(session)
        relay = FeedbackRelay(session) if settings.gateway else None
        say(f"jara-arm: ready: router; listening on {', '.join(settings.endpoints())}")
        while not signals.stop.wait(0.1):
            for up, arm, service in presence.drain():
                log.info("%s (%s) %s", service, arm, "joined" if up else "left")
        log.info("%s: stopping", signals.name)
        if relay is not None:
            relay.close()
        presence.close()
    log.info("router stopped")
    sys.stdout.flush()
    return 0


def add_router_options(parser: argparse.ArgumentParser) -> None:
    """``--log-level``, and the shared Zenoh options with the mode fixed to router (so --mode is hidden)."""
    parser.add_argument("--log-level", type=str.upper, default="INFO", choices=LOG_LEVELS,
                        help="default: INFO")
    add_zenoh_arguments(parser, default_mode="router", default_identity=ROUTER_IDENTITY, fixed_mode=True)


def router_settings(args: argparse.Namespace, parser: argparse.ArgumentParser) -> RouterSettings:
    """The router options of ``up`` or ``router``, checked (exit 2 if wrong), their listen endpoints resolved."""
    settings = RouterSettings(tuple(args.listen), tuple(args.connect), args.config, args.multicast,
                              args.secure, args.identity, gateway=getattr(args, "gateway", False),
                              bus=getattr(args, "bus", False),
                              gateway_ids=tuple(getattr(args, "gateway_id", None) or (GATEWAY_ZID,)))
    for zid in settings.gateway_ids:
        if not re.fullmatch(r"[1-9a-f][0-9a-f]{0,31}", zid):
            parser.error(f"--gateway-id {zid!r}: a Zenoh id is 1 to 32 lowercase hex digits, not starting with 0")
    try:  # resolve the listen endpoints once (--listen, else the config file's, else the default)
        return dataclasses.replace(settings, listen=settings.endpoints())
    except RouterError as exc:
        parser.error(str(exc))


def _arguments(parser: argparse.ArgumentParser) -> None:
    role = parser.add_mutually_exclusive_group()
    role.add_argument("--gateway", action="store_true",
                      help="a client gateway: clients join it, it joins the cell bus (--connect); every "
                      "publication it forwards is best effort and it never waits on a client")
    role.add_argument("--bus", action="store_true",
                      help="a router of the cell bus, which only services and gateways join: its blocking "
                      "publications (low-level position commands) reach the gateways as best effort")
    parser.add_argument("--exit-with-parent", action="store_true",
                        help="exit when the launching process dies (set by `jara-arm up` for its gateway)")
    parser.add_argument("--gateway-id", action="append", default=[], metavar="HEX",
                        help=f"the gateway's Zenoh id (default: {GATEWAY_ZID}); with --bus, every "
                        "gateway's (repeatable)")
    add_router_options(parser)


def _run(args: argparse.Namespace, parser: argparse.ArgumentParser) -> int:
    settings = router_settings(args, parser)
    setup_logging(args.log_level)
    signals = StopSignals()
    if args.exit_with_parent:
        signals.exit_with_parent(lambda parent: log.warning("launcher (pid %d) is gone, stopping", parent))
    try:
        return run_router(settings, signals)
    except RouterError as exc:
        parser.error(str(exc))


COMMAND = Command(
    "router", arguments=_arguments, run=_run,
    help="run a plain Zenoh router that services and clients join",
    description=f"A Zenoh router (default listen endpoint {DEFAULT_LISTEN}) that runs "
    "until SIGINT/SIGTERM, reporting the services that join or leave.")
