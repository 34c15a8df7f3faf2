"""``jara-arm up``: every service of every arm, on a private cell bus, behind a client gateway, on this host.

Topology (launcher/up/gateway.py): the launcher process is the **cell bus**, a Zenoh router on a
private endpoint (a Unix socket only this user can open) that every service process joins as a
client. A **client gateway**, a router process of its own,
listens on the given endpoints and joins the bus: clients reach every service of every arm
through it, and no client shares a dispatch queue with the services' own traffic. The launcher
prints the services' logs (received over the bus), one ready line once every liveliness token is
up and the gateway has joined, restarts crashed processes with backoff, and stops them all, in
reverse start order, on SIGINT/SIGTERM.
"""

from __future__ import annotations

import argparse
import dataclasses
import logging
import os
import subprocess
import sys
import time
from collections.abc import Callable, Sequence

from jara_arm.robots import DEFAULT_ROBOT, ROBOTS, Obstacle, RobotModelError
from jara_arm.schema.keys import DEFAULT_ARM, ArmIdError, Service, any_arm_log, check_arm
from jara_arm.services.runtime.cell import SERVICE_IDENTITY
from jara_arm.services.runtime.realtime import realtime_process
from jara_arm.services.runtime.stop_signals import StopSignals
from jara_arm.services.runtime.timing import SAME_HOST, Health, add_health_arguments, health_argv, health_from_args

from ..command import Command, setup_logging
from ..ros2.bridge import add_ros_arguments
from ..tools.watch import LogPrinter
from .gateway import private_bus
from .router import (DEFAULT_LISTEN, Presence, RouterError, RouterSettings, add_router_options, local_endpoint,
                     open_router, router_settings, say)
from .services import NAMES, SERVICES, ServiceSpec
from .supervisor import Child, Supervisor

log = logging.getLogger("jara_arm.launcher")

#: Warn (and keep waiting) if the services are not all alive by then, and every as long again [s]; the
#: warning shows the last lines of each missing one (a service stuck in its start dumps its stacks there,
#: ``START_STUCK_AFTER``). Beside a busy loop per core the services were up 2-7 s after the launch.
READY_TIMEOUT = 30.0
#: Lines of a missing service's own output shown with that warning.
READY_TAIL_LINES = 30
POLL_PERIOD = 0.1  #: main loop period: children, logs, liveliness [s]


@dataclasses.dataclass(frozen=True)
class ArmSpec:
    arm: str
    robot: str


@dataclasses.dataclass(frozen=True)
class UpSettings:
    arms: tuple[ArmSpec, ...]
    router: RouterSettings
    log_level: str = "INFO"
    #: ``x,y,z,hx,hy,hz`` [m]: boxes of the world, given as --obstacle to every servo (simulated) and every
    #: planner (kept clear of): one list for both
    obstacles: tuple[str, ...] = ()
    #: boxes in the servos' simulated world only, which the planners do not know of (an unmodelled obstacle)
    hidden_obstacles: tuple[str, ...] = ()
    demo: bool = False  # once ready, run ``jara-arm demo`` on every arm (its output on stdout)
    health: Health = SAME_HOST  # passed to every service (--timing, --hung-after)
    #: more endpoints of the cell bus (``--bus-listen``), for services of other hosts; the private one is always there
    bus: tuple[str, ...] = ()
    #: where each arm's program file is (``<dir>/<arm>.program.yaml``, what Ext/teach writes); "": the working directory
    program_dir: str = ""
    #: ``jara-arm ros2`` as a child of the launcher, with these arguments (``--ros-domain`` ...); None: not run
    ros2: tuple[str, ...] | None = None


#: SCHED_FIFO priority of the cell bus's threads: below the servo (40). The client gateway runs at
#: normal priority: its work is what clients ask for, without bound.
ROUTER_RT_PRIORITY = 35
GATEWAY_LABEL = "client gateway"
ROS2_LABEL = "ros2 bridge"


def demo_argv(arm: ArmSpec, settings: UpSettings) -> list[str]:
    """``jara-arm demo`` for one arm, a client of the launcher's router."""
    return [sys.executable, "-m", "jara_arm.launcher", "demo", "--arm", arm.arm,
            "--connect", local_endpoint(settings.router.endpoints()[0]), *secure_argv(settings)]


def ros2_child(settings: UpSettings) -> Child:
    """``jara-arm ros2`` (``--ros2``): a client of the gateway, as any ROS 2 tool; restarted if it dies."""
    assert settings.ros2 is not None
    argv = [sys.executable, "-m", "jara_arm.launcher", "ros2", *settings.ros2,
            "--connect", local_endpoint(settings.router.endpoints()[0])]
    return Child(ROS2_LABEL, argv, echo=lambda line: print(line, file=sys.stderr, flush=True))


def secure_argv(settings: UpSettings) -> list[str]:
    """What a process the launcher starts presents in a secure cell: the ``service`` certificate."""
    if not settings.router.secure:
        return []
    return ["--secure", os.path.abspath(settings.router.secure), "--identity", SERVICE_IDENTITY]


def gateway_settings(settings: UpSettings, bus: str) -> RouterSettings:
    """The client gateway: listening where ``up`` was told to, joined to the bus at ``bus``."""
    r = settings.router
    return RouterSettings(r.endpoints(), (bus,), r.config, r.multicast, r.secure, r.identity, gateway=True)


def gateway_child(settings: UpSettings, bus: str) -> Child:
    """``jara-arm router --gateway`` as a child process of the launcher."""
    g = gateway_settings(settings, bus)
    argv = [sys.executable, "-m", "jara_arm.launcher", "router", "--gateway", "--exit-with-parent",
            "--log-level", settings.log_level, "--connect", bus, *[a for e in g.listen for a in ("--listen", e)]]
    if g.config:
        argv += ["--config", os.path.abspath(g.config)]
    if g.secure:
        argv += ["--secure", os.path.abspath(g.secure), "--identity", g.identity]
    return Child(GATEWAY_LABEL, argv, echo=_echo_gateway)


def _echo_gateway(line: str) -> None:
    """The gateway's warnings, errors and refusals on the launcher's stderr; not its ready line (not the
    cell's) nor its INFO lines (the services it sees join and leave, which the launcher says too)."""
    if (" WARNING " in line or " ERROR " in line) and "the cell is OPEN" not in line:  # not its usage text
        print(line, file=sys.stderr, flush=True)


def bus_secure(settings: UpSettings) -> bool:
    """Whether the cell bus itself runs the secure cell's TLS and roles: only when it is opened to other
    hosts (``--bus-listen``). On its private socket alone it needs neither (the socket's directory lets
    only the cell's OS user in), and access control on every message of every service cost the
    real-time bus enough CPU to starve the services beside a TLS observer (measured with the planner's
    former position stream)."""
    return bool(settings.router.secure and settings.bus)


def bus_settings(settings: UpSettings, bus: str) -> RouterSettings:
    """The launcher's own router: the cell bus, on ``bus`` and any further ``--bus-listen`` endpoints."""
    r = settings.router
    return dataclasses.replace(r, listen=(bus, *settings.bus), bus=True,
                               secure=r.secure if bus_secure(settings) else None)


def child_argv(service: ServiceSpec, arm: ArmSpec, settings: UpSettings, bus: str) -> list[str]:
    """The command line of one service process: a client of the cell bus at ``bus``."""
    argv = [sys.executable, "-m", service.module, "--arm", arm.arm, "--robot", arm.robot,
            "--mode", "client", "--connect", bus,
            "--exit-with-parent", "--log-level", settings.log_level, *health_argv(settings.health)]
    if settings.router.config:
        argv += ["--config", os.path.abspath(settings.router.config)]
    if bus_secure(settings):
        argv += secure_argv(settings)
    if service.service in (Service.SERVO, Service.PLANNER):
        for box in settings.obstacles:
            argv += ["--obstacle", box]
    if service.service is Service.SERVO:
        for box in settings.hidden_obstacles:
            argv += ["--obstacle", box]
    if service.service is Service.COMMAND and settings.program_dir:
        argv += ["--program", os.path.join(os.path.abspath(settings.program_dir), f"{arm.arm}.program.yaml")]
    return argv


def label(service: str, arm: str) -> str:
    return f"{service} ({arm})"


def children(service: ServiceSpec, settings: UpSettings, bus: str) -> list[Child]:
    """The processes of ``service``: one per arm, but one servo for every arm.

    One servo process runs the cycles of every arm on one real-time thread:
    a 1 kHz Python loop costs mostly its wake-ups, so N arms on one thread cost
    a fraction of N threads (docs/decisions.md, "Process layout"). The
    price: a servo process that crashes takes every arm's servo with it (each
    arm then raises 0x400, and the launcher restarts the process).
    """
    arms = settings.arms
    if service.service is Service.SERVO and len(arms) > 1:
        argv = child_argv(service, arms[0], settings, bus)
        for a in arms[1:]:
            argv += ["--with-arm", f"{a.arm}:{a.robot}"]
        return [Child(label(service.name, ",".join(a.arm for a in arms)), argv)]
    return [Child(label(service.name, a.arm), child_argv(service, a, settings, bus)) for a in arms]


def output_of(supervisor: Supervisor, arm: str, service: str) -> list[str]:
    """The last lines the process of ``service`` for ``arm`` printed (one servo serves every arm; ``arm``
    "" for the gateway)."""
    for child in supervisor.children:  # labels are label(service, "a1,a2") or the gateway's own
        name, _, arms = child.label.partition(" (")
        if name == service and (not arm or arm in arms.rstrip(")").split(",")):
            return list(child.tail)
    return []


class Readiness:
    """Prints the one ready line once every expected service is alive; warns while not."""

    def __init__(self, settings: UpSettings, presence: Presence, gateway_joined: Callable[[], bool],
                 output: Callable[[str, str], Sequence[str]] = lambda arm, service: ()) -> None:
        """``output(arm, service)``: the last lines that service's process printed (``arm`` "" for the gateway)."""
        self.presence = presence
        self.gateway_joined = gateway_joined
        self.output = output
        self.expected = [(a.arm, s.name) for a in settings.arms for s in SERVICES]
        self.ready = False
        arms = "; ".join(f"{a.arm} ({a.robot}): {', '.join(s.name for s in SERVICES)}"
                         for a in settings.arms)
        self.line = f"jara-arm: ready: {arms}; listening on {', '.join(settings.router.endpoints())}"
        self._began = time.monotonic()
        self._warn_at = self._began + READY_TIMEOUT

    def missing(self) -> list[tuple[str, str]]:
        """``(arm, service)`` not alive yet; ``("", "client gateway")`` while the gateway has not joined."""
        missing = [k for k in self.expected if k not in self.presence.alive]
        return missing if self.ready or self.gateway_joined() else [*missing, ("", GATEWAY_LABEL)]

    def poll(self) -> None:
        expected = set(self.expected)
        for up, arm, service in self.presence.drain():
            if (arm, service) not in expected:
                continue
            if not self.ready:
                log.debug("%s is alive", label(service, arm))
            elif up:
                log.info("%s is alive again", label(service, arm))
            else:
                log.warning("%s is no longer alive", label(service, arm))
        missing = self.missing()
        if not missing and not self.ready:
            self.ready = True
            say(self.line)
        elif missing and not self.ready and time.monotonic() >= self._warn_at:
            self._warn_at += READY_TIMEOUT
            log.warning("not ready after %.0f s; still waiting for %s", time.monotonic() - self._began,
                        ", ".join(label(s, a) if a else s for a, s in missing))
            for arm, service in missing:
                lines = list(self.output(arm, service))[-READY_TAIL_LINES:]
                if lines:
                    name = label(service, arm) if arm else service
                    log.warning("the last lines of %s:\n%s", name, "\n".join(f"  {name} | {x}" for x in lines))


#: How long the launcher waits for the gateway to join the bus before it starts the services anyway [s]
#: (the ready line still waits for it).
GATEWAY_JOIN_TIMEOUT = 30.0


def await_gateway(gateway: Child, joined: Callable[[], bool], signals: StopSignals) -> None:
    """Until the gateway has joined the bus; RouterError with its own words if it exits first."""
    deadline = time.monotonic() + GATEWAY_JOIN_TIMEOUT
    while not joined() and not signals.stop.wait(0.02):
        if gateway.popen is None or gateway.popen.poll() is not None:
            if gateway.popen is not None:
                gateway.popen.wait()
            time.sleep(0.2)  # its last lines reach the tail
            said = [line for line in gateway.tail if "error" in line.lower() or "cannot" in line]
            raise RouterError(said[-1].split("error: ", 1)[-1] if said else
                              f"the client gateway exited at start: {' / '.join(gateway.tail)}")
        if time.monotonic() > deadline:
            log.warning("the client gateway has not joined the cell bus after %.0f s; starting the services",
                        GATEWAY_JOIN_TIMEOUT)
            return


def start_order() -> list[ServiceSpec]:
    """The alarm monitor first, so that it stops last (the layers stop in reverse order): it
    sees every other service leave, and no servo sees the monitor go while it runs."""
    return sorted(SERVICES, key=lambda s: s.name != Service.ALARM_MONITOR.value)


def run_up(settings: UpSettings, signals: StopSignals) -> int:
    """Run until ``signals.stop``; 0 once every child is stopped. RouterError if the router cannot open."""
    settings.router.config_object()  # RouterError (a usage error) for endpoints or a config the gateway cannot take
    with private_bus() as bus, open_router(cell_bus := bus_settings(settings, bus)) as session:
        # The bus carries the heartbeats, the alarm reports and the hand-overs: starved by
        # normal-priority work, it would make live services look hung.
        realtime_process(ROUTER_RT_PRIORITY, "router", skip_caller=True)
        gateway = gateway_settings(settings, bus)
        gateway.announce()  # how open the cell is, said here: the gateway's own saying is not echoed
        logs = LogPrinter(session, any_arm_log())
        presence = Presence(session)

        def gateway_joined() -> bool:  # evidence, not a token: its link to the bus is up
            return gateway.gateway_ids[0] in {str(z) for z in session.info.routers_zid()}

        # The gateway first, so that it stops last: clients see the services leave.
        # The ROS 2 bridge last, so that it stops first: a client of the gateway as any other.
        supervisor = Supervisor([[gateway_child(settings, bus)], *[children(s, settings, bus) for s in start_order()],
                                 *([[ros2_child(settings)]] if settings.ros2 is not None else [])])
        readiness = Readiness(settings, presence, gateway_joined, lambda arm, service: output_of(supervisor, arm, service))
        log.info("cell bus on %s; client gateway on %s; starting %d process(es)", ", ".join(cell_bus.endpoints()),
                 ", ".join(gateway.endpoints()), len(supervisor.children))
        demos: list[subprocess.Popen] = []
        try:
            if not signals.stop.is_set():  # a Ctrl-C while the router opened
                # The gateway alone first: a client endpoint it cannot open (a port in use) is an error
                # of the command line, said before any service starts.
                gw = supervisor.layers[0][0]
                gw.start()
                await_gateway(gw, gateway_joined, signals)
            if not signals.stop.is_set():
                supervisor.start(first_layer=1)
            while not signals.stop.wait(POLL_PERIOD):
                logs.drain()
                readiness.poll()
                supervisor.poll()
                if settings.demo and readiness.ready and not demos:
                    # Onto sys.stdout, not fd 1: a secure router sends fd 1 through its refusal filter.
                    demos = [subprocess.Popen(demo_argv(a, settings), stdout=sys.stdout) for a in settings.arms]
            log.info("%s: stopping", signals.name)
        finally:
            for d in demos:
                if d.poll() is None:
                    d.terminate()
                d.wait(5)
            # Also on an unexpected error: never leave a child behind.
            supervisor.stop(idle=logs.drain, hurry=signals.hurry)
            logs.drain()
            logs.close()
            presence.close()
    log.info("stopped")
    return 0


def _obstacle(text: str) -> str:
    """``--obstacle`` and ``--hidden-obstacle``: checked here, passed on to the services as written."""
    try:
        return Obstacle.parse(text).argument()
    except RobotModelError as exc:
        raise argparse.ArgumentTypeError(str(exc)) from None


def _arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--arm", action="append", default=[], metavar="ID[:ROBOT]",
                        help=f"an arm to run, optionally with its own robot model "
                        f"(repeatable; default: {DEFAULT_ARM})")
    parser.add_argument("--robot", default=DEFAULT_ROBOT, choices=list(ROBOTS),
                        help=f"robot model of the arms given without one (default: {DEFAULT_ROBOT})")
    parser.add_argument("--demo", action="store_true",
                        help="once ready, drive every arm through `jara-arm demo`")
    parser.add_argument("--obstacle", action="append", default=[], type=_obstacle,
                        metavar="X,Y,Z,HX,HY,HZ",
                        help="a fixed box in every arm's simulated world, which every motion keeps "
                        "clear of: centre and half extents [m] (repeatable)")
    parser.add_argument("--hidden-obstacle", action="append", default=[], type=_obstacle,
                        metavar="X,Y,Z,HX,HY,HZ",
                        help="a box in the simulated world that the planners are not told of (an "
                        "unmodelled obstacle, as for the overload alarm): centre and half extents [m] "
                        "(repeatable)")
    parser.add_argument("--program-dir", default="", metavar="DIR",
                        help="where each arm's program file is, DIR/<arm>.program.yaml: Ext/teach stores its "
                        "points there (default: the working directory)")
    parser.add_argument("--ros2", action="store_true",
                        help="also run `jara-arm ros2`: every arm as ROS 2 topics for nodes on rmw_zenoh")
    parser.add_argument("--ros-identity", default="", metavar="NAME",
                        help="with --ros2 in a secure cell: the cell identity the bridge presents (an observer "
                        "is enough: it only reads the arms)")
    add_ros_arguments(parser)
    parser.add_argument("--bus-listen", action="append", default=[], metavar="ENDPOINT",
                        help="also open the cell bus (where the services meet; private by default) on "
                        "ENDPOINT, for services of other hosts; clients use --listen (repeatable)")
    add_router_options(parser)
    add_health_arguments(parser)


def _settings(args: argparse.Namespace, parser: argparse.ArgumentParser) -> UpSettings:
    """Check what argparse cannot: arm ids, per-arm robots, duplicates (exit 2 if wrong)."""
    arms: list[ArmSpec] = []
    for item in args.arm or [DEFAULT_ARM]:
        arm, sep, robot = item.partition(":")
        robot = robot if sep else args.robot
        try:
            check_arm(arm)
        except ArmIdError as exc:
            parser.error(f"--arm {item}: {exc}")
        if robot not in ROBOTS:
            parser.error(f"--arm {item}: unknown robot {robot!r} (choose from {', '.join(ROBOTS)})")
        if any(a.arm == arm for a in arms):
            parser.error(f"--arm {item}: arm {arm!r} is given twice")
        arms.append(ArmSpec(arm, robot))
    router = router_settings(args, parser)
    ros2: tuple[str, ...] | None = None
    if args.ros2:
        ros2 = ("--ros-domain", str(args.ros_domain), "--ros-rate", str(args.ros_rate),
                *(("--ros-namespace", args.ros_namespace, "--arm", arms[0].arm) if args.ros_namespace else ()))
        if args.ros_namespace and len(arms) != 1:
            parser.error("--ros-namespace names one arm's node: it takes exactly one arm")
        if router.secure:
            if not args.ros_identity:
                parser.error("--ros2 in a secure cell: --ros-identity NAME, the cell identity the bridge presents "
                             "(`jara-arm certs issue DIR NAME --role observer`)")
            ros2 += ("--secure", os.path.abspath(router.secure), "--identity", args.ros_identity)
    elif args.ros_identity:
        parser.error("--ros-identity is for --ros2")
    return UpSettings(tuple(arms), router, args.log_level, tuple(args.obstacle),
                      tuple(args.hidden_obstacle), args.demo, health_from_args(args), tuple(args.bus_listen),
                      args.program_dir, ros2)


def _run(args: argparse.Namespace, parser: argparse.ArgumentParser) -> int:
    settings = _settings(args, parser)
    setup_logging(args.log_level)
    signals = StopSignals()  # before any child exists: a signal must never orphan one
    try:
        return run_up(settings, signals)
    except RouterError as exc:
        parser.error(str(exc))


COMMAND = Command(
    "up", arguments=_arguments, run=_run,
    help="run every service of every arm behind one Zenoh router",
    description="Open a Zenoh router on the --listen endpoints (default "
    f"{DEFAULT_LISTEN}) and run every service of every arm as a process of its own "
    f"that joins it. Services: {', '.join(NAMES)}.")
