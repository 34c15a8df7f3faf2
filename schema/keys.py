"""Key expressions of the wire contract (WIRE.md), and the internal ones.

Every key the system uses is built here, from one prefix, so that no other
module spells a key expression by hand; and here each declares the encoding of
what it carries (:class:`KeyEncoding`), which publishers take with
:func:`encoding_of`: JSON for what people watch (logs, alarms, state), so that
any Zenoh tool reads it, MessagePack for the high-rate and internal streams.
"""

from __future__ import annotations

import dataclasses
import enum
import functools
import inspect
import re
from collections.abc import Callable
from typing import TypeVar, cast

from .encoding import Encoding
from .errors import JaraArmError
from .operations import Interface, operation
from .traffic import Traffic

PREFIX = "JARA_ARM"
DEFAULT_ARM = "arm0"
#: The arm chunk of a key expression that matches every arm (``ArmKeys(ANY_ARM)``), e.g. for access rules.
ANY_ARM = "*"
_ARM_ID = re.compile(r"[A-Za-z0-9_-]+")


class Service(enum.StrEnum):
    """The four services of an arm; the value is the ``<service>`` key chunk."""

    COMMAND = "command"
    PLANNER = "planner"
    SERVO = "servo"
    ALARM_MONITOR = "alarm-monitor"


class ArmIdError(JaraArmError, ValueError):
    """An arm id that is not one key chunk of ``[A-Za-z0-9_-]``."""


def check_arm(arm: str) -> str:
    """``arm`` if it is a valid arm id, else ArmIdError saying what is allowed."""
    if not isinstance(arm, str) or not _ARM_ID.fullmatch(arm):
        raise ArmIdError(f"arm id {arm!r} must be one chunk of [A-Za-z0-9_-], e.g. {DEFAULT_ARM!r}")
    return arm


class KeyEncoding(enum.Enum):
    """The encoding of what a key carries; the value is the key table's ``encoding`` column."""

    JSON = Encoding.JSON.value  #: what people watch: any Zenoh tool reads it (``payload.to_string()``)
    MSGPACK = Encoding.MSGPACK.value  #: the high-rate streams and the internal messages
    AS_REQUEST = "as the request"  #: a queryable's replies: JSON to a JSON request, else MessagePack
    NONE = "none"  #: no payload of its own (a liveliness token; any put)

    @property
    def encoding(self) -> Encoding | None:
        """The codec of every payload on the key; None if the request decides, or there is none."""
        return Encoding(self.value) if self in (KeyEncoding.JSON, KeyEncoding.MSGPACK) else None


@dataclasses.dataclass(frozen=True)
class KeyInfo:
    """One row of the key table: what a key of :class:`ArmKeys` carries, in which encoding, and who serves it."""

    key: str
    kind: str
    by: str
    payload: str
    encoding: KeyEncoding
    #: the priority and congestion control its messages travel with (schema/traffic.py)
    traffic: Traffic


_F = TypeVar("_F", bound=Callable[..., str])


def _key(kind: str, by: str, payload: str, encoding: KeyEncoding, traffic: Traffic,
         examples: tuple[tuple[object, ...], ...] = ((None,),)) -> Callable[[_F], _F]:
    """Marks an :class:`ArmKeys` member as a key of the table (:data:`KEY_TABLE`); ``examples``
    are the arguments (besides ``self``) of its rows, ``None`` standing for a ``<param>`` chunk."""

    def mark(fn: _F) -> _F:
        fn.__key_rows__ = (kind, by, payload, encoding, traffic, examples)  # type: ignore[attr-defined]
        return fn

    return mark


@dataclasses.dataclass(frozen=True)
class ArmKeys:
    """All key expressions of one arm."""

    arm: str = DEFAULT_ARM

    def __post_init__(self) -> None:
        if self.arm != ANY_ARM:
            check_arm(self.arm)

    @property
    def root(self) -> str:
        return f"{PREFIX}/{self.arm}"

    # -- public contract (WIRE.md) -------------------------------------------------
    @_key('queryable', 'command', 'request map → reply map', KeyEncoding.AS_REQUEST,
          Traffic.REPLY, examples=((Interface.COMMON, None), (Interface.MIDDLE, None), (Interface.EXT, None)))
    def interface(self, interface: Interface, op: str | None = None) -> str:
        """``Common/<op>``, ``Middle/<op>`` or ``Ext/<op>`` (command service; ``Ext``: model-specific
        extensions outside the IDL); ``op=None`` gives ``/*``."""
        if op is not None:
            operation(interface, op)
        return f"{self.root}/{interface.value}/{op or '*'}"

    @_key('queryable', 'servo', 'request map → reply map', KeyEncoding.AS_REQUEST, Traffic.REPLY)
    def servo_common(self, op: str | None = None) -> str:
        """``Servo/Common/<op>`` (servo service); ``op=None`` gives ``/*``."""
        if op is not None:
            operation(Interface.COMMON, op)
        return f"{self.root}/Servo/{Interface.COMMON.value}/{op or '*'}"

    @property
    @_key('subscriber', 'servo', '`TimedJointPos`, SyncFIFO', KeyEncoding.MSGPACK, Traffic.STREAM)
    def pos_cmd(self) -> str:
        """``TimedJointPos`` commands into the servo's SyncFIFO."""
        return f"{self.root}/Servo/posCmd"

    @property
    @_key('publisher', 'servo', '`TimedJointPos`, every cycle (to a client gateway\'s clients: the gateway, from '
          '`Servo/posFeedbackBlock`)', KeyEncoding.MSGPACK, Traffic.FEEDBACK)
    def pos_feedback(self) -> str:
        """``TimedJointPos`` measured every cycle by the servo."""
        return f"{self.root}/Servo/posFeedback"

    @property
    @_key('publisher', 'servo', '`FeedbackBlock`, every `FEEDBACK_BLOCK_CYCLES` cycles, while a client gateway '
          'takes it (internal: the gateway publishes its samples on `Servo/posFeedback`)',
          KeyEncoding.MSGPACK, Traffic.FEEDBACK)
    def pos_feedback_block(self) -> str:
        """``FeedbackBlock``: the ``posFeedback`` samples of the last few cycles, for the client gateway."""
        return f"{self.root}/Servo/posFeedbackBlock"

    @property
    @_key('publisher', 'servo', '`TimedJointPos`, each cycle that follows a command, only with the servo\'s '
          '`--publish-targets` and while something subscribes',
          KeyEncoding.MSGPACK, Traffic.INFO)
    def pos_target(self) -> str:
        """``TimedJointPos``: the command the servo followed in a cycle (from its interpolator or the
        SyncFIFO), beside the measured ``posFeedback``; nothing while it holds or brakes by itself."""
        return f"{self.root}/Servo/posTarget"

    @property
    @_key('publisher', 'command', '`StateMessage` `{state, ...}` on every change', KeyEncoding.JSON, Traffic.STATE)
    def state(self) -> str:
        return f"{self.root}/state"

    @property
    @_key('publisher', 'alarm monitor', '`AlarmEvent` `{event, alarm}`', KeyEncoding.JSON, Traffic.CONTROL)
    def alarm(self) -> str:
        return f"{self.root}/alarm"

    @property
    @_key('subscriber', 'every service that moves the arm', 'any put', KeyEncoding.NONE, Traffic.SAFETY)
    def estop(self) -> str:
        return f"{self.root}/estop"

    @_key('publisher', 'every service', '`LogRecord` `{t, level, service, msg, logger}`', KeyEncoding.JSON, Traffic.INFO)
    def log(self, service: Service | None = None) -> str:
        return f"{self.root}/log/{service or '*'}"

    @_key('liveliness token', 'every service', '—', KeyEncoding.NONE, Traffic.SAFETY)
    def alive(self, service: Service | None = None) -> str:
        return f"{self.root}/alive/{service or '*'}"

    @_key('publisher', 'the service answering the call',
          '`CallTrace` `{t, request, reply}` of every call answered on `<served>/<op>`, only while something '
          'subscribes', KeyEncoding.JSON,
          Traffic.TRACE, examples=((Interface.COMMON.value, None), (Interface.MIDDLE.value, None), (Interface.EXT.value, None),
                    (f"Servo/{Interface.COMMON.value}", None), (f"Monitor/{Interface.COMMON.value}", None)))
    def trace(self, served: str, op: str | None = None) -> str:
        """``trace/<served>/<op>``: the calls answered on ``<served>/<op>`` of this arm, ``served`` being
        the interface part of an operation queryable (:meth:`interface`, :meth:`servo_common`,
        :meth:`monitor_common`): ``Common``, ``Middle``, ``Ext``, ``Servo/Common`` or ``Monitor/Common``;
        ``op=None`` gives ``/*``. Queries reach no one but their queryable: the serving service
        publishes each call here so that a recorder sees it."""
        if served not in self._served():
            raise JaraArmError(f"{served!r} is not the interface part of an operation queryable; "
                               f"valid: {', '.join(self._served())}")
        if op is not None:
            operation(Interface(served.rsplit("/", 1)[-1]), op)
        return f"{self.root}/trace/{served}/{op or '*'}"

    def _served(self) -> tuple[str, ...]:
        """The interface parts of the operation queryables, relative to the arm (``Servo/Common``…)."""
        queryables = (*(self.interface(i) for i in Interface), self.servo_common(), self.monitor_common())
        return tuple(k.removeprefix(f"{self.root}/").removesuffix("/*") for k in queryables)

    def traced(self, queryable: str) -> str:
        """The :meth:`trace` key of the calls answered on ``queryable``, an operation queryable of this
        arm (``.../Common/getState``, or ``.../Servo/Common/*`` for every operation)."""
        served, _, op = queryable.removeprefix(f"{self.root}/").rpartition("/")
        if not queryable.startswith(f"{self.root}/"):
            raise JaraArmError(f"{queryable!r} is not a key of arm {self.arm!r}")
        return self.trace(served, None if op == "*" else op)

    @property
    def every_key(self) -> str:
        """``JARA_ARM/<arm>/**``: every key of the arm (what a recorder subscribes to)."""
        return f"{self.root}/**"

    # -- internal, between services (documented in the generated schema) ----------
    @property
    @_key('publisher (internal)', 'servo', '`ServoStatus`, every 10 cycles (every 100, and on any change, while '
          'settled at rest; at once when one of its latched alarms or their causes comes or goes)',
          KeyEncoding.MSGPACK, Traffic.CONTROL)
    def servo_status(self) -> str:
        """``ServoStatus`` from the servo at 100 Hz while it moves: FIFO, velocities, efforts, and the alarms it
        latched itself (the alarm monitor's evidence of them)."""
        return f"{self.root}/Servo/status"

    @property
    @_key('publisher + queryable (internal)', 'servo', '`ServoWorld` (robot model, obstacles) every second; a get '
          'answers it too', KeyEncoding.JSON, Traffic.INFO)
    def servo_world(self) -> str:
        """``ServoWorld`` from the servo: its robot model and obstacles, for viewers (every second, and to a get)."""
        return f"{self.root}/Servo/world"

    @property
    @_key('queryable (internal)', 'planner', '`MotionRequest` → `PlanReply`', KeyEncoding.AS_REQUEST, Traffic.REPLY)
    def planner_plan(self) -> str:
        """Queryable of the planner: ``MotionRequest`` -> ``PlanReply`` (schema.planner)."""
        return f"{self.root}/Planner/plan"

    @property
    @_key('queryable (internal)', 'planner', '`ControlRequest` → `ControlReply`', KeyEncoding.AS_REQUEST, Traffic.REPLY)
    def planner_control(self) -> str:
        """Queryable of the planner: ``ControlRequest`` -> ``{id, comment}``."""
        return f"{self.root}/Planner/control"

    @property
    @_key('queryable (internal)', 'planner', '`MotionRequest` (a jog) → `ControlReply`', KeyEncoding.AS_REQUEST,
          Traffic.REPLY)
    def planner_jog(self) -> str:
        """Queryable of the planner: ``Ext/jogJoint``, ``jogCartesian`` and ``jogStop`` (``MotionRequest``) ->
        ``ControlReply``; served beside ``Planner/plan``, so a lease renewal never waits for a plan."""
        return f"{self.root}/Planner/jog"

    @property
    @_key('publisher (internal)', 'planner', '`PlannerProgress`', KeyEncoding.MSGPACK, Traffic.CONTROL)
    def planner_progress(self) -> str:
        """``PlannerProgress`` from the planner, on every change and at 10 Hz."""
        return f"{self.root}/Planner/progress"

    @property
    @_key('queryable (internal)', 'servo', '`Trajectory` → `MotionReply`', KeyEncoding.AS_REQUEST, Traffic.STREAM)
    def servo_trajectory(self) -> str:
        """Queryable of the servo: one accepted motion's joint samples into its interpolator (schema.motion)."""
        return f"{self.root}/Servo/trajectory"

    @property
    @_key('queryable (internal)', 'servo', '`MotionControl` → `MotionReply`', KeyEncoding.AS_REQUEST, Traffic.STREAM)
    def servo_motion_control(self) -> str:
        """Queryable of the servo: pause, resume, stop, abort and the speed override (schema.motion)."""
        return f"{self.root}/Servo/motionControl"

    @property
    @_key('queryable (internal)', 'servo', '`PowerRequest` → `PowerReply`', KeyEncoding.AS_REQUEST, Traffic.STREAM)
    def servo_power(self) -> str:
        """Queryable of the servo: servo on, off, clearAlarms; the reply carries its status after it (schema.power)."""
        return f"{self.root}/Servo/power"

    @property
    @_key('publisher (internal)', 'servo', '`MotionProgress`, on every change and at 10 Hz', KeyEncoding.MSGPACK,
          Traffic.CONTROL)
    def servo_motion(self) -> str:
        """``MotionProgress``: the servo interpolator's buffered motions (schema.motion)."""
        return f"{self.root}/Servo/motion"

    @property
    @_key('publisher (internal)', 'planner', '`PlannedPath`: the control point polyline of each accepted motion',
          KeyEncoding.MSGPACK, Traffic.INFO)
    def planner_path(self) -> str:
        """``PlannedPath`` from the planner, once per accepted motion."""
        return f"{self.root}/Planner/path"

    @property
    @_key('publisher (internal)', 'servo', '`LoopHealth`, ~1 Hz', KeyEncoding.JSON, Traffic.INFO)
    def servo_health(self) -> str:
        """``LoopHealth`` from the servo about once a second: lateness, overruns, underruns."""
        return f"{self.root}/Servo/health"

    @_key('queryable (internal)', 'alarm monitor', '`getActiveAlarm`, `clearAlarms` (Common table); other operations NOT_IMPLEMENTED',
          KeyEncoding.AS_REQUEST, Traffic.REPLY)
    def monitor_common(self, op: str | None = None) -> str:
        """``Monitor/Common/<op>`` (alarm monitor): ``getActiveAlarm`` and ``clearAlarms``."""
        if op is not None:
            operation(Interface.COMMON, op)
        return f"{self.root}/Monitor/{Interface.COMMON.value}/{op or '*'}"

    @property
    @_key('publisher + queryable (internal)', 'alarm monitor', '`AlarmList` on every change and at 2 Hz',
          KeyEncoding.JSON, Traffic.STATE)
    def monitor_alarms(self) -> str:
        """``AlarmList`` from the alarm monitor on every change and at 2 Hz; a get answers it too."""
        return f"{self.root}/Monitor/alarms"

    @property
    @_key('queryable (internal)', 'servo', 'the `AlarmList` the servo holds: what a restarted monitor takes over',
          KeyEncoding.MSGPACK, Traffic.REPLY)
    def alarm_copy(self) -> str:
        """Queryable of the servo: the monitor's newest ``AlarmList`` as the servo holds it (less
        what it cleared without a monitor), for an alarm monitor that restarts."""
        return f"{self.root}/Monitor/copy"

    @property
    @_key('publisher (internal)', 'command', '`MotionSettings` on change and at 4 Hz', KeyEncoding.JSON, Traffic.STATE)
    def command_settings(self) -> str:
        """``MotionSettings`` from the command service on change and at 4 Hz."""
        return f"{self.root}/Command/settings"

    @_key('publisher (internal)', 'every service', '`Heartbeat {seq, stuck}` every heartbeat period (100 ms same-host)',
          KeyEncoding.MSGPACK, Traffic.SAFETY)
    def heartbeat(self, service: Service | None = None) -> str:
        """``Heartbeat`` from every service every ``Health.heartbeat_period`` (services/runtime/timing.py); ``None`` gives ``/*``."""
        return f"{self.root}/heartbeat/{service or '*'}"


def any_arm_log(service: Service | None = None) -> str:
    """Logs of every arm (``JARA_ARM/*/log/<service or *>``)."""
    return f"{PREFIX}/*/log/{service or '*'}"


def any_arm_every_key() -> str:
    """``JARA_ARM/**``: every key of every arm."""
    return f"{PREFIX}/**"


def any_arm_alive() -> str:
    return f"{PREFIX}/*/alive/*"


def any_arm_alarm() -> str:
    """Alarm events of every arm (``JARA_ARM/*/alarm``)."""
    return f"{PREFIX}/*/alarm"


def any_arm_monitor_common(op: str) -> str:
    """``JARA_ARM/*/Monitor/Common/<op>``: a get reaches the alarm monitor of every arm."""
    operation(Interface.COMMON, op)
    return f"{PREFIX}/*/Monitor/{Interface.COMMON.value}/{op}"


def arm_of(key: str) -> str:
    """The ``<arm>`` chunk of any key of this contract."""
    parts = str(key).split("/")
    if len(parts) < 3 or parts[0] != PREFIX:
        raise JaraArmError(f"not a {PREFIX} key: {key!r}")
    return check_arm(parts[1])


def parse_alive(key: str) -> tuple[str, str]:
    """``(arm, service)`` from an ``alive`` key."""
    parts = str(key).split("/")
    if len(parts) != 4 or parts[0] != PREFIX or parts[2] != "alive":
        raise JaraArmError(f"not a liveliness key: {key!r}")
    return parts[1], parts[3]


def parse_heartbeat(key: str) -> tuple[str, str]:
    """``(arm, service)`` from a ``heartbeat`` key."""
    parts = str(key).split("/")
    if len(parts) != 4 or parts[0] != PREFIX or parts[2] != "heartbeat":
        raise JaraArmError(f"not a heartbeat key: {key!r}")
    return parts[1], parts[3]


def parse_log(key: str) -> tuple[str, str]:
    """``(arm, service)`` from a ``log`` key."""
    parts = str(key).split("/")
    if len(parts) != 4 or parts[0] != PREFIX or parts[2] != "log":
        raise JaraArmError(f"not a log key: {key!r}")
    return parts[1], parts[3]


def op_of(key: str) -> str:
    """The ``<op>`` chunk of an interface key."""
    return str(key).rsplit("/", 1)[-1]


def _key_table() -> tuple[KeyInfo, ...]:
    """Every key :class:`ArmKeys` declares with :func:`_key`, in the order of the class."""
    rows: list[KeyInfo] = []
    sample = ArmKeys("ARM")
    for name, member in vars(ArmKeys).items():
        getter = member.fget if isinstance(member, property) else member
        marked: tuple[str, str, str, KeyEncoding, Traffic, tuple[tuple[object, ...], ...]] | None = getattr(
            getter, "__key_rows__", None)
        if marked is None:
            continue
        fn = cast(Callable[..., str], getter)  # marked, so _key took it: a Callable[..., str]
        kind, by, payload, encoding, traffic, examples = marked
        params = [p for p in inspect.signature(fn).parameters if p != "self"]
        for args in examples:
            key: str = getattr(sample, name) if isinstance(member, property) else getattr(sample, name)(*args)
            if params and args[-1] is None:  # the wildcard chunk names its parameter
                key = key[:-1] + f"<{params[-1]}>"
            rows.append(KeyInfo(key.replace(f"{PREFIX}/ARM/", f"{PREFIX}/<arm>/", 1), kind, by, payload, encoding,
                                traffic))
    return tuple(rows)


#: The key-expression table of WIRE.md, generated from :class:`ArmKeys`: for the generated
#: schema (``schema/generate.py``) and the README's table.
KEY_TABLE: tuple[KeyInfo, ...] = _key_table()

#: Each row's key as a pattern: ``<arm>`` and ``<param>`` chunks match any one chunk (``*`` too).
_PATTERNS = tuple((re.compile(re.sub(r"<\w+>", "[^/]+", re.escape(row.key).replace(r"\<", "<").replace(r"\>", ">"))),
                   row) for row in KEY_TABLE)


@functools.lru_cache(maxsize=256)
def key_info(key: str) -> KeyInfo:
    """The row of :data:`KEY_TABLE` that ``key`` (built by :class:`ArmKeys`) is an instance of."""
    for pattern, row in _PATTERNS:
        if pattern.fullmatch(key):
            return row
    raise JaraArmError(f"not a key of the key table: {key!r}")


def traffic_of(key: str) -> Traffic:
    """The traffic class every message on ``key`` travels with (its publisher's, its queryable's replies)."""
    return key_info(key).traffic


def encoding_of(key: str) -> Encoding:
    """The encoding every payload on ``key`` has (its publisher's, and its queryable's replies).

    Raises JaraArmError for a key whose replies follow the request (:attr:`KeyEncoding.AS_REQUEST`)
    or that carries no payload: a publisher of it is a mistake of ours.
    """
    row = key_info(key)
    if row.encoding.encoding is None:
        raise JaraArmError(f"{row.key} has no encoding of its own ({row.encoding.value})")
    return row.encoding.encoding


# -- ROS 2 (``jara-arm ros2``, launcher/ros2/rmw.py): rmw_zenoh's keys, not ours; listed here for the roles ----------
#: The admin space of rmw_zenoh's liveliness tokens (``@ros2_lv/<domain>/...``).
ROS2_ADMIN_SPACE = "@ros2_lv"
#: Zenoh advanced publishers and subscribers (a transient-local topic's cache) add this chunk after a data key.
ROS2_ADVANCED = "@adv"


def ros2_data_keys() -> tuple[str, ...]:
    """Every rmw_zenoh data key of any ROS domain (``<domain>/<topic>/<type>/<hash>``): a first chunk that
    starts with a digit (key expressions have no numeric range; no key of ours starts with one)."""
    return tuple(f"{d}$*/**" for d in "0123456789")


def ros2_every_key() -> tuple[str, ...]:
    """The data keys, the advanced pub/sub keys under them, and the liveliness tokens of rmw_zenoh."""
    data = ros2_data_keys()
    return (*data, *(f"{k[:-3]}/**/{ROS2_ADVANCED}/**" for k in data), f"{ROS2_ADMIN_SPACE}/**")
