"""The servo service as a real process: SyncFIFO, tracking, stops, alarms, bad input."""

from __future__ import annotations

import shutil
import subprocess
import sys
import time
from collections.abc import Iterator
from pathlib import Path

import msgpack
import numpy as np
import pytest
import zenoh

from jara_arm.robots import robot
from jara_arm.schema import messages
from jara_arm.schema.codec import Reply
from jara_arm.schema.codes import AlarmCode, AlarmType, ReturnCode, StateBit
from jara_arm.schema.keys import Service
from jara_arm.schema.operations import COMMON, OP
from jara_arm.services.servo.control import OVERSPEED_MARGIN

from .harness import PosCommands, Processes, RecordingArm, StatusLog, timed_joints
from .support import STREAM_PRIORITY, Proc, client_session, free_port, service_argv, wait_alive, wait_until

pytestmark = pytest.mark.timeout(120)
DT = 1e-3
IIWA = robot("iiwa")
VMAX = np.array(IIWA.rated_speed)
AMAX = np.array(IIWA.max_accel)
#: [cycles] the servo runs after it took commands it must ignore, before "nothing moved" is
#: checked: an applied command would have moved the arm by then (an observation window, of
#: the servo's own cycles).
IGNORED_WINDOW = 100


class Rig(RecordingArm):
    """A servo process alone, its feedback and every status recorded, and a low-level client's position
    commands to it. No command service: the Common interface is the servo's own."""

    BLOCKS = False  # no gateway: the test is a peer of the servo (RecordingArm.BLOCKS)

    def __init__(self, session: zenoh.Session, robot_name: str, proc: Proc) -> None:
        super().__init__(session, robot_name, proc=proc)
        self.commands = PosCommands(session, self.keys, self.model.cmd_cycle)
        self.statuses = StatusLog(session, self.keys, explain=self.log_tail)

    def common(self, name: str, args: dict | None = None) -> Reply:
        return self.servo(name, args)

    def took(self, received: int, what: str) -> None:
        """Until the servo has taken ``received`` position commands off the wire since it started
        (its status counts them, the ones it drops too), then run ``IGNORED_WINDOW`` more cycles."""
        st = self.statuses.first(lambda s: s.received >= received, f"the servo to take {what}")
        end = st.tm.to_seconds() + IGNORED_WINDOW * DT
        self.statuses.first(lambda s: s.tm.to_seconds() >= end, f"{IGNORED_WINDOW} servo cycles after {what}")

    def reset(self) -> None:
        """Servo off, at rest, alarms cleared, default soft limits, servo on, recordings emptied."""
        self.servo(OP.servoOFF)
        self.wait_rest()
        assert self.servo(OP.clearAlarms).id == ReturnCode.OK
        assert self.servo(OP.setSoftLimitJoint, {"softLimit": self.model.hard_limits}).id == ReturnCode.OK
        assert self.servo(OP.servoON).id == ReturnCode.OK
        on = time.time()
        # A status of a cycle after the servoON (a cycle never runs before its deadline, its tm):
        # everything published before it has arrived, and is emptied here.
        self.statuses.first(lambda st: st.tm.to_seconds() > on and st.servoOn, "a status with the servo on")
        self.record()
        self.statuses.drain()


def start_rig(robot_name: str) -> Iterator[Rig]:
    port = free_port()
    with Processes() as procs:
        proc = procs.start(service_argv(Service.SERVO, port, robot=robot_name))
        with client_session(port) as session:
            wait_alive(session, "arm0", [Service.SERVO])
            yield Rig(session, robot_name, proc)


@pytest.fixture(scope="module")
def iiwa_rig():
    yield from start_rig("iiwa")


@pytest.fixture
def rig(iiwa_rig: Rig) -> Rig:
    iiwa_rig.reset()
    return iiwa_rig


def j1_of(tm: np.ndarray, q: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(tm [s], J1 [rad]) of the feedback, for differences over the real sample spacing."""
    return tm, q[:, 0]


def velocity_and_acceleration(tm: np.ndarray, q: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Differences of the feedback over one cycle only [per s, per s²]: a sample may be lost
    in transit (newest value wins), and a difference over a gap is not the arm's. Where a
    difference spans a gap it is NaN (``acc[i]`` is between ``vel[i]`` and ``vel[i + 1]``)."""
    dt = np.diff(tm)
    one = np.abs(dt - DT) < 0.25 * DT
    vel = np.where(one, np.diff(q) / dt, np.nan)
    acc = np.diff(vel) / dt[1:]  # NaN next to a gap
    assert np.count_nonzero(np.isfinite(acc)) > 0.9 * len(acc), "too many feedback samples lost"
    return vel, acc


def min_jerk(q0: np.ndarray, q1: np.ndarray, duration: float) -> np.ndarray:
    n = int(round(duration / DT)) + 1
    u = np.linspace(0.0, 1.0, n)[:, None]
    s = 10 * u**3 - 15 * u**4 + 6 * u**5
    return q0 + s * (q1 - q0)


def test_manip_info_and_limits(rig: Rig):
    info = rig.servo(OP.getManipInfo)["mInfo"]
    assert (info.manufactur, info.axisNum, info.cmdCycle, info.isGripper) == ("KUKA", 7, 1, False)
    assert rig.servo(OP.getSoftLimitJoint)["softLimit"] == IIWA.hard_limits
    assert rig.state() == StateBit.SERVO_ON
    assert rig.servo(OP.getActiveAlarm)["alarms"] == ()
    assert len(rig.joints()) == 7


def test_streamed_trajectory_is_followed(rig: Rig):
    q0 = rig.joints()
    q1 = q0 + np.array([0.4, -0.2, 0.3, 0.3, -0.2, 0.2, 0.5])
    path = min_jerk(q0, q1, 1.2)
    rig.commands.stream(path)
    assert rig.state() & StateBit.MOVING
    rig.wait_rest()
    fb = rig.recorded()
    assert np.abs(fb[-1] - q1).max() < 2e-4, f"{fb[-1] - q1}\n{rig.log_tail()}"
    # Every feedback sample lies near the commanded path (lag of a few cycles at most).
    dist = np.min(np.linalg.norm(fb[:, None, :] - path[None, ::5, :], axis=2), axis=1)
    assert dist.max() < 5e-3, dist.max()


def test_a_resting_servo_still_stamps_every_cycle_and_never_ahead_of_time(rig: Rig):
    """At rest the clock runs the cycles ten at a time (``clock.REST_BATCH``): every cycle keeps its sample,
    stamped a period after the one before, none stamped later than it arrived (``ServoTime`` relies on a
    cycle never running before its deadline); a call at rest (servoOFF, servoON) is taken, and a stream
    from rest is followed one command per cycle (``test_fifo_consumes_every_command_in_order_one_per_cycle``)."""
    arrivals: list[tuple[float, float]] = []  # (wall time the sample arrived, its tm) [s]

    def take(sample: zenoh.Sample) -> None:  # a test's subscriber: appending is all it does
        arrivals.append((time.time(), timed_joints(sample).tm.to_seconds()))

    rig.servo_time.passes(0.3)  # settled: past SETTLED_CYCLES at rest, so the clock batches
    with rig.session.declare_subscriber(rig.keys.pos_feedback, take):
        rig.servo_time.passes(1.0)
    got = list(arrivals)
    tm = np.array([t for _, t in got])
    steps = np.diff(tm)
    # A host pause past RESYNC_AFTER restarts the schedule (a gap); nothing else may.
    assert np.count_nonzero(np.abs(steps - DT) < 1e-6) >= 0.99 * len(steps), np.unique(np.round(steps, 4))
    assert len(got) >= 900, f"{len(got)} samples in a second of the servo's time"
    # The clocks are the same host's: a sample stamped after its arrival is a cycle run before its deadline.
    early = [(a, t) for a, t in got if t > a + 1e-4]
    assert not early, f"{len(early)} samples stamped after they arrived, e.g. {early[:3]}"
    for name, bit in ((OP.servoOFF, 0), (OP.servoON, StateBit.SERVO_ON)):
        assert rig.servo(name).id == ReturnCode.OK
        assert rig.state() & StateBit.SERVO_ON == bit


def test_fifo_consumes_every_command_in_order_one_per_cycle(rig: Rig):
    q0 = rig.joints()
    path = min_jerk(q0, q0 + np.array([0.2, 0, 0, 0, 0, 0, 0]), 0.4)  # strictly rising J1
    n = len(path)
    before = rig.statuses.newest().consumed
    t0 = time.monotonic()
    for q in path:  # all at once: the FIFO must hold them
        rig.commands.send(q)
    # A resting servo takes what arrived at its next batch of cycles, up to 9 ms on (clock.REST_BATCH).
    wait_until(lambda: rig.state() & StateBit.MOVING, 1.0, 0.001, "the servo taking the commands")
    rig.wait_rest()
    elapsed = time.monotonic() - t0
    status: list[messages.ServoStatus] = []

    def emptied() -> bool:
        status.extend(rig.statuses.drain())
        return bool(status) and status[-1].fifoDepth == 0 and status[-1].consumed - before >= n

    wait_until(emptied, 5.0, what=f"a status with the FIFO empty and {n} consumed")
    assert status[-1].consumed - before == n
    targets = np.array([s.target[0] for s in status])
    assert np.all(np.diff(targets) >= -1e-12), "targets went backwards: commands out of order"
    assert abs(targets[-1] - path[-1, 0]) < 1e-12
    assert elapsed >= n * DT * 0.9  # one per cycle, not all at once
    assert abs(rig.joints()[0] - path[-1, 0]) < 2e-4


def test_underrun_stops_smoothly(rig: Rig):
    q0 = rig.joints()
    v = 0.6 * VMAX[0]  # [rad/s] cruise of J1
    t_acc = 0.3
    t = np.arange(0, 0.8, DT)
    x = np.where(t < t_acc, 0.5 * v / t_acc * t**2, 0.5 * v * t_acc + v * (t - t_acc))
    path = np.repeat(q0[None, :], len(t), axis=0)
    path[:, 0] += x
    rig.commands.stream(path)  # ends at full speed: the FIFO runs dry while moving
    rig.wait_rest()
    tm, fb = j1_of(*rig.recorded_timed())
    vel, acc = velocity_and_acceleration(tm, fb)
    assert np.nanmax(np.abs(vel)) <= v * 1.05
    braking = acc[int(np.nanargmax(vel)):]  # from full speed to rest
    assert np.nanmax(np.abs(braking)) < AMAX[0] * 1.5, np.nanmax(np.abs(braking))  # within the limits
    overshoot = fb[-1] - path[-1, 0]
    assert 0 < overshoot < v**2 / (2 * AMAX[0]) * 2.0, overshoot  # stopped along the way, no jump back
    assert rig.statuses.newest().underruns >= 1
    assert rig.state() == StateBit.SERVO_ON  # at rest, still on, no alarm


def test_emergency_stop(rig: Rig):
    # From the held target, not the measured joints (up to SETTLE_TOLERANCE off it): every acceleration of the
    # recording is checked, and run 110 saw a 1.1e-5 rad dip at the stream's start (a possible cause).
    q0 = rig.target()
    path = min_jerk(q0, q0 + np.array([0.8, 0, 0, 0, 0, 0, 0]), 1.5)
    start = rig.statuses.newest().consumed
    for q in path[:700]:
        rig.commands.send(q)
    rig.statuses.first(lambda st: st.consumed >= start + 400, "the arm 400 cycles into the move")
    t0 = time.monotonic()
    rig.session.put(rig.keys.estop, b"")
    wait_until(lambda: not rig.state() & StateBit.SERVO_ON, 1.0, 0.001, "servo off after e-stop")
    assert time.monotonic() - t0 < 0.1
    alarms = rig.servo(OP.getActiveAlarm)["alarms"]
    assert [(a.code, a.type) for a in alarms] == [(AlarmCode.EMERGENCY_STOP, AlarmType.FAULT)]
    assert rig.state() & StateBit.ALARM
    rig.wait_rest()
    tm, fb = j1_of(*rig.recorded_timed())
    _, acc = velocity_and_acceleration(tm, fb)
    peak = int(np.nanargmax(np.abs(acc)))
    assert abs(acc[peak]) < AMAX[0] * 1.5, (  # a controlled stop: no jump (1.02-1.04 x AMAX here)
        f"J1 accelerated {acc[peak]:.2f} rad/s^2 at sample {peak} of {len(acc)} "
        f"(J1 {fb[max(0, peak - 3):peak + 4]}, at {tm[max(0, peak - 3):peak + 4] - tm[0]} s)\n{rig.log_tail()}")
    assert fb[-1] < path[-1, 0] - 0.1  # stopped short of the target
    held = rig.joints()
    received = rig.statuses.newest().received
    for q in path[700:]:
        rig.commands.send(q)  # ignored: servo off
    rig.took(received + len(path[700:]), "the commands sent while off")
    assert np.abs(rig.joints() - held).max() < 1e-4
    refused = rig.servo(OP.servoON)
    assert refused.id == ReturnCode.STATUS_ERR and "clear" in refused.comment
    assert rig.servo(OP.clearAlarms).id == ReturnCode.OK
    assert rig.servo(OP.servoON).id == ReturnCode.OK
    assert rig.state() == StateBit.SERVO_ON


def test_servo_off_holds_and_ignores_commands(rig: Rig):
    """Nothing moves; the servo's log says once that it drops the stream and why, and once, when the servo
    is on again, how many it dropped."""
    assert rig.servo(OP.servoOFF).id == ReturnCode.OK
    assert rig.state() == 0
    held = rig.joints()
    received = rig.statuses.newest().received
    mark = len(rig.proc.lines)
    path = min_jerk(held, held + 0.3, 0.3)
    rig.commands.stream(path)
    rig.took(received + len(path), "the commands streamed while off")
    assert np.abs(rig.joints() - held).max() < 1e-4
    assert rig.state() == 0
    said = f"dropping the position commands of {rig.keys.pos_cmd}: the servo is off"
    rig.proc.wait_for_line(said, timeout=5, start=mark)
    assert sum(said in line for line in rig.proc.lines[mark:]) == 1, rig.log_tail()
    assert rig.servo(OP.servoON).id == ReturnCode.OK
    rig.proc.wait_for_line(f"dropped {len(path)} position command(s) of {rig.keys.pos_cmd} (the servo is off)",
                           timeout=5, start=mark)


def test_joint_soft_limit_is_the_last_line_of_defence(rig: Rig):
    q0 = rig.joints()
    limits = list(IIWA.hard_limits)
    limits[0] = type(limits[0])(upper=q0[0] + 0.1, lower=q0[0] - 0.1)
    assert rig.servo(OP.setSoftLimitJoint, {"softLimit": limits}).id == ReturnCode.OK
    assert rig.servo(OP.getSoftLimitJoint)["softLimit"][0] == limits[0]
    path = min_jerk(q0, q0 + np.array([0.3, 0, 0, 0, 0, 0, 0]), 0.6)
    received = rig.statuses.newest().received
    rig.commands.stream(path)
    rig.wait_rest()
    # Every command past the limit taken (dropped while the alarm stands) before the clear: one still in
    # transit after it would be refused again, a new alarm (a full suite, quiet, 2026-11-28: state 0x05).
    rig.took(received + len(path), "the streamed commands")
    alarms = rig.servo(OP.getActiveAlarm)["alarms"]
    assert [(a.code, a.type) for a in alarms] == [(AlarmCode.SOFT_LIMIT_JOINT, AlarmType.WARNING)]
    assert "J1" in alarms[0].description
    assert rig.state() == StateBit.SERVO_ON | StateBit.ALARM  # a WARNING keeps the servo on
    fb = rig.recorded()[:, 0]
    assert fb.max() <= limits[0].upper + 5e-3  # target clamped at the limit: physical overshoot only
    assert abs(fb[-1] - limits[0].upper) < 1e-3  # and it settles on the limit
    assert rig.servo(OP.clearAlarms).id == ReturnCode.OK  # the arm is inside: the cause has gone
    assert rig.state() == StateBit.SERVO_ON, (rig.servo(OP.getActiveAlarm)["alarms"], rig.log_tail())


def test_jump_is_refused_as_overspeed(rig: Rig):
    q0 = rig.joints()
    jump = q0.copy()
    jump[2] += VMAX[2] * DT * OVERSPEED_MARGIN * 3
    rig.commands.send(jump)
    wait_until(lambda: rig.state() & StateBit.ALARM, 2.0, what="overspeed alarm")
    alarms = rig.servo(OP.getActiveAlarm)["alarms"]
    assert [(a.code, a.type) for a in alarms] == [(AlarmCode.OVERSPEED, AlarmType.FAULT)]
    assert "J3" in alarms[0].description
    assert not rig.state() & StateBit.SERVO_ON
    assert np.abs(rig.joints() - q0).max() < 1e-4  # not applied


def test_set_soft_limit_refused_while_moving_and_checked(rig: Rig):
    q0 = rig.joints()
    hard = IIWA.hard_limits
    for q in min_jerk(q0, q0 + np.array([0.5, 0, 0, 0, 0, 0, 0]), 1.0):
        rig.commands.send(q)
    wait_until(lambda: rig.state() & StateBit.MOVING, 2.0, 0.005, "the arm moving")
    busy = rig.servo(OP.setSoftLimitJoint, {"softLimit": hard})
    assert busy.id == ReturnCode.STATUS_ERR and "moving" in busy.comment
    rig.wait_rest()
    LV = type(hard[0])
    cases = [
        (hard[:6], "softLimit", "7 entries"),
        ((LV(0.1, 0.2),) + hard[1:], "softLimit[0]", "below"),
        (hard[:3] + (LV(hard[3].upper + 0.1, 0.0),) + hard[4:], "softLimit[3]", "hard limits"),
    ]
    for limits, field, words in cases:
        r = rig.servo(OP.setSoftLimitJoint, {"softLimit": limits})
        assert r.id == ReturnCode.VALUE_ERR and r.comment.startswith(field) and words in r.comment, r
    assert rig.servo(OP.getSoftLimitJoint)["softLimit"] == hard  # nothing changed


@pytest.mark.parametrize("name", list(COMMON))
def test_bad_payloads_get_value_err_and_change_nothing(rig: Rig, name: str):
    key = rig.keys.servo_common(name)
    state = rig.state()
    for payload in (b"\xc1\xc1", msgpack.packb([1, 2]), msgpack.packb({"bogus": 1})):
        reply = rig.client.raw(key, payload)
        assert reply["id"] == ReturnCode.VALUE_ERR, (name, payload, reply)
        assert set(reply) == {"id", "comment"} and reply["comment"]
    bad_json = rig.client.raw(key, b'{"bogus": NaN', json=True)
    assert bad_json["id"] == ReturnCode.VALUE_ERR
    assert rig.state() == state and rig.proc.popen.poll() is None


def test_unknown_operation_and_json(rig: Rig):
    nope = rig.client.raw(rig.keys.servo_common() .replace("*", "getActivAlarm"), b"")
    assert nope["id"] == ReturnCode.NOT_IMPLEMENTED
    reply = rig.client.raw(rig.keys.servo_common(OP.getState), b"{}", json=True)
    assert reply == {"id": 0, "comment": "OK", "state": int(StateBit.SERVO_ON)}
    info = rig.client.raw(rig.keys.servo_common(OP.getManipInfo), b"", json=True)
    assert info["mInfo"]["manufactur"] == "KUKA"


def test_malformed_position_commands_are_dropped(rig: Rig):
    held = rig.joints()
    received = rig.statuses.newest().received
    rig.commands.put(b"\xc1")
    rig.commands.put(msgpack.packb({"tm": {"sec": 0, "nsec": 0}, "pos": [0.0] * 3}))  # wrong length
    rig.commands.put(msgpack.packb({"pos": list(held)}))  # no tm
    rig.took(received + 3, "the three malformed commands")
    assert rig.state() == StateBit.SERVO_ON
    assert np.abs(rig.joints() - held).max() < 1e-4


def test_plain_client_drives_the_servo(iiwa_rig: Rig):
    iiwa_rig.reset()
    port = int(iiwa_rig.proc.argv[iiwa_rig.proc.argv.index("--listen") + 1].rsplit(":", 1)[1])
    script = Path(__file__).with_name("plain_client.py")
    out = subprocess.run([sys.executable, str(script), str(port)], capture_output=True, text=True,
                         timeout=60)
    assert out.returncode == 0, out.stdout + out.stderr
    assert "PLAIN CLIENT OK" in out.stdout


def test_the_readme_plain_client_runs_as_it_is(iiwa_rig: Rig):
    """The README's plain-client snippet, with only the router's port changed: J1 moves 0.15 rad,
    the servo ends off, and no alarm is left."""
    iiwa_rig.reset()
    readme = (Path(__file__).parents[1] / "README.md").read_text()
    snippet = readme.split("<!-- plain client: run as it is by tests/test_servo.py -->\n```python\n", 1)[1]
    snippet = snippet.split("```", 1)[0]
    port = iiwa_rig.proc.argv[iiwa_rig.proc.argv.index("--listen") + 1].rsplit(":", 1)[1]
    assert snippet.count("tcp/127.0.0.1:7447") == 1
    snippet = snippet.replace("tcp/127.0.0.1:7447", f"tcp/127.0.0.1:{port}")
    # Real-time, as the README says to run it (beside busy loops, at normal priority, it once ran dry).
    chrt = shutil.which("chrt")
    assert chrt is not None, "chrt (util-linux) is needed to run the README's client as the README says"
    out = subprocess.run([chrt, "-f", str(STREAM_PRIORITY), sys.executable, "-c", snippet], capture_output=True,
                         text=True, timeout=60)
    assert out.returncode == 0, out.stdout + out.stderr
    assert out.stdout.splitlines() == ["{'id': 0, 'comment': 'OK'}", "0.15", "{'id': 0, 'comment': 'OK'}"], out.stdout
    assert iiwa_rig.state() == 0  # servo off, not moving, no alarm


@pytest.fixture(scope="module")
def panda_rig():
    yield from start_rig("panda")


def test_panda_gripper_is_one_axis(panda_rig: Rig):
    panda_rig.reset()
    info = panda_rig.servo(OP.getManipInfo)["mInfo"]
    assert info.axisNum == 7 and info.isGripper
    q0 = panda_rig.joints()
    assert len(q0) == 8 and abs(q0[7] - 0.04) < 1e-3  # starts open
    q1 = q0.copy()
    q1[7] = 0.01
    panda_rig.commands.stream(min_jerk(q0, q1, 0.6))
    panda_rig.wait_rest()
    assert abs(panda_rig.joints()[7] - 0.01) < 1e-3
    assert len(panda_rig.servo(OP.getSoftLimitJoint)["softLimit"]) == 7  # gripper excluded
