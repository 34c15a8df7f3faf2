"""Encodings on the wire: how a request's is told, the per-key choice, and the labels on what we send.

Pure, except the last tests: an in-process Zenoh session of its own (no
listener, no scouting) with a real query server and publication on it, read the
way generic tools (``z_get``, ``z_sub``) read, with ``payload.to_string()``.
"""

from __future__ import annotations

import json
import os

import msgpack
import pytest
import zenoh

from jara_arm.schema import codec, keys, messages
from jara_arm.schema.codes import ReturnCode
from jara_arm.schema.encoding import Encoding, is_json_object
from jara_arm.schema.errors import JaraArmError, WireError
from jara_arm.schema.keys import ArmKeys, KeyEncoding, Service, encoding_of, key_info
from jara_arm.schema.operations import COMMON, MIDDLE, OP, Interface
from jara_arm.services.runtime.rpc import InterfaceServer, ok
from jara_arm.services.runtime.wire import Publication, decode_sample
from jara_arm.services.runtime.zenoh_args import zenoh_config

from .support import wait_until

GET_STATE = COMMON[OP.getState]
SET_SPEED = MIDDLE[OP.setSpeedJoint]
GET_MAX_SPEED = MIDDLE[OP.getMaxSpeedJoint]
#: The first byte of every MessagePack map: fixmap, map 16, map 32.
MSGPACK_MAP_FIRST = {*range(0x80, 0x90), 0xDE, 0xDF}


# ---------------------------------------------------------------------------- telling them apart
@pytest.mark.parametrize("payload", [b"{}", b'{"spdRatio": 50}', b' \t\r\n{"spdRatio":50}', b"\n\n{"])
@pytest.mark.parametrize("label", [None, "zenoh/bytes", "application/msgpack", "application/json"])
def test_a_json_object_is_json_whatever_its_label(payload, label):
    assert is_json_object(payload)
    assert Encoding.of_request(payload, label) is Encoding.JSON


@pytest.mark.parametrize("n", [0, 1, 15, 16, 65535, 65536])
def test_no_messagepack_map_looks_like_json(n):
    payload = msgpack.packb({f"k{i}": i for i in range(n)})
    assert payload[0] in MSGPACK_MAP_FIRST
    assert not is_json_object(payload)
    assert Encoding.of_request(payload, None) is Encoding.MSGPACK
    assert codec.loads(payload, Encoding.of_request(payload, None)) == {f"k{i}": i for i in range(n)}


def test_the_first_bytes_of_the_two_never_meet():
    assert not MSGPACK_MAP_FIRST & set(b"{ \t\r\n")


@pytest.mark.parametrize("payload", [b"[1, 2]", b"42", b'"{"', b"\xc1", b"\x0b{}"])
def test_anything_else_is_read_as_labelled(payload):
    assert Encoding.of_request(payload, None) is Encoding.MSGPACK
    assert Encoding.of_request(payload, "application/json") is Encoding.JSON


def test_an_empty_request_has_no_arguments_and_its_label_decides_the_reply():
    assert Encoding.of_request(b"", None) is Encoding.MSGPACK
    assert Encoding.of_request(b"", "application/json") is Encoding.JSON
    assert codec.decode_request(GET_STATE, b"", Encoding.JSON) == {}
    with pytest.raises(WireError) as err:
        codec.decode_request(SET_SPEED, b"", Encoding.MSGPACK)
    assert err.value.field == "spdRatio" and "missing" in err.value.reason


@pytest.mark.parametrize("payload", [b"{not json", b'{"spdRatio": 50', b'  {"spdRatio": 50}}'])
def test_invalid_json_that_starts_as_an_object_is_a_payload_error(payload):
    enc = Encoding.of_request(payload, "application/msgpack")
    assert enc is Encoding.JSON
    with pytest.raises(WireError) as err:
        codec.decode_request(SET_SPEED, payload, enc)
    assert err.value.field == "payload" and "JSON" in err.value.reason


def test_messagepack_labelled_json_is_invalid_json_with_a_hint():
    payload = msgpack.packb({"spdRatio": 50})
    enc = Encoding.of_request(payload, "application/json")
    assert enc is Encoding.JSON  # the label is believed for anything that is not a JSON object
    with pytest.raises(WireError) as err:
        codec.decode_request(SET_SPEED, payload, enc)
    assert err.value.field == "payload" and "MessagePack map" in err.value.reason


def test_json_requests_stay_strict():
    with pytest.raises(WireError) as err:
        codec.decode_request(SET_SPEED, b'{"spdRatio": 50, "bogus": 1}', Encoding.JSON)
    assert err.value.field == "bogus"
    with pytest.raises(WireError) as err:
        codec.decode_request(SET_SPEED, b'{"spdRatio": "fast"}', Encoding.JSON)
    assert err.value.field == "spdRatio"


# ---------------------------------------------------------------------------- the per-key choice
ARM = ArmKeys("enc-test")
#: What people watch: JSON, so that an unmodified ``z_sub`` prints it.
WATCHED = [ARM.state, ARM.alarm, ARM.log(Service.SERVO), ARM.log(), ARM.monitor_alarms, ARM.command_settings,
           ARM.servo_health, ARM.servo_world]
#: The 1 kHz streams and the other high-rate or internal ones: MessagePack.
FAST = [ARM.pos_feedback, ARM.pos_cmd, ARM.pos_target, ARM.servo_status, ARM.servo_motion, ARM.heartbeat(Service.COMMAND),
        ARM.planner_progress, ARM.alarm_copy, ARM.planner_path]
QUERYABLES = [ARM.interface(Interface.COMMON, OP.getState), ARM.interface(Interface.MIDDLE, OP.setSpeedJoint),
              ARM.servo_common(OP.servoON), ARM.monitor_common(OP.clearAlarms), ARM.planner_plan,
              ARM.planner_control, ARM.servo_trajectory, ARM.servo_motion_control, ARM.servo_power]


def test_every_key_declares_its_encoding():
    for row in keys.KEY_TABLE:
        assert isinstance(row.encoding, KeyEncoding), row
        if row.encoding is KeyEncoding.AS_REQUEST:
            assert "queryable" in row.kind, row
        if row.encoding is KeyEncoding.NONE:
            assert row.payload in ("—", "any put"), row


@pytest.mark.parametrize("key", WATCHED)
def test_what_people_watch_is_json(key):
    assert encoding_of(key) is Encoding.JSON


@pytest.mark.parametrize("key", FAST)
def test_the_streams_are_messagepack(key):
    assert encoding_of(key) is Encoding.MSGPACK


@pytest.mark.parametrize("key", [*QUERYABLES, ARM.estop, ARM.alive(Service.SERVO)])
def test_keys_without_an_encoding_of_their_own_have_no_publisher(key):
    with pytest.raises(JaraArmError):
        encoding_of(key)


def test_each_key_is_one_row_of_the_table():
    for key in WATCHED + FAST + QUERYABLES + [ARM.estop, ARM.alive(Service.SERVO)]:
        assert sum(bool(pattern.fullmatch(key)) for pattern, _ in keys._PATTERNS) == 1, key
        row_chunks, key_chunks = key_info(key).key.split("/"), key.split("/")
        assert len(row_chunks) == len(key_chunks) and all(
            r == k or r.startswith("<") for r, k in zip(row_chunks, key_chunks)), (key, key_info(key).key)
    with pytest.raises(JaraArmError):
        key_info("JARA_ARM/enc-test/nothing")
    with pytest.raises(JaraArmError):
        key_info("other/enc-test/state")


def test_the_generated_schema_lists_each_keys_encoding():
    from jara_arm.schema import generate

    rows = {row["key"]: row["encoding"] for row in generate.build()["x-keys"]}
    assert rows["JARA_ARM/<arm>/state"] == "application/json"
    assert rows["JARA_ARM/<arm>/Servo/posFeedback"] == "application/msgpack"
    assert rows["JARA_ARM/<arm>/Common/<op>"] == KeyEncoding.AS_REQUEST.value
    assert "| `JARA_ARM/<arm>/log/<service>` | publisher | every service |" in generate.key_table_markdown()
    assert "| `application/json` |" in generate.key_table_markdown()


# ---------------------------------------------------------------------------- on a Zenoh session
@pytest.fixture
def session():
    with zenoh.open(zenoh_config("peer")) as s:  # no listener, no scouting: nobody else's
        yield s


class _Handler:
    def __init__(self) -> None:
        self.speeds: list[float] = []

    def getMaxSpeedJoint(self):
        return ok(speed=[1.5, 2.0])

    def setSpeedJoint(self, spdRatio):
        self.speeds.append(spdRatio)
        return ok()


@pytest.fixture
def served():
    """A session, and on it ``Middle/getMaxSpeedJoint`` and ``Middle/setSpeedJoint`` served by the real query server."""
    keys_ = ArmKeys(f"enc-test-{os.getpid()}")
    handler = _Handler()
    with zenoh.open(zenoh_config("peer")) as session:
        server = InterfaceServer(session, keys_.interface(Interface.MIDDLE),
                                 {OP.getMaxSpeedJoint: GET_MAX_SPEED, OP.setSpeedJoint: SET_SPEED}, handler, "enc-test")
        try:
            yield session, keys_, handler
        finally:
            server.close()
    server.join()  # its worker leaves recv() once the session is closed


def _get(session, key, **kwargs):
    replies = [r.ok for r in session.get(key, timeout=5.0, **kwargs) if r.ok is not None]
    assert len(replies) == 1, key
    return replies[0]


def test_a_json_string_without_encoding_gets_a_json_reply(served):
    """What ``z_get -s <key> -p '{...}'`` does: a str payload, no encoding; it prints ``to_string()``."""
    session, keys_, handler = served
    reply = _get(session, keys_.interface(Interface.MIDDLE, OP.setSpeedJoint), payload='{"spdRatio": 50}')
    assert str(reply.encoding) == "application/json"
    assert json.loads(reply.payload.to_string()) == {"id": 0, "comment": "OK"}
    assert handler.speeds == [50.0]
    speeds = _get(session, keys_.interface(Interface.MIDDLE, OP.getMaxSpeedJoint), payload="{}")
    assert json.loads(speeds.payload.to_string()) == {"id": 0, "comment": "OK", "speed": [1.5, 2.0]}
    bad = _get(session, keys_.interface(Interface.MIDDLE, OP.setSpeedJoint), payload='{"spdRatio": 50')
    body = json.loads(bad.payload.to_string())
    assert body["id"] == ReturnCode.VALUE_ERR and body["comment"].startswith("payload"), body
    assert handler.speeds == [50.0]  # nothing done on bad input


def test_messagepack_clients_keep_getting_messagepack(served):
    session, keys_, handler = served
    key = keys_.interface(Interface.MIDDLE, OP.setSpeedJoint)
    reply = _get(session, key, payload=codec.encode_request(SET_SPEED, {"spdRatio": 25}))
    assert str(reply.encoding) == "application/msgpack"
    assert codec.decode_reply(SET_SPEED, reply.payload.to_bytes()).ok and handler.speeds == [25.0]
    empty = _get(session, keys_.interface(Interface.MIDDLE, OP.getMaxSpeedJoint))  # no payload, no label
    assert str(empty.encoding) == "application/msgpack"
    assert codec.decode_reply(GET_MAX_SPEED, empty.payload.to_bytes())["speed"] == (1.5, 2.0)
    labelled = _get(session, keys_.interface(Interface.MIDDLE, OP.getMaxSpeedJoint), payload=b"",
                    encoding=zenoh.Encoding.APPLICATION_JSON)
    assert str(labelled.encoding) == "application/json"
    assert json.loads(labelled.payload.to_string())["speed"] == [1.5, 2.0]


def test_an_unknown_operation_is_answered_in_the_requests_encoding(served):
    session, keys_, _ = served
    reply = _get(session, keys_.interface(Interface.MIDDLE).replace("*", "getMaxSpeedJoin"), payload="{}")
    assert str(reply.encoding) == "application/json"
    assert json.loads(reply.payload.to_string())["id"] == ReturnCode.NOT_IMPLEMENTED


def test_a_publication_is_in_its_keys_encoding_and_labelled(session):
    keys_ = ArmKeys(f"enc-test-{os.getpid()}")
    got: list[zenoh.Sample] = []
    sub = session.declare_subscriber(keys_.log(), got.append)
    record = messages.LogRecord(1.5, "INFO", "servo", "hello", "tests")
    with Publication(session, keys_.log(Service.SERVO)) as pub:
        assert pub.encoding is Encoding.JSON
        pub.put_message(messages.LOG_RECORD, record)
        wait_until(lambda: got, 5.0, what="the log record")
    sub.undeclare()
    assert str(got[0].encoding) == "application/json"
    assert json.loads(got[0].payload.to_string())["msg"] == "hello"  # what z_sub prints
    assert decode_sample(messages.LOG_RECORD, got[0]) == record


def test_a_hand_built_messagepack_publisher_refuses_a_json_key(session):
    with pytest.raises(JaraArmError, match="application/json"):
        Publication(session, ArmKeys("enc-test").state, Encoding.MSGPACK)
