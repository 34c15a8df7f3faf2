"""Who may do what on the wire: the roles of a secure cell, as Zenoh access-control rules.

A secure cell (``--secure DIR``, docs/secure_cell.md) authenticates every
connection with mutual TLS; the certificate's common name is the holder's
name, and the cell's registry gives each name one :class:`Role`. Every router
and peer then enforces the roles with Zenoh's own access control
(:func:`access_control`), so that a message a role does not allow is dropped
by Zenoh where it enters, before any of our code sees it.

The rights are derived from the key table (:mod:`.keys`) and the operation
table (:mod:`.operations`), never spelled by hand: a getter is an operation
that changes nothing (:func:`changes_nothing`).
"""

from __future__ import annotations

import enum
from collections.abc import Iterable, Mapping
from typing import Any

from .errors import JaraArmError
from .keys import ANY_ARM, ArmKeys, any_arm_every_key, ros2_every_key
from .operations import COMMON, EXT, MIDDLE, Interface, Operation


class RoleError(JaraArmError, ValueError):
    """A role name that is not one of :class:`Role`."""


class Role(enum.StrEnum):
    """What a certificate's holder may do; the value is its name in the registry and on the command line."""

    #: The system's own processes: every key of the cell, internal ones included (position
    #: commands, planner, monitor, heartbeats, liveliness tokens, settings).
    SERVICE = "service"
    #: A Zenoh router of the cell: routes everything to and from the other routers.
    ROUTER = "router"
    #: A person or program that drives the arm: every Common, Middle and Ext operation, the
    #: low-level ``Servo/Common`` operations, ``Monitor/Common``, the e-stop; watches everything.
    OPERATOR = "operator"
    #: An operator that may also stream its own position commands (``Servo/posCmd``, SyncFIFO),
    #: as a low-level client of WIRE.md does. Never ``Servo/trajectory`` or ``Servo/motionControl``:
    #: the planner alone hands motions to the servo; nor ``Servo/power``: the command's (a client switches
    #: the servo through ``Servo/Common``).
    LOW_LEVEL = "low-level"
    #: Watches everything and may stop the arm (anyone who can see the arm may stop it):
    #: getters only, subscriptions, liveliness, the e-stop.
    OBSERVER = "observer"

    @classmethod
    def parse(cls, text: str) -> Role:
        """The role named ``text``; RoleError listing the valid ones otherwise."""
        try:
            return cls(text)
        except ValueError:
            raise RoleError(f"unknown role {text!r}; roles: {', '.join(r.value for r in cls)}") from None


#: Zenoh's access-control message kinds (zenoh 1.x ``AclMessage``).
EVERY_MESSAGE = ("put", "delete", "declare_subscriber", "query", "reply", "declare_queryable",
                 "liveliness_token", "declare_liveliness_subscriber", "liveliness_query")


def changes_nothing(op: Operation) -> bool:
    """A getter: the IDL names every operation that only reads ``get<What>``."""
    return op.name.startswith("get")


def _operation_keys(ops: Iterable[Operation], keys: ArmKeys) -> list[str]:
    out = []
    for op in ops:
        out.append(keys.interface(op.interface, op.name))
        if op.interface is Interface.COMMON:  # the same table, answered by the servo and the monitor
            out.append(keys.servo_common(op.name))
            out.append(keys.monitor_common(op.name))
    return out


def _every_operation() -> list[Operation]:
    return [*COMMON.values(), *MIDDLE.values(), *EXT.values()]


def ingress_rights(role: Role) -> dict[str, list[str]]:
    """What ``role`` may send into the cell: message kind → key expressions (any arm)."""
    everything = any_arm_every_key()
    ros2 = list(ros2_every_key())
    if role is Role.ROUTER:  # "**" matches no verbatim chunk (@ros2_lv, @adv): those are listed
        return {m: ["**", *ros2] for m in EVERY_MESSAGE}
    if role is Role.SERVICE:
        return {m: [everything] for m in EVERY_MESSAGE}
    keys = ArmKeys(ANY_ARM)
    ops = _every_operation() if role in (Role.OPERATOR, Role.LOW_LEVEL) else \
        [op for op in _every_operation() if changes_nothing(op)]
    # The read-only queryables the tools ask (jara-arm view, state, alarms).
    queries = [*_operation_keys(ops, keys), keys.servo_world, keys.monitor_alarms]
    puts = [keys.estop] + ([keys.pos_cmd] if role is Role.LOW_LEVEL else [])
    # Watching is reading: a client may subscribe to every key and see who is alive, but never
    # declare a queryable or a liveliness token (it would stand in for a service) nor reply.
    rights = {"query": sorted(set(queries)), "put": puts, "declare_subscriber": [everything],
              "declare_liveliness_subscriber": [everything], "liveliness_query": [everything]}
    # ROS 2 (rmw_zenoh's keys, ``jara-arm ros2``): any client may be a ROS 2 node, publishing and reading topics,
    # announcing itself, serving a transient-local topic's cache. None of it reaches an arm.
    for message in EVERY_MESSAGE:
        rights[message] = [*rights.get(message, []), *ros2]
    return rights


def egress_rights(role: Role) -> dict[str, list[str]]:
    """What the cell may send to ``role``: message kind → key expressions."""
    if role in (Role.ROUTER, Role.SERVICE):
        return ingress_rights(role)
    everything = any_arm_every_key()
    # Samples, replies, and the declarations that let its queriers and publishers see a match; and all of ROS 2.
    rights = {m: [everything] for m in ("put", "reply", "declare_subscriber", "declare_queryable",
                                        "liveliness_token")}
    for message in EVERY_MESSAGE:
        rights[message] = [*rights.get(message, []), *ros2_every_key()]
    return rights


#: The access-control subject of every link over a Unix socket: the cell bus's.
BUS_SUBJECT = "cell-bus"


def access_control(names: Mapping[str, Role]) -> dict[str, Any]:
    """Zenoh's ``access_control`` configuration for a cell whose registry is ``names``
    (certificate common name → role). Everything not allowed is denied; a name with no
    role (or a connection without a certificate of the cell, which TLS refuses first) may do
    nothing."""
    rules: list[dict[str, Any]] = []
    subjects: list[dict[str, Any]] = []
    policies: list[dict[str, Any]] = []
    for role in Role:
        holders = sorted(n for n, r in names.items() if r is role)
        if not holders and role is not Role.ROUTER:
            continue  # Zenoh refuses a subject without a name
        ids = []
        for flow, rights in (("ingress", ingress_rights(role)), ("egress", egress_rights(role))):
            for message, key_exprs in rights.items():
                rule_id = f"{role.value} {flow} {message}"
                rules.append({"id": rule_id, "messages": [message], "flows": [flow],
                              "permission": "allow", "key_exprs": key_exprs})
                ids.append(rule_id)
        if holders:
            subjects.append({"id": role.value, "cert_common_names": holders})
            policies.append({"id": role.value, "rules": ids, "subjects": [role.value]})
        if role is Role.ROUTER:
            # The cell bus's private Unix socket (launcher/up/gateway.py): no certificate travels there; its
            # directory's permissions let only the cell's own OS user in, and what joins is a service or a
            # gateway, which may what a router may.
            subjects.append({"id": BUS_SUBJECT, "link_protocols": ["unixsock-stream"]})
            policies.append({"id": BUS_SUBJECT, "rules": ids, "subjects": [BUS_SUBJECT]})
    return {"enabled": True, "default_permission": "deny", "rules": rules, "subjects": subjects,
            "policies": policies}
