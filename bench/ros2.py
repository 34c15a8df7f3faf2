"""The ROS 2 bridge's cost and stream: ``python bench/ros2.py [--seconds 10] [--robot iiwa]``.

Launches ``jara-arm up --ros2`` and measures, over ``--seconds`` each:

* at rest, then with the arm moving (PTPs of J1 back and forth): the bridge process's CPU (share of one
  core, ``/proc/<pid>/stat``) and ``joint_states`` as a plain Zenoh subscriber receives it: rate, and the
  gaps between samples (median, 99th percentile, max) [ms];
* with a slow ROS subscriber beside it (a second session whose callback takes 50 ms a sample, as a
  frozen GUI's would): the same stream of the first subscriber, and the servo's late cycles
  (``Servo/loopHealth``) against the quiet run.

Run it alone: a test run or another benchmark beside it changes the figures.
"""

from __future__ import annotations

import argparse
import os
import sys
import threading
import time
from pathlib import Path

import numpy as np
import zenoh
from rosbags.typesys import Stores, get_typestore

sys.path.insert(0, str(Path(__file__).resolve().parent))
from _system import launched_system  # noqa: E402
from cpu import _children, _cmdline, _ticks, _TICK, launchers  # noqa: E402

from jara_arm import robots  # noqa: E402
from jara_arm.client import Arm  # noqa: E402
from jara_arm.schema import codec  # noqa: E402
from jara_arm.schema.keys import ArmKeys  # noqa: E402
from jara_arm.schema.messages import LOOP_HEALTH  # noqa: E402

JAZZY = get_typestore(Stores.ROS2_JAZZY)


def key(topic: str, ros_type: str) -> str:
    pkg, kind, name = ros_type.split("/")
    return f"0/{topic}/{pkg}::{kind}::dds_::{name}_/{JAZZY.hash_rihs01(ros_type)}"


def bridge_pid() -> int:
    for root in launchers():
        for child in _children(root):
            if "ros2" in _cmdline(child):
                return child
    raise RuntimeError("no ros2 bridge process under the launcher")


class Stream:
    """Arrival times of one key's samples (the callback only appends)."""

    def __init__(self, session: zenoh.Session, k: str) -> None:
        self.times: list[float] = []
        self.sub = session.declare_subscriber(k, lambda s: self.times.append(time.monotonic()))

    def window(self, seconds: float) -> tuple[float, np.ndarray]:
        start = len(self.times)
        time.sleep(seconds)
        t = np.array(self.times[start:])
        return len(t) / seconds, np.diff(t) * 1e3


class LateCycles:
    """The servo's late cycles, summed from ``Servo/loopHealth``."""

    def __init__(self, session: zenoh.Session, keys: ArmKeys) -> None:
        self.cycles = self.late = 0
        self.sub = session.declare_subscriber(keys.servo_health, self._take)

    def _take(self, s: zenoh.Sample) -> None:
        h = codec.decode_message(LOOP_HEALTH, s.payload.to_bytes(), codec.Encoding.of(s.encoding))
        self.cycles += h.cycles
        self.late += h.lateCycles


def row(label: str, rate: float, gaps: np.ndarray, cpu: float, late: tuple[int, int]) -> str:
    p50, p99, mx = (np.percentile(gaps, 50), np.percentile(gaps, 99), gaps.max()) if len(gaps) else (0, 0, 0)
    return (f"{label:<28} {rate:6.1f} Hz  gaps {p50:5.1f} / {p99:5.1f} / {mx:6.1f} ms  bridge {cpu:5.3f} core  "
            f"servo late {late[1]} of {late[0]} cycles")


def main() -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--seconds", type=float, default=10.0)
    p.add_argument("--robot", default="iiwa")
    args = p.parse_args()
    model = robots.robot(args.robot)
    with launched_system(args.robot, extra=["--ros2"]) as port:
        conf = zenoh.Config()
        conf.insert_json5("mode", '"client"')
        conf.insert_json5("connect/endpoints", f'["tcp/127.0.0.1:{port}"]')
        conf.insert_json5("scouting/multicast/enabled", "false")
        with zenoh.open(conf) as session, Arm(session, "arm0") as arm:
            arm.wait_alive()
            arm.servoON()
            arm.setSpeedJoint(50)
            states = Stream(session, key("arm0/joint_states", "sensor_msgs/msg/JointState"))
            health = LateCycles(session, ArmKeys("arm0"))
            deadline = time.monotonic() + 30
            while not states.times and time.monotonic() < deadline:
                time.sleep(0.1)
            pid = bridge_pid()
            print(f"{args.robot}, bridge pid {pid}, {os.cpu_count()} cores; rate: joint_states a second; gaps: "
                  "median / p99 / max")

            def measured(label: str, drive: bool) -> None:
                stop = threading.Event()
                mover = None
                if drive:
                    def back_and_forth() -> None:
                        q0 = list(arm.getFeedbackPosJoint())[:model.axis_num]
                        k = 0
                        while not stop.is_set():
                            q = list(q0)
                            q[0] += 0.4 if k % 2 == 0 else 0.0
                            arm.movePTPJointAbs(q)
                            k += 1
                    mover = threading.Thread(target=back_and_forth, daemon=True)
                    mover.start()
                    time.sleep(0.5)
                t0, c0, l0 = _ticks(pid) or 0, health.cycles, health.late
                rate, gaps = states.window(args.seconds)
                cpu = ((_ticks(pid) or 0) - t0) / _TICK / args.seconds
                print(row(label, rate, gaps, cpu, (health.cycles - c0, health.late - l0)), flush=True)
                stop.set()
                if mover is not None:
                    mover.join(30)

            measured("at rest", False)
            measured("moving", True)
            # A session of its own: its blocked callback holds its link, as a frozen ROS tool's would.
            with zenoh.open(conf) as other:
                slow = other.declare_subscriber(key("arm0/joint_states", "sensor_msgs/msg/JointState"),
                                                lambda s: time.sleep(0.05))
                try:
                    measured("moving, a slow subscriber", True)
                finally:
                    slow.undeclare()
            states.sub.undeclare()
            health.sub.undeclare()
    return 0


if __name__ == "__main__":
    sys.exit(main())
