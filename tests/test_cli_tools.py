"""``jara-arm call``, ``echo``, ``state``, ``wait`` and ``completion`` (issue 12, part 3).

The tests without ``live`` in their name need no system (``pytest -k 'not live'``):
parsing, close matches, parameter lists, local checks of bad input (exit 2, no
session opened), decoding, rendering, the completion script run by bash, and
``echo`` against a lone local Zenoh session. The ``live`` ones run the commands
as real processes against ``jara-arm up`` (the ``live``/``arm`` fixtures of
conftest.py), as a user's shell would.
"""

from __future__ import annotations

import json
import shutil
import socket
import subprocess
import sys
import threading
import time
from typing import Any

import msgpack
import numpy as np
import pytest
import zenoh

from jara_arm.launcher import cli
from jara_arm.launcher.tools.arm_state import format_state, read_state
from jara_arm.launcher.tools.call import CallError, close_matches, parameter_list, parse_call, reply_json
from jara_arm.launcher.tools.echo import EchoKeyError, EchoSettings, Thinner, decode_payload, echo_key, run_echo
from jara_arm.launcher.tools.state_view import Beat, Snapshot, render, rpy
from jara_arm.launcher.tools.wait import Condition, state_meets
from jara_arm.schema import codec
from jara_arm.schema import wire_types as w
from jara_arm.schema.codec import Reply
from jara_arm.schema.codes import AlarmType, ReturnCode, StateBit
from jara_arm.schema.keys import ArmKeys, Service
from jara_arm.schema.messages import LoopHealth
from jara_arm.schema.operations import ALL, MIDDLE, OP
from jara_arm.schema.types import Alarm, CarPosWithElbow, Time, hg_matrix
from jara_arm.services.runtime.zenoh_args import zenoh_config

from .harness import LiveArm
from .support import Proc, bash_complete, endpoint, free_port, wait_until

LAUNCHER = [sys.executable, "-m", "jara_arm.launcher"]


@pytest.fixture
def no_network(monkeypatch: pytest.MonkeyPatch) -> None:
    """Any attempt of the command line to join a network fails the test: bad input sends nothing."""
    def refuse(*_: Any, **__: Any) -> Any:
        raise AssertionError("the command opened a Zenoh session")
    monkeypatch.setattr(zenoh, "open", refuse)


# -- parsing ---------------------------------------------------------------------------------------

def test_the_tools_parse_their_arguments() -> None:
    top = cli.parser()
    call = top.parse_args(["call", "--arm", "a1", "--servo", "--timeout", "3", "getState"])
    assert (call.command, call.arm, call.servo, call.timeout, call.op, call.json) == \
        ("call", "a1", True, 3.0, "getState", None)
    echo = top.parse_args(["echo", "Servo/posFeedback", "--rate", "10", "--count", "5"])
    assert (echo.arm, echo.key, echo.rate, echo.count, echo.once) == ("arm0", "Servo/posFeedback", 10.0, 5, False)
    wait = top.parse_args(["wait", "idle", "--timeout", "2"])
    assert (wait.condition, wait.timeout) == (Condition.IDLE, 2.0)
    state = top.parse_args(["state", "--once"])
    assert state.once and state.period == 0.5
    assert cli.command_parser(["echo", "state"])[0].prog.endswith("echo")


def test_the_command_table_says_where_each_command_lives() -> None:
    assert [cli.command(name).name for name in cli.COMMANDS] == list(cli.COMMANDS)


def test_a_command_line_imports_only_its_own_command() -> None:
    """The gateway, the router and the client tools start without the rest of the launcher."""
    code = ("import sys; from jara_arm.launcher import cli; cli.main(['call', '--help']); "
            "print(sorted(m for m in sys.modules if m.startswith('jara_arm.launcher.') and '.tools' not in m))")
    done = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=60, check=True)
    imported = done.stdout.splitlines()[-1]
    for other in ("view", "pendant", "record", "secure.certs", "ros2", "program", "up.up"):
        assert f"jara_arm.launcher.{other}" not in imported, imported


@pytest.mark.parametrize("argv, message", [
    (["wait", "sleepy"], "invalid choice: 'sleepy'"),
    (["wait", "idle", "--timeout", "-1"], "expected a positive number"),
    (["echo", "state", "--rate", "0"], "expected a positive number"),
    (["echo", "state", "--once", "--count", "3"], "not allowed with argument"),
    (["echo", "state", "--count", "0"], "expected a whole number of 1 or more"),
    (["call", "--arm", "bad/id", "getState"], "arm id 'bad/id' must be one chunk"),
    (["completion", "tcsh"], "invalid choice: 'tcsh'"),
])
def test_bad_options_exit_2(argv: list[str], message: str, no_network: None,
                            capsys: pytest.CaptureFixture[str]) -> None:
    assert cli.main(argv) == 2
    err = capsys.readouterr().err
    assert message in err and "Traceback" not in err


# -- call: names, parameters, local checks ------------------------------------------------------------

def test_unknown_operation_names_its_close_matches(no_network: None, capsys: pytest.CaptureFixture[str]) -> None:
    assert cli.main(["call", "movePTPJointAbz"]) == 2
    err = capsys.readouterr().err
    assert "no operation 'movePTPJointAbz'; did you mean movePTPJointAbs, movePTPJointRel?" in err
    assert close_matches("servoon")[:2] == ["servoON", "servoOFF"]  # case does not hide a name
    assert "setSpeedJoint" in close_matches("setSpeedJ")
    assert close_matches("movePTP", servo=True) == []  # the servo has no motion operation
    assert cli.main(["call", "zzzz"]) == 2
    assert f"the operations are: {', '.join(op.name for op in ALL)}" in capsys.readouterr().err


def test_the_servo_takes_only_common_operations(no_network: None, capsys: pytest.CaptureFixture[str]) -> None:
    assert cli.main(["call", "--servo", "setSpeedJoint", "50"]) == 2
    assert "the servo serves only the Common operations, not 'setSpeedJoint'" in capsys.readouterr().err
    assert parse_call(OP.getState, None, servo=True).servo


@pytest.mark.parametrize("op, text, field, shown", [
    (OP.setSpeedJoint, '{"spdRatio": "fast"}', "spdRatio: expected an integer (ULONG), got str",
     "spdRatio: ULONG (0 .. 4294967295) [%]"),
    (OP.setSpeedJoint, '{"spdRatio": 50, "speed": 1}', "speed: unexpected parameter of setSpeedJoint",
     "spdRatio: ULONG"),
    (OP.movePTPJointAbs, '{"jointPoints": [0, 1', "the parameters are not valid JSON",
     "jointPoints: JointPos, a list of double [rad or m]"),
    (OP.movePTPJointAbs, '{"jointPoints": [0, "x"]}', "jointPoints[1]: expected a number (double), got str",
     "jointPoints: JointPos"),
    (OP.movePTPCartesianAbs, None, "carPoint: missing parameter of movePTPCartesianAbs",
     "    elbow: double [rad], 7-axis arm angle"),
    (OP.setSoftLimitJoint, '{"softLimit": [{"upper": 1}]}', "softLimit[0].lower: missing member of LimitValue",
     "    lower: double [rad or m]"),
    (OP.setMaxSpeedCartesian, '{"speed": {"translation": 0.1, "rotation": true}}',
     "speed.rotation: expected a number (double), got bool", "    rotation: double [rad/s]"),
    (OP.getState, '{"x": 1}', "x: unexpected parameter of getState; valid parameters: none", "parameters: none"),
])
def test_bad_parameters_name_the_field_and_list_the_parameters(
        op: str, text: str | None, field: str, shown: str, no_network: None,
        capsys: pytest.CaptureFixture[str]) -> None:
    assert cli.main(["call", op] + ([text] if text is not None else [])) == 2
    err = capsys.readouterr().err
    assert f"jara-arm call: {op}: " in err and field in err, err
    assert shown in err and f"{op} (" in err, err
    assert "Traceback" not in err


def test_every_operations_example_is_a_valid_call() -> None:
    for op in ALL:
        text = parameter_list(op)
        if not op.inputs:
            assert text.endswith("parameters: none")
            continue
        example = text.rsplit(f"jara-arm call {op.name} '", 1)[1].rstrip("'")
        assert set(parse_call(op.name, example).args) == {p.name for p in op.inputs}
        for p in op.inputs:  # every parameter is listed with its unit (if it has one)
            assert f"  {p.name}: " in text and (f"[{p.unit}]" in text if p.unit else True)


def test_an_operation_of_one_parameter_takes_its_value_alone() -> None:
    assert parse_call(OP.setSpeedJoint, "50").args == {"spdRatio": 50}
    assert parse_call(OP.movePTPJointAbs, "[0.1, 0.2]").args == {"jointPoints": (0.1, 0.2)}
    assert parse_call(OP.servoON, "  ").args == {}
    with pytest.raises(CallError, match="spdRatio: -1 is out of range"):
        parse_call(OP.setSpeedJoint, "-1")
    with pytest.raises(CallError, match="payload: expected a map"):  # two parameters: an object only
        parse_call(OP.moveCircularCartesianAbs, "[1, 2]")


def test_the_reply_prints_in_its_wire_form() -> None:
    op = MIDDLE[OP.getFeedbackPosCartesian]
    reply = Reply(ReturnCode.OK, "", {"pos": CarPosWithElbow(hg_matrix(None, (0.5, 0.0, 0.4)), 0.0, 0)})
    printed = json.loads(json.dumps(reply_json(op, reply)))
    assert printed == {"id": 0, "comment": "", "pos": {"carPos": [[1, 0, 0, 0.5], [0, 1, 0, 0], [0, 0, 1, 0.4]],
                                                       "elbow": 0.0, "structFlag": 0}}
    refused = Reply(ReturnCode.NOT_SV_ON_ERR, "servo is off")
    assert reply_json(op, refused) == {"id": -4, "comment": "servo is off"}  # no out parameters when not OK


# -- echo: keys, decoding, thinning ---------------------------------------------------------------------

def test_echo_takes_the_schemas_published_keys() -> None:
    keys = ArmKeys("a1")
    assert echo_key("a1", "state") == keys.state
    assert echo_key("a1", "Servo/posFeedback") == keys.pos_feedback
    assert echo_key("a1", "log/**") == f"{keys.root}/log/**"
    assert echo_key("a1", "heartbeat/servo") == f"{keys.root}/heartbeat/servo"
    with pytest.raises(EchoKeyError, match="no published key 'Common/getState'.*keys: .*Servo/posFeedback"):
        echo_key("a1", "Common/getState")  # a queryable: nothing is published there
    with pytest.raises(EchoKeyError, match="not a key expression"):
        echo_key("a1", "log//servo")


def test_a_bad_echo_key_exits_2_and_says_the_valid_ones(no_network: None,
                                                        capsys: pytest.CaptureFixture[str]) -> None:
    assert cli.main(["echo", "stat"]) == 2
    err = capsys.readouterr().err
    assert "no published key 'stat'" in err and "state" in err and "log/*" in err


def test_samples_decode_by_their_encoding_or_their_first_byte() -> None:
    body = {"state": 1, "queueLength": 2}
    assert decode_payload(msgpack.packb(body), None) == body
    assert decode_payload(msgpack.packb(body), "application/msgpack") == body
    assert decode_payload(json.dumps(body).encode(), "application/json") == body
    assert decode_payload(json.dumps(body).encode(), None) == body  # a generic tool sets no encoding
    assert decode_payload(b"[1, 2]", "zenoh/bytes") == [1, 2]
    assert decode_payload(b"stop now", "text/plain") == "stop now"
    assert decode_payload(b"", None) == {}
    with pytest.raises(Exception, match="neither MessagePack nor JSON nor text"):
        decode_payload(b"\xc1\xff\xfe", None)


def test_the_rate_thins_a_1khz_stream() -> None:
    thinner = Thinner(10.0)
    kept = [i for i in range(1000) if thinner.keep(i * 1e-3)]
    assert len(kept) == 10 and kept[:3] == [0, 100, 200]
    every = Thinner(None)
    assert all(every.keep(i * 1e-3) for i in range(100))


@pytest.fixture
def lone_session() -> Any:
    """A Zenoh peer with no endpoint and no scouting: its own puts reach its own subscribers, nothing else."""
    with zenoh.open(zenoh_config("peer")) as session:
        yield session


def test_echo_prints_what_comes_as_json_lines(lone_session: zenoh.Session,
                                              capsys: pytest.CaptureFixture[str]) -> None:
    keys = ArmKeys("t1")
    settings = EchoSettings(f"{keys.root}/log/**", count=3, timeout=10.0, show_key=True)
    out: list[int] = []

    def publish() -> None:  # once echo's subscriber is declared: its loop runs
        with lone_session.declare_publisher(keys.log()) as probe:
            wait_until(lambda: probe.matching_status.matching, 10, 0.01, "echo's subscriber")
        lone_session.put(keys.log(), msgpack.packb({"msg": "packed"}))
        lone_session.put(keys.log(), json.dumps({"msg": "json"}), encoding=zenoh.Encoding.APPLICATION_JSON)
        lone_session.put(keys.log(), b"\xc1")  # undecodable: said on stderr, skipped
        lone_session.put(keys.log(), json.dumps({"msg": "sniffed"}))

    thread = threading.Thread(target=publish)
    thread.start()
    out.append(run_echo(lone_session, settings, threading.Event(), sys.stdout, sys.stderr))
    thread.join()
    captured = capsys.readouterr()
    assert out == [0]
    lines = [json.loads(line) for line in captured.out.splitlines()]
    assert [line["value"]["msg"] for line in lines] == ["packed", "json", "sniffed"]
    assert {line["key"] for line in lines} == {keys.log()}
    assert "undecodable sample on" in captured.err


def test_echo_times_out_with_a_non_zero_exit(lone_session: zenoh.Session,
                                             capsys: pytest.CaptureFixture[str]) -> None:
    settings = EchoSettings(ArmKeys("t2").state, count=1, timeout=0.2)
    assert run_echo(lone_session, settings, threading.Event(), sys.stdout, sys.stderr) == 1
    assert "0 sample(s) on JARA_ARM/t2/state within 0.2 s" in capsys.readouterr().err


# -- state and wait --------------------------------------------------------------------------------------

def test_state_bits_by_name_and_the_published_queue() -> None:
    assert format_state(0x03) == "0x03 SERVO_ON|MOVING"
    assert format_state(0) == "0x00 none"
    assert format_state(0x41) == "0x41 SERVO_ON|0x40"
    packed = read_state(msgpack.packb({"state": 3, "queueLength": 2, "queueCapacity": 32}), None)
    assert (packed.state, packed.queue_length, packed.queue_capacity) == (3, 2, 32)
    plain = read_state(b'{"state": 1}', None)
    assert (plain.state, plain.queue_length) == (1, None)


@pytest.mark.parametrize("bits, met", [
    (0x01, {Condition.IDLE, Condition.SERVO_ON, Condition.NO_ALARM}),
    (0x03, {Condition.SERVO_ON, Condition.NO_ALARM}),
    (0x00, {Condition.SERVO_OFF, Condition.NO_ALARM}),
    (0x04, {Condition.SERVO_OFF, Condition.ALARM}),
    (0x05, {Condition.IDLE, Condition.SERVO_ON, Condition.ALARM}),  # a WARNING: servo on, stopped
    (0x13, {Condition.SERVO_ON, Condition.NO_ALARM}),  # paused with motions queued: not idle
])
def test_wait_conditions_on_the_state_bits(bits: int, met: set[Condition]) -> None:
    assert {c for c in Condition if c is not Condition.ALIVE and state_meets(c, bits)} == met


def test_the_state_view_shows_every_part() -> None:
    yaw = 0.5
    rot = np.array([[np.cos(yaw), -np.sin(yaw), 0], [np.sin(yaw), np.cos(yaw), 0], [0, 0, 1]])
    assert rpy(rot) == pytest.approx((0.0, 0.0, yaw))
    health = LoopHealth(Time(1, 0), 1000, 1e-3, 20e-6, 80e-6, 1.5e-3, 0, 0, 3, 0, (1000,))
    snap = Snapshot(arm="arm0", taken=0.0, state=int(StateBit.SERVO_ON | StateBit.MOVING), queue=(2, 32),
                    joints=(0.1, -0.2, 0.5), axis_num=2, pose=hg_matrix(rot, (0.5, 0.0, 0.4)),
                    alarms=(Alarm(0x02, AlarmType.WARNING, "overload J2"),), health=health, health_age=0.5,
                    beats={"servo": Beat(5, (), 0.02), "planner": Beat(7, ("the plan loop: 2.0 s",), 0.05)},
                    alive=frozenset({"servo", "planner"}), errors=("getHome: no answer",))
    text = "\n".join(render(snap))
    assert "state     0x03 SERVO_ON|MOVING" in text
    assert "queue     2 motion(s) of 32" in text
    assert "J1 +0.1000  J2 -0.2000  grip +0.5000" in text
    assert "xyz [m] +0.5000 +0.0000 +0.4000   rpy [rad] +0.0000 +0.0000 +0.5000" in text
    assert "alarms    0x02 WARNING overload J2" in text
    assert "1000 cycles of 1.0 ms, late p50 20 us p99 80 us max 1.5 ms" in text and "FIFO 3" in text
    assert "servo up, beat 20.0 ms ago" in text and "STUCK: the plan loop: 2.0 s" in text
    assert "command DOWN" in text and "!         getHome: no answer" in text
    empty = "\n".join(render(Snapshot(arm="arm0", taken=0.0)))
    assert "state     ?" in empty and "no loop report yet" in empty and "queue     ?" in empty


# -- completion ----------------------------------------------------------------------------------------

@pytest.mark.skipif(shutil.which("bash") is None, reason="no bash to run the script")
def test_bash_completes_commands_operations_keys_and_conditions() -> None:
    assert bash_complete(["jara-arm", "ca"]) == ["call"]
    assert bash_complete(["jara-arm", "call", "movePTPJ"]) == ["movePTPJointAbs", "movePTPJointRel"]
    assert bash_complete(["jara-arm", "call", "--servo", "setS"]) == ["setSoftLimitJoint"]
    assert bash_complete(["jara-arm", "call", "--arm", "a1", "servoO"]) == ["servoOFF", "servoON"]
    assert bash_complete(["jara-arm", "call", "--arm", "se"]) == []  # an option's value
    assert bash_complete(["jara-arm", "call", "servoON", "se"]) == []  # the JSON is not an operation
    assert bash_complete(["jara-arm", "call", "--ser"]) == ["--servo"]
    assert bash_complete(["jara-arm", "call", "--sec"]) == ["--secure"]
    assert bash_complete(["jara-arm", "echo", "Servo/pos"]) == ["Servo/posCmd", "Servo/posFeedback", "Servo/posFeedbackBlock",
                                                                "Servo/posTarget"]
    assert "log/servo" in bash_complete(["jara-arm", "echo", "log/"])
    assert bash_complete(["jara-arm", "wait", "no"]) == ["no-alarm"]


def test_the_completion_command_prints_the_script(capsys: pytest.CaptureFixture[str]) -> None:
    assert cli.main(["completion", "bash"]) == 0
    out = capsys.readouterr().out
    assert out.startswith("# bash completion of jara-arm") and "complete -F _jara_arm jara-arm" in out
    assert all(op.name in out for op in ALL)


# -- live: the commands as real processes against `jara-arm up` ----------------------------------------

class Arm(LiveArm):
    """The live system's client (conftest.py ``live``), running ``jara-arm`` commands against it."""

    def run(self, *argv: str, timeout: float = 60.0) -> subprocess.CompletedProcess[str]:
        """``jara-arm <argv>`` as a process, a client of the live system."""
        command, *rest = argv
        return subprocess.run([*LAUNCHER, command, "--connect", self.endpoint, *rest], capture_output=True,
                              text=True, timeout=timeout)


@pytest.fixture(scope="module", params=["iiwa"])
def robot_name(request: pytest.FixtureRequest) -> str:
    return str(request.param)


@pytest.mark.timeout(180)
def test_live_a_session_of_calls_moves_the_arm(arm: Arm) -> None:
    assert json.loads(arm.run("call", OP.servoON).stdout)["id"] == 0
    run = arm.run("call", OP.setSpeedJoint, '{"spdRatio": 50}')
    assert run.returncode == 0 and json.loads(run.stdout)["id"] == 0, run.stderr
    target = np.array(arm.model.ready_pose) + 0.1
    run = arm.run("call", OP.movePTPJointAbs, json.dumps({"jointPoints": target.tolist()}))
    assert run.returncode == 0, run.stderr
    waited = arm.run("wait", "idle", "--timeout", "60")
    assert waited.returncode == 0, waited.stderr
    assert np.abs(arm.joints()[:len(target)] - target).max() < 1e-3  # it went where it was told
    state = arm.run("call", OP.getState)
    assert state.returncode == 0 and json.loads(state.stdout)["state"] == StateBit.SERVO_ON
    servo = arm.run("call", "--servo", OP.getFeedbackPosJoint)
    assert np.abs(np.array(json.loads(servo.stdout)["pos"])[:len(target)] - target).max() < 1e-3


@pytest.mark.timeout(120)
def test_live_a_refused_call_exits_non_zero(arm: Arm) -> None:
    assert arm.run("call", OP.servoOFF).returncode == 0
    run = arm.run("call", OP.movePTPJointAbs, json.dumps({"jointPoints": list(arm.model.ready_pose)}))
    assert run.returncode == 1
    assert json.loads(run.stdout)["id"] == ReturnCode.NOT_SV_ON_ERR
    assert "NOT_SV_ON_ERR (-4)" in run.stderr


@pytest.mark.timeout(120)
@pytest.mark.parametrize("argv, message", [
    (["movePTPJointAbz", '{"jointPoints": [0, 0, 0, 0, 0, 0, 0]}'], "did you mean movePTPJointAbs"),
    ([OP.movePTPJointAbs, '{"jointPoints": [0.5, 0.5'], "not valid JSON"),
    ([OP.movePTPJointAbs, '{"jointPoints": ["0.5", 0, 0, 0, 0, 0, 0]}'], "jointPoints[0]: expected a number"),
])
def test_live_bad_input_is_refused_here_and_nothing_moves(arm: Arm, argv: list[str], message: str) -> None:
    before = arm.servo_time.settled()
    run = arm.run("call", *argv)
    assert run.returncode == 2 and message in run.stderr and "Traceback" not in run.stderr, run.stderr
    assert run.stdout == ""  # no reply: nothing was sent
    arm.servo_time.passes(0.3)
    assert np.abs(arm.servo_time.settled() - before).max() < 1e-6  # [rad] nothing moved (the hold jitters ~1e-12)
    assert not arm.client.state & StateBit.MOVING


@pytest.mark.timeout(120)
def test_live_echo_state_once_prints_the_next_change(arm: Arm) -> None:
    echo = Proc([*LAUNCHER, "echo", "--connect", arm.endpoint, "state", "--once", "--timeout", "60"])
    try:
        def printed() -> bool:  # toggle the servo until echo, subscribed by then, has printed a change
            if echo.popen.poll() is not None:
                return True
            on = bool(arm.client.state & StateBit.SERVO_ON)
            arm.client.common(OP.servoOFF if on else OP.servoON)
            time.sleep(0.2)
            return False
        wait_until(printed, timeout=30, interval=0.1, what="echo's one sample",
                   explain=lambda: f"state {arm.client.state:#x}; echo's output so far:\n{echo.output}")
        assert echo.popen.wait(5) == 0, echo.output
    finally:
        echo.stop()
    lines = [line for line in echo.lines if line.startswith("{")]
    assert len(lines) == 1, echo.output
    assert json.loads(lines[0])["state"] in (0, int(StateBit.SERVO_ON))


@pytest.mark.timeout(120)
def test_live_echo_thins_the_feedback_stream(arm: Arm) -> None:
    run = arm.run("echo", "Servo/posFeedback", "--rate", "10", "--count", "5", "--timeout", "20")
    assert run.returncode == 0, run.stderr
    samples = [codec.decode_message(w.TIMED_JOINT_POS, msgpack.packb(json.loads(line)))
               for line in run.stdout.splitlines()]
    assert len(samples) == 5 and all(len(s.pos) >= arm.model.axis_num for s in samples)
    gaps = np.diff([s.tm.to_seconds() for s in samples])
    # 10 Hz of a 1 kHz stream, kept by receipt time from each due time (``echo.Thinner``): the 5 samples span
    # at least 0.4 s as received, less the first one's extra delivery delay (0.1 s allowed). Not each gap: a
    # sample received late is followed by one on the due time (stamps 0.17 s then 0.04 s apart, a busy host).
    assert gaps.sum() > 0.3, gaps


@pytest.mark.timeout(120)
def test_live_state_once_shows_the_arm(arm: Arm) -> None:
    run = arm.run("state", "--once")
    assert run.returncode == 0, run.stderr
    out = run.stdout
    assert "state     0x01 SERVO_ON" in out and "alarms    none" in out, out
    assert "joints    [rad or m]  J1 " in out and "xyz [m] " in out, out
    assert " cycles of 1.0 ms" in out and "servo up, beat" in out, out
    assert "\x1b[" not in out  # not a terminal: no escape sequences


@pytest.mark.timeout(120)
def test_live_wait_times_out_non_zero_and_meets_what_holds(arm: Arm) -> None:
    t0 = time.monotonic()
    run = arm.run("wait", "servo-off", "--timeout", "1")
    assert run.returncode == 1 and "not servo-off" in run.stderr and "within 1 s" in run.stderr, run.stderr
    assert "last seen: state 0x01 SERVO_ON" in run.stderr
    assert time.monotonic() - t0 < 30
    assert arm.run("wait", "alive", "--timeout", "20").returncode == 0
    assert arm.run("wait", "no-alarm", "--timeout", "5").returncode == 0


def _refused_once(port: int, argv: list[str]) -> subprocess.Popen[str]:
    """``jara-arm argv`` started while something that refuses Zenoh listens on ``port``; returned once it
    made its first try."""
    with socket.create_server(("127.0.0.1", port)) as early:
        proc = subprocess.Popen([*LAUNCHER, *argv, "--connect", endpoint(port)], stdout=subprocess.PIPE,
                                stderr=subprocess.PIPE, text=True)
        try:
            early.settimeout(60)
            conn, _ = early.accept()  # its first try
            conn.close()
        except BaseException:
            proc.kill()
            raise
    return proc


def test_a_command_with_a_timeout_keeps_trying_to_join_until_the_router_listens() -> None:
    """``jara-arm echo --timeout`` started before the router: it is refused once, tries again, and prints
    the sample once the router is up (it used to exit 2 at once: "cannot join the Zenoh network")."""
    port = free_port()
    keys = ArmKeys("t4")
    echo = _refused_once(port, ["echo", "--arm", "t4", "state", "--once", "--timeout", "60"])
    with zenoh.open(zenoh_config("router", listen=[endpoint(port)])) as router:
        try:
            while echo.poll() is None:  # until echo has joined, subscribed and printed one
                router.put(keys.state, msgpack.packb({"state": 1}))
                time.sleep(0.05)
            out, err = echo.communicate()
        finally:
            echo.kill()
    assert echo.returncode == 0, err
    assert json.loads(out)["state"] == 1


def test_wait_alive_started_before_the_router_waits_for_it_and_the_services() -> None:
    """``jara-arm wait --arm ID alive --timeout 60`` just after ``jara-arm up`` (before its router listens): it
    keeps trying to join, then waits for the four services' tokens, and exits 0 once they are all up."""
    port = free_port()
    keys = ArmKeys("t5")
    wait = _refused_once(port, ["wait", "--arm", "t5", "alive", "--timeout", "60"])
    with zenoh.open(zenoh_config("router", listen=[endpoint(port)])) as router:
        tokens = [router.liveliness().declare_token(keys.alive(service)) for service in Service]
        try:
            out, err = wait.communicate(timeout=60)
        finally:
            wait.kill()
            for token in tokens:
                token.undeclare()
    assert wait.returncode == 0, err
