"""The wire schema: round trips of every type and operation, every bad-input class."""

from __future__ import annotations

import dataclasses
import json

import msgpack
import numpy as np
import pytest

from jara_arm.schema import alarms, codec, generate, keys, messages, power
from jara_arm.schema import wire_types as w
from jara_arm.schema.codec import Encoding, Reply
from jara_arm.schema.codes import AlarmType, ReturnCode
from jara_arm.schema.errors import UnknownOperationError, WireError
from jara_arm.schema.operations import ALL, COMMON, EXT, IDL, MIDDLE, Interface, operation
from jara_arm.schema.types import (
    Alarm,
    CarPosWithElbow,
    CartesianSpeed,
    LimitValue,
    ManipInfo,
    Time,
    TimedJointPos,
    hg_matrix,
)

RNG = np.random.default_rng(7)


def rotation() -> np.ndarray:
    q, r = np.linalg.qr(RNG.normal(size=(3, 3)))
    q = q @ np.diag(np.sign(np.diag(r)))
    return q if np.linalg.det(q) > 0 else -q


def sample(t: w.WireType):
    """A valid Python value of wire type ``t``."""
    if t is w.DOUBLE:
        return float(RNG.normal())
    if isinstance(t, w.IntegerType):
        return int(RNG.integers(max(t.lo, 0), min(t.hi, 10**6)))
    if t is w.BOOLEAN:
        return bool(RNG.integers(2))
    if t is w.STRING:
        return "ünïcode ok"
    if t is w.ALARM_TYPE:
        return AlarmType.WARNING
    if t is w.HG_MATRIX:
        return hg_matrix(rotation(), RNG.normal(size=3))
    if isinstance(t, w.SeqType):
        return tuple(sample(t.item) for _ in range(3))
    if t.name == "WireMap":  # a call's request or reply, kept in wire form
        return {"jointPoints": [0.5, -1.0], "carPoint": {"elbow": 0.0}, "id": 0, "comment": "OK"}
    if isinstance(t, w.StructType):
        return t.cls(**{m.name: sample(m.type) for m in t.members})
    raise AssertionError(f"no sample for {t}")


def same(a, b) -> bool:
    if isinstance(a, np.ndarray) or isinstance(b, np.ndarray):
        return np.array_equal(np.asarray(a), np.asarray(b))
    if isinstance(a, tuple):
        return len(a) == len(b) and all(same(x, y) for x, y in zip(a, b))
    return a == b


def test_operation_table_is_the_idl():
    assert len(COMMON) == 9 and len(MIDDLE) == 35 and len(IDL) == 44
    assert set(EXT) == {"setBlendDistance", "getBlendDistance", "setSpeedOverride", "getSpeedOverride",
                        "jogJoint", "jogCartesian", "jogStop", "teach"} and len(ALL) == 52  # outside the IDL
    assert Interface.EXT.idl_name is None and Interface.MIDDLE.idl_name == "ManipulatorCommonInterface_Middle"
    assert {op.name for op in ALL if op.motion} == {
        "closeGripper", "moveGripper", "moveLinearCartesianAbs", "moveLinearCartesianRel",
        "movePTPCartesianAbs", "movePTPCartesianRel", "movePTPJointAbs", "movePTPJointRel",
        "openGripper", "moveCircularCartesianAbs", "moveCircularCartesianRel", "goHome"}
    # IDL spellings that the prose gets wrong (SPEC.md §8).
    assert "getActiveAlarm" in COMMON
    assert [p.name for p in MIDDLE["setSpeedJoint"].inputs] == ["spdRatio"]
    assert [p.name for p in MIDDLE["movePTPJointAbs"].inputs] == ["jointPoints"]
    assert [p.name for p in MIDDLE["getSoftLimitCartesian"].outputs] == ["xLimit", "yLimit", "zLimit"]


@pytest.mark.parametrize("t", w.NAMED_TYPES + messages.MESSAGES + alarms.MESSAGES + power.MESSAGES,
                         ids=lambda t: t.name)
@pytest.mark.parametrize("enc", list(Encoding), ids=lambda e: e.name)
def test_type_round_trip(t, enc):
    value = sample(t)
    back = codec.decode_message(t, codec.encode_message(t, value, enc), enc)
    for m in t.members:
        assert same(getattr(back, m.name), getattr(value, m.name)), m.name


@pytest.mark.parametrize("op", ALL, ids=lambda op: f"{op.interface.value}.{op.name}")
@pytest.mark.parametrize("enc", list(Encoding), ids=lambda e: e.name)
def test_operation_round_trip(op, enc):
    args = {p.name: sample(p.type) for p in op.inputs}
    decoded = codec.decode_request(op, codec.encode_request(op, args, enc), enc)
    assert decoded.keys() == args.keys()
    for k in args:
        assert same(decoded[k], args[k]), k
    outs = {p.name: sample(p.type) for p in op.outputs}
    reply = codec.decode_reply(op, codec.encode_reply(op, Reply(0, "OK", outs), enc), enc)
    assert reply.id == ReturnCode.OK and reply.comment == "OK"
    for k in outs:
        assert same(reply.outs[k], outs[k]), k
    refused = codec.decode_reply(op, codec.encode_reply(op, Reply(-3, "why", {}), enc), enc)
    assert refused.id == ReturnCode.VALUE_ERR and refused.outs == {}
    # Out parameters are present only when id == 0 (WIRE.md).
    assert set(codec.loads(codec.encode_reply(op, Reply(-2, "no", outs), enc), enc)) == {"id", "comment"}


def test_empty_payload_is_an_empty_map():
    assert codec.decode_request(COMMON["getState"], b"") == {}
    assert codec.decode_request(COMMON["getState"], codec.dumps({})) == {}


GOOD_CAR = {"carPos": [[1, 0, 0, 0.5], [0, 1, 0, 0], [0, 0, 1, 0.3]], "elbow": 0, "structFlag": 0}


def car(**changes):
    return {**GOOD_CAR, **changes}


# (operation, raw request value, field named in the error, words in the reason)
BAD = [
    ("setSpeedJoint", {}, "spdRatio", "missing"),
    ("setSpeedJoint", {"spdRatio": 5, "extra": 1}, "extra", "unexpected"),
    ("getState", {"x": 1}, "x", "unexpected"),
    ("setSpeedJoint", {"spdRatio": "fast"}, "spdRatio", "integer"),
    ("setSpeedJoint", {"spdRatio": 5.0}, "spdRatio", "integer"),
    ("setSpeedJoint", {"spdRatio": True}, "spdRatio", "integer"),
    ("setSpeedJoint", {"spdRatio": -1}, "spdRatio", "out of range"),
    ("setSpeedJoint", {"spdRatio": 2**32}, "spdRatio", "out of range"),
    ("setAccelTimeJoint", {"aclTime": float("nan")}, "aclTime", "finite"),
    ("setAccelTimeJoint", {"aclTime": float("inf")}, "aclTime", "finite"),
    ("setAccelTimeJoint", {"aclTime": None}, "aclTime", "number"),
    ("setAccelTimeJoint", {"aclTime": True}, "aclTime", "number"),
    ("movePTPJointAbs", {"jointPoints": 1.0}, "jointPoints", "list"),
    ("movePTPJointAbs", {"jointPoints": [0.0, "a"]}, "jointPoints[1]", "number"),
    ("movePTPJointAbs", {"jointPoints": [0.0, float("nan")]}, "jointPoints[1]", "finite"),
    ("moveLinearCartesianAbs", {"carPoint": car(carPos=[[1, 0, 0, 0]])}, "carPoint.carPos", "3 rows"),
    ("moveLinearCartesianAbs", {"carPoint": car(carPos=[[1, 0, 0], [0, 1, 0], [0, 0, 1]])},
     "carPoint.carPos[0]", "4 numbers"),
    ("moveLinearCartesianAbs", {"carPoint": car(carPos=[[2, 0, 0, 0], [0, 1, 0, 0], [0, 0, 1, 0]])},
     "carPoint.carPos", "rotation"),
    ("moveLinearCartesianAbs", {"carPoint": car(carPos=[[-1, 0, 0, 0], [0, 1, 0, 0], [0, 0, 1, 0]])},
     "carPoint.carPos", "rotation"),  # a reflection: det -1
    ("moveLinearCartesianAbs", {"carPoint": car(carPos=[[1, 0, 0, 0], [0, 1, 0, float("inf")],
                                                        [0, 0, 1, 0]])}, "carPoint.carPos[1][3]", "finite"),
    ("moveLinearCartesianAbs", {"carPoint": {"carPos": GOOD_CAR["carPos"], "elbow": 0}},
     "carPoint.structFlag", "missing"),
    ("moveLinearCartesianAbs", {"carPoint": car(wrist=1)}, "carPoint.wrist", "unexpected"),
    ("moveLinearCartesianAbs", {"carPoint": car(structFlag=-1)}, "carPoint.structFlag", "out of range"),
    ("moveCircularCartesianAbs", {"carPointR": GOOD_CAR}, "carPointT", "missing"),
    ("setSoftLimitJoint", {"softLimit": [{"upper": 1.0}]}, "softLimit[0].lower", "missing"),
    ("setSoftLimitCartesian", {"xLimit": {"upper": 1, "lower": 0}, "yLimit": {"upper": 1, "lower": 0},
                               "zLimit": [0, 1]}, "zLimit", "map"),
    ("setMaxSpeedCartesian", {"speed": {"translation": 1.0, "rotation": "x"}}, "speed.rotation", "number"),
]


@pytest.mark.parametrize("enc", list(Encoding), ids=lambda e: e.name)
@pytest.mark.parametrize("name,value,field,reason", BAD, ids=[f"{b[0]}-{b[2]}-{b[3]}" for b in BAD])
def test_bad_request_names_the_field(name, value, field, reason, enc):
    op = COMMON.get(name) or MIDDLE[name]
    # Python's json writes NaN/Infinity tokens, as careless JSON clients do.
    payload = json.dumps(value).encode() if enc is Encoding.JSON else msgpack.packb(value)
    with pytest.raises(WireError) as err:
        codec.decode_request(op, payload, enc)
    assert err.value.field == field, str(err.value)
    assert reason in err.value.reason, str(err.value)


@pytest.mark.parametrize("payload,enc", [
    (b"\xc1", Encoding.MSGPACK), (b"{not json", Encoding.JSON), (b"\x93\x01\x02\x03", Encoding.MSGPACK),
    (b"[1,2]", Encoding.JSON), (b"\x81\x01\x02", Encoding.MSGPACK),  # map with an integer key
])
def test_bad_payload(payload, enc):
    with pytest.raises(WireError) as err:
        codec.decode_request(COMMON["getState"], payload, enc)
    assert err.value.field == "payload"


def test_rotation_tolerance_is_1e6():
    r = np.eye(3)
    r[0, 0] += 2e-7  # |R^T R - I| = 4e-7
    ok = np.hstack([r, np.zeros((3, 1))]).tolist()
    codec.decode_request(MIDDLE["setBaseOffset"], codec.dumps({"offset": ok}))
    r[0, 0] += 5e-6
    bad = np.hstack([r, np.zeros((3, 1))]).tolist()
    with pytest.raises(WireError):
        codec.decode_request(MIDDLE["setBaseOffset"], codec.dumps({"offset": bad}))


def test_json_encoding_detection():
    assert Encoding.of("application/json") is Encoding.JSON
    assert Encoding.of("application/json;charset=utf-8") is Encoding.JSON
    assert Encoding.of("zenoh/bytes") is Encoding.MSGPACK
    assert Encoding.of(None) is Encoding.MSGPACK


def test_struct_values():
    t = Time.from_seconds(12.5)
    assert (t.sec, t.nsec) == (12, 500_000_000) and t.to_seconds() == 12.5
    info = ManipInfo("KUKA", "iiwa", 7, 1, False)
    assert codec.dumps(w.MANIP_INFO.encode(info)) == msgpack.packb(
        {"manufactur": "KUKA", "type": "iiwa", "axisNum": 7, "cmdCycle": 1, "isGripper": False})
    alarm = Alarm(4, AlarmType.WARNING, "soft limit")
    assert w.ALARM.encode(alarm) == {"code": 4, "type": "WARNING", "description": "soft limit"}
    assert w.LIMIT_VALUE.decode({"upper": 1, "lower": -1}, "x") == LimitValue(1.0, -1.0)
    assert w.CARTESIAN_SPEED.decode({"translation": 0.25, "rotation": 1}, "s") == CartesianSpeed(0.25, 1.0)
    tj = w.TIMED_JOINT_POS.decode({"tm": {"sec": 1, "nsec": 2}, "pos": [1, 2], "extra": 0}, "")
    assert tj == TimedJointPos(Time(1, 2), (1.0, 2.0))  # messages accept extra members
    assert CarPosWithElbow(hg_matrix(), 0.0, 0) == CarPosWithElbow(hg_matrix(), 0.0, 0)


def test_fast_feedback_encoder_equals_the_generic_one():
    pos = [0.1, -2.0, 3.5e-9]
    t_ns = 1_795_331_203_250_143_514
    generic = codec.encode_message(w.TIMED_JOINT_POS, TimedJointPos(Time(1_795_331_203, 250_143_514), tuple(pos)))
    assert messages.timed_joint_pos_payload(t_ns, pos) == generic


def test_a_feedback_block_is_its_samples_byte_for_byte():
    """The servo's block encoder equals the generic one, and the gateway's unpacking gives each sample as the
    servo publishes it alone; anything else is a WireError."""
    samples = [(1_795_331_203_250_143_514 + k * 1_000_000, [0.1 * k, -2.0, 3.5e-9]) for k in range(10)]
    block = messages.feedback_block_payload(samples)
    generic = codec.encode_message(messages.FEEDBACK_BLOCK, messages.FeedbackBlock(tuple(
        TimedJointPos(Time(ns // 1_000_000_000, ns % 1_000_000_000), tuple(pos)) for ns, pos in samples)))
    assert block == generic
    assert messages.feedback_block_samples(block) == [messages.timed_joint_pos_payload(ns, p) for ns, p in samples]
    for bad in (b"\xc1", msgpack.packb([1]), msgpack.packb({"samples": [{"tm": 1, "pos": []}]})):
        with pytest.raises(WireError):
            messages.feedback_block_samples(bad)


def test_fast_status_encoder_equals_the_generic_one():
    st = messages.ServoStatus(Time(1_795_331_203, 250_143_514), True, False, True, 3, 10_001, 10_004, 2,
                              (0.1, -0.2), (1.5, -30.25), (0.0, 1e-9), (LimitValue(2.9, -2.9), LimitValue(1.0, -1.5)),
                              (0.01, 0.02), Time(1_795_331_200, 7), 42)
    assert messages.servo_status_payload(st) == codec.encode_message(messages.SERVO_STATUS, st)
    latches = (messages.ServoLatch(Alarm(0x01, AlarmType.FAULT, "emergency stop"), True, Time(1_795_331_201, 9)),
               messages.ServoLatch(Alarm(0x420, AlarmType.WARNING, "motions [3] discarded"), False,
                                   Time(1_795_331_202, 0)))
    st = dataclasses.replace(st, latches=latches)
    assert messages.servo_status_payload(st) == codec.encode_message(messages.SERVO_STATUS, st)
    assert codec.decode_message(messages.SERVO_STATUS, messages.servo_status_payload(st)) == st


def test_the_newer_servo_status_is_the_later_one_of_a_process_or_of_a_later_process():
    z = (0.0,)
    st = messages.ServoStatus(Time(1_795_331_203, 0), True, False, False, 0, 0, 0, 0, z, z, z,
                              started=Time(1_795_331_200, 0), seq=5)
    assert messages.is_newer(st, None)
    assert messages.is_newer(dataclasses.replace(st, seq=6), st)
    assert not messages.is_newer(st, st)  # the same status again: nothing new
    # older by its number, though made later by its tm: a publication on its way before a reply's status
    assert not messages.is_newer(dataclasses.replace(st, seq=4, tm=Time(1_795_331_204, 0)), st)
    restarted = dataclasses.replace(st, started=Time(1_795_331_210, 0), seq=1)
    assert messages.is_newer(restarted, st) and not messages.is_newer(st, restarted)
    assert messages.is_newer(dataclasses.replace(st, started=Time(0, 0), seq=0), st)  # unnumbered: always taken


@pytest.mark.parametrize("enc", list(Encoding), ids=lambda e: e.name)
@pytest.mark.parametrize("value,field,reason", [
    ({}, "action", "missing"),
    ({"action": 1}, "action", "string"),
    ({"action": "on", "force": True}, "force", "unexpected"),
    ({"action": "on", "alarms": []}, "alarms", "map"),
    ({"action": "on", "alarms": {"tm": {"sec": 1, "nsec": 0}, "alarms": []}}, "alarms.started", "missing"),
], ids=["no-action", "action-type", "extra", "alarms-type", "alarms-started"])
def test_a_bad_power_request_names_the_field(value, field, reason, enc):
    payload = codec.dumps(value, enc)
    with pytest.raises(WireError) as err:
        codec.decode_message(power.POWER_REQUEST, payload, enc)
    assert (err.value.field, err.value.code) == (field, ReturnCode.VALUE_ERR), str(err.value)
    assert reason in err.value.reason, str(err.value)


def test_a_power_request_names_a_known_action_and_holds_a_list_or_none():
    req = codec.decode_message(power.POWER_REQUEST, codec.dumps({"action": "reboot"}))
    assert req.alarms == alarms.NO_LIST  # a caller that holds no monitor's list may leave it out
    with pytest.raises(WireError) as err:
        w.choice(power.PowerAction, req.action, "action")
    assert (err.value.field, err.value.code) == ("action", ReturnCode.VALUE_ERR)
    assert "'reboot'" in err.value.reason and "on, off, clear, sync" in err.value.reason
    assert w.choice(power.PowerAction, "sync", "action") is power.PowerAction.SYNC


def test_keys():
    k = keys.ArmKeys("arm-1_B")
    assert k.interface(Interface.MIDDLE, "movePTPJointAbs") == "JARA_ARM/arm-1_B/Middle/movePTPJointAbs"
    assert k.interface(Interface.COMMON) == "JARA_ARM/arm-1_B/Common/*"
    assert k.servo_common("getState") == "JARA_ARM/arm-1_B/Servo/Common/getState"
    assert k.pos_cmd == "JARA_ARM/arm-1_B/Servo/posCmd"
    assert k.pos_target == "JARA_ARM/arm-1_B/Servo/posTarget"
    assert k.servo_trajectory == "JARA_ARM/arm-1_B/Servo/trajectory"
    assert k.servo_power == "JARA_ARM/arm-1_B/Servo/power"
    assert k.pos_feedback == "JARA_ARM/arm-1_B/Servo/posFeedback"
    assert k.state == "JARA_ARM/arm-1_B/state" and k.alarm == "JARA_ARM/arm-1_B/alarm"
    assert k.estop == "JARA_ARM/arm-1_B/estop"
    assert k.log(keys.Service.ALARM_MONITOR) == "JARA_ARM/arm-1_B/log/alarm-monitor"
    assert k.alive(keys.Service.SERVO) == "JARA_ARM/arm-1_B/alive/servo"
    assert keys.parse_alive(k.alive(keys.Service.PLANNER)) == ("arm-1_B", "planner")
    assert keys.parse_log(k.log(keys.Service.COMMAND)) == ("arm-1_B", "command")
    assert k.monitor_common("clearAlarms") == "JARA_ARM/arm-1_B/Monitor/Common/clearAlarms"
    assert k.monitor_alarms == "JARA_ARM/arm-1_B/Monitor/alarms"
    assert k.command_settings == "JARA_ARM/arm-1_B/Command/settings"
    assert keys.any_arm_monitor_common("getActiveAlarm") == "JARA_ARM/*/Monitor/Common/getActiveAlarm"
    assert keys.any_arm_alarm() == "JARA_ARM/*/alarm" and keys.arm_of(k.alarm) == "arm-1_B"
    with pytest.raises(UnknownOperationError):
        k.monitor_common("getActivAlarm")
    for bad in ("", "a/b", "a*", "arm 0", "x$"):
        with pytest.raises(keys.ArmIdError):
            keys.ArmKeys(bad)
    with pytest.raises(UnknownOperationError) as err:
        k.interface(Interface.COMMON, "getActivAlarm")  # the prose's misspelling
    assert "getActiveAlarm" in str(err.value)  # the message lists the valid choices
    with pytest.raises(UnknownOperationError):
        operation(Interface.MIDDLE, "getState")


def test_generated_schema_is_in_sync():
    assert generate.SCHEMA_FILE.read_text() == generate.render(), \
        "run: python -m jara_arm.schema.generate"
    readme = generate.README_FILE.read_text()
    assert readme == generate.render_readme(readme), "README's key table: run python -m jara_arm.schema.generate"
    for row in keys.KEY_TABLE:  # every key of ArmKeys is in the README's table
        assert f"| `{row.key}` |" in readme
    doc = json.loads(generate.SCHEMA_FILE.read_text())
    assert len(doc["x-operations"]["Common"]) == 9 and len(doc["x-operations"]["Middle"]) == 35
    assert doc["x-return-codes"]["NOT_IMPLEMENTED"] == -6
    assert doc["x-state-bits"]["PAUSED"] == 0x10
    req = doc["x-operations"]["Middle"]["moveCircularCartesianAbs"]["request"]
    assert req["required"] == ["carPointR", "carPointT"] and req["additionalProperties"] is False


def test_alarm_table_covers_every_code_with_its_decided_type():
    """DECISIONS.md "Alarms": e-stop, overspeed and a lost/hung service are FAULTs; the rest WARNINGs."""
    from jara_arm.schema.codes import AlarmCode
    assert {a.code for a in alarms.ALARM_TABLE} == set(AlarmCode)
    faults = {c for c, t in alarms.ALARM_TYPE.items() if t is AlarmType.FAULT}
    assert faults == {0x01, 0x03, 0x400, 0x401, 0x402, 0x403, 0x410, 0x411, 0x412, 0x413}
    assert all(c >= 0x400 for c in AlarmCode if c > 0x05)  # model-specific codes where the spec says
    assert set(alarms.MONITOR_OPERATIONS) == {"getActiveAlarm", "clearAlarms"}
    assert alarms.format_code(1) == "0x01" and alarms.format_code(0x410) == "0x410"


def test_query_deadline_attachment():
    """A forwarded query carries its requester's deadline; anything else is no deadline, never an error."""
    import time

    before = time.time()
    deadline = codec.attachment_deadline(codec.deadline_attachment(0.3))
    assert deadline is not None and before + 0.3 <= deadline <= time.time() + 0.3
    for junk in (None, b"", b"\xc1", msgpack.packb([1.0]), msgpack.packb({"deadline": "soon"}),
                 msgpack.packb({"deadline": True}), msgpack.packb({"deadline": float("nan")}),
                 msgpack.packb({"other": 1.0})):
        assert codec.attachment_deadline(junk) is None
