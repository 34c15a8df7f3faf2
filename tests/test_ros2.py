"""ROS 2 sees the arm (``jara-arm up --ros2``, ``launcher/ros2/``), checked with third-party readers.

Nothing here runs ROS 2. What a ROS 2 node on rmw_zenoh would do is done by hand, from rmw_zenoh's own
description of its wire (``docs/design.md``, ``liveliness_utils.cpp``), and every payload is decoded by
``rosbags`` (its Jazzy message definitions): a plain Zenoh subscriber on the exact data key, the liveliness
tokens read back chunk by chunk, a late subscriber of ``robot_description`` as rmw_zenoh's transient-local
subscription (a Zenoh advanced subscriber that detects late publishers).
"""

from __future__ import annotations

import os
import random
import signal
import struct
import time
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import numpy as np
import pytest
import xxhash
import zenoh
import zenoh.ext
from rosbags.typesys import Stores, get_typestore

from jara_arm import robots
from jara_arm.launcher.ros2 import rmw
from jara_arm.schema.codes import StateBit
from jara_arm.schema.keys import PREFIX, Service

from .harness import LiveArm, launched, listening
from .support import LAUNCHER, Proc, client_session, wait_until

JAZZY = get_typestore(Stores.ROS2_JAZZY)
JOINT_STATE = "sensor_msgs/msg/JointState"


def key_of(topic: str, ros_type: str) -> str:
    """The data key as design.md spells it, built here by hand (not by rmw.py)."""
    pkg, kind, name = ros_type.split("/")
    return f"0/{topic}/{pkg}::{kind}::dds_::{name}_/{JAZZY.hash_rihs01(ros_type)}"


# -- rmw.py, no system ----------------------------------------------------------------------------------
def test_the_data_key_is_rmw_zenohs() -> None:
    h = JAZZY.hash_rihs01(JOINT_STATE)
    assert h.startswith("RIHS01_a13e")  # the issue's example
    assert rmw.data_key(0, "/joint_states", JOINT_STATE, h) == f"0/joint_states/sensor_msgs::msg::dds_::JointState_/{h}"
    assert rmw.data_key(3, "/arm0/joint_states/", JOINT_STATE, h).startswith("3/arm0/joint_states/sensor_msgs")


def test_qos_text_leaves_rmw_zenohs_defaults_empty() -> None:
    assert rmw.QoS(depth=42).text() == "::,:,:,:,,"
    assert rmw.STREAM.text() == "::,10:,:,:,,"
    assert rmw.LATCHED.text() == ":1:,1:,:,:,,"
    assert rmw.QoS(rmw.Reliability.BEST_EFFORT, depth=5).text() == "2::,5:,:,:,,"


def test_the_attachment_is_seq_time_and_gid_in_33_bytes() -> None:
    gid = bytes(range(16))
    a = rmw.attachment(7, 1_700_000_000_123_456_789, gid)
    assert a == struct.pack("<qqB16s", 7, 1_700_000_000_123_456_789, 16, gid)


@pytest.mark.parametrize("seed", range(5))
def test_tokens_read_back_and_gids_are_xxh3_128_of_them(seed: int) -> None:
    rng = random.Random(seed)

    def word() -> str:
        return rng.choice("abcxyz_") + "".join(rng.choice("abc_xyz019") for _ in range(rng.randint(0, 8)))

    ns = "/" + "/".join(word() for _ in range(rng.randint(0, 2))) if rng.random() < 0.7 else "/"
    node = rmw.Node(rng.randint(0, 232), f"{rng.getrandbits(128):x}", rng.randint(0, 99), ns.rstrip("/") or "/",
                    word())
    t = rmw.parse_token(node.token())
    assert (t.entity, t.namespace, t.node, t.domain, t.zid) == (rmw.Entity.NODE, node.namespace, node.name,
                                                               node.domain, node.zid)
    topic = f"{node.namespace.rstrip('/')}/{word()}/{word()}"
    token = node.publisher_token(node.nid + 1, topic, JOINT_STATE, "RIHS01_" + "ab" * 32, rmw.LATCHED)
    p = rmw.parse_token(token)
    assert (p.entity, p.topic, p.type, p.qos[1]) == (rmw.Entity.PUBLISHER, topic, "sensor_msgs::msg::dds_::JointState_",
                                                    "1")
    assert "//" not in token and token.count("/") == 12
    canonical = xxhash.xxh3_128(token.encode()).digest()  # big-endian: high 64 bits, then low
    assert rmw.gid(token) == canonical[8:][::-1] + canonical[:8][::-1]


def test_bad_names_and_domains_are_refused_saying_why() -> None:
    for bad in ("/1arm", "/arm-0", "/arm//x", "/ä"):
        with pytest.raises(rmw.Rmw2Error, match="ROS 2 names"):
            rmw.check_name(bad, "namespace")
    with pytest.raises(rmw.Rmw2Error, match="0 .. 232"):
        rmw.check_domain(233)
    with pytest.raises(rmw.Rmw2Error, match="13 chunks"):
        rmw.parse_token("@ros2_lv/0/abc/1/2/MP/%/%/node/topic")


# -- the live system --------------------------------------------------------------------------------
@pytest.fixture(scope="module")
def system() -> Iterator[tuple[LiveArm, zenoh.Session]]:
    with launched("--robot", "iiwa", "--ros2") as (proc, port), client_session(port) as session:
        arm = LiveArm(session, "iiwa", proc=proc)
        arm.client.wait_alive((Service.SERVO, Service.PLANNER, Service.COMMAND))
        yield arm, session


@pytest.fixture
def arm(system: tuple[LiveArm, zenoh.Session]) -> LiveArm:
    system[0].reset()
    return system[0]


class Collected:
    """Every sample of one key: (receipt time [s], payload, attachment), in a FIFO (the callback only stores)."""

    def __init__(self, session: zenoh.Session, key: str) -> None:
        self.sub = session.declare_subscriber(key, zenoh.handlers.FifoChannel(100_000))

    def take(self) -> list[tuple[float, bytes, bytes]]:
        out = []
        while (s := self.sub.try_recv()) is not None:
            out.append((time.time(), s.payload.to_bytes(), s.attachment.to_bytes() if s.attachment else b""))
        return out

    def close(self) -> None:
        self.sub.undeclare()


def test_live_joint_states_on_the_exact_key_follow_a_ptp(arm: LiveArm,
                                                         system: tuple[LiveArm, zenoh.Session]) -> None:
    session = system[1]
    model = robots.robot("iiwa")
    states = Collected(session, key_of("arm0/joint_states", JOINT_STATE))
    try:
        wait_until(lambda: bool(states.sub.try_recv()), 30.0, what="a joint_states sample")
        states.take()
        t0 = time.time()
        time.sleep(1.0)
        steady = states.take()
        # 100 Hz asked: a rate figure, printed; the bound says it is a stream, not how steady.
        rate = len(steady) / (time.time() - t0)
        assert rate > 50.0, f"{rate:.1f} joint_states a second"
        q0 = arm.joints()
        target = q0.copy()
        target[0] += 0.3
        arm.client.movePTPJointAbs(list(target[:model.axis_num]))
        arm.wait_rest()
        time.sleep(0.1)
        moving = states.take()
    finally:
        states.close()
    first = JAZZY.deserialize_cdr(steady[0][1], JOINT_STATE)
    assert list(first.name) == list(model.arm_joints)
    js = [JAZZY.deserialize_cdr(p, JOINT_STATE) for _, p, _ in moving]
    j1 = np.array([m.position[0] for m in js])
    assert abs(j1[0] - q0[0]) < 1e-3 and abs(j1[-1] - target[0]) < 1e-3, (j1[0], j1[-1])
    assert np.all(np.diff(j1) > -1e-4), "J1 went back while a PTP drove it one way"
    assert max(float(np.max(np.abs(m.velocity[:1]))) for m in js) > 0.05  # velocities too, not zeros
    stamps = [m.header.stamp.sec + m.header.stamp.nanosec * 1e-9 for m in js]
    assert abs(stamps[-1] - time.time()) < 5.0  # the servo's clock: wall time
    # Attachments: sequence +1 each, source time now, one GID throughout.
    att = [struct.unpack("<qqB16s", a) for _, _, a in steady + moving]
    assert all(len(a) == 33 for _, _, a in steady + moving)
    seqs = [a[0] for a in att]
    assert seqs == list(range(seqs[0], seqs[0] + len(seqs))), "lost or reordered on loopback"
    assert all(a[2] == 16 for a in att) and len({a[3] for a in att}) == 1
    assert abs(att[-1][1] * 1e-9 - moving[-1][0]) < 1.0
    print(f"joint_states: {rate:.1f} Hz (100 asked), {len(moving)} samples along the PTP")


def tokens(session: zenoh.Session) -> list[str]:
    return [str(r.ok.key_expr) for r in session.liveliness().get("@ros2_lv/0/**", timeout=5.0) if r.ok is not None]


def test_live_the_liveliness_tokens_are_rmw_zenohs(arm: LiveArm, system: tuple[LiveArm, zenoh.Session]) -> None:
    session = system[1]
    found: list[str] = []

    def all_five() -> bool:
        found[:] = tokens(session)
        return len(found) >= 5

    wait_until(all_five, 30.0, what="the bridge's five tokens")
    chunks = [k.split("/") for k in found]
    nodes = [c for c in chunks if c[5] == "NN"]
    pubs = [c for c in chunks if c[5] == "MP"]
    assert len(nodes) == 1 and len(nodes[0]) == 9, found
    zid, nid = nodes[0][2], nodes[0][3]
    assert nodes[0][4] == nid and nodes[0][6:] == ["%", "%arm0", "jara_arm"], found
    want = {"%arm0%joint_states": ("sensor_msgs::msg::dds_::JointState_", JOINT_STATE, "::,10:,:,:,,"),
            "%arm0%tf": ("tf2_msgs::msg::dds_::TFMessage_", "tf2_msgs/msg/TFMessage", "::,10:,:,:,,"),
            "%arm0%robot_description": ("std_msgs::msg::dds_::String_", "std_msgs/msg/String", ":1:,1:,:,:,,"),
            "%arm0%jara_arm%state": ("diagnostic_msgs::msg::dds_::DiagnosticStatus_",
                                     "diagnostic_msgs/msg/DiagnosticStatus", "::,10:,:,:,,")}
    assert sorted(c[9] for c in pubs) == sorted(want), found
    for c in pubs:
        assert len(c) == 13 and c[:4] == ["@ros2_lv", "0", zid, nid] and c[6:9] == ["%", "%arm0", "jara_arm"], c
        dds, ros_type, qos = want[c[9]]
        assert c[10:] == [dds, JAZZY.hash_rihs01(ros_type), qos], c
        assert rmw.parse_token("/".join(c)).entity is rmw.Entity.PUBLISHER
    assert len({c[4] for c in pubs + nodes}) == 5, "entity ids must be unique in the session"
    # The GID in the samples is the XXH3-128 of the publisher's token.
    states = Collected(session, key_of("arm0/joint_states", JOINT_STATE))
    samples: list[tuple[float, bytes, bytes]] = []
    try:
        wait_until(lambda: bool(samples.extend(states.take()) or samples), 10.0, what="joint_states")
    finally:
        states.close()
    sample = samples[-1]
    token = "/".join(next(c for c in pubs if c[9] == "%arm0%joint_states"))
    canonical = xxhash.xxh3_128(token.encode()).digest()
    assert struct.unpack("<qqB16s", sample[2])[3] == canonical[8:][::-1] + canonical[:8][::-1]


def test_live_robot_description_reaches_a_subscriber_that_joins_late(
        arm: LiveArm, system: tuple[LiveArm, zenoh.Session]) -> None:
    session = system[1]
    key = key_of("arm0/robot_description", "std_msgs/msg/String")
    got: list[Any] = []
    sub = zenoh.ext.declare_advanced_subscriber(session, key, zenoh.handlers.FifoChannel(16),
                                                history=zenoh.ext.HistoryConfig(detect_late_publishers=True))
    try:
        def received() -> bool:
            s = sub.try_recv()
            if s is not None:
                got.append(s)
            return bool(got)

        wait_until(received, 10.0, what="robot_description from the publisher's cache")
    finally:
        sub.undeclare()
    urdf = JAZZY.deserialize_cdr(got[0].payload.to_bytes(), "std_msgs/msg/String").data
    assert urdf == robots.robot("iiwa").urdf.read_text()


def test_live_tf_and_state_say_where_the_links_are_and_what_the_arm_does(
        arm: LiveArm, system: tuple[LiveArm, zenoh.Session]) -> None:
    session = system[1]
    tf = Collected(session, key_of("arm0/tf", "tf2_msgs/msg/TFMessage"))
    state = Collected(session, key_of("arm0/jara_arm/state", "diagnostic_msgs/msg/DiagnosticStatus"))
    try:
        wait_until(lambda: bool(tf.sub.try_recv()), 10.0, what="tf")
        time.sleep(0.05)
        last = JAZZY.deserialize_cdr(tf.take()[-1][1], "tf2_msgs/msg/TFMessage")
        # The flange link's pose in the root link is the arm's forward kinematics.
        model = robots.robot("iiwa")
        flange = next(t for t in last.transforms if t.child_frame_id == model.flange_frame)
        p = flange.transform.translation
        assert np.allclose([p.x, p.y, p.z], arm.fk(arm.joints())[:3, 3], atol=1e-3)
        assert flange.header.frame_id == "lbr_iiwa_link_0"
        wait_until(lambda: bool(state.take()), 10.0, what="jara_arm/state")
        arm.session.put(arm.keys.estop, b"")
        wait_until(lambda: arm.state() & StateBit.ALARM, 10.0, what="the e-stop alarm")

        def fault_said() -> bool:
            said = [JAZZY.deserialize_cdr(p, "diagnostic_msgs/msg/DiagnosticStatus") for _, p, _ in state.take()]
            return any(s.level == 2 and "0x01" in {v.key for v in s.values} for s in said)

        wait_until(fault_said, 10.0, what="jara_arm/state at ERROR naming 0x01")
    finally:
        tf.close()
        state.close()


def test_live_record_ros2_writes_a_bag_whose_messages_match_the_live_ones(
        arm: LiveArm, system: tuple[LiveArm, zenoh.Session], tmp_path: Path) -> None:
    from mcap.reader import make_reader
    from rosbags.highlevel import AnyReader

    session = system[1]
    live = Collected(session, key_of("arm0/joint_states", JOINT_STATE))
    out = tmp_path / "run.mcap"
    record = Proc([*LAUNCHER, "record", "--arm", "arm0", "-o", str(out), "--ros2", "--duration", "4",
                   "--connect", listening(arm.proc)])
    try:
        record.wait_for_line("recording", timeout=60)
        time.sleep(0.5)
        q = arm.joints()
        q[1] += 0.2
        arm.client.movePTPJointAbs(list(q[:arm.model.axis_num]))
        arm.wait_rest()
        assert record.popen.wait(60) == 0, record.output
    finally:
        record.stop()
        samples = live.take()
        live.close()
    bag = tmp_path / "run_ros2"
    assert (bag / "metadata.yaml").is_file() and "ROS 2 bag of" in record.output, record.output
    with open(next(bag.glob("*.mcap")), "rb") as f:
        summary = make_reader(f).get_summary()
    assert summary is not None
    assert {s.encoding for s in summary.schemas.values()} == {"ros2msg"}
    assert {c.message_encoding for c in summary.channels.values()} == {"cdr"}
    with AnyReader([bag], default_typestore=JAZZY) as reader:
        topics = {c.topic: c.msgtype for c in reader.connections}
        assert topics == {"/arm0/joint_states": JOINT_STATE, "/arm0/tf": "tf2_msgs/msg/TFMessage",
                          "/arm0/robot_description": "std_msgs/msg/String",
                          "/arm0/jara_arm/state": "diagnostic_msgs/msg/DiagnosticStatus"}, topics
        recorded = {}
        for conn, _, raw in reader.messages([c for c in reader.connections if c.topic == "/arm0/joint_states"]):
            m = reader.deserialize(raw, conn.msgtype)
            recorded[(m.header.stamp.sec, m.header.stamp.nanosec)] = np.array(m.position)
        urdf = [reader.deserialize(raw, c.msgtype).data for c, _, raw in
                reader.messages([c for c in reader.connections if c.topic == "/arm0/robot_description"])]
    assert urdf == [robots.robot("iiwa").urdf.read_text()]
    seen = {}
    for _, payload, _ in samples:
        m = JAZZY.deserialize_cdr(payload, JOINT_STATE)
        seen[(m.header.stamp.sec, m.header.stamp.nanosec)] = np.array(m.position)
    both = set(recorded) & set(seen)
    # The same servo statuses, both ways: the bridge publishes the newest at 100 Hz, the bag each one. How many
    # depends on how long the move takes (100 statuses a second moving, 10 at rest): beside busy loops the bag
    # held 84 and 48 of them were also live; the shared ones must span the move, not only the rest.
    assert len(both) > 0.5 * min(len(recorded), len(seen)) and len(both) >= 20, (len(recorded), len(seen), len(both))
    assert all(np.array_equal(recorded[k], seen[k]) for k in both)
    shared = [recorded[k][1] for k in both]
    assert max(shared) - min(shared) > 0.1, "the bag and the live stream share no status of the move"
    moved = [recorded[k][1] for k in sorted(recorded)]
    assert max(moved) - min(moved) > 0.19, "the PTP is in the bag"
    print(f"ROS 2 bag: {len(recorded)} joint_states, {len(both)} of them also live")


def test_live_in_a_secure_cell_the_bridge_is_an_observer_and_a_ros_node_reads_it(tmp_path: Path) -> None:
    """``up --secure DIR --ros2 --ros-identity rosbridge``: the bridge joins with an observer's certificate; an
    observer (a ROS 2 machine with the cell's certificate) gets joint_states and sees the tokens; it still
    cannot move the arm."""
    import json

    from jara_arm.launcher.secure.certs import init_cell, issue
    from jara_arm.schema.roles import Role

    cell = init_cell(tmp_path / "cell")
    issue(cell, "rosbridge", Role.OBSERVER)
    issue(cell, "rosnode", Role.OBSERVER)
    with launched("--robot", "iiwa", "--secure", str(cell.root), "--ros2", "--ros-identity", "rosbridge",
                  scheme="tls") as (proc, _):
        conf = zenoh.Config.from_file(str(cell.zenoh_file("rosnode")))
        conf.insert_json5("connect/endpoints", json.dumps([listening(proc)]))
        with zenoh.open(conf) as session:
            states = Collected(session, key_of("arm0/joint_states", JOINT_STATE))
            try:
                got: list[tuple[float, bytes, bytes]] = []
                wait_until(lambda: bool(got.extend(states.take()) or got), 30.0, what="joint_states in a secure cell")
            finally:
                states.close()
            names = JAZZY.deserialize_cdr(got[-1][1], JOINT_STATE).name
            assert list(names) == list(robots.robot("iiwa").arm_joints)
            found: list[str] = []

            def five_tokens() -> bool:
                found[:] = tokens(session)
                return len(found) >= 5

            wait_until(five_tokens, 30.0, what="the bridge's tokens")
            assert any("/MP/" in k and "%arm0%joint_states" in k for k in found), found
        # Nothing of ROS 2 the bridge or the ROS node did was refused. (Zenoh logs every kind a role may not do
        # on a key it first meets, tried or not: lines about JARA_ARM keys the bridge only reads are that, and
        # about the bare prefix "JARA_ARM", seen once beside two busy loops. The gateway's egress lines to
        # "peer ?", its link to the bus, come with or without ROS 2.)
        ros = [line for line in proc.lines if ("rosbridge may not" in line or "rosnode may not" in line)
               and f" on {PREFIX}/" not in line and not line.endswith(f" on {PREFIX}")]
        assert not ros, "\n".join(ros)


def test_live_joint_states_stop_while_no_servo_is_heard(arm: LiveArm, system: tuple[LiveArm, zenoh.Session]) -> None:
    """The servo stopped (SIGSTOP) for 1 s: joint_states stop within 0.5 s (``bridge.STALE``) instead of repeating
    a pose nobody measures, and come back with the servo."""
    session = system[1]
    states = Collected(session, key_of("arm0/joint_states", JOINT_STATE))
    try:
        wait_until(lambda: bool(states.take()), 10.0, what="joint_states")
        servo = arm.pid(Service.SERVO)
        os.kill(servo, signal.SIGSTOP)
        frozen = time.time()
        try:
            time.sleep(1.0)
        finally:
            # Taken before the servo runs again: at its real-time priority it preempts this process at once, and a
            # joint_states it caused could carry a time before one taken after (failed once beside busy loops).
            resumed = time.time()
            os.kill(servo, signal.SIGCONT)
        wait_until(lambda: bool(states.take()), 10.0, what="joint_states again")
        time.sleep(0.2)
        got = states.take()
    finally:
        states.close()
    # When the bridge published each: the attachment's source time (the receipt times of a FIFO drained late say
    # nothing).
    sent = [struct.unpack("<qqB16s", a)[1] * 1e-9 for _, _, a in got]
    during = [t for t in sent if frozen + 0.7 < t < resumed]
    assert not during, f"{len(during)} joint_states published while the servo was stopped"
    assert any(t > resumed for t in sent), "no joint_states after the servo came back"
    arm.reset()  # a 1 s stall is logged, not a FAULT (hung at 1.5 s); reset clears whatever it left
