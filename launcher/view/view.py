"""``jara-arm view``: a web page with a live 3D view of every arm on the Zenoh network.

The page is viser's (served by this process, client included: nothing comes
from the internet), on loopback unless ``--host`` says otherwise. Arms are
found by their liveliness tokens (``JARA_ARM/*/alive/*``): one that appears is
drawn, one whose servo leaves is greyed at its last pose, and one that comes
back is drawn again (rebuilt if its robot changed). Per arm, from:

* ``Servo/world`` (a get, then its publication): the robot model, hence its
  URDF (links, meshes, primitives), the base position and the obstacles;
* ``Servo/status`` (100 Hz moving, 10 Hz at rest): the measured joints; only
  the newest sample is kept (a ring of one) and the page is updated at most
  ``rate`` times a second. Not ``Servo/posFeedback`` (1 kHz): a page is drawn
  at 30 Hz, and with a browser beside it this process falls behind a 1 kHz
  stream. Every service then went unheard for 1-2.7 s (false hung FAULTs in
  6 of 12 runs of ``tests/test_view.py``'s live test; 0 of 10 on
  ``Servo/status``): by all signs the router, held up by its queue to this
  process (inferred, not traced);
* ``Command/settings``: the Cartesian soft-limit box, the base offset (the
  robot frame) and the control point offset (the control point frame);
* ``Planner/path`` and ``Planner/progress``: the path of the running motion;
* ``state`` (and ``getState`` once), ``Monitor/alarms`` and ``alarm``: the
  state bits and the alarms, on the page and on the arm's label.

It only reads: nothing it does can move an arm. Zenoh's callbacks do nothing
here: every subscription is a channel that the page's one loop drains.
"""

from __future__ import annotations

import argparse
import asyncio
import contextlib
import dataclasses
import errno
import io
import logging
import socket
import sys
import threading
import time
from typing import TYPE_CHECKING, Any, TextIO

import zenoh

from jara_arm.robots import RobotModelError
from jara_arm.robots import robot as robot_model
from jara_arm.schema import codec
from jara_arm.schema.alarms import ALARM_LIST, AlarmList, format_code
from jara_arm.schema.codec import Encoding
from jara_arm.schema.errors import JaraArmError
from jara_arm.schema.keys import ArmKeys, Service, any_arm_alive, parse_alive
from jara_arm.schema.messages import ALARM_EVENT, SERVO_STATUS, SERVO_WORLD, ServoWorld
from jara_arm.schema.operations import OP, Interface
from jara_arm.schema.planner import MOTION_SETTINGS, PLANNED_PATH, PLANNER_PROGRESS
from jara_arm.schema.types import Alarm
from jara_arm.services.runtime.arguments import positive_float

from ..command import USAGE_ERROR, Command, setup_logging
from ..feeds import decode, newest, undeclare
from ..session import add_client_zenoh_arguments, arm_id, listening
from ..tools.arm_state import format_state, read_state

if TYPE_CHECKING:  # viser, trimesh and Pinocchio take 0.7 s to import: only `jara-arm view` pays it, in View
    import viser

    from .scene import ArmScene

log = logging.getLogger(__name__)

DEFAULT_PORT = 8080
DEFAULT_HOST = "127.0.0.1"
DEFAULT_RATE = 30.0  # [Hz] page updates
#: Arms' worlds are placed this far apart along y in the page [m] (each simulation has its own).
SPACING = 1.5
_PATHS = 16  # Planner/path messages held between two frames
_EVENTS = 64  # alarm events held between two frames
_ASK_TIMEOUT = 2.0  # [s] for the world and the state asked on discovery


class ViewError(JaraArmError, RuntimeError):
    """The page cannot be served (a port in use, an address not of this host)."""


@dataclasses.dataclass(frozen=True)
class ViewSettings:
    arms: tuple[str, ...] = ()  # only these arms; () for every arm
    host: str = DEFAULT_HOST
    port: int = DEFAULT_PORT
    rate: float = DEFAULT_RATE  # [Hz] page updates at most


class ArmFeeds:
    """One arm's subscriptions and pending gets, every one a channel; :meth:`close` undeclares them."""

    def __init__(self, session: zenoh.Session, arm: str) -> None:
        self.keys = keys = ArmKeys(arm)
        self._session = session
        ring = zenoh.handlers.RingChannel
        self.feedback = session.declare_subscriber(keys.servo_status, ring(1))
        self.world = session.declare_subscriber(keys.servo_world, ring(1))
        self.settings = session.declare_subscriber(keys.command_settings, ring(1))
        self.progress = session.declare_subscriber(keys.planner_progress, ring(1))
        self.paths = session.declare_subscriber(keys.planner_path, zenoh.handlers.FifoChannel(_PATHS))
        self.state = session.declare_subscriber(keys.state, ring(1))
        self.alarms = session.declare_subscriber(keys.monitor_alarms, ring(1))
        self.events = session.declare_subscriber(keys.alarm, zenoh.handlers.FifoChannel(_EVENTS))
        self._subs = (self.feedback, self.world, self.settings, self.progress, self.paths, self.state,
                      self.alarms, self.events)
        self.world_reply: Any = None
        self.state_reply: Any = None
        self.ask()

    def ask(self) -> None:
        """Get the world and the state now (answers come in channels, read by the loop)."""
        get = self._session.get
        self.world_reply = get(self.keys.servo_world, zenoh.handlers.FifoChannel(4), payload=b"{}",
                               timeout=_ASK_TIMEOUT)
        self.state_reply = get(self.keys.interface(Interface.COMMON, OP.getState),
                               zenoh.handlers.FifoChannel(4), payload=b"{}", timeout=_ASK_TIMEOUT)

    def close(self) -> None:
        undeclare(self._subs)


class ArmView:
    """What the page shows of one arm, updated from its :class:`ArmFeeds` by :meth:`step`."""

    def __init__(self, server: viser.ViserServer, arm: str, feeds: ArmFeeds, slot: int) -> None:
        self.arm = arm
        self.feeds = feeds
        self.slot = slot
        self._server = server
        self.scene: ArmScene | None = None
        self.robot: str | None = None
        self.services: set[str] = set()
        self.state: str = "unknown"
        self.alarms: tuple[Alarm, ...] = ()
        self._alarm_list: AlarmList | None = None
        self.last_event = ""
        self.running = 0  # motion id being streamed
        self._paths: dict[int, tuple[str, tuple[tuple[float, ...], ...]]] = {}
        self._shown_path = -1
        self._pending_world: ServoWorld | None = None
        self._pending_settings: Any = None
        self.frames = 0  # joint updates drawn

    @property
    def present(self) -> bool:
        return Service.SERVO.value in self.services

    def step(self) -> None:
        """Take what came since the last frame and draw it (the page's loop thread only)."""
        f = self.feeds
        world = newest(f.world) or self._reply(f.world_reply, "world_reply")
        if world is not None and (w := decode(SERVO_WORLD, world)) is not None:
            self._take_world(w)
        if (s := newest(f.settings)) is not None:
            self._pending_settings = decode(MOTION_SETTINGS, s) or self._pending_settings
        if (s := newest(f.state)) is not None:
            self._take_state(s.payload.to_bytes(), s.encoding)
        elif (r := self._reply(f.state_reply, "state_reply")) is not None and r.ok is not None:
            try:
                body = codec.loads(r.ok.payload.to_bytes(), Encoding.of(r.ok.encoding))
                if isinstance(body, dict) and body.get("id") == 0 and isinstance(body.get("state"), int):
                    self.state = format_state(body["state"])
            except JaraArmError:
                pass
        if (s := newest(f.alarms)) is not None and (lst := decode(ALARM_LIST, s)) is not None:
            self._alarm_list = lst
            self.alarms = lst.alarms
        while (s := f.events.try_recv()) is not None:
            if (event := decode(ALARM_EVENT, s)) is not None:
                self.last_event = f"{event.event} {format_code(event.alarm.code)} {event.alarm.description}"
        while (s := f.paths.try_recv()) is not None:
            if (path := decode(PLANNED_PATH, s)) is not None:
                self._paths[path.motion] = (path.op, path.points)
                for old in sorted(self._paths)[:-_PATHS]:
                    del self._paths[old]
        if (s := newest(f.progress)) is not None and (progress := decode(PLANNER_PROGRESS, s)) is not None:
            self.running = progress.running
        feedback = newest(f.feedback)
        scene = self.scene
        if scene is None:
            return
        if self._pending_settings is not None:
            scene.show_settings(self._pending_settings)
            self._pending_settings = None
        if feedback is not None and (fb := decode(SERVO_STATUS, feedback)) is not None and fb.pos:
            try:
                self.frames += scene.show_joints(fb.pos)
            except ValueError as exc:
                log.warning("arm %s: %s", self.arm, exc)
        if self.running != self._shown_path:
            shown = self._paths.get(self.running)
            scene.show_path(shown[1] if shown else None)
            self._shown_path = self.running if shown or not self.running else -1
        scene.show_gone(not self.present)
        scene.show_label(self.label())

    def _reply(self, pending: Any, name: str) -> Any:
        """The first reply of a pending get, once (the get is then dropped)."""
        if pending is None:
            return None
        try:
            reply = pending.try_recv()
        except zenoh.ZError:  # the get ended with no reply (the service is not up yet)
            reply = None
            setattr(self.feeds, name, None)
        if reply is not None:
            setattr(self.feeds, name, None)
        return reply

    def _take_world(self, world: ServoWorld) -> None:
        if world.robot != self.robot or self.scene is None:
            try:
                model = robot_model(world.robot)
            except RobotModelError as exc:
                log.warning("arm %s: %s; not drawn", self.arm, exc)
                return
            if self.scene is not None:
                self.scene.remove()
            from .scene import ArmScene, RobotGeometry

            self.scene = ArmScene(self._server.scene, f"/{self.arm}", RobotGeometry(model),
                                  offset=(0.0, SPACING * self.slot, 0.0))
            self.robot = world.robot
            self._shown_path = -1
        self.scene.show_world(world)

    def _take_state(self, payload: bytes, encoding: object) -> None:
        try:
            self.state = format_state(read_state(payload, encoding).state)
        except JaraArmError as exc:
            log.warning("arm %s: malformed state: %s", self.arm, exc)

    def label(self) -> str:
        """The arm's label in the scene: id, robot, state, alarms."""
        if not self.present:
            return f"{self.arm} ({self.robot or '?'}): gone"
        alarms = ", ".join(format_code(a.code) for a in self.alarms) or "no alarm"
        return f"{self.arm} ({self.robot or '?'}): {self.state}; {alarms}"

    def markdown(self) -> str:
        """The arm's lines in the page's panel."""
        alarms = "".join(f"\n  - `{format_code(a.code)}` {a.type.value}: {a.description}" for a in self.alarms)
        motion = ""
        if self.running:
            op = self._paths.get(self.running, ("?",))[0]
            motion = f"\n- motion {self.running} ({op})"
        services = ", ".join(sorted(self.services)) or "none"
        return (f"**{self.arm}** — {self.robot or 'robot unknown'}\n\n- state: `{self.state}`"
                f"\n- alarms: {'none' if not self.alarms else ''}{alarms}"
                + (f"\n- last alarm event: {self.last_event}" if self.last_event else "")
                + motion + f"\n- services: {services}")

    def close(self) -> None:
        self.feeds.close()
        if self.scene is not None:
            self.scene.remove()


def check_port(host: str, port: int) -> None:
    """ViewError unless ``host:port`` can be listened on now (viser would quietly take another port)."""
    try:
        infos = socket.getaddrinfo(host, port, type=socket.SOCK_STREAM)
    except socket.gaierror as exc:
        raise ViewError(f"--host {host}: not an address of this host ({exc.strerror})") from None
    family, kind, proto, _, address = infos[0]
    with socket.socket(family, kind, proto) as s:
        s.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
        try:
            s.bind(address)
        except OSError as exc:
            why = "in use" if exc.errno == errno.EADDRINUSE else exc.strerror
            raise ViewError(f"cannot serve the page on {host}:{port}: {why}") from None


class View:
    """The page and its arms: :meth:`step` once per frame, from one thread."""

    def __init__(self, session: zenoh.Session, settings: ViewSettings) -> None:
        self.settings = settings
        self._session = session
        check_port(settings.host, settings.port)
        import viser

        with contextlib.redirect_stdout(io.StringIO()):  # viser's banner: run_view prints the URL itself
            self.server = viser.ViserServer(host=settings.host, port=settings.port, label="jara-arm view",
                                            verbose=False)
        if self.server.get_port() != settings.port:  # taken between the check and now
            self.server.stop()
            raise ViewError(f"cannot serve the page on {settings.host}:{settings.port}: in use")
        self.server.scene.set_up_direction("+z")
        # Plain light: in software WebGL, shadows and the environment map made a page load cost 8 CPU-seconds
        # and an idle page 0.2 core (docs/decisions.md, "The page is lit plainly").
        self.server.scene.configure_default_lights(cast_shadow=False)
        self.server.scene.configure_environment_map(hdri=None)
        self.server.initial_camera.position = (1.25, -0.95, 0.85)  # [m] the first arm from the front, a bit above
        self.server.initial_camera.look_at = (0.15, 0.1, 0.3)
        self.server.scene.add_grid("/ground", width=4.0, height=4.0 + SPACING * 4, cell_size=0.25,
                                   section_size=1.0)
        self._panel = self.server.gui.add_markdown("waiting for arms (liveliness tokens "
                                                   f"{any_arm_alive()})")
        self._shown_panel = ""
        self.arms: dict[str, ArmView] = {}
        self._slots: dict[str, int] = {}
        self._tokens = session.liveliness().declare_subscriber(any_arm_alive(), zenoh.handlers.FifoChannel(1024),
                                                               history=True)

    @property
    def url(self) -> str:
        host = self.settings.host
        return f"http://{'[' + host + ']' if ':' in host else host}:{self.server.get_port()}/"

    def step(self) -> None:
        while (token := self._tokens.try_recv()) is not None:
            self._take_token(token)
        for view in self.arms.values():
            view.step()
        panel = "\n\n".join(v.markdown() for _, v in sorted(self.arms.items())) or self._panel.content
        if panel != self._shown_panel:
            self._panel.content = panel
            self._shown_panel = panel

    def _take_token(self, sample: zenoh.Sample) -> None:
        try:
            arm, service = parse_alive(str(sample.key_expr))
        except JaraArmError:
            return
        if self.settings.arms and arm not in self.settings.arms:
            return
        view = self.arms.get(arm)
        if sample.kind == zenoh.SampleKind.PUT:
            if view is None:
                slot = self._slots.setdefault(arm, len(self._slots))
                view = self.arms[arm] = ArmView(self.server, arm, ArmFeeds(self._session, arm), slot)
                log.info("arm %s appeared", arm)
            elif service == Service.SERVO.value and not view.present:
                view.feeds.ask()  # back: its robot may have changed
                log.info("arm %s: its servo is back", arm)
            view.services.add(service)
        elif view is not None:
            view.services.discard(service)

    def close(self) -> None:
        self._tokens.undeclare()
        for view in self.arms.values():
            view.feeds.close()
        _drop_connections(self.server)
        with contextlib.redirect_stdout(io.StringIO()):  # viser's "Server stopped"
            self.server.stop()


def _drop_connections(server: viser.ViserServer) -> None:
    """Drop the page's unused connections before viser stops its server. A browser opens a spare connection ahead of
    need and may never send a request on it; websockets' shutdown waits out its 10 s opening handshake, and
    viser's ``stop()`` gave up joining after 6 s (viser 1.1.1): ``jara-arm view`` took 6 s to exit on Ctrl-C
    with a page open. Uses viser's private event loop; without it (another viser), the plain stop."""
    loop = getattr(getattr(server, "_websock_server", None), "_background_event_loop", None)
    if not isinstance(loop, asyncio.AbstractEventLoop) or loop.is_closed():
        return
    done = threading.Event()

    def cancel() -> None:  # only the connections still in their handshake: the page's own closes as usual
        for task in asyncio.all_tasks():
            awaited = getattr(task.get_coro(), "cr_await", None)
            if "handshake" in getattr(awaited, "__qualname__", ""):
                task.cancel()
        done.set()

    with contextlib.suppress(RuntimeError):  # the loop closed meanwhile
        loop.call_soon_threadsafe(cancel)
        done.wait(1.0)


def run_view(session: zenoh.Session, settings: ViewSettings, stop: threading.Event, out: TextIO) -> int:
    """Serve the page until ``stop``; ViewError if it cannot be served."""
    view = View(session, settings)
    try:
        print(f"jara-arm view: {view.url} (every arm on the network; Ctrl-C to stop)", file=out, flush=True)
        period = 1.0 / settings.rate
        while not stop.is_set():
            t0 = time.monotonic()
            view.step()
            stop.wait(max(0.0, period - (time.monotonic() - t0)))
        return 0
    finally:
        view.close()


def _port(text: str) -> int:
    """``--port``: a TCP port number."""
    try:
        port = int(text)
    except ValueError:
        port = 0
    if not 1 <= port <= 65535:
        raise argparse.ArgumentTypeError(f"{text!r} is not a TCP port (1..65535)")
    return port


def _arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--arm", type=arm_id, action="append", default=[], metavar="ID",
                        help="only this arm (repeatable; default: every arm that comes)")
    parser.add_argument("--host", default=DEFAULT_HOST, metavar="ADDRESS",
                        help=f"serve the page on this address (default: {DEFAULT_HOST}, this host only)")
    parser.add_argument("--port", type=_port, default=DEFAULT_PORT, metavar="P",
                        help=f"serve the page on this TCP port (default: {DEFAULT_PORT})")
    parser.add_argument("--rate", type=positive_float, default=DEFAULT_RATE, metavar="HZ",
                        help=f"page updates a second at most (default: {DEFAULT_RATE:g})")
    add_client_zenoh_arguments(parser)


def _run(args: argparse.Namespace, parser: argparse.ArgumentParser) -> int:
    """The page until SIGINT/SIGTERM; a page that cannot be served is a usage error (exit 2)."""
    setup_logging("WARNING")
    with listening(args, parser) as (session, stop):
        try:
            return run_view(session, ViewSettings(tuple(dict.fromkeys(args.arm)), args.host, args.port, args.rate),
                            stop, sys.stdout)
        except ViewError as exc:
            print(f"{parser.prog}: {exc}", file=sys.stderr)
            return USAGE_ERROR


COMMAND = Command(
    "view", arguments=_arguments, run=_run,
    help="a web page with a live 3D view of every arm (read only)",
    description="Serve a web page (viser; everything served by this process, nothing from the "
    "internet) with a live 3D view of every arm on the network: links from the robot's URDF at "
    "the servo's feedback, obstacles, Cartesian soft-limit box, base offset, control point and the "
    "path of the running motion; state and alarms in the panel. It never moves an arm.")
