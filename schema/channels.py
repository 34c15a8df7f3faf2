"""The message type of every key that carries samples, and its JSON Schema standing alone.

A recorder gives each key a channel and each channel a schema (MCAP: one
JSON Schema per channel, read by the ``mcap`` CLI and Foxglove); a schema there
cannot point into ``jara_arm.schema.json``, so :func:`channel_schema` carries the
named types it refers to in its own ``$defs``.
"""

from __future__ import annotations

import json
from collections.abc import Mapping
from types import MappingProxyType
from typing import Any

from . import alarms, messages, motion, planner, power, wire_types
from . import wire_types as w
from .keys import ArmKeys, key_info
from .operations import Interface
from .wire_types import StructType

_DEFS_PREFIX = "#/$defs/"
#: The schema name and JSON Schema of a key that carries no message of its own (``estop``: any put).
ANY_PUT = "AnyPut"
_ANY_PUT_SCHEMA: dict[str, Any] = {
    "type": "object", "title": ANY_PUT,
    "description": 'any put: recorded as {} when empty, else as {"payload": its value or text}'}


def _message_types() -> Mapping[str, StructType[Any]]:
    """By key-table row (``key_info(key).key``): the type of every message published on it."""
    a = ArmKeys("ARM")
    pairs: tuple[tuple[str, StructType[Any]], ...] = (
        (a.pos_cmd, w.TIMED_JOINT_POS), (a.pos_feedback, w.TIMED_JOINT_POS), (a.pos_feedback_block, messages.FEEDBACK_BLOCK), (a.pos_target, w.TIMED_JOINT_POS),
        (a.state, messages.STATE_MESSAGE), (a.alarm, messages.ALARM_EVENT), (a.log(), messages.LOG_RECORD),
        (a.servo_status, messages.SERVO_STATUS), (a.planner_progress, planner.PLANNER_PROGRESS),
        (a.servo_health, messages.LOOP_HEALTH), (a.monitor_alarms, alarms.ALARM_LIST),
        (a.command_settings, planner.MOTION_SETTINGS),
        (a.heartbeat(), alarms.HEARTBEAT), (a.servo_world, messages.SERVO_WORLD), (a.planner_path, planner.PLANNED_PATH),
        (a.servo_motion, motion.MOTION_PROGRESS),
        *((a.traced(q), messages.CALL_TRACE) for q in (*(a.interface(i) for i in Interface), a.servo_common(),
                                                      a.monitor_common())),
    )
    return MappingProxyType({key_info(key).key: kind for key, kind in pairs})


#: The message type of each key-table row that samples are published on.
MESSAGE_TYPES: Mapping[str, StructType[Any]] = _message_types()


def definitions() -> dict[str, dict[str, Any]]:
    """Every named type and message as JSON Schema, by name (the ``$defs`` of the generated schema)."""
    defs = {t.name: t.json_schema() for t in wire_types.NAMED_TYPES}
    every = messages.MESSAGES + planner.MESSAGES + motion.MESSAGES + power.MESSAGES + alarms.MESSAGES
    defs.update({m.name: m.json_schema() for m in every})
    return defs


def message_type(key: str) -> StructType[Any] | None:
    """The type of the samples on ``key`` (a key of the key table); None for a key that carries
    none of its own (``estop``). Raises JaraArmError for a key outside the table."""
    return MESSAGE_TYPES.get(key_info(key).key)


def _refs(node: Any) -> set[str]:
    """The names of the ``$defs`` that ``node`` refers to directly."""
    if isinstance(node, dict):
        own = {node["$ref"].removeprefix(_DEFS_PREFIX)} if isinstance(node.get("$ref"), str) else set()
        return own.union(*(_refs(v) for v in node.values()))
    if isinstance(node, list):
        return set().union(*(_refs(v) for v in node))
    return set()


def channel_schema(key: str) -> tuple[str, bytes]:
    """``(name, JSON Schema)`` of the samples on ``key``, standing alone (its ``$defs`` hold every
    named type it refers to), as UTF-8 JSON: what an MCAP channel of ``key`` carries."""
    kind = message_type(key)
    if kind is None:
        return ANY_PUT, json.dumps({"$schema": "https://json-schema.org/draft/2020-12/schema",
                                    **_ANY_PUT_SCHEMA}).encode()
    every = definitions()
    schema: dict[str, Any] = {"$schema": "https://json-schema.org/draft/2020-12/schema", "title": kind.name,
                              **kind.json_schema()}
    wanted, pending = {}, _refs(schema)
    while pending:  # the closure of the references
        name = pending.pop()
        if name not in wanted:
            wanted[name] = every[name]
            pending |= _refs(every[name]) - set(wanted)
    if wanted:
        schema["$defs"] = dict(sorted(wanted.items()))
    return kind.name, json.dumps(schema).encode()
