"""The roles of a secure cell as access rules (``schema/roles.py``): what each may send, checked key by key.

The live refusals are in test_secure.py; these check the rules themselves, for
every operation of the tables.
"""

from __future__ import annotations

import json

import pytest
import zenoh

from jara_arm.launcher.secure.certs import init_cell, issue
from jara_arm.launcher.up.gateway import BUS_ZID
from jara_arm.launcher.up.router import RouterSettings
from jara_arm.schema.keys import ANY_ARM, ArmKeys, Service, any_arm_every_key, ros2_every_key
from jara_arm.schema.operations import COMMON, EXT, MIDDLE, Interface
from jara_arm.schema.roles import BUS_SUBJECT, EVERY_MESSAGE, Role, RoleError, access_control, changes_nothing, ingress_rights

KEYS = ArmKeys(ANY_ARM)
CLIENTS = (Role.OPERATOR, Role.LOW_LEVEL, Role.OBSERVER)
OPERATIONS = [*COMMON.values(), *MIDDLE.values(), *EXT.values()]


def test_a_getter_reads_only() -> None:
    """Every operation the observer may call takes no input and returns something; every other one is not
    a getter (a setter, a motion, a command)."""
    getters = [op for op in OPERATIONS if changes_nothing(op)]
    assert getters and all(not op.inputs and op.outputs and not op.motion for op in getters)
    assert not any(changes_nothing(op) for op in OPERATIONS if op.motion or op.inputs)
    assert {"servoON", "servoOFF", "clearAlarms", "setSpeedJoint", "pause", "stop"} & \
        {op.name for op in getters} == set()


def test_an_observer_may_query_the_getters_and_nothing_else() -> None:
    queries = set(ingress_rights(Role.OBSERVER)["query"])
    for op in OPERATIONS:
        key = KEYS.interface(op.interface, op.name)
        assert (key in queries) == changes_nothing(op), key
        if op.interface is Interface.COMMON:
            assert (KEYS.servo_common(op.name) in queries) == changes_nothing(op)
            assert (KEYS.monitor_common(op.name) in queries) == changes_nothing(op)
    assert KEYS.planner_plan not in queries and KEYS.planner_control not in queries


def test_an_operator_may_call_every_operation_but_no_internal_queryable() -> None:
    queries = set(ingress_rights(Role.OPERATOR)["query"])
    assert {KEYS.interface(op.interface, op.name) for op in OPERATIONS} <= queries
    assert {KEYS.servo_common(name) for name in COMMON} <= queries
    assert KEYS.planner_plan not in queries and KEYS.planner_control not in queries and KEYS.alarm_copy not in queries
    assert KEYS.planner_jog not in queries  # a jog goes through the command, which checks the state first


@pytest.mark.parametrize("role", CLIENTS)
def test_no_client_may_stand_in_for_a_service(role: Role) -> None:
    rights = ingress_rights(role)
    arms = zenoh.KeyExpr(any_arm_every_key())
    for message in ("declare_queryable", "liveliness_token", "reply", "delete"):
        # ROS 2's keys only (a client may be a ROS 2 node): none of them is an arm's.
        assert set(rights.get(message, [])) <= set(ros2_every_key()), f"{role}: {message}"
        assert not any(zenoh.KeyExpr(k).intersects(arms) for k in rights.get(message, [])), f"{role}: {message}"
    puts = set(rights["put"])
    assert KEYS.estop in puts  # anyone who can see the arm may stop it
    for internal in (KEYS.servo_motion, KEYS.heartbeat(Service.SERVO), KEYS.heartbeat(), KEYS.servo_status,
                     KEYS.command_settings, KEYS.planner_progress):
        assert internal not in puts
    for internal in (KEYS.servo_trajectory, KEYS.servo_motion_control, KEYS.servo_power, KEYS.planner_plan,
                     KEYS.planner_control):
        assert internal not in rights["query"]  # only the services hand motions to the servo and switch it
    assert (KEYS.pos_cmd in puts) == (role is Role.LOW_LEVEL)


def test_services_and_routers_may_send_everything() -> None:
    for role in (Role.SERVICE, Role.ROUTER):
        assert set(ingress_rights(role)) == set(EVERY_MESSAGE)


def test_zenoh_takes_the_configuration() -> None:
    acl = access_control({"router": Role.ROUTER, "service": Role.SERVICE, "alice": Role.OPERATOR,
                          "lowell": Role.LOW_LEVEL, "olga": Role.OBSERVER})
    assert acl["default_permission"] == "deny"
    assert {s["id"] for s in acl["subjects"]} == {r.value for r in Role} | {BUS_SUBJECT}
    conf = zenoh.Config()
    conf.insert_json5("access_control", json.dumps(acl))  # ZError if Zenoh refused a field


def test_a_role_without_holders_is_left_out() -> None:
    acl = access_control({"olga": Role.OBSERVER})
    assert [s.get("cert_common_names") for s in acl["subjects"]] == [None, ["olga"]]  # the bus's, then olga's


def test_the_cell_bus_link_has_the_router_role() -> None:
    """The private Unix socket of the cell bus (launcher/up/gateway.py) carries no certificate: a gateway's link
    to it is known by its protocol, and may what a router may."""
    acl = access_control({"alice": Role.OPERATOR})
    [bus] = [s for s in acl["subjects"] if s["id"] == BUS_SUBJECT]
    assert bus == {"id": BUS_SUBJECT, "link_protocols": ["unixsock-stream"]}
    [policy] = [p for p in acl["policies"] if p["subjects"] == [BUS_SUBJECT]]
    assert policy["rules"] and all(r.startswith("router ") for r in policy["rules"])


def test_an_unknown_role_names_the_valid_ones() -> None:
    with pytest.raises(RoleError, match="roles: service, router, operator, low-level, observer"):
        Role.parse("admin")


def _subjects_of(acl: dict, cert: str | None, protocol: str, zid: str) -> list[str]:
    """The subjects of ``acl`` a link matches (Zenoh's rule: every attribute a subject lists must hold)."""
    link = {"cert_common_names": cert, "link_protocols": protocol, "zids": zid}
    listed = [{k: v for k, v in s.items() if k in link and v is not None} for s in acl["subjects"]]
    return [s["id"] for s, attrs in zip(acl["subjects"], listed)
            if attrs and all(link[k] in v for k, v in attrs.items())]


def test_each_link_of_a_secure_gateway_has_one_subject_and_the_relay_deny_holds_on_the_bus_link(
        tmp_path) -> None:
    """Zenoh allows what any of a link's subjects allows, and traces a denial for each subject tried before
    the one that allows: with two subjects on the bus link, the deny of the gateway's relay had no effect and
    the refusal log reported the whole bus refused in 1 secure start of 6 (launcher/up/gateway.py)."""
    cell = init_cell(tmp_path / "cell")
    issue(cell, "alice", Role.OPERATOR)
    conf = RouterSettings(listen=("tls/127.0.0.1:7447",), secure=str(tmp_path / "cell"), gateway=True).config_object()
    acl = json.loads(conf.get_json("access_control"))
    links = {"bus over its Unix socket": (None, "unixsock-stream", BUS_ZID),
             "bus over TLS": ("router", "tls", BUS_ZID), "alice": ("alice", "tls", "a1")}
    subjects = {name: _subjects_of(acl, *link) for name, link in links.items()}
    assert subjects == {"bus over its Unix socket": [BUS_SUBJECT], "bus over TLS": [Role.ROUTER.value],
                        "alice": [Role.OPERATOR.value]}
    [deny] = [r for r in acl["rules"] if r["permission"] == "deny"]
    for subject in (BUS_SUBJECT, Role.ROUTER.value):
        [policy] = [p for p in acl["policies"] if p["subjects"] == [subject]]
        assert deny["id"] in policy["rules"]
    assert deny["key_exprs"] == [KEYS.pos_feedback]
