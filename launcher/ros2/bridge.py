"""``jara-arm ros2``: every arm as ROS 2 topics, as rmw_zenoh publishes them, on the cell's own Zenoh network.

A ROS 2 node on rmw_zenoh (``RMW_IMPLEMENTATION=rmw_zenoh_cpp``) that connects to the cell's router sees,
per arm, a node ``<namespace>/jara_arm`` (namespace ``/<arm>`` unless ``--ros-namespace``) publishing:

* ``joint_states`` (``sensor_msgs/msg/JointState``) and ``tf`` (``tf2_msgs/msg/TFMessage``) at ``--rate``
  (100 Hz): the newest measured joints and velocities the servo published (``Servo/status``), repeated
  at rest, as robot_state_publisher expects;
* ``robot_description`` (``std_msgs/msg/String``, transient local: a late subscriber gets it from the
  publisher's cache, a Zenoh advanced publisher, as rmw_zenoh's transient-local publishers);
* ``jara_arm/state`` (``diagnostic_msgs/msg/DiagnosticStatus``): on every change and every second.

Arms are found as ``jara-arm view`` finds them (their liveliness tokens). This process only reads what any
client may read; every subscription is a ring of one and every publisher drops rather than waits
(``CongestionControl.DROP``), so a slow ROS subscriber slows down nobody, this process included. The
names, keys and tokens: ``rmw.py``; the messages: ``messages.py``. Tests: ``tests/test_ros2.py``.
"""

from __future__ import annotations

import argparse
import dataclasses
import itertools
import logging
import sys
import threading
import time
from typing import Any, TextIO

import zenoh
import zenoh.ext

from jara_arm.robots import RobotModelError
from jara_arm.robots import robot as robot_model
from jara_arm.schema.alarms import ALARM_LIST
from jara_arm.schema.errors import JaraArmError
from jara_arm.schema.keys import ArmKeys, Service, any_arm_alive, parse_alive
from jara_arm.schema.messages import SERVO_STATUS, SERVO_WORLD
from jara_arm.services.runtime.arguments import positive_float

from ..command import USAGE_ERROR, Command, setup_logging
from ..feeds import decode, newest, undeclare
from ..session import add_client_zenoh_arguments, arm_id, listening
from ..tools.arm_state import read_state
from . import messages as msgs
from . import rmw

log = logging.getLogger(__name__)

DEFAULT_RATE = 100.0  # [Hz] joint_states and tf
DEFAULT_DOMAIN = 0
NODE_NAME = "jara_arm"
#: ``jara_arm/state`` is published on every change and at least this often [s].
STATE_EVERY = 1.0
#: The servo's world is asked again this often until it answers [s].
ASK_EVERY = 1.0
#: joint_states and tf stop when no servo status came for this long [s]: the servo says one at least every
#: 0.1 s (10 Hz at rest); a servo gone or frozen is not an arm at rest.
STALE = 0.5


@dataclasses.dataclass(frozen=True)
class BridgeSettings:
    arms: tuple[str, ...] = ()  # only these arms; () for every arm that comes
    domain: int = DEFAULT_DOMAIN
    namespace: str = ""  # the ROS namespace of every arm's node; "": /<arm>
    rate: float = DEFAULT_RATE  # [Hz]

    def namespace_of(self, arm: str) -> str:
        return self.namespace or f"/{arm}"


class _Topic:
    """One publisher, as rmw_zenoh makes one: its key, its liveliness token, its GID and sequence."""

    def __init__(self, session: zenoh.Session, node: rmw.Node, eid: int, topic: str, ros_type: str,
                 qos: rmw.QoS) -> None:
        self.ros_type = ros_type
        type_hash = msgs.type_hash(ros_type)
        self.key = rmw.data_key(node.domain, topic, ros_type, type_hash)
        token = node.publisher_token(eid, topic, ros_type, type_hash, qos)
        self.gid = rmw.gid(token)
        self._seq = itertools.count(1)
        if qos.durability is rmw.Durability.TRANSIENT_LOCAL:
            self._pub: Any = zenoh.ext.declare_advanced_publisher(
                session, self.key, cache=zenoh.ext.CacheConfig(qos.depth), publisher_detection=True,
                congestion_control=zenoh.CongestionControl.DROP)
        else:
            self._pub = session.declare_publisher(self.key, congestion_control=zenoh.CongestionControl.DROP)
        self._token = session.liveliness().declare_token(token)

    def put(self, message: Any) -> bytes:
        """Publish ``message``; its CDR, for :meth:`put_cdr` to publish again."""
        data = msgs.cdr(message, self.ros_type)
        self.put_cdr(data)
        return data

    def put_cdr(self, data: bytes) -> None:
        self._pub.put(data, attachment=rmw.attachment(next(self._seq), time.time_ns(), self.gid))

    def close(self) -> None:
        undeclare((self._token, self._pub))


class ArmBridge:
    """One arm: its feeds (rings of one) and, once its robot is known, its node and topics."""

    def __init__(self, session: zenoh.Session, arm: str, settings: BridgeSettings, nid: int) -> None:
        self.arm, self.settings, self.nid = arm, settings, nid
        self.keys = keys = ArmKeys(arm)
        self._session = session
        ring = zenoh.handlers.RingChannel
        self._status = session.declare_subscriber(keys.servo_status, ring(1))
        self._world = session.declare_subscriber(keys.servo_world, ring(1))
        self._state_sub = session.declare_subscriber(keys.state, ring(1))
        self._alarms_sub = session.declare_subscriber(keys.monitor_alarms, ring(1))
        self._asked: Any = None
        self._asked_at = 0.0
        self.robot = ""
        self._desc: msgs.ArmDescription | None = None
        self._kin: msgs.Kinematics | None = None
        self._topics: dict[str, _Topic] = {}
        self._node_token: Any = None
        self._last: tuple[float, tuple[float, ...], tuple[float, ...]] | None = None  # tm [s], pos, vel
        self._sent: tuple[float, bytes, bytes] | None = None  # tm [s], joint_states and tf as sent (CDR)
        self._heard = 0.0  # [monotonic s] when the last status came
        self._state = 0
        self._alarms: tuple[Any, ...] = ()
        self._said: tuple[int, tuple[int, ...]] | None = None
        self._said_at = 0.0

    # -- the arm -------------------------------------------------------------------------------
    def _take_world(self, now: float) -> None:
        world = None
        sample = newest(self._world)
        if sample is not None:
            world = decode(SERVO_WORLD, sample)
        if world is None and self._asked is not None:
            try:
                reply = self._asked.try_recv()
            except zenoh.ZError:  # the get ended without an answer: asked again below
                reply, self._asked = None, None
            if reply is not None:
                self._asked = None
                world = decode(SERVO_WORLD, reply.ok) if reply.ok is not None else None
        if world is None and self.robot == "" and now - self._asked_at > ASK_EVERY:
            self._asked = self._session.get(self.keys.servo_world, zenoh.handlers.FifoChannel(4), payload=b"{}",
                                            timeout=ASK_EVERY)
            self._asked_at = now
        if world is not None and world.robot != self.robot:
            try:
                self._declare(robot_model(world.robot))
            except RobotModelError as exc:
                log.warning("arm %s: robot %r unknown here: %s", self.arm, world.robot, exc)

    def _declare(self, model: Any) -> None:
        """The node and its publishers for ``model`` (again if the arm's robot changed)."""
        self._undeclare()
        self.robot = model.name
        self._desc = msgs.ArmDescription.of(model)
        self._kin = msgs.Kinematics(self._desc)
        s = self.settings
        node = rmw.Node(s.domain, str(self._session.zid()), self.nid, s.namespace_of(self.arm), NODE_NAME)
        self._node_token = self._session.liveliness().declare_token(node.token())
        ns = node.namespace.rstrip("/")
        specs = (("joint_states", msgs.JOINT_STATE, rmw.STREAM), ("tf", msgs.TF_MESSAGE, rmw.STREAM),
                 ("robot_description", msgs.STRING, rmw.LATCHED), ("jara_arm/state", msgs.DIAGNOSTIC_STATUS,
                                                                   rmw.STREAM))
        for k, (name, ros_type, qos) in enumerate(specs, 1):
            self._topics[name] = _Topic(self._session, node, self.nid + k, f"{ns}/{name}", ros_type, qos)
        self._topics["robot_description"].put(msgs.description(self._desc))
        self._said, self._sent = None, None
        log.info("arm %s (%s): ROS 2 node %s/%s, domain %d", self.arm, self.robot, ns, NODE_NAME, s.domain)

    # -- each period ---------------------------------------------------------------------------
    def step(self, now: float) -> None:
        self._take_world(now)
        status = newest(self._status)
        if status is not None:
            st = decode(SERVO_STATUS, status)
            if st is not None and st.pos:
                self._last = (st.tm.to_seconds(), tuple(st.pos), tuple(st.vel))
                self._heard = now
        state = newest(self._state_sub)
        if state is not None:
            try:
                self._state = read_state(state.payload.to_bytes(), state.encoding).state
            except JaraArmError as exc:
                log.warning("arm %s: malformed state: %s", self.arm, exc)
        alarms = newest(self._alarms_sub)
        if alarms is not None:
            book = decode(ALARM_LIST, alarms)
            if book is not None:
                self._alarms = tuple(book.alarms)
        if self._desc is None or self._kin is None:
            return
        if self._last is not None and now - self._heard <= STALE:  # a stale pose repeated would look alive
            t, q, v = self._last
            if self._sent is not None and self._sent[0] == t:  # the same status (10 Hz at rest): as sent
                self._topics["joint_states"].put_cdr(self._sent[1])
                self._topics["tf"].put_cdr(self._sent[2])
            else:
                self._sent = (t, self._topics["joint_states"].put(msgs.joint_state(self._desc, t, q, v)),
                              self._topics["tf"].put(msgs.tf_message(self._kin, t, q)))
        said = (self._state, tuple(a.code for a in self._alarms))
        if said != self._said or now - self._said_at >= STATE_EVERY:
            self._topics["jara_arm/state"].put(msgs.arm_state(self.arm, self.robot, self._state, self._alarms))
            self._said, self._said_at = said, now

    def _undeclare(self) -> None:
        for topic in self._topics.values():
            topic.close()
        self._topics.clear()
        if self._node_token is not None:
            undeclare((self._node_token,))
            self._node_token = None

    def close(self) -> None:
        self._undeclare()
        undeclare((self._status, self._world, self._state_sub, self._alarms_sub))


class Bridge:
    """Every arm that comes (their liveliness tokens); :meth:`step` once per period, from one thread."""

    #: Entity ids per arm: its node's, then its publishers' (rmw_zenoh counts them per session).
    IDS_PER_ARM = 10

    def __init__(self, session: zenoh.Session, settings: BridgeSettings) -> None:
        self.settings = settings
        self._session = session
        self.arms: dict[str, ArmBridge] = {}
        self._tokens = session.liveliness().declare_subscriber(any_arm_alive(), zenoh.handlers.FifoChannel(1024),
                                                               history=True)

    def step(self) -> None:
        while (sample := self._tokens.try_recv()) is not None:
            try:
                arm, service = parse_alive(str(sample.key_expr))
            except JaraArmError:
                continue
            wanted = not self.settings.arms or arm in self.settings.arms
            if wanted and sample.kind == zenoh.SampleKind.PUT and service == Service.SERVO.value \
                    and arm not in self.arms:
                self.arms[arm] = ArmBridge(self._session, arm, self.settings, self.IDS_PER_ARM * len(self.arms))
                log.info("arm %s appeared", arm)
        now = time.monotonic()
        for bridge in self.arms.values():
            bridge.step(now)

    def close(self) -> None:
        self._tokens.undeclare()
        for bridge in self.arms.values():
            bridge.close()


def run_bridge(session: zenoh.Session, settings: BridgeSettings, stop: threading.Event, out: TextIO) -> int:
    bridge = Bridge(session, settings)
    try:
        print(f"jara-arm ros2: ROS 2 domain {settings.domain}, {settings.rate:g} Hz, "
              f"{'arms ' + ', '.join(settings.arms) if settings.arms else 'every arm'} (Ctrl-C to stop)",
              file=out, flush=True)
        period = 1.0 / settings.rate
        next_at = time.monotonic()
        while not stop.is_set():
            bridge.step()
            next_at = max(next_at + period, time.monotonic())  # late: the next period, not a burst
            stop.wait(max(0.0, next_at - time.monotonic()))
        return 0
    finally:
        bridge.close()


def _domain(text: str) -> int:
    try:
        return rmw.check_domain(int(text))
    except (ValueError, rmw.Rmw2Error) as exc:
        raise argparse.ArgumentTypeError(str(exc) if isinstance(exc, rmw.Rmw2Error) else
                                         f"{text!r} is not a ROS domain id") from None


def _namespace(text: str) -> str:
    if text in ("", "/"):  # the default (/<arm>), or the root namespace
        return text
    try:
        return "/" + rmw.check_name(text, "namespace").strip("/")
    except rmw.Rmw2Error as exc:
        raise argparse.ArgumentTypeError(str(exc)) from None


def add_ros_arguments(parser: argparse.ArgumentParser, prefix: str = "") -> None:
    """``--ros-domain``, ``--ros-namespace`` and ``--ros-rate`` (``jara-arm up --ros2`` has them too)."""
    parser.add_argument("--ros-domain", type=_domain, default=DEFAULT_DOMAIN, metavar="N",
                        help=f"the ROS 2 domain id, 0 .. 232 (default: {DEFAULT_DOMAIN}, as ROS_DOMAIN_ID)")
    parser.add_argument("--ros-namespace", type=_namespace, default="", metavar="NS",
                        help="the ROS namespace of the arm's node and topics (default: /<arm>)")
    parser.add_argument("--ros-rate", type=positive_float, default=DEFAULT_RATE, metavar="HZ",
                        help=f"joint_states and tf a second (default: {DEFAULT_RATE:g})")


def _arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--arm", type=arm_id, action="append", default=[], metavar="ID",
                        help="only this arm (repeatable; default: every arm that comes)")
    add_ros_arguments(parser)
    add_client_zenoh_arguments(parser)


def _run(args: argparse.Namespace, parser: argparse.ArgumentParser) -> int:
    setup_logging("INFO")
    arms = tuple(dict.fromkeys(args.arm))
    if args.ros_namespace and len(arms) != 1:
        print(f"{parser.prog}: --ros-namespace names one arm's node: give exactly one --arm", file=sys.stderr)
        return USAGE_ERROR
    with listening(args, parser, timestamping=True) as (session, stop):  # rmw_zenoh's sessions have it too
        return run_bridge(session, BridgeSettings(arms, args.ros_domain, args.ros_namespace, args.ros_rate),
                          stop, sys.stdout)


COMMAND = Command(
    "ros2", arguments=_arguments, run=_run,
    help="every arm as ROS 2 topics, for nodes on rmw_zenoh (read only)",
    description="Publish each arm's joint_states, tf, robot_description and jara_arm/state as ROS 2's Zenoh "
    "middleware (rmw_zenoh, Jazzy) does, with its node and publisher liveliness tokens: a ROS 2 node "
    "with RMW_IMPLEMENTATION=rmw_zenoh_cpp connected to the cell's router sees them, no bridge node "
    "needed. It never moves an arm.")
