"""What a secure cell costs: CPU per process of ``jara-arm up`` open and ``--secure``, the arm moving.

    python bench/secure_cost.py [--seconds 30]

Runs the same system twice, one after the other: open (TCP), then secure (mutual
TLS, the roles enforced by the router's access control, its refusal log
filtering Zenoh's trace). In each, an operator drives the arm back and forth
between two joint poses at 100 % (the next motion queued while one runs) and
the CPU of every process is measured over the window (``bench/cpu.py``).
"""

from __future__ import annotations

import argparse
import json
import sys
import tempfile
import threading
import time
from pathlib import Path

import zenoh

sys.path.insert(0, str(Path(__file__).parent))
import cpu  # noqa: E402
from _system import launched_system  # noqa: E402

from jara_arm.launcher.secure.certs import init_cell, issue  # noqa: E402
from jara_arm.client import Arm  # noqa: E402
from jara_arm.robots import robot  # noqa: E402
from jara_arm.schema.operations import OP, Interface  # noqa: E402
from jara_arm.schema.roles import Role  # noqa: E402
from jara_arm.services.runtime.zenoh_args import zenoh_config  # noqa: E402

MODEL = robot("iiwa")


def drive(session: zenoh.Session, stop: threading.Event) -> int:
    """PTP back and forth, one motion queued ahead; returns the motions sent."""
    arm = Arm(session)
    assert arm.call(Interface.COMMON, OP.servoON).ok
    assert arm.call(Interface.MIDDLE, OP.setSpeedJoint, {"spdRatio": 100}).ok
    a, b = list(MODEL.ready_pose), list(MODEL.ready_pose)
    b[0] += 0.8
    sent = 0
    while not stop.is_set():
        if arm.state & 0x02 and sent:  # moving: keep one queued, no more
            time.sleep(0.05)
            continue
        for target in (b, a):
            assert arm.call(Interface.MIDDLE, OP.movePTPJointAbs, {"jointPoints": target}).ok
            sent += 1
    arm.close()
    return sent


def run(label: str, seconds: float, secure: Path | None) -> dict[str, float]:
    with launched_system(secure=str(secure) if secure else None) as port:
        if secure:
            conf = zenoh.Config.from_file(str(secure / "alice.json5"))
            conf.insert_json5("connect/endpoints", json.dumps([f"tls/127.0.0.1:{port}"]))
        else:
            conf = zenoh_config("client", connect=[f"tcp/127.0.0.1:{port}"])
        with zenoh.open(conf) as session:
            stop = threading.Event()
            motions: list[int] = []
            driver = threading.Thread(target=lambda: motions.append(drive(session, stop)))
            driver.start()
            time.sleep(2.0)  # past the start-up
            shares = cpu.measure(cpu.launchers(), seconds)
            stop.set()
            driver.join()
    print(f"== {label}: {motions[0]} motions\n{cpu.table(shares)}", flush=True)
    return shares


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--seconds", type=float, default=30.0, help="measuring window per system [s]")
    args = p.parse_args()
    with tempfile.TemporaryDirectory() as tmp:
        cell = init_cell(Path(tmp) / "cell")
        issue(cell, "alice", Role.OPERATOR)
        open_ = run("open (tcp)", args.seconds, None)
        secure = run("secure (mutual TLS, roles, refusal log)", args.seconds, cell.root)
    for name in sorted(set(open_) | set(secure)):
        print(f"{name:<28} {open_.get(name, 0.0):6.3f} -> {secure.get(name, 0.0):6.3f}")
    print(f"{'total':<28} {sum(open_.values()):6.3f} -> {sum(secure.values()):6.3f}")


if __name__ == "__main__":
    main()
