"""``jara-arm record`` and ``replay``, the call traces, and the recording reader (issue 13, part 3).

The tests without ``live`` in their name start no process and no router (``pytest -k 'not live'``):
transcoding, the channel schemas, the reader, bad files, the traces of the real query server and
record/replay against a lone in-process Zenoh peer. The ``live`` ones record a real session of
``jara-arm up`` (a PTP, a LIN, an e-stop) with the ``record`` process and replay it into a router of
their own where no arm runs.
"""

from __future__ import annotations

import contextlib
import io
import json
import os
import signal
import sys
import threading
import time
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import jsonschema
import msgpack
import numpy as np
import pytest
import zenoh
from mcap.reader import make_reader

from jara_arm.launcher import cli
from jara_arm.launcher.record.record import RecordSettings, run_record
from jara_arm.launcher.record.recording import (
    Recorded,
    RecordingError,
    RecordingWriter,
    arms,
    info,
    keys,
    read_messages,
    to_json,
)
from jara_arm.launcher.record.replay import ReplaySettings, replayed, run_replay
from jara_arm.robots import robot
from jara_arm.schema import codec
from jara_arm.schema.channels import MESSAGE_TYPES, channel_schema, message_type
from jara_arm.schema.codes import AlarmCode, ReturnCode, StateBit
from jara_arm.schema.encoding import Encoding
from jara_arm.schema.errors import JaraArmError
from jara_arm.schema.keys import KEY_TABLE, ArmKeys, KeyEncoding, Service, encoding_of, key_info
from jara_arm.schema.messages import CALL_TRACE, LOG_RECORD, CallTrace, LogRecord, timed_joint_pos_payload
from jara_arm.schema.operations import MIDDLE, OP, Interface
from jara_arm.schema.types import CarPosWithElbow, hg_matrix
from jara_arm.services.runtime.rpc import InterfaceServer, ok
from jara_arm.services.runtime.wire import label
from jara_arm.services.runtime.zenoh_args import zenoh_config

from .harness import launched
from .support import Client, Proc, client_session, endpoint, free_port, wait_recording, wait_until

LAUNCHER = [sys.executable, "-m", "jara_arm.launcher"]
T0 = 1_800_000_000_000_000_000  # [ns] a Unix time for hand-made recordings


@pytest.fixture
def lone_session() -> Iterator[zenoh.Session]:
    """A Zenoh peer with no endpoint and no scouting: its own puts reach its own subscribers, nothing else."""
    with zenoh.open(zenoh_config("peer")) as session:
        yield session


@pytest.fixture
def no_network(monkeypatch: pytest.MonkeyPatch) -> None:
    def refuse(*_: Any, **__: Any) -> Any:
        raise AssertionError("the command opened a Zenoh session")
    monkeypatch.setattr(zenoh, "open", refuse)


def validate(key: str, value: dict[str, Any]) -> None:
    """``value`` against the JSON Schema of ``key``'s channel (raises jsonschema.ValidationError)."""
    _, schema = channel_schema(key)
    jsonschema.Draft202012Validator(json.loads(schema)).validate(value)


# -- transcoding and the channel schemas -----------------------------------------------------------------

def test_samples_become_json_objects_whatever_their_encoding() -> None:
    packed = timed_joint_pos_payload(T0 + 5, [0.5, -1.25])
    assert json.loads(to_json(packed, "application/msgpack")) == {"tm": {"sec": T0 // 10**9, "nsec": 5},
                                                                  "pos": [0.5, -1.25]}
    assert json.loads(to_json(b'{"state": 1}', "application/json")) == {"state": 1}
    assert to_json(b"", None) == b"{}"  # an e-stop put
    assert json.loads(to_json(b"stop!", "text/plain")) == {"payload": "stop!"}
    assert json.loads(to_json(msgpack.packb([1, 2]), "application/msgpack")) == {"payload": [1, 2]}
    assert json.loads(to_json(msgpack.packb({"x": float("nan"), "b": b"\x01\xff"}), None)) == {"x": None, "b": "01ff"}
    assert json.loads(to_json(b"\xc1", None)) == {"payload": "c1"}  # nothing reads it: its bytes


def test_every_published_key_has_its_message_type_and_a_schema_of_its_own() -> None:
    sample = ArmKeys("a1")
    published = [r for r in KEY_TABLE if ("publisher" in r.kind or "subscriber" in r.kind)
                 and r.encoding in (KeyEncoding.JSON, KeyEncoding.MSGPACK)]
    assert {r.key for r in published} == set(MESSAGE_TYPES)
    for row in published:
        kind = MESSAGE_TYPES[row.key]
        assert kind.name in row.payload, (row.key, kind.name)  # the table's payload column names the same type
        name, data = channel_schema(row.key.replace("<arm>", sample.arm).replace("<service>", "servo")
                                    .replace("<op>", OP.getState))
        schema = json.loads(data)
        jsonschema.Draft202012Validator.check_schema(schema)
        refs = {v.removeprefix("#/$defs/") for v in _values(schema, "$ref")}
        assert name == kind.name and refs <= set(schema.get("$defs", {})), (row.key, refs)
    assert message_type(sample.estop) is None and channel_schema(sample.estop)[0] == "AnyPut"
    with pytest.raises(JaraArmError):
        message_type("JARA_ARM/a1/nothing")


def _values(node: Any, name: str) -> Iterator[Any]:
    if isinstance(node, dict):
        for k, v in node.items():
            if k == name:
                yield v
            yield from _values(v, name)
    elif isinstance(node, list):
        for v in node:
            yield from _values(v, name)


def test_the_channel_schemas_take_what_the_services_publish_and_refuse_other_things() -> None:
    k = ArmKeys("a1")
    validate(k.pos_feedback, json.loads(to_json(timed_joint_pos_payload(T0, [0.1, 0.2]), "application/msgpack")))
    record = LogRecord(1.5, "INFO", "servo", "up", "x")
    validate(k.log(Service.SERVO), json.loads(codec.encode_message(LOG_RECORD, record, Encoding.JSON)))
    trace = CallTrace(2.0, {"jointPoints": [0.1]}, {"id": 0, "comment": "OK"})
    validate(k.trace(Interface.MIDDLE.value, OP.movePTPJointAbs),
             json.loads(codec.encode_message(CALL_TRACE, trace, Encoding.JSON)))
    validate(k.estop, {})
    with pytest.raises(jsonschema.ValidationError):
        validate(k.pos_feedback, {"tm": {"sec": 1, "nsec": 2}, "pos": ["a"]})
    with pytest.raises(jsonschema.ValidationError):
        validate(k.trace(Interface.COMMON.value, OP.getState), {"t": 1.0, "request": {}})


def test_every_operation_queryable_has_a_json_trace_key() -> None:
    k = ArmKeys("a1")
    assert k.traced(k.interface(Interface.MIDDLE, OP.movePTPJointAbs)) == "JARA_ARM/a1/trace/Middle/movePTPJointAbs"
    assert k.traced(k.servo_common()) == "JARA_ARM/a1/trace/Servo/Common/*"
    assert k.traced(k.monitor_common(OP.clearAlarms)) == "JARA_ARM/a1/trace/Monitor/Common/clearAlarms"
    for queryable in (k.interface(Interface.COMMON, OP.getState), k.servo_common(OP.servoON)):
        assert encoding_of(k.traced(queryable)) is Encoding.JSON
        assert key_info(k.traced(queryable)).kind == "publisher"
    for not_an_interface in (k.state, k.planner_plan, ArmKeys("a2").interface(Interface.COMMON)):
        with pytest.raises(JaraArmError):
            k.traced(not_an_interface)
    with pytest.raises(JaraArmError):
        k.trace(Interface.MIDDLE.value, "noSuchOperation")


# -- the traces of the real query server ---------------------------------------------------------------

class _Handler:
    def setSpeedJoint(self, spdRatio: int) -> Any:
        return ok()

    def getMaxSpeedJoint(self) -> Any:
        return ok(speed=[1.5, 2.0])


@pytest.mark.timeout(30)
def test_the_query_server_traces_each_call_while_something_subscribes(lone_session: zenoh.Session) -> None:
    keys_ = ArmKeys(f"trace-{os.getpid()}")
    table = {OP.setSpeedJoint: MIDDLE[OP.setSpeedJoint], OP.getMaxSpeedJoint: MIDDLE[OP.getMaxSpeedJoint]}
    server = InterfaceServer(lone_session, keys_.interface(Interface.MIDDLE), table, _Handler(), "trace-test")
    try:
        assert not server._tracer.listened  # nobody listens: a call costs one look-up
        get = lone_session.get(keys_.interface(Interface.MIDDLE, OP.setSpeedJoint), payload='{"spdRatio": 10}')
        assert [r.ok for r in get if r.ok is not None]
        traces = lone_session.declare_subscriber(keys_.every_key, zenoh.handlers.FifoChannel(16))
        wait_until(lambda: server._tracer.listened, 5, what="the trace publisher to match")
        packed = codec.encode_request(MIDDLE[OP.setSpeedJoint], {"spdRatio": 50})
        for payload in (packed, b"{}", b"\xc1"):
            replies = [r.ok for r in lone_session.get(keys_.interface(Interface.MIDDLE, OP.setSpeedJoint),
                                                      payload=payload, timeout=5) if r.ok is not None]
            assert len(replies) == 1
        got = [traces.recv() for _ in range(3)]
        assert traces.try_recv() is None  # the call before the subscriber left no trace
        assert {str(s.key_expr) for s in got} == {keys_.trace(Interface.MIDDLE.value, OP.setSpeedJoint)}
        assert all(str(s.encoding) == "application/json" for s in got)
        values = [json.loads(s.payload.to_bytes()) for s in got]
        assert values[0]["request"] == {"spdRatio": 50} and values[0]["reply"] == {"id": 0, "comment": "OK"}
        assert values[1]["request"] == {} and values[1]["reply"]["id"] == ReturnCode.VALUE_ERR
        assert values[2]["request"] == {"payload": "\ufffd"} and values[2]["reply"]["id"] == ReturnCode.VALUE_ERR
        assert abs(values[0]["t"] - time.time()) < 5
        traces.undeclare()
    finally:
        server.close()


# -- the recording file -----------------------------------------------------------------------------------

def write_recording(path: Path) -> list[tuple[str, int, dict[str, Any]]]:
    """A small recording of two arms; what it holds, as ``(key, log_time [ns], value)`` in order."""
    a, b = ArmKeys("a1"), ArmKeys("a2")
    rows: list[tuple[str, int, dict[str, Any]]] = []
    for i in range(300):
        t = T0 + i * 1_000_000
        rows.append((a.pos_feedback, t, {"tm": {"sec": t // 10**9, "nsec": t % 10**9}, "pos": [0.001 * i, 0.5]}))
        rows.append((a.pos_cmd, t, {"tm": {"sec": t // 10**9, "nsec": t % 10**9}, "pos": [0.001 * i, 0.5]}))
        if i % 50 == 0:
            rows.append((a.state, t, {"state": i // 50 % 2}))
            rows.append((b.log(Service.SERVO), t, {"t": t / 1e9, "level": "INFO", "service": "servo",
                                                    "msg": f"line {i}", "logger": "x"}))
    rows.append((a.trace(Interface.MIDDLE.value, OP.movePTPJointAbs), T0 + 250_000_000,
                 {"t": 1.0, "request": {"jointPoints": [0.1, 0.2]}, "reply": {"id": 0, "comment": "OK"}}))
    rows.append((a.estop, T0 + 260_000_000, {}))
    rows.sort(key=lambda r: r[1])
    writer = RecordingWriter(path)
    for key, t, value in rows:
        writer.write(key, t, t, json.dumps(value).encode())
    writer.close()
    return rows


def test_a_recording_reads_back_by_key_with_its_arms_and_counts(tmp_path: Path) -> None:
    path = tmp_path / "run.mcap"
    rows = write_recording(path)
    assert arms(path) == ["a1", "a2"]
    assert keys(path) == sorted({key for key, _, _ in rows})
    summary = info(path)
    assert summary.counts[ArmKeys("a1").pos_feedback] == 300 and summary.messages == len(rows)
    assert summary.start == pytest.approx(T0 / 1e9) and summary.end == pytest.approx((T0 + 299_000_000) / 1e9)
    every = list(read_messages(path))
    assert [(r.key, r.value) for r in every] == [(k, v) for k, _, v in rows]
    assert every[0] == Recorded(rows[0][0], rows[0][1] * 1e-9, rows[0][2])
    states = list(read_messages(path, ["JARA_ARM/*/state", ArmKeys("a2").every_key]))
    assert {r.key for r in states} == {ArmKeys("a1").state, ArmKeys("a2").log(Service.SERVO)} and len(states) == 12
    assert all(a.t <= b.t for a, b in zip(states, states[1:]))
    assert list(read_messages(path, ["JARA_ARM/nobody/**"])) == []
    with pytest.raises(RecordingError, match="not a key expression"):
        list(read_messages(path, ["JARA_ARM//x"]))
    with path.open("rb") as f:  # what other MCAP tools see
        reader = make_reader(f)
        mcap_summary = reader.get_summary()
        assert mcap_summary is not None
        for channel in mcap_summary.channels.values():
            assert channel.message_encoding == "json"
            schema = mcap_summary.schemas[channel.schema_id]
            assert schema.encoding == "jsonschema" and (schema.name, schema.data) == channel_schema(channel.topic)


def test_bad_files_are_said_in_a_readable_message(tmp_path: Path) -> None:
    with pytest.raises(RecordingError, match="cannot read .*missing.mcap: No such file"):
        info(tmp_path / "missing.mcap")
    junk = tmp_path / "junk.mcap"
    junk.write_bytes(b"this is no recording" * 20)
    with pytest.raises(RecordingError, match="junk.mcap is not an MCAP recording"):
        info(junk)
    good = tmp_path / "good.mcap"
    write_recording(good)
    cut = tmp_path / "cut.mcap"
    cut.write_bytes(good.read_bytes()[: good.stat().st_size // 2])
    with pytest.raises(RecordingError, match="cut.mcap is damaged"):
        list(read_messages(cut))
    with pytest.raises(RecordingError, match="cannot write"):
        RecordingWriter(tmp_path / "no" / "such" / "dir.mcap")


@pytest.mark.parametrize("argv, message", [
    (["record", "-o", "/proc/no/run.mcap"], "jara-arm record: cannot write /proc/no/run.mcap"),
    (["replay", "/nonexistent/run.mcap"], "jara-arm replay: cannot read /nonexistent/run.mcap"),
    (["replay", "JUNK"], "junk.mcap is damaged: it ends in the middle of a record"),
    (["replay", "GOOD", "--arm", "a9"], "no arm a9 in the recording (it holds a1, a2)"),
])
def test_bad_files_and_arms_exit_2_before_joining_any_network(
        argv: list[str], message: str, tmp_path: Path, no_network: None, capsys: pytest.CaptureFixture[str]) -> None:
    (tmp_path / "junk.mcap").write_bytes(b"\x89MCAP0\r\n garbage")  # MCAP's magic, then nothing of it
    write_recording(tmp_path / "good.mcap")
    argv = [{"JUNK": str(tmp_path / "junk.mcap"), "GOOD": str(tmp_path / "good.mcap")}.get(a, a) for a in argv]
    assert cli.main(argv) == 2
    err = capsys.readouterr().err
    assert message in err and "Traceback" not in err, err


# -- record and replay against a lone in-process peer ---------------------------------------------------------

@pytest.mark.timeout(60)
def test_record_writes_every_sample_of_the_arm_with_its_times(lone_session: zenoh.Session, tmp_path: Path) -> None:
    k, other = ArmKeys("r1"), ArmKeys("r2")
    path = tmp_path / "lone.mcap"
    stop, err, status = threading.Event(), io.StringIO(), []
    writer = RecordingWriter(path)
    thread = threading.Thread(target=lambda: status.append(
        run_record(lone_session, writer, RecordSettings(("r1",)), stop, err, False)))
    thread.start()
    wait_until(lambda: "recording" in err.getvalue(), 10, what="the recorder to subscribe")
    feedback = lone_session.declare_publisher(k.pos_feedback, encoding=label(Encoding.MSGPACK))
    t_sent = time.time()
    for i in range(200):
        feedback.put(timed_joint_pos_payload(T0 + i, [0.01 * i]))
    lone_session.put(k.state, b'{"state": 1}', encoding=zenoh.Encoding.APPLICATION_JSON)
    lone_session.put(k.estop, b"")
    lone_session.put(other.state, b'{"state": 1}', encoding=zenoh.Encoding.APPLICATION_JSON)  # not recorded
    feedback.undeclare()
    wait_until(lambda: "msg/s" in err.getvalue(), 10, 0.05, "a progress line")
    stop.set()
    thread.join(10)
    assert status == [0], err.getvalue()
    assert "msg/s" in err.getvalue() and "recorded 202 messages on 3 keys" in err.getvalue(), err.getvalue()
    got = list(read_messages(path))
    assert [r.key for r in got] == [k.pos_feedback] * 200 + [k.state, k.estop]
    assert [r.value["pos"] for r in got[:200]] == [[0.01 * i] for i in range(200)]
    assert got[200].value == {"state": 1} and got[201].value == {}
    assert all(t_sent - 1 < r.t < time.time() for r in got)


@pytest.mark.timeout(60)
def test_replay_publishes_the_recording_in_order_in_each_keys_encoding(lone_session: zenoh.Session,
                                                                       tmp_path: Path) -> None:
    path = tmp_path / "run.mcap"
    rows = write_recording(path)
    sub = lone_session.declare_subscriber("JARA_ARM/**", zenoh.handlers.FifoChannel(10_000))
    err = io.StringIO()
    t0 = time.monotonic()
    status = run_replay(lone_session, path, info(path), ReplaySettings(speed=2.0), threading.Event(), err, False)
    took = time.monotonic() - t0
    assert status == 0, err.getvalue()
    got = []
    while (s := sub.try_recv()) is not None:
        encoding = Encoding.of(s.encoding)
        assert encoding is encoding_of(str(s.key_expr)), str(s.key_expr)
        got.append((str(s.key_expr), codec.loads(s.payload.to_bytes(), encoding)))
    sub.undeclare()
    expected = [(key, value) for key, _, value in rows if replayed(key)]
    assert got == expected
    assert not any(key in (ArmKeys("a1").pos_cmd, ArmKeys("a1").estop) for key, _ in got)
    assert "not replayed" in err.getvalue() and ArmKeys("a1").pos_cmd in err.getvalue()
    assert 0.299 / 2 * 0.9 < took < 5.0  # 0.3 s recorded, at twice the pace


@pytest.mark.timeout(60)
def test_replay_of_one_arm_and_its_refusal_while_that_arm_is_alive(lone_session: zenoh.Session,
                                                                   tmp_path: Path) -> None:
    path = tmp_path / "run.mcap"
    write_recording(path)
    sub = lone_session.declare_subscriber("JARA_ARM/**", zenoh.handlers.FifoChannel(10_000))
    assert run_replay(lone_session, path, info(path), ReplaySettings(50.0, ("a2",)), threading.Event(),
                      io.StringIO(), False) == 0
    assert {str(s.key_expr) for s in iter(sub.try_recv, None)} == {ArmKeys("a2").log(Service.SERVO)}
    token = lone_session.liveliness().declare_token(ArmKeys("a1").alive(Service.SERVO))
    err = io.StringIO()
    try:
        assert run_replay(lone_session, path, info(path), ReplaySettings(50.0), threading.Event(), err, False) == 1
    finally:
        token.undeclare()
    assert "refused: arm a1 (servo) is alive on this network" in err.getvalue(), err.getvalue()
    assert sub.try_recv() is None  # nothing published
    sub.undeclare()


# -- live: a real session recorded, then replayed where no arm runs -------------------------------------------------

LOW_RATE = ("state", "alarm", "trace/**", "log/**", "Command/settings", "Monitor/alarms")


@contextlib.contextmanager
def recorder(port: int, path: Path) -> Iterator[Proc]:
    proc = Proc([*LAUNCHER, "record", "--connect", endpoint(port), "-o", str(path)])
    try:
        proc.wait_for_line("recording JARA_ARM/**", timeout=30)
        yield proc
    finally:
        proc.stop(signal.SIGINT)


@pytest.fixture(scope="module")
def recorded(tmp_path_factory: pytest.TempPathFactory) -> tuple[Path, dict[str, Any]]:
    """A session of ``jara-arm up`` (iiwa) recorded by ``jara-arm record``: servo on, a PTP, a LIN, an
    e-stop (the alarm), clearAlarms; the file and what was done."""
    path = tmp_path_factory.mktemp("record") / "session.mcap"
    model = robot("iiwa")
    target = (np.array(model.ready_pose) + 0.1).tolist()
    with launched("--robot", "iiwa") as (_proc, port), client_session(port) as session:
        client = Client(session)
        client.wait_alive((Service.SERVO, Service.PLANNER, Service.COMMAND, Service.ALARM_MONITOR))
        with recorder(port, path) as rec:
            wait_recording(rec)
            t_start = time.time()
            assert client.common(OP.servoON).ok
            assert client.middle(OP.setSpeedJoint, {"spdRatio": 100}).ok
            assert client.middle(OP.setSpeedCartesian, {"spdRatio": 100}).ok
            assert client.middle(OP.movePTPJointAbs, {"jointPoints": target}).ok
            client.wait_idle()
            down = CarPosWithElbow(hg_matrix(translation=(0.0, -0.05, -0.05)), 0.0, 0)
            assert client.middle(OP.moveLinearCartesianRel, {"carPoint": down}).ok
            client.wait_idle()
            session.put(client.keys.estop, b"")
            wait_until(lambda: client.state & StateBit.ALARM, 10, what="the e-stop alarm")
            cleared = session.declare_subscriber(client.keys.trace(Interface.COMMON.value, OP.clearAlarms),
                                                 zenoh.handlers.FifoChannel(4))
            assert client.common(OP.clearAlarms).ok
            # The trace goes out after the reply: once it is here, the recorder's copy is on its way
            # too, and the recorder takes what is on its way when stopped (record.LINGER).
            wait_until(lambda: cleared.try_recv() is not None, 10, what="the trace of clearAlarms")
            cleared.undeclare()
            t_end = time.time()
            code = rec.stop(signal.SIGINT)
            assert code == 0, rec.output
            assert "msg/s" in rec.output and "recorded " in rec.output, rec.output
    return path, {"target": target, "t_start": t_start, "t_end": t_end}


@pytest.mark.timeout(300)
def test_live_the_recording_holds_every_channel_with_its_schema_the_1khz_feedback_and_the_calls(
        recorded: tuple[Path, dict[str, Any]]) -> None:
    path, done = recorded
    k = ArmKeys("arm0")
    with path.open("rb") as f:
        summary = make_reader(f).get_summary()
    assert summary is not None
    topics = {c.topic: c for c in summary.channels.values()}
    for key in (k.pos_feedback, k.servo_status, k.state, k.alarm, k.log(Service.SERVO),
                k.planner_progress, k.monitor_alarms, k.estop, k.trace(Interface.COMMON.value, OP.servoON),
                k.trace(Interface.MIDDLE.value, OP.movePTPJointAbs),
                k.trace(Interface.MIDDLE.value, OP.moveLinearCartesianRel),
                k.trace(Interface.COMMON.value, OP.clearAlarms)):
        assert key in topics, (key, sorted(topics))
    for topic, channel in topics.items():
        schema = summary.schemas[channel.schema_id]
        assert channel.message_encoding == "json" and schema.encoding == "jsonschema", topic
        assert (schema.name, schema.data) == channel_schema(topic)
        for rec in list(read_messages(path, [topic]))[:20]:  # what was written meets its channel's schema
            validate(topic, rec.value)
    feedback = list(read_messages(path, [k.pos_feedback]))
    span = feedback[-1].t - feedback[0].t
    # 1 kHz: the recorder dropped nothing (its exit code), but it is a client of the gateway, whose
    # streams are best effort per client: fresh-clone CI runs lost 7 % in gaps of 2-18 ms (not traced)
    assert span > 2.0 and len(feedback) / span == pytest.approx(1000, rel=0.1)
    stamps = [r.value["tm"]["sec"] + r.value["tm"]["nsec"] * 1e-9 for r in feedback]
    assert np.all(np.diff(stamps) > 0)
    ptp = [r.value for r in read_messages(path, [k.trace(Interface.MIDDLE.value, OP.movePTPJointAbs)])]
    assert len(ptp) == 1 and ptp[0]["request"] == {"jointPoints": done["target"]}
    assert ptp[0]["reply"] == {"id": 0, "comment": ptp[0]["reply"]["comment"]}
    raised = [r.value for r in read_messages(path, [k.alarm]) if r.value["event"] == "raised"]
    assert [a["alarm"]["code"] for a in raised] == [AlarmCode.EMERGENCY_STOP]
    assert all(done["t_start"] - 2 < r.t < done["t_end"] + 2 for r in read_messages(path, [k.state]))


@pytest.mark.timeout(300)
def test_live_a_replay_into_a_router_without_arms_gives_subscribers_the_same_sequence(
        recorded: tuple[Path, dict[str, Any]]) -> None:
    path, _ = recorded
    k = ArmKeys("arm0")
    low_rate = [f"{k.root}/{key}" for key in LOW_RATE]
    expected = [(r.key, r.value) for r in read_messages(path, low_rate)]
    assert any(key == k.trace(Interface.MIDDLE.value, OP.movePTPJointAbs) for key, _ in expected)
    port = free_port()
    router = Proc([*LAUNCHER, "router", "--listen", endpoint(port)])
    try:
        router.wait_for_line("ready", timeout=30)
        with client_session(port) as session:
            every = session.declare_subscriber("JARA_ARM/**", zenoh.handlers.FifoChannel(1_000_000))
            with client_session(port) as probe, probe.declare_publisher(low_rate[0]) as pub:
                wait_until(lambda: pub.matching_status.matching, 10, 0.01, "the subscription at the router")
            run = Proc([*LAUNCHER, "replay", str(path), "--speed", "2", "--connect", endpoint(port)])
            assert run.popen.wait(240) == 0, run.output
            assert "replayed " in run.output and "not replayed" in run.output, run.output
            wanted = [zenoh.KeyExpr(key) for key in low_rate]
            recorded_feedback = len(list(read_messages(path, [k.pos_feedback])))
            got: list[tuple[str, Any]] = []
            feedback = commands = 0

            def drained() -> bool:
                """What arrived so far; whether it is all (the replay has exited, but the router may still be
                forwarding its last samples: a busy-loop run found the last settings missing at once)."""
                nonlocal feedback, commands
                for s in iter(every.try_recv, None):  # one subscriber: the order the replay published in
                    key = str(s.key_expr)
                    feedback += key == k.pos_feedback
                    commands += key in (k.pos_cmd, k.estop)
                    if any(w_.intersects(s.key_expr) for w_ in wanted):
                        got.append((key, codec.loads(s.payload.to_bytes(), Encoding.of(s.encoding))))
                return len(got) >= len(expected) and feedback >= recorded_feedback

            with contextlib.suppress(AssertionError):  # what is missing after 10 s: the asserts below say it
                wait_until(drained, 10.0, 0.05, "every replayed sample")
            assert got == expected
            assert feedback == recorded_feedback
            assert commands == 0  # position commands and the e-stop are never replayed
    finally:
        router.stop(signal.SIGINT)


@pytest.mark.timeout(300)
def test_live_replay_refuses_onto_a_network_where_the_arm_runs(recorded: tuple[Path, dict[str, Any]]) -> None:
    path, _ = recorded
    with launched("--robot", "iiwa") as (_proc, port):
        run = Proc([*LAUNCHER, "replay", str(path), "--connect", endpoint(port)])
        assert run.popen.wait(60) == 1, run.output
        assert "refused: arm arm0 (" in run.output and "is alive on this network" in run.output, run.output
