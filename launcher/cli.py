"""``jara-arm``: run the arm services on this host, one of them, or a bare Zenoh router.

    jara-arm up [--arm ID[:ROBOT]]... [--robot NAME] [--demo] [--obstacle X,Y,Z,HX,HY,HZ]... [--hidden-obstacle ...]...
                [--listen ENDPOINT]... [--connect ENDPOINT]... [--config ZENOH_CONFIG_FILE] [--multicast]
                [--bus-listen ENDPOINT]... [--log-level LEVEL]
    jara-arm service NAME [the service's own arguments; see jara-arm service NAME --help]
    jara-arm router [--gateway | --bus] [--gateway-id HEX]... [--listen ENDPOINT]... [--connect ENDPOINT]...
                    [--config FILE] [--multicast]
    jara-arm logs [--arm ID] [--service NAME] [--level LEVEL] [Zenoh options]
    jara-arm alarms [--arm ID] [Zenoh options]
    jara-arm call [--arm ID] [--servo] [--timeout S] OP [JSON] [Zenoh options]
    jara-arm echo [--arm ID] [--rate HZ] [--once | --count N] [--timeout S] [--show-key] KEY [Zenoh options]
    jara-arm state [--arm ID] [--once] [--period S] [Zenoh options]
    jara-arm wait [--arm ID] [--timeout S] [--poll S] CONDITION [Zenoh options]
    jara-arm record [--arm ID]... -o FILE.mcap [--duration S] [Zenoh options]
    jara-arm replay FILE.mcap [--speed X] [--arm ID]... [Zenoh options]
    jara-arm plot [--arm ID] (--seconds S | --from FILE.mcap) [--start S] [--end S] [--robot NAME] -o FILE.png
                  [--path FILE.png] [--size WxH] [--no-show] [Zenoh options]
    jara-arm view [--arm ID]... [--host ADDRESS] [--port P] [--rate HZ] [Zenoh options]
    jara-arm certs init DIR [--days N] [--host H]...
    jara-arm certs issue DIR NAME --role ROLE [--host H]... [--days N] [--force]
    jara-arm certs list DIR
    jara-arm completion bash

``logs`` and ``alarms`` join any Zenoh network (by default as a client of
tcp/127.0.0.1:7447) and print what arrives until SIGINT/SIGTERM
(``launcher/tools/watch.py``); ``call``, ``echo``, ``state`` and ``wait`` join it
the same way (``launcher/tools/call.py``, ``echo.py``, ``state_view.py``,
``wait.py``), and ``plot`` too unless it reads a recording
(``launcher/record/plot.py``); ``view`` serves a web page with a live 3D view of
the arms (``launcher/view/view.py``). ``certs`` makes a secure cell's directory,
its certificate authority and the certificates of its identities, and lists them
(``launcher/secure/certs.py``). ``up``, ``service`` and ``router`` are in
``launcher/up/``.

A user mistake (unknown robot, bad arm id, a port already in use…) prints one
readable message and exits with status 2.
"""

from __future__ import annotations

import argparse
import dataclasses
import logging
import re
import sys
import time
from collections.abc import Sequence
from pathlib import Path

import zenoh

from jara_arm.client import Arm, ArmError
from jara_arm.robots import DEFAULT_ROBOT, ROBOTS, Obstacle, RobotModelError
from jara_arm.schema.keys import DEFAULT_ARM, ArmIdError, Service, check_arm
from jara_arm.schema.roles import Role
from jara_arm.services.runtime.arguments import non_negative_float, positive_float, positive_int
from jara_arm.services.runtime.cell import ROUTER_IDENTITY, CellError
from jara_arm.services.runtime.timing import add_health_arguments, health_from_args
from jara_arm.services.runtime.zenoh_args import add_zenoh_arguments, default_endpoint, zenoh_config

from .completion import SHELLS, bash_script
from .record.record import RecordSettings, lower_priority, run_record
from .record.recording import RecordingError, RecordingWriter
from .record.recording import info as recording_info
from .record.replay import ReplaySettings, plan, run_replay
from .secure import certs
from .stop_signals import StopSignals
from .tools.call import CallError, parse_call, run_call
from .tools.client import ArmClient, ClientError
from .tools.demo import run_demo
from .tools.echo import EchoKeyError, EchoSettings, echo_key, echo_keys, run_echo
from .tools.state_view import run_state
from .tools.wait import CONDITION_HELP, Condition, run_wait
from .tools.watch import LOG_LEVELS as RECORD_LEVELS
from .tools.watch import run_alarms, run_logs
from .up.gateway import GATEWAY_ZID
from .up.router import DEFAULT_LISTEN, RouterError, RouterSettings, run_router, zerror_text
from .up.services import NAMES, SERVICES, spec
from .up.up import ArmSpec, UpSettings, run_up
from .view.view import DEFAULT_HOST, DEFAULT_PORT, DEFAULT_RATE, ViewError, ViewSettings, run_view

LOG_LEVELS = ("DEBUG", "INFO", "WARNING", "ERROR")
USAGE_ERROR = 2


class _Parsers:
    """The top-level parser and its subcommand parsers, by name."""

    def __init__(self) -> None:
        self.top = argparse.ArgumentParser(
            prog="jara-arm", description="JARA_ARM robot-arm services over Zenoh.")
        sub = self.top.add_subparsers(dest="command", required=True, metavar="COMMAND")

        self.up = sub.add_parser(
            "up", help="run every service of every arm behind one Zenoh router",
            description="Open a Zenoh router on the --listen endpoints (default "
            f"{DEFAULT_LISTEN}) and run every service of every arm as a process of its own "
            f"that joins it. Services: {', '.join(NAMES)}.")
        self.up.add_argument("--arm", action="append", default=[], metavar="ID[:ROBOT]",
                             help=f"an arm to run, optionally with its own robot model "
                             f"(repeatable; default: {DEFAULT_ARM})")
        self.up.add_argument("--robot", default=DEFAULT_ROBOT, choices=list(ROBOTS),
                             help=f"robot model of the arms given without one (default: {DEFAULT_ROBOT})")
        self.up.add_argument("--demo", action="store_true",
                             help="once ready, drive every arm through `jara-arm demo`")
        self.up.add_argument("--obstacle", action="append", default=[], type=_obstacle,
                             metavar="X,Y,Z,HX,HY,HZ",
                             help="a fixed box in every arm's simulated world, which every motion keeps "
                             "clear of: centre and half extents [m] (repeatable)")
        self.up.add_argument("--hidden-obstacle", action="append", default=[], type=_obstacle,
                             metavar="X,Y,Z,HX,HY,HZ",
                             help="a box in the simulated world that the planners are not told of (an "
                             "unmodelled obstacle, as for the overload alarm): centre and half extents [m] "
                             "(repeatable)")
        self.up.add_argument("--bus-listen", action="append", default=[], metavar="ENDPOINT",
                             help="also open the cell bus (where the services meet; private by default) on "
                             "ENDPOINT, for services of other hosts; clients use --listen (repeatable)")
        _log_level(self.up)
        _router_zenoh_arguments(self.up)
        add_health_arguments(self.up)

        self.service = sub.add_parser(
            "service", help="run one service in this process",
            description="Run one service of one arm in this process (as compose does).")
        self.service.add_argument("name", choices=NAMES, metavar="NAME",
                                  help="; ".join(f"{s.name}: {s.description}" for s in SERVICES))
        self.service.add_argument("args", nargs=argparse.REMAINDER,
                                  help="the service's arguments (jara-arm service NAME --help)")

        self.router = sub.add_parser(
            "router", help="run a plain Zenoh router that services and clients join",
            description=f"A Zenoh router (default listen endpoint {DEFAULT_LISTEN}) that runs "
            "until SIGINT/SIGTERM, reporting the services that join or leave.")
        role = self.router.add_mutually_exclusive_group()
        role.add_argument("--gateway", action="store_true",
                          help="a client gateway: clients join it, it joins the cell bus (--connect); every "
                          "publication it forwards is best effort and it never waits on a client")
        role.add_argument("--bus", action="store_true",
                          help="a router of the cell bus, which only services and gateways join: its blocking "
                          "publications (low-level position commands) reach the gateways as best effort")
        self.router.add_argument("--gateway-id", action="append", default=[], metavar="HEX",
                                 help=f"the gateway's Zenoh id (default: {GATEWAY_ZID}); with --bus, every "
                                 "gateway's (repeatable)")
        _log_level(self.router)
        _router_zenoh_arguments(self.router)

        self.logs = sub.add_parser(
            "logs", help="print the services' log records as they come",
            description="Subscribe to JARA_ARM/<arm>/log/<service> from anywhere on the Zenoh "
            "network and print each record as it arrives.")
        _arm_filter(self.logs)
        self.logs.add_argument("--service", choices=[s.value for s in Service], metavar="NAME",
                               help=f"only this service ({', '.join(s.value for s in Service)}; "
                               "default: every one)")
        self.logs.add_argument("--level", type=str.upper, default="DEBUG", choices=RECORD_LEVELS,
                               help="only records at this level or above (default: DEBUG, all)")
        _client_zenoh_arguments(self.logs)

        self.alarms = sub.add_parser(
            "alarms", help="print the active alarms, then every alarm event as it comes",
            description="Ask the alarm monitor for the active alarms and print them, then print "
            "every event on JARA_ARM/<arm>/alarm (raised, cleared) as it arrives.")
        _arm_filter(self.alarms)
        _client_zenoh_arguments(self.alarms)

        self.demo = sub.add_parser(
            "demo", help="drive a running arm through a short, visible sequence",
            description="Servo on, speeds, PTP, LIN, CIRC, pause/resume, home, servo off, over the "
            "public interface only; prints each step with its return code and what was measured.")
        self.demo.add_argument("--arm", type=_arm_id, default=DEFAULT_ARM, metavar="ID",
                               help=f"the arm to drive (default: {DEFAULT_ARM})")
        _client_zenoh_arguments(self.demo)

        self.call = sub.add_parser(
            "call", help="call any operation by its name (IDL or Ext) and print the reply as JSON",
            description="Call one of the Common, Middle or Ext operations (Servo/Common with --servo) and "
            "print the reply {id, comment, <out parameters>} as JSON; exit 1 if its id is not OK. "
            "The parameters are checked here first: a mistake is reported with the operation's "
            "parameter list, and nothing is sent.",
            epilog="examples: jara-arm call servoON; jara-arm call setSpeedJoint '{\"spdRatio\": 50}'; "
            "jara-arm call setSpeedJoint 50 (an operation's one parameter may come alone)")
        _arm(self.call)
        self.call.add_argument("--servo", action="store_true",
                               help="ask the servo (Servo/Common/<op>) instead of the command service")
        self.call.add_argument("--timeout", type=positive_float, default=10.0, metavar="S",
                               help="wait this long to join the network, and then for the reply [s] (default: 10)")
        self.call.add_argument("op", metavar="OP", help="the operation's name (IDL, or Ext), e.g. movePTPJointAbs")
        self.call.add_argument("json", nargs="?", metavar="JSON",
                               help="the in parameters as a JSON object (default: none)")
        _client_zenoh_arguments(self.call)

        self.echo = sub.add_parser(
            "echo", help="print the samples of any key as JSON lines",
            description="Subscribe to JARA_ARM/<arm>/KEY and print every sample decoded (MessagePack "
            "or JSON) as one JSON line. Keys: " + ", ".join(echo_keys()) + " ('*' is one chunk, "
            "'**' any number of them).")
        _arm(self.echo)
        self.echo.add_argument("key", metavar="KEY", help="relative to JARA_ARM/<arm>/, e.g. state, log/**")
        self.echo.add_argument("--rate", type=positive_float, metavar="HZ",
                               help="print at most this many samples a second (thins the 1 kHz streams)")
        ends = self.echo.add_mutually_exclusive_group()
        ends.add_argument("--once", action="store_true", help="exit after the first sample")
        ends.add_argument("--count", type=positive_int, metavar="N", help="exit after N samples")
        self.echo.add_argument("--timeout", type=positive_float, metavar="S",
                               help="exit 1 if the samples asked for did not come within S seconds (joining the network "
                               "included)")
        self.echo.add_argument("--show-key", action="store_true",
                               help='print {"key": ..., "value": ...} (for keys with wildcards)')
        _client_zenoh_arguments(self.echo)

        self.state = sub.add_parser(
            "state", help="a live one-screen view of an arm",
            description="State bits by name, queue depth, joints, Cartesian pose, active alarms, servo "
            "loop health and services, refreshed in place on a terminal (as repeated blocks otherwise).")
        _arm(self.state)
        self.state.add_argument("--once", action="store_true", help="print one view and exit")
        self.state.add_argument("--period", type=positive_float, default=0.5, metavar="S",
                                help="refresh period [s] (default: 0.5)")
        _client_zenoh_arguments(self.state)

        self.wait = sub.add_parser(
            "wait", help="wait until the arm meets a condition (for scripts)",
            description="Exit 0 as soon as the condition holds, 1 with what was seen last if it did not "
            "within the timeout. Conditions: " + "; ".join(f"{c.value}: {h}" for c, h in CONDITION_HELP.items()))
        _arm(self.wait)
        self.wait.add_argument("condition", choices=[c.value for c in Condition], metavar="CONDITION",
                               help=", ".join(c.value for c in Condition))
        self.wait.add_argument("--timeout", type=positive_float, default=60.0, metavar="S",
                               help="give up after S seconds, joining the network included (default: 60)")
        self.wait.add_argument("--poll", type=positive_float, default=0.05, metavar="S",
                               help="look this often [s] (default: 0.05)")
        _client_zenoh_arguments(self.wait)

        self.record = sub.add_parser(
            "record", help="record every sample of the arms into an MCAP file",
            description="Subscribe to JARA_ARM/<arm>/** and write every sample (the 1 kHz streams and the traces "
            "of the Common and Middle calls with their replies included) into an MCAP file: a channel per key, "
            "JSON messages, a JSON Schema per channel from schema/. Shows size, count and rate every second; "
            "stops on SIGINT/SIGTERM or after --duration.")
        self.record.add_argument("--arm", action="append", type=_arm_id, default=[], metavar="ID",
                                 help="an arm to record (repeatable; default: every arm)")
        self.record.add_argument("-o", "--output", required=True, metavar="FILE.mcap", help="the file to write")
        self.record.add_argument("--duration", type=positive_float, metavar="S", help="stop after S seconds")
        _client_zenoh_arguments(self.record)

        self.replay = sub.add_parser(
            "replay", help="publish a recording again, in time, where no arm runs",
            description="Publish the messages of an MCAP recording on their keys at their recorded pace (divided "
            "by --speed), each in its key's encoding, for echo, plot, view or any subscriber. Refuses while "
            "a recorded arm is alive on the network. Never replays what the services subscribe to "
            "(Servo/posCmd, estop, Monitor/report); call traces go out as publications, "
            "never as queries.")
        self.replay.add_argument("file", metavar="FILE.mcap", help="a recording of jara-arm record")
        self.replay.add_argument("--speed", type=positive_float, default=1.0, metavar="X",
                                 help="X times the recorded pace (default: 1)")
        self.replay.add_argument("--arm", action="append", type=_arm_id, default=[], metavar="ID",
                                 help="an arm to replay (repeatable; default: every arm of the recording)")
        _client_zenoh_arguments(self.replay)
        self.plot = sub.add_parser(
            "plot", help="plot an arm's joint traces and Cartesian path to PNG (live or from a recording)",
            description="Joint positions, velocities and accelerations against time, with the joint limits, "
            "and the control point's path in 3D, from the arm's Servo/posFeedback: live (for --seconds, or "
            "until Ctrl-C) or from a recording (--from). Written as two PNG files, shown on screen if there is "
            "one.", epilog="examples: jara-arm plot --seconds 5 -o run.png; "
            "jara-arm plot --from run.mcap --start 2 --end 4.5 -o ptp.png --size 1920x1080")
        self.plot.add_argument("--arm", type=_arm_id, metavar="ID",
                               help=f"the arm (default: {DEFAULT_ARM} live, the recording's only arm with --from)")
        source = self.plot.add_mutually_exclusive_group()
        source.add_argument("--seconds", type=positive_float, metavar="S",
                            help="live: take the feedback for S seconds (default: until Ctrl-C)")
        source.add_argument("--from", dest="recording", metavar="FILE.mcap",
                            help="read the feedback from a recording of `jara-arm record`")
        self.plot.add_argument("--start", type=non_negative_float, default=0.0, metavar="S",
                               help="window start [s] after the first sample (default: 0)")
        self.plot.add_argument("--end", type=non_negative_float, metavar="S",
                               help="window end [s] after the first sample (default: the last sample)")
        self.plot.add_argument("--robot", choices=list(ROBOTS), metavar="NAME",
                               help=f"the arm's robot model ({', '.join(ROBOTS)}; default: from getManipInfo)")
        self.plot.add_argument("-o", "--output", required=True, metavar="FILE.png",
                               help="the joint figure's file")
        self.plot.add_argument("--path", dest="path_output", metavar="FILE.png",
                               help="the Cartesian path figure's file (default: the -o name + _path.png)")
        self.plot.add_argument("--size", default="1600x1200", metavar="WxH",
                               help="size of each figure [px] (default: 1600x1200)")
        self.plot.add_argument("--no-show", dest="show", action="store_false",
                               help="only write the files, even where there is a screen")
        _client_zenoh_arguments(self.plot)
        self.view = sub.add_parser(
            "view", help="a web page with a live 3D view of every arm (read only)",
            description="Serve a web page (viser; everything served by this process, nothing from the "
            "internet) with a live 3D view of every arm on the network: links from the robot's URDF at "
            "the servo's feedback, obstacles, Cartesian soft-limit box, base offset, control point and the "
            "path of the running motion; state and alarms in the panel. It never moves an arm.")
        self.view.add_argument("--arm", type=_arm_id, action="append", default=[], metavar="ID",
                               help="only this arm (repeatable; default: every arm that comes)")
        self.view.add_argument("--host", default=DEFAULT_HOST, metavar="ADDRESS",
                               help=f"serve the page on this address (default: {DEFAULT_HOST}, this host only)")
        self.view.add_argument("--port", type=_port, default=DEFAULT_PORT, metavar="P",
                               help=f"serve the page on this TCP port (default: {DEFAULT_PORT})")
        self.view.add_argument("--rate", type=positive_float, default=DEFAULT_RATE, metavar="HZ",
                               help=f"page updates a second at most (default: {DEFAULT_RATE:g})")
        _client_zenoh_arguments(self.view)

        self.certs = sub.add_parser(
            "certs", help="make a secure cell's certificate authority and issue its certificates",
            description="A secure cell (--secure DIR) is a directory: its own certificate authority (ca.pem, "
            "ca.key), a registry of identities and their roles (cell.json), and for each identity NAME a "
            "certificate (common name NAME), a private key and a Zenoh configuration (NAME.pem, NAME.key, "
            "NAME.json5). Roles: " + ", ".join(r.value for r in Role) + ".")
        actions = self.certs.add_subparsers(dest="certs_command", required=True, metavar="ACTION")
        self.certs_init = actions.add_parser(
            "init", help="make a cell: its CA, and the identities router and service",
            description="Make the cell directory DIR (and its parents): a new certificate authority, an empty "
            "registry, and the identities that `jara-arm up --secure DIR` runs as: router (role router) and "
            "service (role service). Refuses a directory that already holds a CA.")
        self.certs_init.add_argument("dir", type=Path, metavar="DIR", help="the cell directory to make")
        self.certs_init.add_argument("--days", type=positive_int, default=certs.CA_DAYS, metavar="N",
                                     help=f"the CA's validity [days] (default: {certs.CA_DAYS}); router's and "
                                     f"service's: the same, or {certs.ISSUE_DAYS} if shorter")
        _hosts(self.certs_init, "router's and service's certificates")
        self.certs_issue = actions.add_parser(
            "issue", help="issue an identity: its key, certificate and Zenoh configuration",
            description="Issue identity NAME with ROLE in the cell DIR (where its ca.key is): NAME.key, NAME.pem, "
            "NAME.json5, and its entry in the registry. Copy the three files to NAME's host, and cell.json "
            "to every router of the cell.")
        self.certs_issue.add_argument("dir", type=Path, metavar="DIR", help="the cell directory")
        self.certs_issue.add_argument("name", metavar="NAME",
                                      help="the identity's name (its certificate's common name): 1-64 of "
                                      "[A-Za-z0-9_.-]")
        self.certs_issue.add_argument("--role", required=True, choices=[r.value for r in Role], metavar="ROLE",
                                      help=f"what NAME may do: {', '.join(r.value for r in Role)}")
        _hosts(self.certs_issue, "certificate")
        self.certs_issue.add_argument("--days", type=positive_int, default=certs.ISSUE_DAYS, metavar="N",
                                      help=f"the certificate's validity [days] (default: {certs.ISSUE_DAYS})")
        self.certs_issue.add_argument("--force", action="store_true",
                                      help="replace an identity already issued (new key, new serial)")
        self.certs_list = actions.add_parser(
            "list", help="the identities of a cell: name, role, expiry, hosts",
            description="One line per identity of the cell's registry: name, role, expiry (EXPIRED once "
            "past), hosts.")
        self.certs_list.add_argument("dir", type=Path, metavar="DIR", help="the cell directory")

        self.completion = sub.add_parser(
            "completion", help="print a shell completion script",
            description="Print the completion script of jara-arm (commands, options, operation names, "
            "keys): source <(jara-arm completion bash)")
        self.completion.add_argument("shell", choices=SHELLS)

    def commands(self) -> dict[str, argparse.ArgumentParser]:
        """Every command's parser, by name (for the completion script)."""
        return {name: getattr(self, name.replace("-", "_")) for name in COMMANDS}


#: The subcommands, in the order of ``jara-arm --help``.
COMMANDS = ("up", "service", "router", "logs", "alarms", "demo", "call", "echo", "state", "wait", "record", "replay",
            "plot", "view", "certs", "completion")


def _obstacle(text: str) -> str:
    """``--obstacle`` and ``--hidden-obstacle`` of ``up``: checked here, passed on to the services as written."""
    try:
        return Obstacle.parse(text).argument()
    except RobotModelError as exc:
        raise argparse.ArgumentTypeError(str(exc)) from None


def _port(text: str) -> int:
    """``--port`` of ``view``: a TCP port number."""
    try:
        port = int(text)
    except ValueError:
        port = 0
    if not 1 <= port <= 65535:
        raise argparse.ArgumentTypeError(f"{text!r} is not a TCP port (1..65535)")
    return port


def _arm_id(text: str) -> str:
    try:
        return check_arm(text)
    except ArmIdError as exc:
        raise argparse.ArgumentTypeError(str(exc)) from None






def _hosts(parser: argparse.ArgumentParser, what: str) -> None:
    parser.add_argument("--host", action="append", default=[], metavar="H",
                        help=f"a DNS name or IP address the {what} may serve TLS on (repeatable; "
                        f"default: {', '.join(certs.DEFAULT_HOSTS)})")


def _arm(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--arm", type=_arm_id, default=DEFAULT_ARM, metavar="ID",
                        help=f"the arm (default: {DEFAULT_ARM})")


def _arm_filter(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--arm", type=_arm_id, metavar="ID", help="only this arm (default: every arm)")


def _client_zenoh_arguments(parser: argparse.ArgumentParser) -> None:
    """The shared Zenoh options; a client of the launcher's default endpoint unless told otherwise."""
    add_zenoh_arguments(parser, default_mode="client",
                        default_connect=f"{DEFAULT_LISTEN}, {default_endpoint('secure')} with --secure")


def _log_level(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--log-level", type=str.upper, default="INFO", choices=LOG_LEVELS,
                        help="default: INFO")


def _router_zenoh_arguments(parser: argparse.ArgumentParser) -> None:
    """The shared Zenoh options, with the mode fixed to router (so --mode is hidden)."""
    add_zenoh_arguments(parser, default_mode="router", default_identity=ROUTER_IDENTITY, fixed_mode=True)


def command_parser(argv: Sequence[str]) -> tuple[argparse.ArgumentParser, list[str]]:
    """The parser that reads ``jara-arm <argv>``, and the arguments it gets.

    ``["service", "servo", "--arm", "a1"]`` gives the servo's own parser and
    ``["--arm", "a1"]``. ValueError for an unknown command or service.
    """
    argv = list(argv)
    parsers = _Parsers()
    if argv[:1] and argv[0] in COMMANDS and argv[0] != "service":
        return parsers.commands()[argv[0]], argv[1:]
    if argv[:1] == ["service"] and len(argv) >= 2 and argv[1] in NAMES:
        return spec(argv[1]).parser(), argv[2:]
    raise ValueError(f"not a jara-arm command: {' '.join(argv)!r}")


def _router_settings(args: argparse.Namespace, parser: argparse.ArgumentParser) -> RouterSettings:
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


def _up_settings(args: argparse.Namespace, parser: argparse.ArgumentParser) -> UpSettings:
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
    return UpSettings(tuple(arms), _router_settings(args, parser), args.log_level, tuple(args.obstacle),
                      tuple(args.hidden_obstacle), args.demo, health_from_args(args), tuple(args.bus_listen))


def _setup_logging(level: str) -> None:
    """The launcher's own messages: stderr, in the format of the services' log lines."""
    handler = logging.StreamHandler(sys.stderr)
    handler.setFormatter(logging.Formatter(
        "%(asctime)s.%(msecs)03d %(levelname)-7s jara-arm: %(message)s", datefmt="%H:%M:%S"))
    root = logging.getLogger()
    root.addHandler(handler)
    root.setLevel(level)


def _open(args: argparse.Namespace, parser: argparse.ArgumentParser,
          join_within: float | None = None) -> zenoh.Session:
    """A session on the network of the client options (exit 2 with the reason if it cannot be had), trying
    for up to ``join_within`` [s] (a command with a timeout, started before the router listens)."""
    connect = args.connect or ([] if args.config else [default_endpoint(args.secure)])
    try:
        return zenoh.open(zenoh_config(args.mode, args.listen, connect, args.config, args.multicast,
                                       args.secure, args.identity, join_within))
    except CellError as exc:
        parser.error(str(exc))
    except zenoh.ZError as exc:
        parser.error(f"cannot join the Zenoh network ({', '.join(connect) or args.config}): "
                     f"{zerror_text(exc)}")


def _tool(args: argparse.Namespace, parser: argparse.ArgumentParser) -> int:
    """``call``, ``echo``, ``state``, ``wait``: what can be checked without the network is checked
    first (exit 2, nothing sent), then one session for the command."""
    name = args.command
    try:
        call = parse_call(args.op, args.json, args.servo) if name == "call" else None
        key = echo_key(args.arm, args.key) if name == "echo" else None
    except (CallError, EchoKeyError) as exc:
        print(f"jara-arm {name}: {exc}", file=sys.stderr)
        return USAGE_ERROR
    began = time.monotonic()
    session = _open(args, parser, join_within=args.timeout if name in ("call", "echo", "wait") else None)
    signals = StopSignals()
    with session:
        # [s] per query: a call's reply within what joining left of its timeout
        timeout = max(0.1, args.timeout - (time.monotonic() - began)) if name == "call" else 2.0
        client = ArmClient(session, args.arm, timeout=timeout)
        try:
            if call is not None:
                return run_call(client, call, sys.stdout, sys.stderr)
            if key is not None:
                count = 1 if args.once else args.count
                return run_echo(session, EchoSettings(key, args.rate, count, args.timeout, args.show_key, began),
                                signals.stop, sys.stdout, sys.stderr)
            if name == "state":
                return run_state(client, signals.stop, sys.stdout, once=args.once, period=args.period,
                                 tty=sys.stdout.isatty())
            return run_wait(client, Condition(args.condition), args.timeout, args.poll, signals.stop, sys.stderr,
                            began)
        except ClientError as exc:
            # A router drops what a role may not do without a word to the client: silence.
            hint = (f" (in a secure cell this is also what identity {args.identity!r} gets for what its role "
                    "may not do: the router's log says which)") if args.secure else ""
            print(f"jara-arm {name}: {exc}{hint}", file=sys.stderr)
            return 1
        finally:
            client.close()


def _listen(args: argparse.Namespace, parser: argparse.ArgumentParser) -> int:
    """``logs`` and ``alarms``: a session on the network, printing until SIGINT/SIGTERM."""
    session = _open(args, parser)
    signals = StopSignals()
    with session:
        if args.command == "logs":
            return run_logs(session, signals.stop, args.arm, args.service, args.level)
        if args.command == "demo":
            try:
                with Arm(session, args.arm) as arm:
                    return 1 if run_demo(arm, sys.stdout) else 0
            except (ClientError, ArmError) as exc:
                print(f"jara-arm demo: {exc}", file=sys.stderr)
                return 1
        return run_alarms(session, signals.stop, args.arm)


def _record(args: argparse.Namespace, parser: argparse.ArgumentParser) -> int:
    """``record``: the file opened first (a path that cannot be written: exit 2, nothing joined)."""
    try:
        writer = RecordingWriter(Path(args.output))
    except RecordingError as exc:
        print(f"jara-arm record: {exc}", file=sys.stderr)
        return USAGE_ERROR
    try:
        session = _open(args, parser)
    except SystemExit:
        writer.close()
        raise
    signals = StopSignals()
    lower_priority()
    with session:
        return run_record(session, writer, RecordSettings(tuple(dict.fromkeys(args.arm)), args.duration),
                          signals.stop, sys.stderr, sys.stderr.isatty())


def _replay(args: argparse.Namespace, parser: argparse.ArgumentParser) -> int:
    """``replay``: the file read and the arms checked first (exit 2, nothing joined), then the network."""
    path = Path(args.file)
    settings = ReplaySettings(args.speed, tuple(dict.fromkeys(args.arm)))
    try:
        info = recording_info(path)
        plan(info, settings)
    except RecordingError as exc:
        print(f"jara-arm replay: {exc}", file=sys.stderr)
        return USAGE_ERROR
    session = _open(args, parser)
    signals = StopSignals()
    with session:
        return run_replay(session, path, info, settings, signals.stop, sys.stderr, sys.stderr.isatty())
def _plot(args: argparse.Namespace, parser: argparse.ArgumentParser) -> int:
    """``plot``: the options checked first (exit 2, nothing read or written), then the samples from the
    recording or from a session on the network, then the figures."""
    # Here, not at the top: matplotlib and Pinocchio take half a second to import, which only plot pays.
    from .record.plot import PlotDataError, PlotInputError, PlotSettings, collect_live, read_recording, render

    try:
        settings = PlotSettings.check(arm=args.arm, recording=args.recording, seconds=args.seconds,
                                      start=args.start, end=args.end, output=args.output,
                                      path_output=args.path_output, size=args.size, robot=args.robot,
                                      show=args.show)
    except PlotInputError as exc:
        print(f"jara-arm plot: {exc}", file=sys.stderr)
        return USAGE_ERROR
    try:
        if settings.recording is not None:
            feedback = read_recording(settings.recording, settings.arm, sys.stderr)
        else:
            session = _open(args, parser)
            signals = StopSignals()
            with session:
                client = ArmClient(session, settings.arm or DEFAULT_ARM, timeout=2.0)
                try:
                    feedback = collect_live(session, client, settings.seconds, signals.stop, sys.stderr)
                finally:
                    client.close()
    except PlotDataError as exc:
        print(f"jara-arm plot: {exc}", file=sys.stderr)
        return 1
    return render(feedback, settings, sys.stderr)
def _view(args: argparse.Namespace, parser: argparse.ArgumentParser) -> int:
    """``view``: the page until SIGINT/SIGTERM; a page that cannot be served is a usage error (exit 2)."""
    session = _open(args, parser)
    signals = StopSignals()
    with session:
        try:
            return run_view(session, ViewSettings(tuple(dict.fromkeys(args.arm)), args.host, args.port, args.rate),
                            signals.stop, sys.stdout)
        except ViewError as exc:
            print(f"jara-arm view: {exc}", file=sys.stderr)
            return USAGE_ERROR


def _certs(args: argparse.Namespace) -> int:
    """``certs init``, ``issue``, ``list``: what was made or found on stdout; a mistake (exit 2) on stderr."""
    try:
        if args.certs_command == "init":
            certs.report_init(args.dir, sys.stdout, days=args.days, hosts=args.host or certs.DEFAULT_HOSTS)
        elif args.certs_command == "issue":
            certs.report_issue(args.dir, args.name, Role(args.role), sys.stdout,
                               hosts=args.host or certs.DEFAULT_HOSTS, days=args.days, force=args.force)
        else:
            certs.report_list(args.dir, sys.stdout)
        return 0
    except (certs.CertsError, CellError) as exc:
        print(f"jara-arm certs: {exc}", file=sys.stderr)
        return USAGE_ERROR


def _run(argv: list[str]) -> int:
    parsers = _Parsers()
    args = parsers.top.parse_args(argv)
    if args.command == "service":
        return spec(args.name).run(args.args)
    if args.command in ("logs", "alarms", "demo"):
        _setup_logging("WARNING")
        return _listen(args, getattr(parsers, args.command))
    if args.command in ("call", "echo", "state", "wait"):
        _setup_logging("WARNING")
        return _tool(args, getattr(parsers, args.command))
    if args.command in ("record", "replay"):
        _setup_logging("WARNING")
        return (_record if args.command == "record" else _replay)(args, getattr(parsers, args.command))
    if args.command == "plot":
        _setup_logging("WARNING")
        return _plot(args, parsers.plot)
    if args.command == "view":
        _setup_logging("WARNING")
        return _view(args, parsers.view)
    if args.command == "certs":
        return _certs(args)
    if args.command == "completion":
        print(bash_script(parsers.commands()), end="")
        return 0
    parser = parsers.up if args.command == "up" else parsers.router
    settings = (_up_settings(args, parser) if args.command == "up"
                else _router_settings(args, parser))
    _setup_logging(args.log_level)
    signals = StopSignals()  # before any child exists: a signal must never orphan one
    try:
        if isinstance(settings, UpSettings):
            return run_up(settings, signals)
        return run_router(settings, signals)
    except RouterError as exc:
        parser.error(str(exc))
    return USAGE_ERROR  # not reached: parser.error exits


def main(argv: Sequence[str] | None = None) -> int:
    """Entry point of the ``jara-arm`` console script; returns the exit status."""
    try:
        return _run(list(sys.argv[1:] if argv is None else argv))
    except SystemExit as exc:  # argparse's exits (usage errors: 2, --help: 0)
        if exc.code is None or isinstance(exc.code, int):
            return exc.code or 0
        print(exc.code, file=sys.stderr)
        return 1


if __name__ == "__main__":  # pragma: no cover
    sys.exit(main())
