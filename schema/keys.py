"""Key expressions of the wire contract (WIRE.md), and the internal ones.

Every key the system uses is built here, from one prefix, so that no other
module spells a key expression by hand.
"""

from __future__ import annotations

import dataclasses
import enum
import re

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
class ArmKeys:
    """All key expressions of one arm."""

    arm: str = DEFAULT_ARM

    def __post_init__(self) -> None:
        check_arm(self.arm)

    @property
    def root(self) -> str:
        return f"{PREFIX}/{self.arm}"

    # -- public contract (WIRE.md) -------------------------------------------------
    def interface(self, interface: Interface, op: str | None = None) -> str:
        """``Common/<op>`` or ``Middle/<op>`` (command service); ``op=None`` gives ``/*``."""
        if op is not None:
            operation(interface, op)
        return f"{self.root}/{interface.value}/{op or '*'}"

    def servo_common(self, op: str | None = None) -> str:
        """``Servo/Common/<op>`` (servo service); ``op=None`` gives ``/*``."""
        if op is not None:
            operation(Interface.COMMON, op)
        return f"{self.root}/Servo/{Interface.COMMON.value}/{op or '*'}"

    @property
    def pos_cmd(self) -> str:
        """``TimedJointPos`` commands into the servo's SyncFIFO."""
        return f"{self.root}/Servo/posCmd"

    @property
    def pos_block(self) -> str:
        """``PositionBlock``: the planner's commands into the same SyncFIFO, a few cycles per message."""
        return f"{self.root}/Servo/posBlock"

    @property
    def pos_feedback(self) -> str:
        """``TimedJointPos`` measured every cycle by the servo."""
        return f"{self.root}/Servo/posFeedback"

    @property
    def state(self) -> str:
        return f"{self.root}/state"

    @property
    def alarm(self) -> str:
        return f"{self.root}/alarm"

    @property
    def estop(self) -> str:
        return f"{self.root}/estop"

    def log(self, service: Service | None = None) -> str:
        return f"{self.root}/log/{service or '*'}"

    def alive(self, service: Service | None = None) -> str:
        return f"{self.root}/alive/{service or '*'}"

    # -- internal, between services (documented in the generated schema) ----------
    @property
    def servo_status(self) -> str:
        """``ServoStatus`` from the servo at a few hundred Hz: FIFO, velocities, efforts."""
        return f"{self.root}/Servo/status"

    @property
    def planner_plan(self) -> str:
        """Queryable of the planner: ``MotionRequest`` -> ``PlanReply`` (schema.planner)."""
        return f"{self.root}/Planner/plan"

    @property
    def planner_control(self) -> str:
        """Queryable of the planner: ``ControlRequest`` -> ``{id, comment}``."""
        return f"{self.root}/Planner/control"

    @property
    def planner_progress(self) -> str:
        """``PlannerProgress`` from the planner, on every change and at 10 Hz."""
        return f"{self.root}/Planner/progress"

    @property
    def servo_health(self) -> str:
        """``LoopHealth`` from the servo about once a second: lateness, overruns, underruns."""
        return f"{self.root}/Servo/health"

    def monitor_common(self, op: str | None = None) -> str:
        """``Monitor/Common/<op>`` (alarm monitor): ``getActiveAlarm`` and ``clearAlarms``."""
        if op is not None:
            operation(Interface.COMMON, op)
        return f"{self.root}/Monitor/{Interface.COMMON.value}/{op or '*'}"

    @property
    def monitor_alarms(self) -> str:
        """``AlarmList`` from the alarm monitor on every change and at 2 Hz; a get answers it too."""
        return f"{self.root}/Monitor/alarms"

    @property
    def monitor_report(self) -> str:
        """``AlarmReport`` from any service to the alarm monitor: raised, or its cause gone."""
        return f"{self.root}/Monitor/report"

    def alarm_copy(self, service: Service | None = None) -> str:
        """Queryable of the servo and the command service: the newest ``AlarmList`` it adopted,
        for an alarm monitor that restarts; ``None`` gives ``/*``."""
        return f"{self.root}/Monitor/copy/{service or '*'}"

    @property
    def command_settings(self) -> str:
        """``MotionSettings`` from the command service on change and at 4 Hz."""
        return f"{self.root}/Command/settings"

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


#: The key-expression table of WIRE.md, for the generated schema and the README.
KEY_TABLE: tuple[tuple[str, str, str, str], ...] = (
    ("JARA_ARM/<arm>/Common/<op>", "queryable", "command", "request map -> reply map"),
    ("JARA_ARM/<arm>/Middle/<op>", "queryable", "command", "request map -> reply map"),
    ("JARA_ARM/<arm>/Servo/Common/<op>", "queryable", "servo", "request map -> reply map"),
    ("JARA_ARM/<arm>/Servo/posCmd", "subscriber", "servo", "TimedJointPos, SyncFIFO"),
    ("JARA_ARM/<arm>/Servo/posFeedback", "publisher", "servo", "TimedJointPos, every cycle"),
    ("JARA_ARM/<arm>/state", "publisher", "command", "StateMessage, on every change"),
    ("JARA_ARM/<arm>/alarm", "publisher", "alarm-monitor", "AlarmEvent"),
    ("JARA_ARM/<arm>/estop", "subscriber", "every service that moves the arm", "any put"),
    ("JARA_ARM/<arm>/log/<service>", "publisher", "every service", "LogRecord"),
    ("JARA_ARM/<arm>/alive/<service>", "liveliness token", "every service", "-"),
    ("JARA_ARM/<arm>/Servo/posBlock", "subscriber (internal)", "servo",
     "PositionBlock from the planner: several cycles' commands into the same SyncFIFO"),
    ("JARA_ARM/<arm>/Servo/status", "publisher (internal)", "servo",
     "ServoStatus, every 10 cycles (every 100 and on change when settled)"),
    ("JARA_ARM/<arm>/Servo/health", "publisher (internal)", "servo", "LoopHealth, ~1 Hz"),
    ("JARA_ARM/<arm>/Planner/plan", "queryable (internal)", "planner", "MotionRequest -> PlanReply"),
    ("JARA_ARM/<arm>/Planner/control", "queryable (internal)", "planner",
     "ControlRequest -> {id, comment}"),
    ("JARA_ARM/<arm>/Planner/progress", "publisher (internal)", "planner", "PlannerProgress"),
    ("JARA_ARM/<arm>/Monitor/Common/<op>", "queryable (internal)", "alarm-monitor",
     "getActiveAlarm, clearAlarms (Common table); other ops NOT_IMPLEMENTED"),
    ("JARA_ARM/<arm>/Monitor/alarms", "publisher and queryable (internal)", "alarm-monitor",
     "AlarmList, on every change and at 2 Hz"),
    ("JARA_ARM/<arm>/Monitor/report", "subscriber (internal)", "alarm-monitor",
     "AlarmReport from the services"),
    ("JARA_ARM/<arm>/Monitor/copy/<service>", "queryable (internal)", "servo, command",
     "the newest AlarmList the service adopted: what a restarted monitor takes over"),
    ("JARA_ARM/<arm>/Command/settings", "publisher (internal)", "command",
     "MotionSettings, on change and at 4 Hz"),
    ("JARA_ARM/<arm>/heartbeat/<service>", "publisher (internal)", "every service",
     "Heartbeat, every heartbeat period (100 ms same-host): the process runs; which loops are stuck"),
)
