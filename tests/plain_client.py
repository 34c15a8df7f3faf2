"""A client that knows only Zenoh and MessagePack: what a user in any language writes.

    python tests/plain_client.py PORT

Drives the servo (servo on, a streamed 0.3 rad move of J1, servo off) and
exits 0 when the feedback shows the move; imports nothing from the project.
"""

import math
import sys
import time

import msgpack
import zenoh

PORT = int(sys.argv[1])
ARM = "arm0"
SERVO = f"JARA_ARM/{ARM}/Servo/Common/"


def call(session, op, request=None):
    replies = list(session.get(SERVO + op, payload=msgpack.packb(request or {}), timeout=10))
    assert len(replies) == 1 and replies[0].ok is not None, f"{op}: {replies}"
    reply = msgpack.unpackb(replies[0].ok.payload.to_bytes())
    assert reply["id"] == 0, f"{op}: {reply}"
    return reply


conf = zenoh.Config()
conf.insert_json5("mode", '"client"')
conf.insert_json5("connect/endpoints", f'["tcp/127.0.0.1:{PORT}"]')
conf.insert_json5("scouting/multicast/enabled", "false")
with zenoh.open(conf) as session:
    feedback = session.declare_subscriber(f"JARA_ARM/{ARM}/Servo/posFeedback",
                                          zenoh.handlers.RingChannel(1))
    info = call(session, "getManipInfo")["mInfo"]
    call(session, "servoON")
    q0 = call(session, "getFeedbackPosJoint")["pos"]
    assert len(q0) == info["axisNum"] + (1 if info["isGripper"] else 0)
    pub = session.declare_publisher(f"JARA_ARM/{ARM}/Servo/posCmd")
    n = 600  # 0.6 s at 1 kHz, smooth start and stop
    t0 = time.monotonic()
    for k in range(n):
        u = (1 - math.cos(math.pi * k / (n - 1))) / 2
        q = list(q0)
        q[0] += 0.3 * u
        now = time.time()
        pub.put(msgpack.packb({"tm": {"sec": int(now), "nsec": int(now % 1 * 1e9)}, "pos": q}))
        if k > 100:  # keep 100 commands ahead of the servo, then one per cycle
            time.sleep(max(0.0, t0 + (k - 100) * 1e-3 - time.monotonic()))
    deadline = time.monotonic() + 10.0
    while call(session, "getState")["state"] & 0x02:  # moving: commands left, or the arm not yet at rest
        assert time.monotonic() < deadline, "the arm did not come to rest"
        time.sleep(0.01)
    last = msgpack.unpackb(feedback.recv().payload.to_bytes())
    assert abs(last["pos"][0] - (q0[0] + 0.3)) < 1e-3, last
    assert call(session, "getState")["state"] & 0x01
    call(session, "servoOFF")
    print("PLAIN CLIENT OK", round(last["pos"][0] - q0[0], 5))
