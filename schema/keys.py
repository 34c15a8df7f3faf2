"""Key expressions of the wire contract (WIRE.md), and the internal ones.

Every key the system uses is built here, from one prefix, so that no other
module spells a key expression by hand.
"""

from __future__ import annotations

import dataclasses
import enum
import inspect
import re
from collections.abc import Callable
from typing import TypeVar, cast

from .errors import JaraArmError
from .operations import Interface, operation

PREFIX = "JARA_ARM"
DEFAULT_ARM = "arm0"
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


@dataclasses.dataclass(frozen=True)
class KeyInfo:
    """One row of the key table: what a key of :class:`ArmKeys` carries and who serves it."""

    key: str
    kind: str
    by: str
    payload: str


_F = TypeVar("_F", bound=Callable[..., str])


def _key(kind: str, by: str, payload: str, examples: tuple[tuple[object, ...], ...] = ((None,),)) -> Callable[[_F], _F]:
    """Marks an :class:`ArmKeys` member as a key of the table (:data:`KEY_TABLE`); ``examples``
    are the arguments (besides ``self``) of its rows, ``None`` standing for a ``<param>`` chunk."""

    def mark(fn: _F) -> _F:
        fn.__key_rows__ = (kind, by, payload, examples)  # type: ignore[attr-defined]
        return fn

    return mark


@dataclasses.dataclass(frozen=True)
class ArmKeys:
    """All key expressions of one arm."""

    arm: str = DEFAULT_ARM

    def __post_init__(self) -> None:
        check_arm(self.arm)

    @property
    def root(self) -> str:
        return f"{PREFIX}/{self.arm}"

    # -- public contract (WIRE.md) -------------------------------------------------
    @_key('queryable', 'command', 'request map → reply map', examples=((Interface.COMMON, None), (Interface.MIDDLE, None)))
    def interface(self, interface: Interface, op: str | None = None) -> str:
        """``Common/<op>`` or ``Middle/<op>`` (command service); ``op=None`` gives ``/*``."""
        if op is not None:
            operation(interface, op)
        return f"{self.root}/{interface.value}/{op or '*'}"

    @_key('queryable', 'servo', 'request map → reply map')
    def servo_common(self, op: str | None = None) -> str:
        """``Servo/Common/<op>`` (servo service); ``op=None`` gives ``/*``."""
        if op is not None:
            operation(Interface.COMMON, op)
        return f"{self.root}/Servo/{Interface.COMMON.value}/{op or '*'}"

    @property
    @_key('subscriber', 'servo', '`TimedJointPos`, SyncFIFO')
    def pos_cmd(self) -> str:
        """``TimedJointPos`` commands into the servo's SyncFIFO."""
        return f"{self.root}/Servo/posCmd"

    @property
    @_key('subscriber (internal)', 'servo', "`PositionBlock` from the planner: several cycles' commands into the same SyncFIFO")
    def pos_block(self) -> str:
        """``PositionBlock``: the planner's commands into the same SyncFIFO, a few cycles per message."""
        return f"{self.root}/Servo/posBlock"

    @property
    @_key('publisher', 'servo', '`TimedJointPos`, every cycle')
    def pos_feedback(self) -> str:
        """``TimedJointPos`` measured every cycle by the servo."""
        return f"{self.root}/Servo/posFeedback"

    @property
    @_key('publisher', 'command', '`StateMessage` `{state, ...}` on every change')
    def state(self) -> str:
        return f"{self.root}/state"

    @property
    @_key('publisher', 'alarm monitor', '`AlarmEvent` `{event, alarm}`')
    def alarm(self) -> str:
        return f"{self.root}/alarm"

    @property
    @_key('subscriber', 'every service that moves the arm', 'any put')
    def estop(self) -> str:
        return f"{self.root}/estop"

    @_key('publisher', 'every service', '`LogRecord` `{t, level, service, msg, logger}`')
    def log(self, service: Service | None = None) -> str:
        return f"{self.root}/log/{service or '*'}"

    @_key('liveliness token', 'every service', '—')
    def alive(self, service: Service | None = None) -> str:
        return f"{self.root}/alive/{service or '*'}"

    # -- internal, between services (documented in the generated schema) ----------
    @property
    @_key('publisher (internal)', 'servo', '`ServoStatus`, every 10 cycles (every 100, and on any change, while settled at rest)')
    def servo_status(self) -> str:
        """``ServoStatus`` from the servo at a few hundred Hz: FIFO, velocities, efforts."""
        return f"{self.root}/Servo/status"

    @property
    @_key('queryable (internal)', 'planner', '`MotionRequest` → `PlanReply`')
    def planner_plan(self) -> str:
        """Queryable of the planner: ``MotionRequest`` -> ``PlanReply`` (schema.planner)."""
        return f"{self.root}/Planner/plan"

    @property
    @_key('queryable (internal)', 'planner', '`ControlRequest` → `{id, comment}`')
    def planner_control(self) -> str:
        """Queryable of the planner: ``ControlRequest`` -> ``{id, comment}``."""
        return f"{self.root}/Planner/control"

    @property
    @_key('publisher (internal)', 'planner', '`PlannerProgress`')
    def planner_progress(self) -> str:
        """``PlannerProgress`` from the planner, on every change and at 10 Hz."""
        return f"{self.root}/Planner/progress"

    @property
    @_key('publisher (internal)', 'servo', '`LoopHealth`, ~1 Hz')
    def servo_health(self) -> str:
        """``LoopHealth`` from the servo about once a second: lateness, overruns, underruns."""
        return f"{self.root}/Servo/health"

    @_key('queryable (internal)', 'alarm monitor', '`getActiveAlarm`, `clearAlarms` (Common table); other operations NOT_IMPLEMENTED')
    def monitor_common(self, op: str | None = None) -> str:
        """``Monitor/Common/<op>`` (alarm monitor): ``getActiveAlarm`` and ``clearAlarms``."""
        if op is not None:
            operation(Interface.COMMON, op)
        return f"{self.root}/Monitor/{Interface.COMMON.value}/{op or '*'}"

    @property
    @_key('publisher + queryable (internal)', 'alarm monitor', '`AlarmList` on every change and at 2 Hz')
    def monitor_alarms(self) -> str:
        """``AlarmList`` from the alarm monitor on every change and at 2 Hz; a get answers it too."""
        return f"{self.root}/Monitor/alarms"

    @property
    @_key('subscriber (internal)', 'alarm monitor', '`AlarmReport` from the services: raised, or its cause gone')
    def monitor_report(self) -> str:
        """``AlarmReport`` from any service to the alarm monitor: raised, or its cause gone."""
        return f"{self.root}/Monitor/report"

    @property
    @_key('queryable (internal)', 'servo', 'the `AlarmList` the servo holds: what a restarted monitor takes over')
    def alarm_copy(self) -> str:
        """Queryable of the servo: the monitor's newest ``AlarmList`` as the servo holds it (less
        what it cleared without a monitor), for an alarm monitor that restarts."""
        return f"{self.root}/Monitor/copy"

    @property
    @_key('publisher (internal)', 'command', '`MotionSettings` on change and at 4 Hz')
    def command_settings(self) -> str:
        """``MotionSettings`` from the command service on change and at 4 Hz."""
        return f"{self.root}/Command/settings"

    @_key('publisher (internal)', 'every service', '`Heartbeat {seq, stuck}` every heartbeat period (100 ms same-host)')
    def heartbeat(self, service: Service | None = None) -> str:
        """``Heartbeat`` from every service every ``Health.heartbeat_period`` (services/runtime/timing.py); ``None`` gives ``/*``."""
        return f"{self.root}/heartbeat/{service or '*'}"


def any_arm_log(service: Service | None = None) -> str:
    """Logs of every arm (``JARA_ARM/*/log/<service or *>``)."""
    return f"{PREFIX}/*/log/{service or '*'}"


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
        marked: tuple[str, str, str, tuple[tuple[object, ...], ...]] | None = getattr(getter, "__key_rows__", None)
        if marked is None:
            continue
        fn = cast(Callable[..., str], getter)  # marked, so _key took it: a Callable[..., str]
        kind, by, payload, examples = marked
        params = [p for p in inspect.signature(fn).parameters if p != "self"]
        for args in examples:
            key: str = getattr(sample, name) if isinstance(member, property) else getattr(sample, name)(*args)
            if params and args[-1] is None:  # the wildcard chunk names its parameter
                key = key[:-1] + f"<{params[-1]}>"
            rows.append(KeyInfo(key.replace(f"{PREFIX}/ARM/", f"{PREFIX}/<arm>/", 1), kind, by, payload))
    return tuple(rows)


#: The key-expression table of WIRE.md, generated from :class:`ArmKeys`: for the generated
#: schema (``schema/generate.py``) and the README's table.
KEY_TABLE: tuple[KeyInfo, ...] = _key_table()
